#!/usr/bin/env bash
# Session 21: Ant's inferred cost seed 3 to 6 M steps (from 4.7 M), then chain34 (the rest of Ant's 6 M rows, Ant
# 10 M, the main table's remaining runs). Ran as a longer list until its first run; chain34 took over from there.
. "$(dirname "$0")/_env.sh"
. "$(dirname "$0")/_extend.sh"
extend_copy ant ppo_lag_inferred 3 && \
    $RX ant:ppo_lag_inferred:3:6000000 --inferred-run $INFER/ant_wall >> $EXT/train.log 2>&1
exec bash "$(dirname "$0")/chain34.sh"
