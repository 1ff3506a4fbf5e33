"""Pilot: expected nominal-feature SMDs of the paper-protocol point-mass data under a start distribution
(the script behind docs/envs.md, "Balance of the nominal features"; run from the repository root).

python examples/pilot_point_mass_starts.py SPEC N_VIOL N_GOOD [deterministic]
SPEC: ``edges`` (the environment's default), ``edges:LO[:DEPTH]`` (strips [0, DEPTH] x [LO, 19] along both
edges; ``edges:5:2.5`` is ``start="balanced"``) or ``arc:R:a0-a1,a2-a3,...``. PILOT_OFFSET=K shifts the seeds.
Prints the pools' group counts and lengths and the largest expected |SMD| for p_good 0, 0.005, 0.01, 0.02
(the pools reweighted). Arc angles in degrees: start = goal - R (cos a, sin a), a uniform on the union of the intervals (by length), and
mirrored about the diagonal (a -> 90 - a) with probability 1/2.
"""
import sys, json
import numpy as np
import torch
from pbicrl.envs.point_mass import PointMassEnv
from pbicrl.demonstrators.nav_rollouts import rollout_episodes, policy_actor

from _pilot_balance import expected_smds

torch.set_num_threads(1)
spec, n_v, n_g = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
det = len(sys.argv) > 4 and sys.argv[4] == "deterministic"
env = PointMassEnv("true")
if spec.startswith("edges:"):
    parts = spec.split(":")
    lo = float(parts[1]); A = float(parts[2]) if len(parts) > 2 else 1.0
    def sample_start(rng, edge=None):
        edge = "left" if rng.random() < 0.5 else "bottom"
        along, across = rng.uniform(lo, 19.0), rng.uniform(0.0, A)
        return (np.array([across, along]) if edge == "left" else np.array([along, across])), edge
    env.sample_start = sample_start
elif spec != "edges":
    _, R, ivs = spec.split(":")
    R = float(R)
    ivs = [tuple(map(float, s.split("-"))) for s in ivs.split(",")]
    lens = np.array([b - a for a, b in ivs])
    def sample_start(rng, edge=None):
        k = rng.choice(len(ivs), p=lens / lens.sum())
        a = rng.uniform(*ivs[k])
        if rng.random() < 0.5:
            a = 90.0 - a
        r = np.deg2rad(a)
        return np.array([20.0 - R * np.cos(r), 20.0 - R * np.sin(r)]), "arc"
    env.sample_start = sample_start
rows = []
OFF = int(__import__("os").environ.get("PILOT_OFFSET", "0"))
for name, n, seed in (("violating", n_v, 10_000 + OFF), ("good", n_g, 500_000 + OFF)):
    torch.manual_seed(seed)  # the sampled actions (the reset seeds are set per episode)
    act = policy_actor(f"src/pbicrl/data/policies/point_mass_{name}.zip", det)
    for ep in rollout_episodes(env, act, n, seed=seed, policy_name=name):
        f = ep.features.mean(0)
        rows.append((name == "good", ep.group, ep.reached, f[0], f[3], len(ep.states)))
A = np.array(rows, dtype=float)
good, grp, reached, igd, gnr, L = A.T
out = {"spec": spec, "det": det}
for name, m in (("violating", good == 0), ("good", good == 1)):
    out[name] = {"n": int(m.sum()), "reached": float(reached[m].mean()),
                 "groups": [int(((grp == k) & m).sum()) for k in (1, 2, 3)],
                 "len_by_group": [round(float(L[(grp == k) & m].mean()), 2) if ((grp == k) & m).any() else None for k in (1, 2, 3)]}
def smd_table(p_good):
    r = expected_smds(good, grp, reached, {"inv_goal_distance": igd, "goal_not_reached": gnr}, p_good)
    return {k: (round(v, 3) if k == "max" else {pair: round(d, 3) for pair, d in v.items()}) for k, v in r.items()}
for p in (0.0, 0.005, 0.01, 0.02):
    out[f"p_good={p}"] = smd_table(p)
print(json.dumps(out))
