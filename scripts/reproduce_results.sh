#!/usr/bin/env bash
# The runs behind the README's results tables, exactly as they were made.
# Stage 1 ran on an H100 with gsplat (`--stage1-only --device cuda`, ~25 s per scene);
# without CUDA the same commands train it on the CPU (much slower). Stage 2 ran on the
# CPU, one torch thread per run, two runs at a time on a 2-core machine.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
A=.venv/bin/avgs
DEVICE="${DEVICE:-$(.venv/bin/python -c 'import torch; print("cuda" if torch.cuda.is_available() else "cpu")')}"
export OMP_NUM_THREADS=1
PRESETS="office house apartment outdoor"
COMMON="--max-gaussians 50000 --audio-points 20000 --eval-every 1000"

for p in $PRESETS; do   # 200 train + 50 val poses each (4-9 min per scene on 2 cores)
  [ -d data/presets/${p}_0 ] || $A synth data/presets --preset $p --scene-id ${p}_0 --poses 250 --seed 0
  [ -f runs/stage1/${p}_0.ckpt.stage1.pt ] || \
    $A train data/presets/${p}_0 --out runs/stage1/${p}_0.ckpt --stage1-only --device $DEVICE --max-gaussians 50000
done

# Main table: AV-GS and the --no-context control, same stage 1, same 4000 iterations.
for p in $PRESETS; do
  G=runs/stage1/${p}_0.ckpt.stage1.pt
  $A train data/presets/${p}_0 --out runs/main/avgs/${p}_0.ckpt --stage1 $G $COMMON --iterations 4000
  $A train data/presets/${p}_0 --out runs/main/nocontext/${p}_0.ckpt --stage1 $G $COMMON --iterations 4000 --no-context
done
$A eval data/presets --method mono-mono --method mono-energy --method stereo-energy \
  --method ckpt:runs/main/nocontext --method ckpt:runs/main/avgs --json runs/main/eval.json

# Ablations on the office scene, 3000 iterations each (the val column of each log's final record).
G=runs/stage1/office_0.ckpt.stage1.pt
S=data/presets/office_0
ab() { name=$1; shift; $A train $S --out runs/ablation/$name/office_0.ckpt --stage1 $G $COMMON --iterations 3000 "$@"; }
ab default; ab sfm --init sfm; ab no-pm --no-point-management; ab no-context --no-context
for v in 5 10 20 25; do ab vic$v --vicinity-percentile $v; done
for d in runs/ablation/*/; do echo "$d $(grep '"final"' $d/office_0.ckpt.log.jsonl)"; done
