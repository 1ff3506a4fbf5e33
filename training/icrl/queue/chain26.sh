#!/usr/bin/env bash
# Session 19: HalfCheetah's PPO-Lagrangian rows to 10 M steps, seeds from 0 up (_hc10m.sh), then chain25.sh.
SEEDS="0 1 2 3 4" NEXT=chain25.sh
. "$(dirname "$0")/_hc10m.sh"
