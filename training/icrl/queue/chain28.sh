#!/usr/bin/env bash
# Session 20, replaces chain25 (stopped after Ant ppo_lag_inferred seed 1 reached 6 M): ICL on the pendulum, which
# gained an ICL environment this session (2 M PPO steps, ~9 min per seed here), then the rest of chain25: Ant's
# inferred cost to 6 M steps for seeds 2-4 and Ant ICL seeds 3-4. Beside chain24 and chain29.
. "$(dirname "$0")/_env.sh"
. "$(dirname "$0")/_extend.sh"
for s in 0 1 2 3 4; do
    $R pendulum:icl:$s:2000000 >> $OUT/train_icl_pendulum.log 2>&1
done
for s in 0 1 2 3 4; do
    extend_copy ant ppo_lag_inferred $s && \
        $RX ant:ppo_lag_inferred:$s:6000000 --inferred-run $INFER/ant_wall >> $EXT/train.log 2>&1
done
$R ant:icl:3:2500000 >> $OUT/train_icl_ant.log 2>&1
$R ant:icl:4:2500000 >> $OUT/train_icl_ant.log 2>&1
