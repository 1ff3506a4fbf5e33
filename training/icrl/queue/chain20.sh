#!/usr/bin/env bash
# Session 18, after chain16: every walker row and Ant without a constraint to 3 seeds, then the walker's
# PPO-Lagrangian rows to 5.
. "$(dirname "$0")/_env.sh"
$R walker:ppo_lag_true:3:3000000 >> $OUT/train.log 2>&1
$R walker:ppo:2:3000000 >> $OUT/train.log 2>&1
$R ant:ppo:2:3000000 >> $OUT/train.log 2>&1
$R walker:ppo_lag_true:4:3000000 >> $OUT/train.log 2>&1
