#!/bin/bash
# Blocked Ant ICL seed 0, Blocked Walker ppo_lag_true seed 0, Blocked Ant ICL seeds 1 and 2, in this order. Each run resumes from its checkpoint and finished runs are skipped: rerun this
# script to go on (docs/benchmarks/icrl/README.md, Resume). Start it niced and detached, e.g.
#   setsid nohup nice -n 19 bash training/icrl/queue/chain7.sh >> chain7.out 2>&1 < /dev/null &
. "$(dirname "$0")/_env.sh"
$R ant:icl:0:2500000 >> $OUT/train_icl_ant.log 2>&1
$R walker:ppo_lag_true:0:3000000 >> $OUT/train.log 2>&1
$R ant:icl:1:2500000 >> $OUT/train_icl_ant.log 2>&1
$R ant:icl:2:2500000 >> $OUT/train_icl_ant.log 2>&1
