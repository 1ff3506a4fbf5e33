"""Pilot: nominal-feature SMDs of paper-protocol Fetch-Reach data under a start box (docs/envs.md, "Balance of
the nominal features"; run from the repository root).

python examples/pilot_fetch_reach_starts.py x0,y0,z0,x1,y1,z1 N_VIOL N_GOOD [POOL.npy]
PILOT_OFFSET=K shifts the seeds; POOL.npy (one row per rollout: good, group, reached, mean inverse goal distance,
mean goal_not_reached, states, start xyz) feeds examples/pilot_fetch_reach_scan.py."""
import sys, json, os, time
import numpy as np, torch
from pbicrl.demonstrators.navigation import make_nav_env
from pbicrl.demonstrators.nav_rollouts import rollout_episodes, policy_actor
torch.set_num_threads(1)
box = [float(v) for v in sys.argv[1].split(",")]
n_v, n_g = int(sys.argv[2]), int(sys.argv[3])
env = make_nav_env("fetch_reach", "true", start="equidistant")
env.start_low, env.start_high = np.array(box[:3]), np.array(box[3:])
OFF = int(os.environ.get("PILOT_OFFSET", "0"))
rows = []; t0 = time.time()
for name, n, seed in (("violating", n_v, 10_000 + OFF), ("good", n_g, 500_000 + OFF)):
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
    w = np.where(good == 1, p_good / max((good == 1).sum(), 1), (1 - p_good) / (good == 0).sum())
    keep = reached == 1; res = {}
    for fname, x in (("igd", igd), ("gnr", gnr)):
        mu, var = {}, {}
        for k in (1, 2, 3):
            m = keep & (grp == k); ww = w[m]
            mu[k] = np.sum(ww * x[m]) / ww.sum(); var[k] = np.sum(ww * (x[m] - mu[k]) ** 2) / ww.sum()
        res[fname] = {f"{a}-{b}": round(float((mu[a] - mu[b]) / np.sqrt((var[a] + var[b]) / 2)), 3) for a, b in ((1, 2), (1, 3), (2, 3))}
    res["max"] = max(abs(v) for f in ("igd", "gnr") for v in res[f].values())
    return res
for p in (0.0, 0.01):
    out[f"p={p}"] = smd(p)
print(json.dumps(out))
