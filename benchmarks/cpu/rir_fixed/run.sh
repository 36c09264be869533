#!/bin/bash
# The whole rerun of docs/results.md "three_rooms on the fixed truth": the scene, stage 1, six runs two at a time, the table
set -e
A=.venv/bin/avgs; mkdir -p runs/fix3
[ -d data/rir/three_rooms_fixed ] || $A synth data/rir --task rir --preset three_rooms --scene-id three_rooms_fixed --seed 0
[ -e runs/fix3/three_rooms.ckpt.stage1.pt ] || OMP_NUM_THREADS=1 $A train data/rir/three_rooms_fixed --task rir --stage1-only --seed 0 --no-progress --out runs/fix3/three_rooms.ckpt
for N in 0 1 2; do
  bash benchmarks/cpu/rir_fixed/one.sh three_rooms_fixed av $N & bash benchmarks/cpu/rir_fixed/one.sh three_rooms_fixed nc $N & wait
done
bash benchmarks/cpu/rir_fixed/layout.sh
$A eval --task rir data/rir --scene three_rooms_fixed --methods nearest,linear --split both --out runs/fix3/table/baselines.json
.venv/bin/python scripts/rir_spatial_table.py data/rir runs/fix3/table --times > benchmarks/cpu/rir_fixed/table.md
for K in 0 1 2; do  # level against distance and behind a wall, each seed
  out=runs/fix3/level/three_rooms_fixed-s$K; mkdir -p runs/fix3/level
  OMP_NUM_THREADS=1 .venv/bin/python scripts/rir_level_distance.py --distance-scene data/rir/three_rooms_fixed --wall-scene data/rir/three_rooms_fixed \
    --runs runs/fix3/table --settings avgs no-context --seed $K --figure $out.png --table $out.md
done
