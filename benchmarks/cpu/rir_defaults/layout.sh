#!/bin/bash
# The sweep-like layout scripts/rir_spatial_table.py and rir_level_distance.py read:
# T/<scene>/<setting>/seed<k>/scene.ckpt (a link) and status.json; a run of runs/def6 only once it is done
T=runs/def6/table; mkdir -p $T
link() {  # scene setting seed checkpoint
  local d=$T/$1/$2/seed$3 done=${4%.ckpt}.done
  case $4 in runs/def6/*) [ -e $done ] || { echo "not done: $4"; return; };; esac
  mkdir -p $d && ln -sfn $(realpath $4) $d/scene.ckpt && echo '{"status": "trained"}' > $d/status.json
}
for N in 0 1 2; do
  for S in rect_small rect_large; do link $S avgs $N runs/def6/$S.av.s$N.ckpt; link $S no-context $N runs/def6/$S.nc.s$N.ckpt; done
done
for S in l_room three_rooms u_room; do
  link $S avgs 0 runs/sched/$S.avdef.ckpt; link $S no-context 0 runs/sched/$S.nc3000.ckpt
  for N in 1 2; do link $S avgs $N runs/def6/$S.av.s$N.ckpt; link $S no-context $N runs/def6/$S.nc.s$N.ckpt; done
done
link two_rooms avgs 0 runs/sched/two_rooms.av3000.ckpt; link two_rooms no-context 0 runs/sched/two_rooms.nc3000.ckpt
for N in 1 2; do link two_rooms avgs $N runs/sched/two_rooms.av3000.s$N.ckpt; link two_rooms no-context $N runs/def6/two_rooms.nc.s$N.ckpt; done
