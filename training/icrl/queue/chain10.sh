#!/bin/bash
# Biased Pendulum: ppo_lag_true seed 0 extended from 1 M to the benchmark expert's 10 M steps (at 1 M it was no expert:
# violation 1.00), then the unconstrained ppo seed 0 to 3 M. Each run resumes from its checkpoint (a larger STEPS
# extends a finished run) and finished runs are skipped: rerun this script to go on. Start it niced and detached, e.g.
#   setsid nohup nice -n 19 bash training/icrl/queue/chain10.sh >> chain10.out 2>&1 < /dev/null &
. "$(dirname "$0")/_env.sh"
# $R pendulum:ppo_lag_true:0:10000000 >> $OUT/train.log 2>&1   # done; see below
# $R pendulum:ppo:0:3000000 >> $OUT/train.log 2>&1   # done; see below
# Session 16: done, and retired. Its ppo_lag_true run (the benchmark's nu_0) was moved to
# pendulum/ppo_lag_true_benchmark_nu0/seed0; pendulum/ppo_lag_true/seed0 is now the nu_0 = 10 run of chain12.sh,
# which the first line would extend by mistake: both lines are commented out.
