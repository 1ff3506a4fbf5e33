#!/bin/bash
# Blocked Ant: ppo_lag_true and ppo_lag_inferred seeds 0-2, in this order. Each run resumes from its checkpoint and finished runs are skipped: rerun this
# script to go on (docs/benchmarks/icrl/README.md, Resume). Start it niced and detached, e.g.
#   setsid nohup nice -n 19 bash training/icrl/queue/chain3.sh >> chain3.out 2>&1 < /dev/null &
set -u
REPO=$(cd "$(dirname "$0")/../../.." && pwd)
OUT=${ICRL_RUNS:-/work/icrl_runs}  # restore from training/icrl first when missing (README)
INFER=${ICRL_INFER:-/work/icrl_infer}
PY=${PYTHON:-python}
cd "$REPO"
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 PYTHONPATH="$REPO/src"
R="$PY -m pbicrl.cli.icrl_benchmark --out $OUT --run"
$R ant:ppo_lag_inferred:0:3000000 --inferred-run $INFER/ant_wall >> $OUT/train_inferred.log 2>&1
$R ant:ppo_lag_true:1:3000000 >> $OUT/train.log 2>&1
$R ant:ppo_lag_inferred:1:3000000 --inferred-run $INFER/ant_wall >> $OUT/train_inferred.log 2>&1
$R ant:ppo_lag_true:2:3000000 >> $OUT/train.log 2>&1
$R ant:ppo_lag_inferred:2:3000000 --inferred-run $INFER/ant_wall >> $OUT/train_inferred.log 2>&1
