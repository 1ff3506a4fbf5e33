# Sourced by chain26.sh/chain27.sh (6 M -> 10 M) and chain30.sh (10 M -> 20 M) with SEEDS (their order), STEPS (the
# new budget), FROM and TO (the shorter budget's root and the longer one's) and optionally NEXT (the chain to go on
# with): HalfCheetah's PPO-Lagrangian rows continued to a longer budget (at 6 M the feasible reward still rose 12-18%
# between the last two fifths, at 10 M 9-12%). Each finished run of FROM is copied into TO (committed as
# training/icrl_10m, training/icrl_20m) so the shorter report stays whole; true and inferred cost in turn, so the
# two rows grow together; a run another chain holds is refused (its lock), a finished one skipped.
export ICRL_RUNS=$FROM ICRL_EXT=$TO
. "$(dirname "${BASH_SOURCE[0]}")/_env.sh"
. "$(dirname "${BASH_SOURCE[0]}")/_extend.sh"
for s in $SEEDS; do
    extend_copy halfcheetah ppo_lag_true $s && $RX halfcheetah:ppo_lag_true:$s:$STEPS >> $EXT/train.log 2>&1
    extend_copy halfcheetah ppo_lag_inferred $s && \
        $RX halfcheetah:ppo_lag_inferred:$s:$STEPS --inferred-run $INFER/halfcheetah_wall >> $EXT/train.log 2>&1
done
unset ICRL_RUNS ICRL_EXT
if [ -n "${NEXT:-}" ]; then exec bash "$(dirname "${BASH_SOURCE[0]}")/$NEXT"; fi
