"""Scan sub-boxes of a pilot pool (examples/pilot_fetch_reach_starts.py ... POOL.npy) for the expected largest
nominal-feature |SMD| at p_good = 0.01. The minimum over many boxes is optimistic: confirm a chosen box with a
fresh pilot (other PILOT_OFFSET).

python examples/pilot_fetch_reach_scan.py POOL.npy
"""
import numpy as np, itertools, sys

from _pilot_balance import expected_smds
A = np.load(sys.argv[1])
good, grp, reached, igd, gnr, L, x0, y0, z0 = A.T
def smd(sel, p_good=0.01):
    r = expected_smds(good[sel], grp[sel], reached[sel], {"igd": igd[sel], "gnr": gnr[sel]}, p_good)
    return None if r is None else {f"{f}{pair.replace('-', '')}": d for f in ("igd", "gnr") for pair, d in r[f].items()}
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
