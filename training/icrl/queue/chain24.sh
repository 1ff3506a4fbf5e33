#!/usr/bin/env bash
# Session 19, replaces chain20 + chain22 (the machine's jobs were stopped at the end of session 18): the walker and
# Ant without a constraint to 3 seeds (the rows had 2), then Ant's true-cost expert to 6 M steps (at 3 M its
# feasible reward still rose 90% between the last two fifths), then the walker's true cost to 5 seeds.
. "$(dirname "$0")/_env.sh"
. "$(dirname "$0")/_extend.sh"
$R walker:ppo:2:3000000 >> $OUT/train.log 2>&1
$R ant:ppo:2:3000000 >> $OUT/train.log 2>&1
for s in 0 1 2 3 4; do
    extend_copy ant ppo_lag_true $s && $RX ant:ppo_lag_true:$s:6000000 >> $EXT/train.log 2>&1
done
$R walker:ppo_lag_true:4:3000000 >> $OUT/train.log 2>&1
