#!/usr/bin/env bash
# Session 22, lane A of two (chain36 is lane B): Ant's inferred-cost row from 6 M to 10 M steps, even seeds (seed 0
# resumes from its checkpoint), so the comparison at Ant's stable budget (10 M, the true-cost row's +4.1%) has
# finished seeds on both rows; then the true-cost seed 3. Finished runs are skipped, a run held by another chain
# refused.
export ICRL_RUNS=${ICRL_6M:-/work/icrl_6m} ICRL_EXT=${ICRL_10M:-/work/icrl_10m}
. "$(dirname "$0")/_env.sh"
. "$(dirname "$0")/_extend.sh"
for s in 0 2 4; do
    extend_copy ant ppo_lag_inferred $s && \
        $RX ant:ppo_lag_inferred:$s:10000000 --inferred-run $INFER/ant_wall >> $EXT/train.log 2>&1
done
extend_copy ant ppo_lag_true 3 && $RX ant:ppo_lag_true:3:10000000 >> $EXT/train.log 2>&1
