#!/bin/bash
# Blocked Walker: ppo_lag_inferred seed 0 (pbicrl's conservative cost from the icrl_walker demonstrations, inferred into
# $ICRL_INFER/walker_wall first: docs/benchmarks/icrl/README.md), then ppo_lag_true and ppo_lag_inferred seed 1. Each
# run resumes from its checkpoint and finished runs are skipped: rerun this script to go on. Start it niced and
# detached, e.g.
#   setsid nohup nice -n 19 bash training/icrl/queue/chain9.sh >> chain9.out 2>&1 < /dev/null &
. "$(dirname "$0")/_env.sh"
$R walker:ppo_lag_inferred:0:3000000 --inferred-run $INFER/walker_wall >> $OUT/train_inferred.log 2>&1
$R walker:ppo_lag_true:1:3000000 >> $OUT/train.log 2>&1
$R walker:ppo_lag_inferred:1:3000000 --inferred-run $INFER/walker_wall >> $OUT/train_inferred.log 2>&1
# appended in session 15: the ICL baseline on the walker (Ant's budgets: 6 rounds, 2.5 M PPO steps)
$R walker:icl:0:2500000 >> $OUT/train_icl_walker.log 2>&1
