#!/bin/bash
# Blocked Half-Cheetah: ppo seeds 3 and 4, in this order. Each run resumes from its checkpoint and finished runs are skipped: rerun this
# script to go on (docs/benchmarks/icrl/README.md, Resume). Start it niced and detached, e.g.
#   setsid nohup nice -n 19 bash training/icrl/queue/chain4.sh >> chain4.out 2>&1 < /dev/null &
. "$(dirname "$0")/_env.sh"
$R halfcheetah:ppo:3:1000000 >> $OUT/train.log 2>&1
$R halfcheetah:ppo:4:1000000 >> $OUT/train.log 2>&1
