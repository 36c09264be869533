#!/usr/bin/env bash
# Device: stage-2 runs of the raw-head scenes named in $SCENES through the avgs CLI, then
# avgs eval of the checkpoint folders there (baselines are scored at home on the same files).
# Per scene and seed 0-2: AV-GS, --no-context and --no-direction-every-layer, 2000 iterations,
# G_a from the geometry (--init sfm), 16 runs at a time sharing the GPU. Made docs/results.md's
# "Direction at every layer" table, two scenes per call (the 64 MiB a call may carry):
#   .venv/bin/python scripts/device/prepare.py data/rawhrtf/outdoor_0 data/rawhrtf/apartment_0
#   device run: SCENES="outdoor_0 apartment_0" bash scripts/device/cli_batch.sh
#     carry: .gpu/whl .gpu/data/rawhrtf/outdoor_0 .gpu/data/rawhrtf/apartment_0 .gpu/data/rawhrtf/position.json
# DATA=presets reads .gpu/data/presets instead; NO_FIRST=1 leaves the first-layer runs out.
# ITERS, DEV=cpu, P and NOPIP=1 (no wheels to install) let it run at home for a dry run.
set -u
T0=$(date +%s)
[ -n "${NOPIP:-}" ] || python3 -m pip install -q --no-deps --no-index --find-links .gpu/whl soundfile tqdm cffi pycparser 2>&1 | grep -v WARNING | tail -2
python3 -c "import torch, scipy, soundfile, tqdm; print(torch.__version__, torch.cuda.is_available())" || exit 3
export PYTHONPATH=$PWD OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
R=/tmp/r; rm -rf $R; mkdir -p $R
COMMON="--init sfm --no-gaussians --iterations ${ITERS:-2000} --max-gaussians 50000 --audio-points 20000 --eval-every 500 --no-progress --device ${DEV:-cuda}"
jobs_file=/tmp/jobs.txt; : > $jobs_file
D=.gpu/data/${DATA:-rawhrtf}
for sc in $SCENES; do for s in 0 1 2; do
  echo "$sc avgs_s$s --seed $s" >> $jobs_file
  echo "$sc nocontext_s$s --seed $s --no-context" >> $jobs_file
  [ -n "${NO_FIRST:-}" ] || echo "$sc firstlayer_s$s --seed $s --no-direction-every-layer" >> $jobs_file
done; done
timeout 480 xargs -P ${P:-16} -L 1 bash -c 'mkdir -p '$R'/$1; python3 scripts/device/avgs_gpu.py train '$D'/$0 --out '$R'/$1/$0.ckpt '"$COMMON"' "${@:2}" > '$R'/$1/$0.out 2>&1' < $jobs_file
echo "trained in $(( $(date +%s) - T0 )) s"
mkdir -p /tmp/data; ln -sfn $PWD/$D/position.json /tmp/data/position.json; for sc in $SCENES; do ln -sfn $PWD/$D/$sc /tmp/data/$sc; done
M=""; for d in $R/*/; do M="$M --method ckpt:$d"; done
python3 scripts/device/avgs_gpu.py eval /tmp/data $M --json $OUT/eval.json --no-progress 2>&1 | tail -30
echo "total $(( $(date +%s) - T0 )) s"
tar czf $OUT/logs.tgz -C $R $(cd $R && ls */*.log.jsonl */*.out)
grep -h "wrote\|Error\|error" $R/*/*.out | head -40
