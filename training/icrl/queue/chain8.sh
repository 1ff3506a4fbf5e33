#!/bin/bash
# Blocked Walker: `ppo` (no cost) seed 0, the unconstrained policy its ranked demonstrations need (group 3), then
# HalfCheetah `icl` seeds 3 and 4. Each run resumes from its checkpoint and finished runs are skipped: rerun this
# script to go on (docs/benchmarks/icrl/README.md, Resume). Start it niced and detached, e.g.
#   setsid nohup nice -n 19 bash training/icrl/queue/chain8.sh >> chain8.out 2>&1 < /dev/null &
. "$(dirname "$0")/_env.sh"
$R walker:ppo:0:3000000 >> $OUT/train.log 2>&1
$R halfcheetah:icl:3:4500000 >> $OUT/train_icl_hc.log 2>&1
$R halfcheetah:icl:4:4500000 >> $OUT/train_icl_hc.log 2>&1
