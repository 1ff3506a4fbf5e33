# Sourced by chain26.sh and chain27.sh with SEEDS (their order) and NEXT (the chain to go on with) set: HalfCheetah's
# PPO-Lagrangian rows from 6 M to 10 M steps (at 6 M the feasible reward still rose 12-18% between the last two
# fifths). Each 6 M run (training/icrl_6m) is copied into its own root ($ICRL_10M, committed as training/icrl_10m)
# so the 6 M report stays whole. chain26 takes the seeds from 0 up, chain27 from 4 down, true and inferred cost in
# turn, so the two rows grow together; a run the other chain holds is refused (its lock), a finished one skipped.
export ICRL_RUNS=${ICRL_6M:-/work/icrl_6m} ICRL_EXT=${ICRL_10M:-/work/icrl_10m}
. "$(dirname "${BASH_SOURCE[0]}")/_env.sh"
. "$(dirname "${BASH_SOURCE[0]}")/_extend.sh"
for s in $SEEDS; do
    extend_copy halfcheetah ppo_lag_true $s && $RX halfcheetah:ppo_lag_true:$s:10000000 >> $EXT/train.log 2>&1
    extend_copy halfcheetah ppo_lag_inferred $s && \
        $RX halfcheetah:ppo_lag_inferred:$s:10000000 --inferred-run $INFER/halfcheetah_wall >> $EXT/train.log 2>&1
done
unset ICRL_RUNS ICRL_EXT
exec bash "$(dirname "${BASH_SOURCE[0]}")/$NEXT"
