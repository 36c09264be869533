#!/usr/bin/env bash
# The runs behind the results tables of docs/results.md, exactly as they were made.
# Stage 1 ran on the CPU with our PyTorch rasterizer for the current tables (39-47 min per
# scene, 4-5 runs sharing 2 cores); with CUDA the same commands use gsplat (~25 s per scene).
# Stage 2 ran on the CPU, one torch thread per run, two runs at a time on a 2-core
# machine (JOBS=2). A run whose checkpoint exists is skipped, so the script continues
# where it stopped.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
A=.venv/bin/avgs
DEVICE="${DEVICE:-$(.venv/bin/python -c 'import torch; print("cuda" if torch.cuda.is_available() else "cpu")')}"
JOBS="${JOBS:-2}"
export OMP_NUM_THREADS=1
PRESETS="office house apartment outdoor"
COMMON="--max-gaussians 50000 --audio-points 20000 --eval-every 500 --no-progress"

mkdir -p runs/stage1
for p in $PRESETS; do   # 200 train + 50 val poses each (4-9 min per scene on 2 cores)
  [ -d data/presets/${p}_0 ] || $A synth data/presets --preset $p --scene-id ${p}_0 --poses 250 --seed 0
  [ -f runs/stage1/${p}_0.ckpt.stage1.pt ] || \
    $A train data/presets/${p}_0 --out runs/stage1/${p}_0.ckpt --stage1-only --device $DEVICE --max-gaussians 50000
done

# One stage-2 run: run SCENE OUT [flags...], skipped when OUT exists; at most JOBS at once.
# The scene is read from $DATA/SCENE (default data/presets).
run() {
  local scene=$1 out=$2 data=${DATA:-data/presets}; shift 2
  [ -f "$out" ] && return 0
  while [ "$(jobs -rp | wc -l)" -ge "$JOBS" ]; do wait -n; done
  mkdir -p "$(dirname "$out")"
  $A train "$data/$scene" --out "$out" $COMMON "$@" > "$out.out" 2>&1 &
}
# ... on the scene's shared stage 1.
train() { run "$1" "$2" --stage1 "runs/stage1/$1.ckpt.stage1.pt" "${@:3}"; }

# Main table: AV-GS and the --no-context control with the defaults; same stage 1, 2000
# iterations each.
for p in $PRESETS; do
  train ${p}_0 runs/main/avgs/${p}_0.ckpt --iterations 2000
  train ${p}_0 runs/main/nocontext/${p}_0.ckpt --iterations 2000 --no-context
done

# Direction and position features of B: the paper's Fourier direction features with AV-NeRF's
# 10-frequency listener encoding (the defaults before this comparison) against circular
# harmonics with 4 frequencies (the defaults after it). G_a straight from the geometry
# (--init sfm, no stage 1), so the comparison needs no GPU.
sfm() { run "$1" "$2" --init sfm --no-gaussians --iterations 2000 "${@:3}"; }
# (Made before the direction feature went to every layer of B's difference MLP: first layer only.)
OLD="--direction-encoding fourier --position-frequencies 10 --no-direction-every-layer"
for p in $PRESETS; do
  sfm ${p}_0 runs/features/old/avgs/${p}_0.ckpt $OLD
  sfm ${p}_0 runs/features/old/nocontext/${p}_0.ckpt $OLD --no-context
  sfm ${p}_0 runs/features/new/avgs/${p}_0.ckpt --no-direction-every-layer
  sfm ${p}_0 runs/features/new/nocontext/${p}_0.ckpt --no-context --no-direction-every-layer
done

# Ablations on the office scene, 2000 iterations each (the val column of each log's final record).
ab() { name=$1; shift; train office_0 runs/ablation/$name/office_0.ckpt --iterations 2000 "$@"; }
ab sfm --init sfm; ab no-pm --no-point-management; ab masks --no-reverb-tail
for v in 5 10 25; do ab vic$v --vicinity-percentile $v; done
train office_0 runs/conv/office_0.ckpt --iterations 2000 --post-conv   # AV-NeRF's conv head
wait

# The same four presets with the raw KEMAR head (--raw-hrtf: the ears' own colouration stays
# in the audio, as in a binaural recording and in DESIGN's anchor measurement); G_a straight
# from the geometry (no stage 1), AV-GS and the no-context control.
for p in office house apartment outdoor; do
  [ -d data/rawhrtf/${p}_0 ] || $A synth data/rawhrtf --preset $p --scene-id ${p}_0 --poses 250 --seed 0 --raw-hrtf --no-progress
done
for p in office house apartment outdoor; do
  DATA=data/rawhrtf sfm ${p}_0 runs/rawhrtf/avgs/${p}_0.ckpt
  DATA=data/rawhrtf sfm ${p}_0 runs/rawhrtf/nocontext/${p}_0.ckpt --no-context
done
# The scene context with fewer recordings: a quarter of the training poses, three seeds.
for p in $PRESETS; do
  [ -d data/sparse50/${p}_0 ] || .venv/bin/python scripts/subset_scene.py data/presets/${p}_0 data/sparse50 --poses 50
done
for s in 0 1 2; do
  r=runs/sparse50; [ $s = 0 ] || r=runs/sparse50_s$s
  for p in $PRESETS; do
    DATA=data/sparse50 sfm ${p}_0 $r/avgs/${p}_0.ckpt --seed $s
    DATA=data/sparse50 sfm ${p}_0 $r/nocontext/${p}_0.ckpt --seed $s --no-context
  done
done
# The direction feature at every layer of B's difference MLP (the default) against the first
# layer only (--no-direction-every-layer), with the control, three seeds per raw-head preset.
# The numbers in docs/results.md for these came from an H100 with the same commands
# (scripts/device/cli_batch.sh, two presets per call); here they run on the CPU.
for p in office house apartment outdoor; do for s in 0 1 2; do
  DATA=data/rawhrtf sfm ${p}_0 runs/layers/avgs_s$s/${p}_0.ckpt --seed $s
  DATA=data/rawhrtf sfm ${p}_0 runs/layers/nocontext_s$s/${p}_0.ckpt --seed $s --no-context
  DATA=data/rawhrtf sfm ${p}_0 runs/layers/firstlayer_s$s/${p}_0.ckpt --seed $s --no-direction-every-layer
done; done
wait

$A eval data/presets --method mono-mono --method mono-energy --method stereo-energy --method oracle-mask \
  --method ckpt:runs/main/nocontext --method ckpt:runs/main/avgs --json runs/main/eval.json --no-progress
$A eval data/presets --method stereo-energy --method ckpt:runs/features/old/nocontext --method ckpt:runs/features/old/avgs \
  --method ckpt:runs/features/new/nocontext --method ckpt:runs/features/new/avgs --json runs/features/eval.json --no-progress
AB=""; for d in runs/main/avgs runs/main/nocontext runs/ablation/* runs/conv; do AB="$AB --method ckpt:$d/office_0.ckpt"; done
$A eval data/presets --scene office_0 --method stereo-energy $AB --json runs/ablation/eval.json --no-progress
$A eval data/rawhrtf --method mono-mono --method mono-energy --method stereo-energy --method oracle-mask \
  --method ckpt:runs/rawhrtf/nocontext --method ckpt:runs/rawhrtf/avgs --json runs/rawhrtf/eval.json --no-progress
M=""; for r in sparse50 sparse50_s1 sparse50_s2; do M="$M --method ckpt:runs/$r/nocontext --method ckpt:runs/$r/avgs"; done
$A eval data/sparse50 --method stereo-energy $M --json runs/sparse50/eval.json --no-progress
L=""; for d in runs/layers/*/; do L="$L --method ckpt:$d"; done
$A eval data/rawhrtf $L --json runs/layers/eval.json --no-progress
