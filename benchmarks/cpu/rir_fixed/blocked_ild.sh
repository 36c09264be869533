#!/bin/bash
# The early ILD's factor behind a wall (RIRConfig.blocked_ild) given to the defaults' checkpoints of this folder's runs
# (scripts/rir_refit.py --blocked-ild-only: fitted with each checkpoint's own B, nothing else changed), laid out as
# "<setting>-ild" beside them for scripts/rir_spatial_table.py, then the table again (table_ild.md).
T=runs/fix3/table; export OMP_NUM_THREADS=1
for S in three_rooms_fixed two_rooms u_room l_room; do for N in 0 1 2; do for K in av nc; do
  name=avgs; [ $K = nc ] && name=no-context
  d=$T/$S/$name-ild/seed$N; mkdir -p $d; echo '{"status": "trained"}' > $d/status.json
  [ -e $d/scene.ckpt ] || .venv/bin/python scripts/rir_refit.py data/rir/$S runs/fix3/$S.$K.s$N.ckpt $d/scene.ckpt --blocked-ild-only
  cp runs/fix3/$S.$K.s$N.ckpt.log.jsonl $d/scene.ckpt.log.jsonl
done; done; done
.venv/bin/python scripts/rir_spatial_table.py data/rir runs/fix3/table --times > benchmarks/cpu/rir_fixed/table_ild.md
