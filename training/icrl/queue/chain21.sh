#!/usr/bin/env bash
# Session 18, after chain19: the walker's inferred cost and ICL to 3 seeds; HalfCheetah's inferred cost to 6 M
# steps (beside chain20's true cost); the walker's inferred cost to 5 seeds; HalfCheetah ICL seed 4 (resumes at
# 1.56 M) and Ant ICL seeds 3-4.
. "$(dirname "$0")/_env.sh"
. "$(dirname "$0")/_extend.sh"
$R walker:ppo_lag_inferred:3:3000000 --inferred-run $INFER/walker_wall >> $OUT/train_inferred.log 2>&1
$R walker:icl:2:2500000 >> $OUT/train_icl_walker.log 2>&1
for s in 0 1 2 3 4; do
    extend_copy halfcheetah ppo_lag_inferred $s && \
        $RX halfcheetah:ppo_lag_inferred:$s:6000000 --inferred-run $INFER/halfcheetah_wall >> $EXT/train.log 2>&1
done
$R walker:ppo_lag_inferred:4:3000000 --inferred-run $INFER/walker_wall >> $OUT/train_inferred.log 2>&1
$R halfcheetah:icl:4:4500000 >> $OUT/train_icl_hc.log 2>&1
$R ant:icl:3:2500000 >> $OUT/train_icl_ant.log 2>&1
$R ant:icl:4:2500000 >> $OUT/train_icl_ant.log 2>&1
