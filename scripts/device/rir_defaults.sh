#!/usr/bin/env bash
# Device: the impulse-response task with its defaults, not --quick (stage 1 with gsplat on the
# frames, then stage 2: width 256, batch 4, 20k points from G, the paper's schedule) on the
# two-room preset: AV-GS and --no-context, seeds 0-2, six runs side by side on one GPU from one
# shared stage 1; the checkpoints and the baselines scored by `avgs eval --task rir --split both`;
# the CUDA tests beside stage 2.
#   .venv/bin/python scripts/device/prepare.py data/rir/two_rooms --frames
#   device run (carry .gpu): bash scripts/device/rir_defaults.sh [END_S]
# END_S (default 470): seconds after the start by which the scores are written. The stage-2
# iterations are what fits: all six runs start with the default 40k schedule, their rate is read
# from their logs (within PROBE_S, default 90 seconds), and they start again with the iterations
# that end in time (a whole schedule: warm-up and decay). If CUDA fails, the same on the CPU.
# A dry run here (two runs): SEEDS=0 SKIP_INSTALL=1 PY=.venv/bin/python DEVICE=cpu STAGE1_ARGS="--stage1-iterations 20" \
#   PROBE_S=30 OUT=/tmp/out bash scripts/device/rir_defaults.sh 200
# Writes $OUT/summary.txt and $OUT/results.tgz (scores, logs); scripts/rir_defaults_table.py
# makes the table of docs/results.md from them.
set -u
T0=$(date +%s)
now() { echo $(( $(date +%s) - T0 )); }
END=${1:-470}
PROBE=${PROBE_S:-90}
PY=${PY:-python3}
DEV=${DEVICE:-cuda}
[ -n "${SKIP_INSTALL:-}" ] || python3 -m pip install -q --no-deps --no-index --no-compile --target /tmp/site \
  --find-links .gpu/whl --find-links .gpu/whl2 soundfile cffi pycparser pyroomacoustics gsplat 2>&1 | grep -v WARNING
export PYTHONPATH=/tmp/site:$PWD PYTHONUNBUFFERED=1
$PY scripts/device/prepare.py --unpack .gpu/data || exit 1
A="$PY scripts/device/avgs_gpu.py"
D=.gpu/data/rir/two_rooms
W=$OUT/w
mkdir -p "$W"
S=$OUT/summary.txt
{ nvidia-smi -L; nproc; $PY -c "import torch; print('torch', torch.__version__, torch.cuda.is_available() and torch.cuda.get_device_name(0))"; } 2>&1 | tee -a "$S"

OMP_NUM_THREADS=4 $A train $D --task rir --out "$W/stage1.ckpt" --stage1-only --device $DEV ${STAGE1_ARGS:-} --no-progress > "$W/stage1.log" 2>&1 \
  || { echo "stage 1 on $DEV failed:"; tail -20 "$W/stage1.log"; } | tee -a "$S"
echo "stage 1 done at $(now) s" | tee -a "$S"
# The CUDA tests once stage 1 has built gsplat's extension (two builds at once share its folder and fail).
$PY -m pytest -q -m cuda tests/ -p no:cacheprovider > "$W/cuda_tests.txt" 2>&1 &
TESTS=$!
G="--stage1 $W/stage1.ckpt.stage1.pt"
[ -f "$W/stage1.ckpt.stage1.pt" ] || { G="--init sfm --no-gaussians"; echo "no stage 1: G_a from scene.json's surfaces" | tee -a "$S"; }

RUNS=$(( 2 * $(wc -w <<< "${SEEDS:-0 1 2}") ))
start_runs() {  # $1 device, $2 iterations
  PIDS=()
  for seed in ${SEEDS:-0 1 2}; do
    for setting in avgs nocontext; do
      flag=""; [ $setting = nocontext ] && flag=--no-context
      OMP_NUM_THREADS=2 $A train $D --task rir --out "$W/$setting-s$seed.ckpt" $G \
        --seed $seed --device $1 --iterations $2 --log-every 25 --checkpoint-every 1000 $flag --no-progress \
        > "$W/$setting-s$seed.out" 2>&1 &
      PIDS+=($!)
    done
  done
}
rate() {  # "R N K": the slowest run's stage-2 iterations per second, the runs logging, their fewest records
  $PY - "$W" <<'EOF'
import json, sys, pathlib
rates, counts = [], []
for log in pathlib.Path(sys.argv[1]).glob("*-s*.ckpt.log.jsonl"):
    recs = [json.loads(l) for l in log.read_text().splitlines() if '"stage2"' in l]
    recs = [r for r in recs if "iteration" in r and "seconds" in r]
    if len(recs) >= 3:  # from the second record on: the first iterations pay for warm-up
        a, b = recs[1], recs[-1]
        rates.append((b["iteration"] - a["iteration"]) / max(1e-9, b["seconds"] - a["seconds"]))
        counts.append(len(recs))
print(f"{min(rates):.3f} {len(rates)} {min(counts)}" if rates else "0 0 0")
EOF
}
probe() {  # $1 device: the rate of six runs side by side, once each has logged 8 records (PROBE_S at most)
  start_runs $1 40000
  for _ in $(seq 1 $(( PROBE / 5 ))); do
    sleep 5
    read R N K <<< "$(rate)"
    [ "$N" = $RUNS ] && [ "$K" -ge 8 ] && break
  done
  kill "${PIDS[@]}" 2>/dev/null; wait "${PIDS[@]}" 2>/dev/null
  rm -f "$W"/*-s*.ckpt*
  echo "probe on $1: $N of $RUNS runs logging, slowest $R it/s (at $(now) s)" | tee -a "$S"
}
probe $DEV
if [ "$N" = 0 ] && [ $DEV = cuda ]; then
  tail -30 "$W/avgs-s0.out" | tee -a "$S"
  DEV=cpu; probe cpu
fi
STARTUP=30  # each run reads the responses and fits its laws before its first iteration
LEFT=$(( END - $(now) - 45 - STARTUP ))  # 45 s: scoring and packing
IT=$($PY -c "print(max(500, int($R * $LEFT * 0.8 / 500) * 500))")  # 0.8: the evaluations every 2000 and at the end
echo "stage 2: $IT iterations per run on $DEV, ${LEFT} s left for it" | tee -a "$S"
T1=$(date +%s)
start_runs $DEV $IT
( sleep $(( LEFT + STARTUP + 30 )); kill "${PIDS[@]}" 2>/dev/null ) &
GUARD=$!
wait "${PIDS[@]}"
kill $GUARD 2>/dev/null
echo "stage 2 runs ended after $(( $(date +%s) - T1 )) s (at $(now) s)" | tee -a "$S"
for f in "$W"/*-s*.out; do echo "$(basename $f): $(tail -1 $f | cut -c1-200)"; done | tee -a "$S"

EVALS=()
for ck in "$W"/*-s*.ckpt; do
  [ -f "$ck" ] || continue
  OMP_NUM_THREADS=2 $A eval $D --task rir --split both --method "ckpt:$ck" --json "${ck%.ckpt}.eval.json" --no-progress \
    > "${ck%.ckpt}.eval.txt" 2>&1 &
  EVALS+=($!)
done
OMP_NUM_THREADS=2 $A eval $D --task rir --split both --method nearest --method linear --json "$W/baselines.eval.json" \
  --no-progress > "$W/baselines.eval.txt" 2>&1 &
EVALS+=($!)
wait "${EVALS[@]}"
kill $TESTS 2>/dev/null
echo "CUDA tests: $(tail -1 $W/cuda_tests.txt)" | tee -a "$S"
echo "scored at $(now) s" | tee -a "$S"
rm -f "$W"/*.ckpt "$W"/*.stage1.pt
tar -czf $OUT/results.tgz -C $OUT w && rm -rf "$W"
echo "done at $(now) s" | tee -a "$S"
