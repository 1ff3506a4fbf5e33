"""Speed of the identifiability analysis (:func:`pbicrl.analysis.identify.identify`) as the number of features grows.

Synthetic workload (:func:`make_dataset`): N trajectories of 10 states in 3 equal groups, ranked as in the point-mass
data (features 0-3: inverse goal distance, in orange, in red, goal not reached; G2 enters orange, G3 red), plus
``d - 4`` extra features that every candidate list includes:

* ``cells``: one-hot of a random grid cell per state (a trajectory's mean feature is the fraction of its time in
  each cell), the shape of a per-cell constraint search; cells no trajectory visits are constant and skipped;
* ``noise``: a uniform [0, 1] value per state and feature (dense, the worst case for the LPs).

Two rankings: ``separated`` (as simulated: G2 and G3 are told apart by orange and red, so some direction orders
every pair strictly and every candidate penalty is unbounded: the per-feature LPs all run) and ``noisy`` (five G1
trajectories also labelled G3, the same behaviour ranked best and worst: not separable at any d, so there are no
separation-scale LPs; whether recession LPs run depends on the cone).

    nice python benchmarks/bench_identify_features.py [--features 100 1000 10000] [--variants noisy,separated]
        [--kind cells] [--trajectories 300] [--solver auto|highspy|linprog] [--timeout 1800] [--json FILE]

Each row runs in its own process (``--timeout`` seconds at most; its peak memory is that process's): one call of
``identify`` (scipy's import and a warm-up outside it), wall and CPU seconds, and the load average before and after.
``benchmarks/reports/identify.md`` has the numbers.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from pbicrl.inference.data import Dataset


def make_dataset(d: int, *, n: int = 300, length: int = 10, kind: str = "cells", noisy: bool = False,
                 seed: int = 0) -> Dataset:
    """``n`` trajectories in 3 equal groups, ``length`` states each, ``d >= 4`` features (see the module docstring)."""
    if d < 4:
        raise ValueError("d: at least the 4 point-mass features")
    rng = np.random.default_rng(seed)
    group = np.repeat([1, 2, 3], -(-n // 3))[:n]
    S = n * length
    g = np.repeat(group, length)
    feats = np.zeros((S, d))
    feats[:, 0] = rng.uniform(0.05, 0.15, S)                      # inverse goal distance
    feats[:, 1] = (g == 2) & (rng.random(S) < 0.2)                # in the orange region
    feats[:, 2] = (g == 3) & (rng.random(S) < 0.2)                # in the red region
    first = np.arange(n) * length
    feats[first, 1] = group == 2                                  # every G2 trajectory enters orange, G3 red
    feats[first, 2] = group == 3
    feats[:, 3] = 1.0
    feats[first + length - 1, 3] = rng.random(n) < 0.5            # goal reached at the last step or not
    if d > 4 and kind == "cells":
        feats[np.arange(S), 4 + rng.integers(0, d - 4, S)] = 1.0
    elif d > 4 and kind == "noise":
        feats[:, 4:] = rng.random((S, d - 4))
    elif d > 4:
        raise ValueError(f"kind: expected 'cells' or 'noise', got {kind!r}")
    if noisy:  # five G1 trajectories also ranked last (the same behaviour labelled twice): no w orders those pairs
        dup = np.arange(5)
        feats = np.vstack([feats, feats[(dup[:, None] * length + np.arange(length)).ravel()]])
        group = np.r_[group, np.full(dup.size, 3)]
        n += dup.size
    names = ("inv_goal_distance", "in_orange", "in_red", "goal_not_reached") + tuple(f"x{j}" for j in range(d - 4))
    return Dataset(features=feats, offsets=np.arange(n + 1) * length, group=group, feature_names=names,
                   nominal_weights=np.r_[1.0, 0.0, 0.0, -1.0, np.zeros(d - 4)])


def _one(d: int, variant: str, kind: str, trajectories: int, solver: str) -> dict:
    """One row, in this process: time one ``identify`` call (progress bar on stderr after a few seconds)."""
    import resource

    import scipy.optimize  # noqa: F401  (imported lazily by identify; paid once per process)

    import pbicrl.analysis.identify as ident

    ident._WARM = {"auto": None, "highspy": True, "linprog": False}[solver]
    ident.identify(make_dataset(8, n=60))  # warm-up outside the timing
    ds = make_dataset(d, n=trajectories, kind=kind, noisy=variant == "noisy")
    t, c = time.perf_counter(), time.process_time()
    res = ident.identify(ds, progress=True)
    dt, dc = time.perf_counter() - t, time.process_time() - c
    free = sum(f.identifiable is not False or "dependent" in f.reason for f in res.features)
    return {"d": d, "kind": kind, "trajectories": trajectories, "variant": variant, "seconds": dt, "cpu_seconds": dc,
            "n_lp": res.n_lp, "separable": res.separable, "free": free,
            "unbounded": int(sum(f.unbounded for f in res.features)),
            "positive_scale": int(sum((f.min_penalty or 0.0) > 0 for f in res.features)),
            "companions": bool(getattr(res, "companions", True)),
            "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
            "solver": "highspy (warm starts)" if ident._LPSolver(ident._WARM).warm else "scipy linprog"}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--features", nargs="+", default=["100", "1000", "10000"],
                    help="feature counts, space- or comma-separated")
    ap.add_argument("--variants", default="noisy,separated")
    ap.add_argument("--kind", default="cells", choices=("cells", "noise"))
    ap.add_argument("--trajectories", type=int, default=300)
    ap.add_argument("--solver", default="auto", choices=("auto", "highspy", "linprog"),
                    help="auto: warm-started highspy models when installed, else scipy's linprog")
    ap.add_argument("--timeout", type=float, default=1800.0, help="seconds per row (each row is its own process)")
    ap.add_argument("--json")
    ap.add_argument("--one", help=argparse.SUPPRESS)  # internal: run one row, print it as JSON
    args = ap.parse_args()
    if args.one:
        d, variant = args.one.split(":")
        print(json.dumps(_one(int(d), variant, args.kind, args.trajectories, args.solver)))
        return
    import os
    import subprocess
    import sys

    print(f"{'d':>7} {'free':>6} {'variant':<10} {'seconds':>8} {'CPU s':>8} {'LPs':>6} {'separable':>9} "
          f"{'unbounded':>9} {'min|w_p|>0':>10} {'peak MB':>8} {'load':>10}  solver", flush=True)
    rows = []
    for d in (int(x) for f in args.features for x in f.split(",") if x):
        for variant in args.variants.split(","):
            load0 = os.getloadavg()[0]
            cmd = [sys.executable, __file__, "--one", f"{d}:{variant}", "--kind", args.kind,
                   "--trajectories", str(args.trajectories), "--solver", args.solver]
            t = time.perf_counter()
            try:
                out = subprocess.run(cmd, stdout=subprocess.PIPE, text=True, timeout=args.timeout, check=True)
                row = json.loads(out.stdout.strip().splitlines()[-1])
            except subprocess.TimeoutExpired:
                row = {"d": d, "variant": variant, "seconds": None, "timeout": args.timeout}
            row["load"] = [round(load0, 2), round(os.getloadavg()[0], 2)]
            rows.append(row)
            if row.get("seconds") is None:
                print(f"{d:>7} {'':>6} {variant:<10} {'>' + format(time.perf_counter() - t, '.0f'):>8}  "
                      f"(timeout {args.timeout:g} s)  load {row['load'][0]}-{row['load'][1]}", flush=True)
                continue
            print(f"{d:>7} {row['free']:>6} {variant:<10} {row['seconds']:8.2f} {row['cpu_seconds']:8.2f} "
                  f"{row['n_lp']:>6} {str(row['separable']):>9} {row['unbounded']:>9} {row['positive_scale']:>10} "
                  f"{row['peak_rss_mb']:8.0f} {row['load'][0]:>4}-{row['load'][1]:<5}  {row['solver']}"
                  + ("" if row.get("companions", True) else ", no companions"), flush=True)
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(rows, fh, indent=2)


if __name__ == "__main__":
    main()
