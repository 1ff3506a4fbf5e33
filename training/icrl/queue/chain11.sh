#!/bin/bash
# Blocked Swimmer: ppo_lag_true seed 0 extended from 3 M to the benchmark expert's 5 M steps (at 3 M it was no expert:
# violation 1.00, multiplier about 22), then the unconstrained ppo seed 0 (3 M). Each run resumes from its checkpoint
# (a larger STEPS extends a finished run); rerun this script to go on. Start it niced and detached, e.g.
#   setsid nohup nice -n 19 bash training/icrl/queue/chain11.sh >> chain11.out 2>&1 < /dev/null &
. "$(dirname "$0")/_env.sh"
# $R swimmer:ppo_lag_true:0:5000000 >> $OUT/train.log 2>&1   # done; see below
# $R swimmer:ppo:0:3000000 >> $OUT/train.log 2>&1   # done; see below
# Session 16: done, and retired. Its ppo_lag_true run (the benchmark's nu_0) was moved to
# swimmer/ppo_lag_true_benchmark_nu0/seed0; swimmer/ppo_lag_true/seed0 is now the nu_0 = 30 run of chain14.sh,
# which the first line would extend by mistake: both lines are commented out.
