#!/bin/bash
# one.sh SCENE SETTING SEED : a defaults run of the impulse-response task on a scene written with the
# simulator's phantom direct sound removed (docs/results.md), stage 1 shared (runs/fix3/SCENE.ckpt.stage1.pt), then its eval
S=$1; K=$2; N=$3; W=runs/fix3; A=.venv/bin/avgs; export OMP_NUM_THREADS=1
st=$W/${S%_fixed}.ckpt.stage1.pt
extra=""; [ $K = nc ] && extra="--no-context"
out=$W/$S.$K.s$N.ckpt
[ -e $W/$S.$K.s$N.done ] && exit 0
$A train data/rir/$S --task rir --seed $N $extra --stage1 $st --no-progress --out $out > $W/$S.$K.s$N.out 2>&1 || exit 1
$A eval data/rir/$S --task rir --split both --method ckpt:$out --json $W/$S.$K.s$N.eval.json > $W/$S.$K.s$N.eval.out 2>&1
echo done > $W/$S.$K.s$N.done
