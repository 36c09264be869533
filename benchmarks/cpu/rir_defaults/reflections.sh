#!/usr/bin/env bash
# The defaults table's 36 checkpoints with the walls' first reflections in the early ILD, without training
# again (the fits are render-time: scripts/rir_refit.py), laid out as a sweep in OUT and scored.
#   bash benchmarks/cpu/rir_defaults/reflections.sh TABLE OUT [--local]
# TABLE: the sweep of layout.sh (<scene>/<setting>/seed<k>/scene.ckpt with its spatial.json);
# --local: the ILD's local correction too (RIRConfig.ild_local, off by default).
# "before" (the direct sound left to B) is kept from TABLE's cache; every checkpoint is scored anew.
set -euo pipefail
TABLE=$1 OUT=$2 FLAGS=${3:-}
PY=${PY:-.venv/bin/python}
mkdir -p "$OUT"
cp "$TABLE/baselines.json" "$OUT/"
one() {
  rel=${1#"$TABLE"/}; dst=$OUT/$rel; scene=${rel%%/*}
  mkdir -p "$dst"
  [ -f "$dst/scene.ckpt" ] || OMP_NUM_THREADS=1 $PY scripts/rir_refit.py "data/rir/$scene" "$1/scene.ckpt" "$dst/scene.ckpt" $FLAGS > "$dst/refit.out"
  [ -e "$dst/scene.before.ckpt" ] || ln -s "$(readlink -f "$1/scene.before.ckpt")" "$dst/scene.before.ckpt"
  [ -f "$dst/spatial.json" ] || cp "$1/spatial.json" "$dst/spatial.json"
}
export -f one; export TABLE OUT FLAGS PY
ls -d "$TABLE"/*/*/seed* | xargs -P 2 -I{} bash -c 'one {}'
OMP_NUM_THREADS=1 $PY scripts/rir_spatial_table.py data/rir "$OUT" --again
