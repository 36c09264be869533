#!/bin/bash
# job.sh stage1 SCENE | job.sh run SCENE av|nc SEED : one job of more.sh (a run waits for its scene's stage 1)
A=.venv/bin/avgs; export OMP_NUM_THREADS=1; mkdir -p runs/fix3
if [ "$1" = stage1 ]; then
  [ -e runs/fix3/${2%_fixed}.ckpt.stage1.pt ] || $A train data/rir/$2 --task rir --stage1-only --seed 0 --no-progress \
    --out runs/fix3/${2%_fixed}.ckpt > runs/fix3/$2.stage1.out 2>&1
else
  until [ -e runs/fix3/${2%_fixed}.ckpt.stage1.pt ]; do sleep 10; done
  bash benchmarks/cpu/rir_fixed/one.sh $2 $3 $4
fi
