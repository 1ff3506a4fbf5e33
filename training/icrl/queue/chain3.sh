#!/bin/bash
# Blocked Ant: ppo_lag_true and ppo_lag_inferred seeds 0-2, in this order. Each run resumes from its checkpoint and finished runs are skipped: rerun this
# script to go on (docs/benchmarks/icrl/README.md, Resume). Start it niced and detached, e.g.
#   setsid nohup nice -n 19 bash training/icrl/queue/chain3.sh >> chain3.out 2>&1 < /dev/null &
. "$(dirname "$0")/_env.sh"
$R ant:ppo_lag_inferred:0:3000000 --inferred-run $INFER/ant_wall >> $OUT/train_inferred.log 2>&1
$R ant:ppo_lag_true:1:3000000 >> $OUT/train.log 2>&1
$R ant:ppo_lag_inferred:1:3000000 --inferred-run $INFER/ant_wall >> $OUT/train_inferred.log 2>&1
$R ant:ppo_lag_true:2:3000000 >> $OUT/train.log 2>&1
$R ant:ppo_lag_inferred:2:3000000 --inferred-run $INFER/ant_wall >> $OUT/train_inferred.log 2>&1
# appended in session 15: Ant seeds 3 (both costs), toward the 5 seeds per row
$R ant:ppo_lag_true:3:3000000 >> $OUT/train.log 2>&1
$R ant:ppo_lag_inferred:3:3000000 --inferred-run $INFER/ant_wall >> $OUT/train_inferred.log 2>&1
