# The settings every chain shares: sourced by chain*.sh (set -u; REPO, OUT, INFER, PY, R).
set -u
REPO=$(cd "$(dirname "${BASH_SOURCE[0]}")/../../.." && pwd)
OUT=${ICRL_RUNS:-/work/icrl_runs}  # restore from training/icrl first when missing (README)
INFER=${ICRL_INFER:-/work/icrl_infer}
PY=${PYTHON:-python}
cd "$REPO"
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 PYTHONPATH="$REPO/src"
R="$PY -m pbicrl.cli.icrl_benchmark --out $OUT --run"
# refuse before any run is copied or started: a python without pbicrl's dependencies (e.g. the system one when
# PYTHON is not set) fails every run of the chain in turn, each after extend_copy has copied it
"$PY" -c "import numba, torch, gymnasium, mujoco, pbicrl" 2>/dev/null || {
    echo "queue: $PY cannot import pbicrl and its training dependencies; set PYTHON to the venv's python" >&2; exit 1; }
