#!/bin/bash
# Biased Pendulum: ppo_lag_inferred seeds 0-4 (pbicrl's conservative cost from the icrl_pendulum demonstrations,
# inferred into $ICRL_INFER/pendulum_wall first: docs/benchmarks/icrl/README.md), 2 M steps as ppo_lag_true, then
# the unconstrained ppo seeds 1-4 (3 M as seed 0). Each run resumes from its checkpoint and finished runs are
# skipped: rerun this script to go on. Start it niced and detached, e.g.
#   setsid nohup nice -n 19 bash training/icrl/queue/chain13.sh >> chain13.out 2>&1 < /dev/null &
. "$(dirname "$0")/_env.sh"
for s in 0 1 2 3 4; do
  $R pendulum:ppo_lag_inferred:$s:2000000 --inferred-run $INFER/pendulum_wall >> $OUT/train_pendulum.log 2>&1
done
for s in 1 2 3 4; do
  $R pendulum:ppo:$s:3000000 >> $OUT/train_pendulum.log 2>&1
done
