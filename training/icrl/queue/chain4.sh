#!/bin/bash
# Blocked Half-Cheetah: ppo seeds 3 and 4, in this order. Each run resumes from its checkpoint and finished runs are skipped: rerun this
# script to go on (docs/benchmarks/icrl/README.md, Resume). Start it niced and detached, e.g.
#   setsid nohup nice -n 19 bash training/icrl/queue/chain4.sh >> chain4.out 2>&1 < /dev/null &
set -u
REPO=$(cd "$(dirname "$0")/../../.." && pwd)
OUT=${ICRL_RUNS:-/work/icrl_runs}  # restore from training/icrl first when missing (README)
INFER=${ICRL_INFER:-/work/icrl_infer}
PY=${PYTHON:-python}
cd "$REPO"
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 PYTHONPATH="$REPO/src"
R="$PY -m pbicrl.cli.icrl_benchmark --out $OUT --run"
$R halfcheetah:ppo:3:1000000 >> $OUT/train.log 2>&1
$R halfcheetah:ppo:4:1000000 >> $OUT/train.log 2>&1
