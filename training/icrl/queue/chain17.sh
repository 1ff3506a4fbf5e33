#!/usr/bin/env bash
# Session 17: Ant's true cost seed 4 (beside chain18's inferred seed 4: the rows of the one missed target).
. "$(dirname "$0")/_env.sh"
$R ant:ppo_lag_true:4:3000000 >> $OUT/train.log 2>&1
