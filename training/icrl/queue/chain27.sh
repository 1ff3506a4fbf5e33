#!/usr/bin/env bash
# Session 19: HalfCheetah's PPO-Lagrangian rows to 10 M steps, seeds from 4 down (_hc10m.sh), then chain24.sh.
SEEDS="4 3 2 1 0" NEXT=chain24.sh
. "$(dirname "$0")/_hc10m.sh"
