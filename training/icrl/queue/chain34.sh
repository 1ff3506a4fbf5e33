#!/usr/bin/env bash
# Session 21 (replaces chain33 after its first run, Ant inferred seed 3 to 6 M): Ant's 6 M-step rows to five seeds,
# then Ant's PPO-Lagrangian rows from 6 M to 10 M steps (the budget of the authors' Ant expert; at 6 M the true-cost
# expert still rose 10% between the last two fifths), root /work/icrl_10m (committed as training/icrl_10m beside
# HalfCheetah's), the true-cost seeds first; then the main table's remaining runs (Ant ICL seeds 3-4, walker true
# cost seed 4: the ends of chain25 and chain24). Finished runs are skipped, a run held by another chain refused.
. "$(dirname "$0")/_env.sh"
. "$(dirname "$0")/_extend.sh"
extend_copy ant ppo_lag_true 4 && $RX ant:ppo_lag_true:4:6000000 >> $EXT/train.log 2>&1
extend_copy ant ppo_lag_inferred 4 && \
    $RX ant:ppo_lag_inferred:4:6000000 --inferred-run $INFER/ant_wall >> $EXT/train.log 2>&1
export ICRL_RUNS=${ICRL_6M:-/work/icrl_6m} ICRL_EXT=${ICRL_10M:-/work/icrl_10m}
. "$(dirname "$0")/_env.sh"
. "$(dirname "$0")/_extend.sh"
for s in 0 1 2; do
    extend_copy ant ppo_lag_true $s && $RX ant:ppo_lag_true:$s:10000000 >> $EXT/train.log 2>&1
done
for s in 0 1 2 3 4; do
    extend_copy ant ppo_lag_inferred $s && \
        $RX ant:ppo_lag_inferred:$s:10000000 --inferred-run $INFER/ant_wall >> $EXT/train.log 2>&1
    [ $s -ge 3 ] && extend_copy ant ppo_lag_true $s && $RX ant:ppo_lag_true:$s:10000000 >> $EXT/train.log 2>&1
done
unset ICRL_RUNS ICRL_EXT
bash "$(dirname "$0")/chain25.sh"       # its last runs: Ant icl seeds 3-4 (the rest are done and skipped)
exec bash "$(dirname "$0")/chain24.sh"  # its last run: walker ppo_lag_true seed 4
