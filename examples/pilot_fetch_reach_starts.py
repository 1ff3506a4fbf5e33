"""Pilot: nominal-feature SMDs of paper-protocol Fetch-Reach data under a start box (docs/envs.md, "Balance of
the nominal features"; run from the repository root).

python examples/pilot_fetch_reach_starts.py x0,y0,z0,x1,y1,z1 N_VIOL N_GOOD [POOL.npy]
PILOT_OFFSET=K shifts the seeds; POOL.npy (one row per rollout: good, group, reached, mean inverse goal distance,
mean goal_not_reached, states, start xyz) feeds examples/pilot_fetch_reach_scan.py."""
import sys, json, os, time
import numpy as np, torch
from pbicrl.demonstrators.navigation import make_nav_env
from pbicrl.demonstrators.nav_rollouts import rollout_episodes, policy_actor

from _pilot_balance import expected_smds
torch.set_num_threads(1)
box = [float(v) for v in sys.argv[1].split(",")]
n_v, n_g = int(sys.argv[2]), int(sys.argv[3])
env = make_nav_env("fetch_reach", "true", start="equidistant")
env.start_low, env.start_high = np.array(box[:3]), np.array(box[3:])
OFF = int(os.environ.get("PILOT_OFFSET", "0"))
rows = []; t0 = time.time()
for name, n, seed in (("violating", n_v, 10_000 + OFF), ("good", n_g, 500_000 + OFF)):
    torch.manual_seed(seed)  # the sampled actions (the reset seeds are set per episode)
    act = policy_actor(f"src/pbicrl/data/policies/fetch_reach_{name}.zip", False)
    for ep in rollout_episodes(env, act, n, seed=seed, policy_name=name):
        f = ep.features.mean(0)
        rows.append((name == "good", ep.group, ep.reached, f[0], f[3], len(ep.states), *ep.states[0]))
A = np.array(rows, dtype=float)
if len(sys.argv) > 4: np.save(sys.argv[4], A)
good, grp, reached, igd, gnr, L = A.T[:6]
out = {"box": box, "s_per_rollout": round((time.time() - t0) / len(rows), 3)}
for name, m in (("violating", good == 0), ("good", good == 1)):
    out[name] = {"n": int(m.sum()), "reached": round(float(reached[m].mean()), 3),
                 "groups": [int(((grp == k) & m & (reached == 1)).sum()) for k in (1, 2, 3)],
                 "len": [round(float(L[(grp == k) & m & (reached == 1)].mean()), 2) if ((grp == k) & m & (reached == 1)).any() else None for k in (1, 2, 3)],
                 "igd": [round(float(igd[(grp == k) & m & (reached == 1)].mean()), 3) if ((grp == k) & m & (reached == 1)).any() else None for k in (1, 2, 3)]}
def smd(p_good):
    r = expected_smds(good, grp, reached, {"igd": igd, "gnr": gnr}, p_good)
    return {k: (round(v, 3) if k == "max" else {pair: round(d, 3) for pair, d in v.items()}) for k, v in r.items()}
for p in (0.0, 0.01):
    out[f"p={p}"] = smd(p)
print(json.dumps(out))
