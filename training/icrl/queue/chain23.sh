#!/usr/bin/env bash
# Session 18, after chain21: Ant's inferred cost to 6 M steps, beside chain22.
. "$(dirname "$0")/_env.sh"
. "$(dirname "$0")/_extend.sh"
for s in 0 1 2 3 4; do
    extend_copy ant ppo_lag_inferred $s && \
        $RX ant:ppo_lag_inferred:$s:6000000 --inferred-run $INFER/ant_wall >> $EXT/train.log 2>&1
done
