#!/bin/bash
# Blocked Half-Cheetah: ICL seeds 0-2, in this order. Each run resumes from its checkpoint and finished runs are skipped: rerun this
# script to go on (docs/benchmarks/icrl/README.md, Resume). Start it niced and detached, e.g.
#   setsid nohup nice -n 19 bash training/icrl/queue/chain6.sh >> chain6.out 2>&1 < /dev/null &
. "$(dirname "$0")/_env.sh"
$PY -m pbicrl.cli.icrl_benchmark --out $OUT --run halfcheetah:icl:0:4500000 --run halfcheetah:icl:1:4500000 --run halfcheetah:icl:2:4500000 >> $OUT/train_icl_hc.log 2>&1
