#!/bin/bash
# The sweep-like layout scripts/rir_spatial_table.py and rir_level_distance.py read (runs/fix3/table/<scene>/<setting>/seed<k>/):
# each run of one.sh once it is done, and the same checkpoint without the lag behind a wall (blocked_lag 0), "<setting>-no-lag"
T=runs/fix3/table
for S in three_rooms_fixed two_rooms u_room l_room; do for N in 0 1 2; do for K in av nc; do
  ckpt=runs/fix3/$S.$K.s$N.ckpt; [ -e runs/fix3/$S.$K.s$N.done ] || { echo "not done: $ckpt"; continue; }
  name=avgs; [ $K = nc ] && name=no-context
  d=$T/$S/$name/seed$N; mkdir -p $d && ln -sfn $(realpath $ckpt) $d/scene.ckpt && echo '{"status": "trained"}' > $d/status.json
  d=$T/$S/$name-no-lag/seed$N; mkdir -p $d; echo '{"status": "trained"}' > $d/status.json
  [ -e $d/scene.ckpt ] || .venv/bin/python -c "
import sys; from avgs.io.checkpoint import load_checkpoint, save_checkpoint
c = load_checkpoint(sys.argv[1]); c['binauralizer']['blocked_lag'].zero_(); save_checkpoint(c, sys.argv[2])" $ckpt $d/scene.ckpt
  cp $ckpt.log.jsonl $d/scene.ckpt.log.jsonl
done; done; done
