#!/usr/bin/env bash
# Session 20, beside chain29 (swimmer ICL, seeds from 0 up): the swimmer's ICL seeds from the other end (seed 2
# resumes its checkpoint; a seed chain29 holds is refused by its lock, a finished one skipped), then chain24.sh
# (Ant ppo_lag_true to 6 M, seeds 3-4; seed 3 stopped at its checkpoint to make room for these).
. "$(dirname "$0")/_env.sh"
for s in 2 4 3 1 0; do
    $R swimmer:icl:$s:2000000 >> $OUT/train_icl_swimmer.log 2>&1
done
exec bash "$(dirname "$0")/chain24.sh"
