"""Roll out a wall demonstrator N times (stochastic actions unless ``deterministic`` is given; reset seeds
``FIRST_SEED + j``, default 900000+, not used for data) and print how many episodes last 500 steps, cross the
wall, reach wall - 0.5 (complete, not crossing), and the furthest x of each; for Ant also how many complete,
non-crossing episodes end with the torso upside down.

Usage: python examples/check_wall_policy.py ant training/ant_good/model.zip 20 [deterministic] [--first-seed 800000]
"""
import argparse
import json

import numpy as np
import torch

from pbicrl.demonstrators.sac import load_policy
from pbicrl.envs.mujoco_wall import REACH_MARGIN, make_wall_env, rollout_wall_env, wall_spec

ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
ap.add_argument("env", choices=["halfcheetah", "ant"])
ap.add_argument("policy")
ap.add_argument("n", type=int)
ap.add_argument("mode", nargs="?", choices=["stochastic", "deterministic"], default="stochastic")
ap.add_argument("--first-seed", type=int, default=900_000)
args = ap.parse_args()
torch.set_num_threads(1)
torch.manual_seed(0)  # the sampled actions: a rerun gives the same numbers
deterministic = args.mode == "deterministic"
spec = wall_spec(args.env)
pol = load_policy(args.policy)
env = make_wall_env(args.env, constrained=True, max_episode_steps=500)
wrapper = env.env
rows = []
for j in range(args.n):
    ro = rollout_wall_env(env, lambda o: pol.predict(o, deterministic=deterministic)[0], seed=args.first_seed + j,
                          n_steps=500)
    x = ro["x"]
    flipped = args.env == "ant" and wrapper.torso_up_z() < 0.0  # the env is left at the episode's last state
    rows.append((len(x), float(x.max()), bool((x >= spec.wall_x).any()), flipped))
L, M, C, F = (np.array([r[k] for r in rows]) for k in range(4))
ok = (L == 500) & ~C
out = {"path": args.policy, "deterministic": deterministic, "first_seed": args.first_seed, "n": args.n,
       "full_length": int((L == 500).sum()), "cross": int(C.sum()),
       "reach": int(((M >= spec.wall_x - REACH_MARGIN) & ok).sum()),
       "max_x": np.round(np.sort(M), 2).tolist()}
if args.env == "ant":
    out["flipped_complete_not_crossing"] = int((F & ok).sum())
print(json.dumps(out))
