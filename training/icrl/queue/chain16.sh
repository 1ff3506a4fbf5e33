#!/usr/bin/env bash
# Session 17, after chain15: rows with fewer than 3 seeds. The walker's true cost (2 of 5), Ant without a
# constraint (1 of 5), the walker without a constraint (1 of 5).
. "$(dirname "$0")/_env.sh"
$R walker:ppo_lag_true:2:3000000 >> $OUT/train.log 2>&1
$R ant:ppo:1:3000000 >> $OUT/train.log 2>&1
$R walker:ppo:1:3000000 >> $OUT/train.log 2>&1
