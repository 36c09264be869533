#!/bin/bash
# Everything of docs/results.md "three_rooms on the fixed truth" and "two_rooms, u_room and l_room with the lag":
# the scenes, stage 1 once per scene, six runs per scene two at a time (more.sh), the tables and the level reports
set -e
A=.venv/bin/avgs; mkdir -p runs/fix3/level
[ -d data/rir/three_rooms_fixed ] || $A synth data/rir --task rir --preset three_rooms --scene-id three_rooms_fixed --seed 0
for P in two_rooms u_room l_room; do [ -d data/rir/$P ] || $A synth data/rir --task rir --preset $P --scene-id $P --seed 0; done
bash benchmarks/cpu/rir_fixed/more.sh
bash benchmarks/cpu/rir_fixed/layout.sh
$A eval --task rir data/rir --scene three_rooms_fixed --scene two_rooms --scene u_room --scene l_room --methods nearest,linear \
  --split both --out runs/fix3/table/baselines.json
cp runs/fix3/table/baselines.json benchmarks/cpu/rir_fixed/baselines.json
.venv/bin/python scripts/rir_spatial_table.py data/rir runs/fix3/table --times > benchmarks/cpu/rir_fixed/table.md
.venv/bin/python scripts/rir_scene_table.py runs/fix3/table > benchmarks/cpu/rir_fixed/scene_table.md
bash benchmarks/cpu/rir_fixed/collect.sh
.venv/bin/python benchmarks/cpu/rir_fixed/overall.py > benchmarks/cpu/rir_fixed/overall.md
for K in 0 1 2; do  # level against distance and behind a wall, each seed
  out=runs/fix3/level/three_rooms_fixed-s$K
  OMP_NUM_THREADS=1 .venv/bin/python scripts/rir_level_distance.py --distance-scene data/rir/three_rooms_fixed --wall-scene data/rir/three_rooms_fixed \
    --runs runs/fix3/table --settings avgs no-context --seed $K --figure $out.png --table $out.md
  cp $out.md benchmarks/cpu/rir_fixed/level/
done
