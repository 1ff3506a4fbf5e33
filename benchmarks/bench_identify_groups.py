"""Identifiability analysis over many groups (issue 18): time and peak memory against the number of groups K.

Workload: N trajectories with 2 features ranked by the return ``f0 - 2 f1`` (plus ``--noise`` times a standard
normal), cut into K equal groups (K = N: a total ranking), nominal weights 0. Without noise the rankings are
separable and both penalties unbounded (along ``(1, -2)``); with noise they are not. Times :func:`pbicrl.analysis.identify.identify` (candidates: both features, default
margins, alpha 0.05) and its peak traced memory, for this checkout and, with ``--baseline FILE``, for another
version of ``identify.py`` (e.g. ``git show df0b1de:src/pbicrl/analysis/identify.py > /tmp/identify_old.py``)
loaded in its place, rows alternating. ``Dataset`` refuses more than ``MAX_GROUPS`` groups; that cap is lifted
here (it belongs to the data module, not to the analysis).

    nice python benchmarks/bench_identify_groups.py [--groups 30,300,1000,20000] [--baseline FILE] [--json FILE]
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import sys
import time
import tracemalloc
import warnings
from typing import Any, Callable

import numpy as np

import pbicrl.inference.data as data_mod
from pbicrl.inference.data import Dataset


def make_ranking(n: int, K: int, noise: float = 0.0, seed: int = 0) -> Dataset:
    rng = np.random.default_rng(seed)
    F = rng.uniform(0, 1, (n, 2))
    ret = F @ np.array([1.0, -2.0]) + noise * rng.standard_normal(n)
    group = np.empty(n, dtype=np.int64)
    group[np.argsort(-ret)] = np.repeat(np.arange(1, K + 1), -(-n // K))[:n]
    return Dataset(features=F, offsets=np.arange(n + 1), group=group, feature_names=["f0", "f1"],
                   nominal_weights=[0.0, 0.0])


def _load(path: str) -> Callable[..., Any]:
    spec = importlib.util.spec_from_file_location("identify_baseline", path)
    mod = importlib.util.module_from_spec(spec)  # type: ignore[arg-type]
    sys.modules[spec.name] = mod  # dataclasses look their module up while the class is built
    spec.loader.exec_module(mod)  # type: ignore[union-attr]
    return mod.identify


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=20_000, help="trajectories")
    ap.add_argument("--groups", default="3,30,300,1000,20000")
    ap.add_argument("--baseline", help="another identify.py, timed on the same data (only up to --baseline-max)")
    ap.add_argument("--baseline-max", type=int, default=300, help="largest K for the baseline (its LP is K^2)")
    ap.add_argument("--noise", type=float, default=0.0)
    ap.add_argument("--json")
    args = ap.parse_args()
    warnings.simplefilter("ignore")
    data_mod.MAX_GROUPS = 10**7
    from pbicrl.analysis.identify import identify

    from scipy.optimize import linprog  # noqa: F401  (import paid once, outside the timings)

    impls = [("now", identify)] + ([("before", _load(args.baseline))] if args.baseline else [])
    rows = []
    print(f"{'K':>7} {'code':<7} {'s':>7} {'peak MB':>8} {'LPs':>4} separable unbounded, directions")
    for K in (int(k) for k in args.groups.split(",")):
        ds = make_ranking(args.n, K, args.noise)
        for name, fn in impls:
            if name == "before" and K > args.baseline_max:
                continue
            t = time.perf_counter()
            res = fn(ds, candidates=["f0", "f1"], penalty_sign="any")
            dt = time.perf_counter() - t
            tracemalloc.start()  # a second call for the memory (tracing slows allocation-heavy code)
            fn(ds, candidates=["f0", "f1"], penalty_sign="any")
            peak = tracemalloc.get_traced_memory()[1] / 1e6
            tracemalloc.stop()
            rows.append({"K": K, "code": name, "seconds": dt, "peak_mb": peak, "n_lp": res.n_lp,
                         "separable": bool(res.separable),
                         "ends": {f.name: f.penalty_range for f in res.features},
                         "directions": [dict(x) for x in res.unbounded_directions]})
            print(f"{K:7,} {name:<7} {dt:7.2f} {peak:8.1f} {res.n_lp:4d} {res.separable!s:<9} "
                  f"{[f.direction for f in res.features]} {rows[-1]['directions']}", flush=True)
    if args.json:
        with open(args.json, "w") as fh:
            json.dump({"n": args.n, "rows": rows}, fh, indent=2, default=str)


if __name__ == "__main__":
    main()
