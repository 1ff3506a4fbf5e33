#!/usr/bin/env bash
# Session 21: HalfCheetah's true-cost expert from 10 M to 20 M steps for seeds 1 and 2 first (seed 0 reached 20 M in
# session 20), so the stable-budget question has three seeds of the reference expert; then the inferred-cost row
# (seed 0 resumes from its checkpoint), then the rest. Finished runs are skipped, a run held by another chain refused.
export ICRL_RUNS=${ICRL_10M:-/work/icrl_10m} ICRL_EXT=${ICRL_20M:-/work/icrl_20m}
. "$(dirname "$0")/_env.sh"
. "$(dirname "$0")/_extend.sh"
for s in 1 2; do
    extend_copy halfcheetah ppo_lag_true $s && $RX halfcheetah:ppo_lag_true:$s:20000000 >> $EXT/train.log 2>&1
done
for s in 0 1 2; do
    extend_copy halfcheetah ppo_lag_inferred $s && \
        $RX halfcheetah:ppo_lag_inferred:$s:20000000 --inferred-run $INFER/halfcheetah_wall >> $EXT/train.log 2>&1
done
SEEDS="3 4" STEPS=20000000 FROM=$ICRL_RUNS TO=$ICRL_EXT
. "$(dirname "$0")/_hcext.sh"
