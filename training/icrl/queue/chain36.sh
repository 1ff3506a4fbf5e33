#!/usr/bin/env bash
# Session 22, lane B of two (chain35 is lane A): Ant's inferred-cost row from 6 M to 10 M steps, odd seeds, and the
# true-cost seed 4; then chain32 (HalfCheetah's inferred-cost row to 20 M: seed 2 resumes from its checkpoint, then
# seeds 3-4 on both rows) and the main table's last runs (chain25: Ant ICL seeds 3-4; chain24: walker true cost
# seed 4). Finished runs are skipped, a run held by another chain refused.
export ICRL_RUNS=${ICRL_6M:-/work/icrl_6m} ICRL_EXT=${ICRL_10M:-/work/icrl_10m}
. "$(dirname "$0")/_env.sh"
. "$(dirname "$0")/_extend.sh"
for s in 1 3; do
    extend_copy ant ppo_lag_inferred $s && \
        $RX ant:ppo_lag_inferred:$s:10000000 --inferred-run $INFER/ant_wall >> $EXT/train.log 2>&1
done
extend_copy ant ppo_lag_true 4 && $RX ant:ppo_lag_true:4:10000000 >> $EXT/train.log 2>&1
unset ICRL_RUNS ICRL_EXT
bash "$(dirname "$0")/chain32.sh"
bash "$(dirname "$0")/chain25.sh"       # its last runs: Ant icl seeds 3-4 (the rest are done and skipped)
exec bash "$(dirname "$0")/chain24.sh"  # its last run: walker ppo_lag_true seed 4
