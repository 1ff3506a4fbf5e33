#!/usr/bin/env bash
# Session 19, replaces chain21 + chain23, beside chain24: HalfCheetah ICL seed 4 (resumes at 3 M), then Ant's
# inferred cost to 6 M steps (its seeds reach 6 M at about the pace of chain24's true cost), then Ant ICL seeds 3-4.
. "$(dirname "$0")/_env.sh"
. "$(dirname "$0")/_extend.sh"
$R halfcheetah:icl:4:4500000 >> $OUT/train_icl_hc.log 2>&1
for s in 0 1 2 3 4; do
    extend_copy ant ppo_lag_inferred $s && \
        $RX ant:ppo_lag_inferred:$s:6000000 --inferred-run $INFER/ant_wall >> $EXT/train.log 2>&1
done
$R ant:icl:3:2500000 >> $OUT/train_icl_ant.log 2>&1
$R ant:icl:4:2500000 >> $OUT/train_icl_ant.log 2>&1
