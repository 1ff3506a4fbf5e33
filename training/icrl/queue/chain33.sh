#!/usr/bin/env bash
# Session 21: Ant's 6 M-step rows to five seeds, the shortest continuation first (inferred seed 3 from 4.7 M, true
# seed 4 from 3.8 M, inferred seed 4 from 3 M), then chain25's and chain24's remaining runs (Ant ICL seeds 3-4,
# walker true cost seed 4); finished runs are skipped.
. "$(dirname "$0")/_env.sh"
. "$(dirname "$0")/_extend.sh"
extend_copy ant ppo_lag_inferred 3 && \
    $RX ant:ppo_lag_inferred:3:6000000 --inferred-run $INFER/ant_wall >> $EXT/train.log 2>&1
extend_copy ant ppo_lag_true 4 && $RX ant:ppo_lag_true:4:6000000 >> $EXT/train.log 2>&1
extend_copy ant ppo_lag_inferred 4 && \
    $RX ant:ppo_lag_inferred:4:6000000 --inferred-run $INFER/ant_wall >> $EXT/train.log 2>&1
$R ant:icl:3:2500000 >> $OUT/train_icl_ant.log 2>&1
$R ant:icl:4:2500000 >> $OUT/train_icl_ant.log 2>&1
$R walker:ppo_lag_true:4:3000000 >> $OUT/train.log 2>&1
