#!/bin/bash
# Blocked Ant ICL seed 0, Blocked Walker ppo_lag_true seed 0, Blocked Ant ICL seeds 1 and 2, in this order. Each run resumes from its checkpoint and finished runs are skipped: rerun this
# script to go on (docs/benchmarks/icrl/README.md, Resume). Start it niced and detached, e.g.
#   setsid nohup nice -n 19 bash training/icrl/queue/chain7.sh >> chain7.out 2>&1 < /dev/null &
set -u
REPO=$(cd "$(dirname "$0")/../../.." && pwd)
OUT=${ICRL_RUNS:-/work/icrl_runs}  # restore from training/icrl first when missing (README)
INFER=${ICRL_INFER:-/work/icrl_infer}
PY=${PYTHON:-python}
cd "$REPO"
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 PYTHONPATH="$REPO/src"
R="$PY -m pbicrl.cli.icrl_benchmark --out $OUT --run"
$R ant:icl:0:2500000 >> $OUT/train_icl_ant.log 2>&1
$R walker:ppo_lag_true:0:3000000 >> $OUT/train.log 2>&1
$R ant:icl:1:2500000 >> $OUT/train_icl_ant.log 2>&1
$R ant:icl:2:2500000 >> $OUT/train_icl_ant.log 2>&1
