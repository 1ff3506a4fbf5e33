#!/usr/bin/env bash
# Session 20, after chain29 (started by /work/after.sh "[c]hain29.sh"): HalfCheetah's PPO-Lagrangian rows from 10 M
# to 20 M steps, the benchmark's largest budget, seeds from 0 up (_hcext.sh): the expert still rose 12% between the
# last two fifths at 10 M; does it flatten before 20 M?
SEEDS="0 1 2 3 4" STEPS=20000000 FROM=${ICRL_10M:-/work/icrl_10m} TO=${ICRL_20M:-/work/icrl_20m}
. "$(dirname "$0")/_hcext.sh"
