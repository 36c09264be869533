#!/usr/bin/env bash
# The runs behind the results tables of docs/results.md, as `avgs sweep` calls on Ray (the
# scale extra, which scripts/setup.sh installs). Each sweep trains scenes x settings x seeds
# into OUT/<scene>/<setting>/seed<k>/ (checkpoint, log, curves), scores every checkpoint and
# writes OUT/results.json and OUT/results.md (mean ± std over seeds per scene and overall);
# the baselines are scored beside them by `avgs eval` (OUT/baselines.json). Started again, a
# sweep skips finished runs and resumes interrupted ones, so the script continues where it
# stopped; a failed run does not stop the others, and the script exits 1 at the end.
#
# Stage 1 ran on the CPU with our PyTorch rasterizer for the current tables (39-47 min per
# scene); with CUDA the same commands use gsplat (~25 s per scene). Stage 2: one torch thread
# per run, as many runs at once as the machine has cores. GPUS=0.0625 shares a GPU among 16
# runs (as the H100 runs of the "direction at every layer" table did); ADDRESS=HEAD:6379
# sends the sweeps to a Ray cluster (README: Scaling out).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
A=.venv/bin/avgs
DEVICE="${DEVICE:-$(.venv/bin/python -c 'import torch; print("cuda" if torch.cuda.is_available() else "cpu")')}"
export OMP_NUM_THREADS=1
PRESETS="office_0 house_0 apartment_0 outdoor_0"
COMMON="--max-gaussians 50000 --audio-points 20000 --eval-every 500 --no-progress --device $DEVICE"
SFM="--init sfm --no-gaussians --iterations 2000"          # G_a straight from the geometry: no stage 1
SHARED="--iterations 2000 --stage1 runs/stage1/{scene}.ckpt.stage1.pt"   # each preset's one stage 1
status=0
sweep() {
  $A sweep --threads-per-run 1 --gpus-per-run "${GPUS:-0}" ${ADDRESS:+--address "$ADDRESS"} --no-progress "$@" || status=1
}
baselines() { local out=$1; shift; [ -f "$out" ] || $A eval "$@" --json "$out" --no-progress || status=1; }
ALL="--method mono-mono --method mono-energy --method stereo-energy --method oracle-mask"

mkdir -p runs/stage1
for p in $PRESETS; do   # 200 train + 50 val poses each (4-9 min per scene on 2 cores)
  [ -d data/presets/$p ] || $A synth data/presets --preset ${p%_0} --scene-id $p --poses 250 --seed 0
  [ -f runs/stage1/$p.ckpt.stage1.pt ] || \
    $A train data/presets/$p --out runs/stage1/$p.ckpt --stage1-only --device $DEVICE --max-gaussians 50000
done

# Main table: AV-GS and the --no-context control with the defaults on the shared stage 1.
sweep --data data/presets --scenes $PRESETS --out runs/main --common="$COMMON $SHARED" \
  --setting avgs= --setting nocontext=--no-context
baselines runs/main/baselines.json data/presets $ALL

# Direction and position features of B: the paper's Fourier direction features with AV-NeRF's
# 10-frequency listener encoding (the defaults before this comparison) against circular
# harmonics with 4 frequencies (the defaults after it); made before the direction feature went
# to every layer of B's difference MLP, so both at the first layer only.
OLD="--direction-encoding fourier --position-frequencies 10 --no-direction-every-layer"
sweep --data data/presets --scenes $PRESETS --out runs/features --common="$COMMON $SFM" \
  --setting old-avgs="$OLD" --setting old-nocontext="$OLD --no-context" \
  --setting new-avgs=--no-direction-every-layer --setting new-nocontext="--no-context --no-direction-every-layer"

# Ablations on the office scene, 2000 iterations each, on its shared stage 1 (AV-GS and the
# control with the defaults are the main table's office rows).
sweep --data data/presets --scenes office_0 --out runs/ablation --common="$COMMON $SHARED" \
  --setting sfm="--init sfm" --setting no-pm=--no-point-management --setting masks=--no-reverb-tail \
  --setting vic5="--vicinity-percentile 5" --setting vic10="--vicinity-percentile 10" \
  --setting vic25="--vicinity-percentile 25" --setting conv=--post-conv   # conv: AV-NeRF's conv head
baselines runs/ablation/baselines.json data/presets --scene office_0 --method stereo-energy

# The same four presets with the raw KEMAR head (--raw-hrtf: the ears' own colouration stays
# in the audio, as in a binaural recording and in the anchor measurement of docs/design.md, "Metrics and baselines").
for p in $PRESETS; do
  [ -d data/rawhrtf/$p ] || $A synth data/rawhrtf --preset ${p%_0} --scene-id $p --poses 250 --seed 0 --raw-hrtf --no-progress
done
sweep --data data/rawhrtf --scenes $PRESETS --out runs/rawhrtf --common="$COMMON $SFM" \
  --setting avgs= --setting nocontext=--no-context
baselines runs/rawhrtf/baselines.json data/rawhrtf $ALL

# The scene context with fewer recordings: a quarter of the training poses, three seeds.
for p in $PRESETS; do
  [ -d data/sparse50/$p ] || .venv/bin/python scripts/subset_scene.py data/presets/$p data/sparse50 --poses 50
done
sweep --data data/sparse50 --scenes $PRESETS --out runs/sparse50 --seeds 0 1 2 --common="$COMMON $SFM" \
  --setting avgs= --setting nocontext=--no-context
baselines runs/sparse50/baselines.json data/sparse50 --method stereo-energy

# The direction feature at every layer of B's difference MLP (the default) against the first
# layer only, with the control, three seeds per raw-head preset (on an H100 for docs/results.md:
# DEVICE=cuda GPUS=0.0625).
sweep --data data/rawhrtf --scenes $PRESETS --out runs/layers --seeds 0 1 2 --common="$COMMON $SFM" \
  --setting avgs= --setting nocontext=--no-context --setting firstlayer=--no-direction-every-layer

# The impulse-response task (docs/results.md "Impulse responses"): six presets, AV-GS and the
# control, three seeds, scored on the validation pairs and the held-out sources.
RIR_PRESETS="rect_small rect_large l_room u_room two_rooms three_rooms"
mkdir -p runs/rir
for p in $RIR_PRESETS; do
  [ -d data/rir/$p ] || $A synth data/rir --task rir --preset $p --scene-id $p --seed 0 --no-progress
done
[ -f runs/rir/baselines.json ] || $A eval --task rir data/rir --split both --out runs/rir/baselines.json --no-progress \
  --methods nearest,linear,opus-nearest,opus-linear,aac-nearest,aac-linear || status=1
for split in heldout val; do
  sweep --data data/rir --scenes $RIR_PRESETS --out runs/rir --seeds 0 1 2 --eval-split $split \
    --common="--quick --rir-width 256 --iterations 400" --setting avgs="--task rir" --setting no-context="--task rir --no-context"
  cp runs/rir/results.json runs/rir/results-$split.json
done
.venv/bin/python scripts/rir_table.py runs/rir
.venv/bin/python scripts/rir_level_distance.py --seed 0 || status=1

exit $status
