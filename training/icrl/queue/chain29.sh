#!/usr/bin/env bash
# Session 20, beside chain24 and chain28: ICL on the swimmer, which gained an ICL environment this session
# (2 M PPO steps per seed).
. "$(dirname "$0")/_env.sh"
for s in 0 1 2 3 4; do
    $R swimmer:icl:$s:2000000 >> $OUT/train_icl_swimmer.log 2>&1
done
