#!/usr/bin/env bash
# Rebuilds the bundled demo scene: assets/demo/scene.ckpt and assets/demo/clip.wav.
#
# The demo is source-aware: an impulse-response scene (`--task rir`, the two-room preset),
# so dragging the source in the explorer is heard (its level, the wall between the rooms).
# The exact sequence that made the committed files, on 2 CPU cores (stage 1 about 17 min
# with one thread on a shared machine, stage 2 about 1 min); with CUDA, stage 1 uses gsplat.
#
#   bash scripts/make_demo.sh            # everything (uses CUDA for stage 1 when present)
#   DEVICE=cpu bash scripts/make_demo.sh # force the CPU
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
AVGS=.venv/bin/avgs
DEVICE="${DEVICE:-$(.venv/bin/python -c 'import torch; print("cuda" if torch.cuda.is_available() else "cpu")')}"
SCENE=data/rir/two_rooms
WORK=runs/demo_rir
mkdir -p "$WORK"

# 1. The scene: two rooms and a door; 6 sources (1 held out) x 28 receivers x 4 facings of
#    binaural impulse responses, plus 100 key frames (about 9 min on 2 cores).
[ -d "$SCENE" ] || $AVGS synth data/rir --task rir --preset two_rooms --scene-id two_rooms --seed 0

# 2. Stage 1: G on the key frames (3k iterations; on the CPU at most 128x96 pixels, 20k Gaussians).
[ -f "$WORK/scene.ckpt.stage1.pt" ] || \
  OMP_NUM_THREADS=1 $AVGS --threads 1 train "$SCENE" --task rir --out "$WORK/scene.ckpt" --stage1-only --device "$DEVICE"

# 3. Stage 2 of the impulse-response task: G_a (8000 of G's points), F and the RIR variant of B.
#    The defaults: the ears' energy and energy-decay losses, the direct-plus-diffuse distance law
#    (docs/results.md "Impulse responses"), the direct sound placed by geometry with the head fitted to
#    the training responses (RIRConfig.direct_sound; 273 us) and its early ILD from a fitted head shadow
#    where G_a leaves the straight path free (RIRConfig.direct_ild; the log's "ild" and "sight" records:
#    9.0 / 1.3 / 0.8 dB, blocked from 7 points along a path, 320 / 342 and 106 / 106 training pairs told
#    apart), corrected near the 342 training responses in sight by their own (RIRConfig.ild_local), and the
#    direct sound's level from 1 / d^2 (RIRConfig.direct_level). The committed demo was made so on
#    2026-11-26 (stage 1 12 min, stage 2 1 min, one thread); the ITD law, the ILD's local correction and the
#    level law were added to those weights on 2026-11-27 (scripts/rir_refit.py: the same fits as
#    training's start; the weights do not depend on them). B's wall term (RIRConfig.wall_loss) is
#    learned, so for it stage 2 was run again (2026-11-27, 2 min) on that demo's own G: a stage-1 file
#    written from the checkpoint's Gaussians (avgs.train.stage1.save_stage1) and `--stage1 FILE` here.
#    The walls' reflections and, behind a wall, the first sound's lag after the straight line
#    (RIRConfig.blocked_lag: 3.4 ms) were added the same way (scripts/rir_refit.py, 2026-11-28 and 2026-11-29), and
#    behind a wall the early ILD's factor (RIRConfig.blocked_ild; `rir_refit.py --blocked-ild-only`, 2026-11-29). Then all
#    of these were fitted again on the demo's final points, as training now does at its end (`rir_refit.py
#    --geometry-only`, 2026-11-29: behind a wall from 4 points on the path, the lag 2.7 ms, the factor 0.1).
OMP_NUM_THREADS=1 $AVGS --threads 1 train "$SCENE" --task rir --init gs --out "$WORK/scene.ckpt" --audio-points 8000 \
  --iterations 500 --batch-size 8 --lr 1e-3 --rir-width 256 --eval-every 250

# 4. Release: keep G for drawing, drop the optimizer state (the file stays under 25 MB).
mkdir -p assets/demo
$AVGS prune "$WORK/scene.ckpt" --out assets/demo/scene.ckpt --scene "$SCENE" --keep-gaussians

# 5. The clip to listen to: 6 s of the generator's speech-like signal (seed 11), 16-bit.
.venv/bin/python - <<'PY'
import numpy as np, soundfile as sf
from avgs.synth.signals import speech_like
x = speech_like(6 * 22050, np.random.default_rng(11))
sf.write("assets/demo/clip.wav", (0.7 * x / np.max(np.abs(x))).astype(np.float32), 22050, subtype="PCM_16")
PY
$AVGS info assets/demo/scene.ckpt
