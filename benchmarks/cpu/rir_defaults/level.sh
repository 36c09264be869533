#!/bin/bash
# level.sh SEED PAIR... : scripts/rir_level_distance.py on runs/def6/table, PAIR = distance_scene:wall_scene
export OMP_NUM_THREADS=1; K=$1; shift
for P in "$@"; do D=${P%%:*}; W=${P##*:}
  out=runs/def6/level/$D-$W-s$K
  [ -e $out.md ] || .venv/bin/python scripts/rir_level_distance.py --distance-scene data/rir/$D --wall-scene data/rir/$W \
    --runs runs/def6/table --settings avgs no-context --seed $K --figure $out.png --table $out.md > $out.out 2>&1
done
