#!/usr/bin/env bash
# Device: the CUDA tests (gsplat against our rasterizer) and `avgs bench --quick` with CUDA,
# which wrote benchmarks/h100/:
#   .venv/bin/python scripts/device/prepare.py data/rawhrtf/office_0 --frames
#   device run: bash scripts/device/h100.sh    (NOTEST=1 skips the tests)
#     carry: .gpu/whl .gpu/whl2 .gpu/data/rawhrtf/office_0 .gpu/data/rawhrtf/position.json
set -u
python3 -m pip install -q --no-deps --no-index --find-links .gpu/whl --find-links .gpu/whl2 soundfile cffi pycparser pyroomacoustics gsplat 2>&1 | grep -v WARNING | tail -2
export PYTHONPATH=$PWD
python3 -c "import torch, gsplat; print(torch.__version__, gsplat.__version__, torch.cuda.get_device_name(0))"
[ -n "${NOTEST:-}" ] || python3 -m pytest -q -m cuda tests/test_gaussians.py -p no:cacheprovider 2>&1 | tail -8
mkdir -p $OUT/h100
T0=$(date +%s)
python3 scripts/device/avgs_gpu.py bench --quick --data .gpu/data/rawhrtf/office_0 --presets '' --skip simulator --out $OUT/h100 --work /tmp/w --threads 2 2>&1 | tail -15
echo "bench $(( $(date +%s) - T0 )) s"
