"""Speed of the identifiability analysis (:func:`pbicrl.analysis.identify.identify`) as the number of trajectories grows.

Workload: 3 groups, d = 4 features shaped like the point-mass data (a continuous goal term, two region
fractions, a goal-not-reached term), trajectories of 10 states; N = 10^3, 10^4, 10^5. Two variants:
``separated`` (the best group never enters a region, as with the paper's labelling; every penalty is
unbounded) and ``noisy`` (5% of the labels shuffled, so the rankings are not separable). The time includes the
mean features and all LPs; scipy's import (paid once per process) is timed separately.

    nice python benchmarks/bench_identify.py [--sizes 1000,10000,100000] [--repeat 3] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from pbicrl.inference.data import Dataset


def make_dataset(n: int, *, noisy: bool, length: int = 10, seed: int = 0) -> Dataset:
    """``n`` trajectories in 3 equal groups, ``length`` states each, d = 4."""
    rng = np.random.default_rng(seed)
    group = np.repeat([1, 2, 3], -(-n // 3))[:n]
    S = n * length
    feats = np.zeros((S, 4))
    g = np.repeat(group, length)
    feats[:, 0] = rng.uniform(0.05, 0.15, S)                      # inverse goal distance
    feats[:, 1] = (g == 2) & (rng.random(S) < 0.2)                # in the orange region
    feats[:, 2] = (g == 3) & (rng.random(S) < 0.2)                # in the red region
    first = np.arange(n) * length
    feats[first, 1] = group == 2                                  # every G2 trajectory enters orange, G3 red
    feats[first, 2] = group == 3
    feats[:, 3] = 1.0
    feats[np.arange(n) * length + length - 1, 3] = rng.random(n) < 0.5  # goal reached at the last step or not
    if noisy:
        flip = rng.random(n) < 0.05
        group = group.copy()
        group[flip] = rng.integers(1, 4, flip.sum())
    return Dataset(features=feats, offsets=np.arange(n + 1) * length, group=group,
                   feature_names=("inv_goal_distance", "in_orange", "in_red", "goal_not_reached"),
                   nominal_weights=np.array([1.0, 0.0, 0.0, -1.0]))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", default="1000,10000,100000")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--json")
    args = ap.parse_args()
    t = time.perf_counter()
    import scipy.optimize  # noqa: F401  (imported lazily by identify; paid once per process)
    t_import = time.perf_counter() - t
    from pbicrl.analysis.identify import identify

    identify(make_dataset(300, noisy=False))  # warm-up outside the timing
    print(f"scipy.optimize import: {t_import:.3f} s (once per process, not included below)")
    print(f"\n{'N':>8} {'variant':<10} {'best s':>8} {'median s':>9} {'LPs':>5} {'separable':>9} {'unbounded':>10}")
    rows = []
    for n in (int(x) for x in args.sizes.split(",")):
        for noisy in (False, True):
            times = []
            for r in range(args.repeat):
                ds = make_dataset(n, noisy=noisy, seed=r)
                t = time.perf_counter()
                res = identify(ds)
                times.append(time.perf_counter() - t)
            row = {"n": n, "variant": "noisy" if noisy else "separated", "best_s": min(times),
                   "median_s": float(np.median(times)), "n_lp": res.n_lp, "separable": res.separable,
                   "unbounded": [f.name for f in res.features if f.unbounded]}
            rows.append(row)
            print(f"{n:>8} {row['variant']:<10} {row['best_s']:8.3f} {row['median_s']:9.3f} {res.n_lp:>5} "
                  f"{str(res.separable):>9} {len(row['unbounded']):>10}")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump({"scipy_import_s": t_import, "rows": rows}, fh, indent=2)


if __name__ == "__main__":
    main()
