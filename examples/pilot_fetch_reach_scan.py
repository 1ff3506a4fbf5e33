"""Scan sub-boxes of a pilot pool (examples/pilot_fetch_reach_starts.py ... POOL.npy) for the expected largest
nominal-feature |SMD| at p_good = 0.01. The minimum over many boxes is optimistic: confirm a chosen box with a
fresh pilot (other PILOT_OFFSET).

python examples/pilot_fetch_reach_scan.py POOL.npy
"""
import numpy as np, itertools, sys
A = np.load(sys.argv[1])
good, grp, reached, igd, gnr, L, x0, y0, z0 = A.T
def smd(sel, p_good=0.01):
    g = good[sel]; w = np.where(g == 1, p_good / max(g.sum(), 1), (1 - p_good) / (g == 0).sum())
    keep = reached[sel] == 1; gr = grp[sel]; res = {}
    for fname, x in (("igd", igd[sel]), ("gnr", gnr[sel])):
        mu, var = {}, {}
        for k in (1, 2, 3):
            m = keep & (gr == k); ww = w[m]
            if ww.sum() == 0: return None
            mu[k] = np.sum(ww * x[m]) / ww.sum(); var[k] = np.sum(ww * (x[m] - mu[k]) ** 2) / ww.sum()
        for a, b in ((1, 2), (1, 3), (2, 3)):
            res[f"{fname}{a}{b}"] = (mu[a] - mu[b]) / np.sqrt((var[a] + var[b]) / 2)
    return res
rows = []
for xl, yl, yh, zh in itertools.product([1.15, 1.20, 1.25], np.arange(0.50, 0.76, 0.05), np.arange(1.05, 1.31, 0.05), [0.80, 0.90]):
    sel = (x0 >= xl - 0.01) & (y0 >= yl) & (y0 <= yh) & (z0 <= zh + 0.01)
    r = smd(sel)
    if r is None: continue
    nv = int((sel & (good == 0)).sum()); ng = int((sel & (good == 1)).sum())
    frac = [float(np.mean(grp[sel & (good == 0)] == k)) for k in (1, 2, 3)]
    rows.append((max(abs(v) for v in r.values()), xl, round(yl, 2), round(yh, 2), zh, nv, ng, np.round(frac, 2).tolist(), {k: round(v, 2) for k, v in r.items()}))
rows.sort(key=lambda t: t[0])
for r in rows[:15]: print(r)
print("equidistant-like:", [r for r in rows if r[1] == 1.25 and r[2] == 0.6 and r[3] == 1.2 and r[4] == 0.9])
