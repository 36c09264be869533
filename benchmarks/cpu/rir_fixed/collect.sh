#!/bin/bash
# Each run's scores (spatial.json, after scripts/rir_spatial_table.py scored it) and training log into runs/ here,
# named <preset>-<setting>-seed<k> (three_rooms_fixed as three_rooms)
B=benchmarks/cpu/rir_fixed; mkdir -p $B/runs
for d in runs/fix3/table/*/*/seed*; do
  [ -e $d/spatial.json ] || continue
  S=$(basename $(dirname $(dirname $d))); K=$(basename $(dirname $d)); N=$(basename $d)
  P=${S%_fixed}; cp $d/spatial.json $B/runs/$P-$K-$N.spatial.json
  case $K in *-no-lag|*-ild|*-geo) ;; *) cp $(realpath $d/scene.ckpt).log.jsonl $B/runs/$P-$K-$N.log.jsonl;; esac
done
