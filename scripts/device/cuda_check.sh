#!/usr/bin/env bash
# Device: the CUDA tests (gsplat against our rasterizer, the direct sound placed from GPU tensors) and the
# impulse-response task end to end on the GPU (training with its final scores, `avgs eval --device cuda`).
#   .venv/bin/python scripts/device/prepare.py data/rir/two_rooms
#   device run (carry .gpu): bash scripts/device/cuda_check.sh
set -u
T0=$(date +%s)
python3 -m pip install -q --no-deps --no-index --no-compile --target /tmp/site \
  --find-links .gpu/whl --find-links .gpu/whl2 soundfile cffi pycparser pyroomacoustics gsplat 2>&1 | grep -v WARNING
export PYTHONPATH=/tmp/site:$PWD PYTHONUNBUFFERED=1
python3 scripts/device/prepare.py --unpack .gpu/data || exit 1
A="python3 scripts/device/avgs_gpu.py"
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
