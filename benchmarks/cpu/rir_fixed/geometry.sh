#!/bin/bash
# The straight path's tests fitted again on each checkpoint's own final points (the walls' reflections, the lag and the
# early ILD's factor after them: what `avgs train` now does at its end, ImpulseResponseTraining.refit_geometry), given
# to the "-ild" checkpoints of blocked_ild.sh with scripts/rir_refit.py --geometry-only and laid out as "<setting>-geo"
# beside them for scripts/rir_spatial_table.py, then the table again (table_geo.md).
T=runs/fix3/table; export OMP_NUM_THREADS=1
for S in three_rooms_fixed two_rooms u_room l_room; do for N in 0 1 2; do for K in avgs no-context; do
  d=$T/$S/$K-geo/seed$N; mkdir -p $d; echo '{"status": "trained"}' > $d/status.json
  [ -e $d/scene.ckpt ] || .venv/bin/python scripts/rir_refit.py data/rir/$S $T/$S/$K-ild/seed$N/scene.ckpt $d/scene.ckpt --geometry-only
  cp $T/$S/$K-ild/seed$N/scene.ckpt.log.jsonl $d/scene.ckpt.log.jsonl
done; done; done
.venv/bin/python scripts/rir_spatial_table.py data/rir runs/fix3/table --times > benchmarks/cpu/rir_fixed/table_geo.md
