#!/usr/bin/env bash
# Device: stage 1 of a scene without geometry on the GPU (gsplat, the paper's full-size frames),
# started from the SfM points triangulated here, then stage 2 from the G it made; the
# comparison with the CPU runs of docs/results.md "Scenes without geometry".
#   here: .venv/bin/python scripts/strip_geometry.py data/demo/demo_house data/stripped
#         .venv/bin/python scripts/device/sfm_points.py data/stripped/demo_house .gpu/sfm_demo_house.npz
#         .venv/bin/python -c "import sys; sys.path.insert(0, 'scripts/device'); from pathlib import Path; \
#             from prepare import pack_scene; pack_scene(Path('data/stripped/demo_house'), Path('.gpu/data/stripped/demo_house'), True)"
#         pip download (README of the device tool) gsplat soundfile cffi pycparser tqdm into .gpu/whl
#   device run: bash scripts/device/stage1_gpu.sh        carry: .gpu
# $OUT gets stage 2's log and the stage-1 file in 15 MB parts (cat stage1.pt.part* > stage1.pt).
set -u
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .gpu/whl/*.whl 2>&1 | grep -v WARNING | tail -2
export PYTHONPATH=$PWD:/tmp/site PYTHONUNBUFFERED=1
python3 -c "import torch, gsplat; print(torch.__version__, gsplat.__version__, torch.cuda.get_device_name(0))"
nvidia-smi --query-gpu=name,memory.used,memory.total --format=csv
S=.gpu/data/stripped/demo_house; W=/tmp/w; mkdir -p $W
A="python3 scripts/device/avgs_gpu.py --threads 2"
T0=$(date +%s)
AVGS_SFM_POINTS=.gpu/sfm_demo_house.npz $A train $S --out $W/stage1_gpu.ckpt --init sfm --stage1-only --device cuda --no-progress 2>&1 | tail -5
T1=$(date +%s); echo "stage 1 (GPU, with gsplat's first compile): $((T1 - T0)) s"
$A train $S --out $W/gs_from_gpu.ckpt --init gs --stage1 $W/stage1_gpu.ckpt.stage1.pt --iterations 2000 --eval-every 500 --device cuda --no-progress 2>&1 | tail -3
echo "stage 2 (GPU): $(( $(date +%s) - T1 )) s"
cp $W/gs_from_gpu.ckpt.log.jsonl $OUT/gs_from_gpu.log.jsonl  # stage 1's own log is the stage-1 file's history
split -b 15M -d $W/stage1_gpu.ckpt.stage1.pt $OUT/stage1.pt.part
