#!/usr/bin/env bash
# Session 20, replaces chain25 (stopped after Ant ppo_lag_inferred seed 1 reached 6 M): ICL on the pendulum, which
# gained an ICL environment this session (2 M PPO steps, ~13 min per seed here), then the rest of chain25 (its
# finished runs are skipped): Ant's inferred cost to 6 M steps for seeds 2-4 and Ant ICL seeds 3-4.
. "$(dirname "$0")/_env.sh"
for s in 0 1 2 3 4; do
    $R pendulum:icl:$s:2000000 >> $OUT/train_icl_pendulum.log 2>&1
done
exec bash "$(dirname "$0")/chain25.sh"
