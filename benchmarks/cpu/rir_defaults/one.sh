#!/bin/bash
# one.sh SCENE SETTING SEED : a defaults run of the impulse-response task, stage 1 shared per scene, then its eval
S=$1; K=$2; N=$3; W=runs/def6; A=.venv/bin/avgs; export OMP_NUM_THREADS=1
st=runs/sched/$S.stage1.pt; [ $S = two_rooms ] && st=runs/defaults40k/shared.stage1.pt
[ -e $st ] || st=$W/$S.stage1.pt
extra=""; [ $K = nc ] && extra="--no-context"
out=$W/$S.$K.s$N.ckpt
[ -e $W/$S.$K.s$N.done ] && exit 0
if [ -e $st ]; then
  $A train data/rir/$S --task rir --seed $N $extra --stage1 $st --out $out > $W/$S.$K.s$N.out 2>&1
else
  $A train data/rir/$S --task rir --seed $N $extra --out $out > $W/$S.$K.s$N.out 2>&1 && cp $out.stage1.pt $st
fi
$A eval data/rir/$S --task rir --split both --method ckpt:$out --json $W/$S.$K.s$N.eval.json > $W/$S.$K.s$N.eval.out 2>&1
echo done > $W/$S.$K.s$N.done
