#!/usr/bin/env bash
# Session 19: HalfCheetah's PPO-Lagrangian rows to 10 M steps, seeds from 4 down (_hcext.sh), then chain24.sh.
SEEDS="4 3 2 1 0" STEPS=10000000 FROM=${ICRL_6M:-/work/icrl_6m} TO=${ICRL_10M:-/work/icrl_10m} NEXT=chain24.sh
. "$(dirname "$0")/_hcext.sh"
