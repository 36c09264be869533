#!/usr/bin/env bash
# Device: the CUDA tests (gsplat against our rasterizer, the direct sound placed from GPU tensors) and the
# impulse-response task end to end on the GPU (training with its final scores, `avgs eval --device cuda`).
#   .venv/bin/python scripts/device/prepare.py data/rir/two_rooms
#   device run (carry .gpu): bash scripts/device/cuda_check.sh
# With the argument `binaural`, the binaural task alone (training, `avgs eval` with both syntheses and
# `avgs render` on the GPU) on a quick scene:
#   avgs synth /tmp/bq --preset office --scene-id office_quick --quick; prepare.py /tmp/bq/office_quick --frames
#   device run (carry .gpu): bash scripts/device/cuda_check.sh binaural
# Run the two one after the other, not side by side: each unpacks .gpu/data in place.
set -u
T0=$(date +%s)
python3 -m pip install -q --no-deps --no-index --no-compile --target /tmp/site \
  --find-links .gpu/whl --find-links .gpu/whl2 soundfile cffi pycparser pyroomacoustics gsplat 2>&1 | grep -v WARNING
export PYTHONPATH=/tmp/site:$PWD PYTHONUNBUFFERED=1
python3 scripts/device/prepare.py --unpack .gpu/data || exit 1
A="python3 scripts/device/avgs_gpu.py"
if [ "${1:-}" = binaural ]; then
  B=.gpu/data/bq/office_quick
  OMP_NUM_THREADS=4 $A train $B --quick --init sfm --no-gaussians --device cuda --out /tmp/b.ckpt --no-progress > $OUT/train.txt 2>&1
  echo "train: rc $? at $(( $(date +%s) - T0 )) s"; tail -1 $OUT/train.txt
  for synthesis in spectrogram filter; do
    OMP_NUM_THREADS=4 $A eval .gpu/data/bq --method ckpt:/tmp/b.ckpt --synthesis $synthesis --device cuda --no-progress > $OUT/eval_$synthesis.txt 2>&1
    echo "eval ($synthesis): rc $?"; tail -2 $OUT/eval_$synthesis.txt
  done
  OMP_NUM_THREADS=4 $A render /tmp/b.ckpt --listener 0 0 0 --yaw 90 --input $B/source_syn_re.wav --output /tmp/o.wav --device cuda > $OUT/render.txt 2>&1
  echo "render: rc $?"; tail -2 $OUT/render.txt
  echo "done at $(( $(date +%s) - T0 )) s"
  exit 0
fi
D=.gpu/data/rir/two_rooms
python3 -m pytest -q -m cuda tests/test_gaussians.py tests/test_rir_direct_sound.py -p no:cacheprovider > $OUT/cuda_tests.txt 2>&1 &
TESTS=$!
OMP_NUM_THREADS=4 $A train $D --task rir --out /tmp/r.ckpt --init sfm --no-gaussians --iterations 200 --eval-every 100 \
  --device cuda --no-progress > $OUT/train.txt 2>&1; echo "train: rc $? at $(( $(date +%s) - T0 )) s"
OMP_NUM_THREADS=4 $A eval $D --task rir --split both --method ckpt:/tmp/r.ckpt --device cuda --no-progress > $OUT/eval.txt 2>&1
echo "eval: rc $? at $(( $(date +%s) - T0 )) s"
tail -2 $OUT/train.txt; tail -4 $OUT/eval.txt
wait $TESTS
tail -3 $OUT/cuda_tests.txt
echo "done at $(( $(date +%s) - T0 )) s"
