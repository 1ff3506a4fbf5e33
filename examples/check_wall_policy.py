"""Roll out a wall demonstrator N times (stochastic actions unless ``deterministic`` is given; reset seeds
900000+, not used for data) and print how many episodes last 500 steps, cross the wall, reach wall - 0.5, and the
furthest x of each.

Usage: python examples/check_wall_policy.py ant training/ant_good/model.zip 20 [deterministic]
"""
import json
import sys

import numpy as np
import torch

from pbicrl.demonstrators.sac import load_policy
from pbicrl.envs.mujoco_wall import make_wall_env, rollout_wall_env, wall_spec

torch.set_num_threads(1)
name, path, n = sys.argv[1], sys.argv[2], int(sys.argv[3])
deterministic = len(sys.argv) > 4 and sys.argv[4] == "deterministic"
spec = wall_spec(name)
pol = load_policy(path)
env = make_wall_env(name, constrained=True, max_episode_steps=500)
rows = []
for j in range(n):
    ro = rollout_wall_env(env, lambda o: pol.predict(o, deterministic=deterministic)[0], seed=900_000 + j, n_steps=500)
    x = ro["x"]; rows.append((len(x), float(x.max()), bool((x >= spec.wall_x).any())))
L = np.array([r[0] for r in rows]); M = np.array([r[1] for r in rows]); C = np.array([r[2] for r in rows])
print(json.dumps({"path": path, "deterministic": deterministic, "n": n, "full_length": int((L == 500).sum()), "cross": int(C.sum()),
      "reach": int(((M >= spec.wall_x - 0.5) & ~C & (L == 500)).sum()), "max_x": np.round(np.sort(M), 2).tolist()}))
