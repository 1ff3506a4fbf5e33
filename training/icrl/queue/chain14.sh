#!/bin/bash
# Blocked Swimmer with nu_0 = 30 (session 16; the benchmark's 1 still crossed in every episode after 5 M steps, kept
# as swimmer/ppo_lag_true_benchmark_nu0): ppo_lag_inferred seed 0 (pbicrl's conservative cost from the icrl_swimmer
# demonstrations, inferred into $ICRL_INFER/swimmer_wall first), then ppo_lag_true and ppo_lag_inferred seeds 1-4,
# 2 M steps each (ppo_lag_true seed 0, started as a diagnosis run with the same settings and adopted, has 2 M), then
# the unconstrained ppo seeds 1-4 (3 M as seed 0). Each run resumes from its checkpoint and finished runs are
# skipped: rerun this script to go on. Start it niced and detached, e.g.
#   setsid nohup nice -n 19 bash training/icrl/queue/chain14.sh >> chain14.out 2>&1 < /dev/null &
. "$(dirname "$0")/_env.sh"
$R swimmer:ppo_lag_inferred:0:2000000 --inferred-run $INFER/swimmer_wall >> $OUT/train_swimmer.log 2>&1
for s in 1 2 3 4; do
  $R swimmer:ppo_lag_true:$s:2000000 >> $OUT/train_swimmer.log 2>&1
  $R swimmer:ppo_lag_inferred:$s:2000000 --inferred-run $INFER/swimmer_wall >> $OUT/train_swimmer.log 2>&1
done
for s in 1 2 3 4; do
  $R swimmer:ppo:$s:3000000 >> $OUT/train_swimmer.log 2>&1
done
