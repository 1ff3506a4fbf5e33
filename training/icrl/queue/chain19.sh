#!/usr/bin/env bash
# Session 17, beside chain16: the walker's inferred cost seed 2 (the row has 2 of 5), then walker ICL seed 1.
. "$(dirname "$0")/_env.sh"
$R walker:ppo_lag_inferred:2:3000000 --inferred-run $INFER/walker_wall >> $OUT/train_inferred.log 2>&1
$R walker:icl:1:2500000 >> $OUT/train_icl_walker.log 2>&1
