#!/usr/bin/env bash
# Session 17: Ant's inferred-cost seed 3 beside chain3's true-cost seed 3 (the Ant feasible-reward target is the
# one missed), then the cheap swimmer PPO seeds, then the walker's inferred seed 1.
. "$(dirname "$0")/_env.sh"
$R ant:ppo_lag_inferred:3:3000000 --inferred-run $INFER/ant_wall >> $OUT/train_inferred.log 2>&1
for s in 3 4; do
  $R swimmer:ppo:$s:3000000 >> $OUT/train_swimmer.log 2>&1
done
$R walker:ppo_lag_inferred:1:3000000 --inferred-run $INFER/walker_wall >> $OUT/train_inferred.log 2>&1
