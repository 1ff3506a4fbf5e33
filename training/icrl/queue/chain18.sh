#!/usr/bin/env bash
# Session 17: Ant's inferred cost seed 4 (beside chain17's true-cost seed 4).
. "$(dirname "$0")/_env.sh"
$R ant:ppo_lag_inferred:4:3000000 --inferred-run $INFER/ant_wall >> $OUT/train_inferred.log 2>&1
