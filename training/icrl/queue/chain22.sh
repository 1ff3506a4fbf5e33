#!/usr/bin/env bash
# Session 18, after chain20: Ant's true-cost expert to 6 M steps (at 3 M its feasible reward still rose 90%
# between the last two fifths of training).
. "$(dirname "$0")/_env.sh"
. "$(dirname "$0")/_extend.sh"
for s in 0 1 2 3 4; do
    extend_copy ant ppo_lag_true $s && $RX ant:ppo_lag_true:$s:6000000 >> $EXT/train.log 2>&1
done
