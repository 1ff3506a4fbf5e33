#!/usr/bin/env bash
# Session 19: HalfCheetah's PPO-Lagrangian rows to 10 M steps, seeds from 0 up (_hcext.sh), then chain25.sh.
SEEDS="0 1 2 3 4" STEPS=10000000 FROM=${ICRL_6M:-/work/icrl_6m} TO=${ICRL_10M:-/work/icrl_10m} NEXT=chain25.sh
. "$(dirname "$0")/_hcext.sh"
