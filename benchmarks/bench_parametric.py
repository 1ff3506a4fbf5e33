"""Speed of parametric inference with the location sampled: binary-search counts vs a naive recount.

Workload (issue spec): 2 groups x 100 trajectories x 500 steps, all 10,000 pairs, 400,000 iterations with
theta sampled (the HalfCheetah/Ant setting: an axis halfspace x >= theta).

    python benchmarks/bench_parametric.py [--iterations N] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from pbicrl.inference.codes import C_EVALS, C_T_PROP
from pbicrl.inference.constraints import AxisHalfspace, ConstraintSet
from pbicrl.inference.likelihood import PreferenceLikelihood
from pbicrl.inference.samplers import build_kernel
from pbicrl.inference.synthetic import make_wall_problem


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--iterations", type=int, default=400_000)
    ap.add_argument("--json")
    args = ap.parse_args()
    n = args.iterations
    ds = make_wall_problem(100, length=500, seed=0).dataset
    lik = PreferenceLikelihood.from_dataset(ds)
    cs = ConstraintSet((AxisHalfspace(0, name="wall"),), ds)
    print(f"workload: {ds.n_trajectories} trajectories x {ds.lengths[0]} steps, {lik.preferences.n_pairs:,} pairs, "
          f"{n:,} iterations per chain")
    rows = []
    for method, kw in (("paper", {"f_s": 3, "sigma": 1.0}), ("pbicrl", {"sigma": 1.0})):
        for naive in (False, True):
            kernel = build_kernel(lik, constraints=cs, sampler=method, iterations=n, sigma_theta=0.5,
                                  naive_counts=naive, **kw)
            state = kernel.init(0)
            kernel.run(np.random.default_rng(1), state, 10)  # compile outside the timing
            t = time.perf_counter()
            end = kernel.run(np.random.default_rng(1), state, n)
            dt = time.perf_counter() - t
            rows.append({"method": method, "counts": "naive O(N T)" if naive else "binary search O(N log T)",
                         "seconds_per_chain": dt, "theta_proposals": int(end.counts[C_T_PROP]),
                         "likelihood_evals": int(end.counts[C_EVALS])})
    print(f"\n{'sampler':<8} {'parameter counts':<26} {'s/chain':>8} {'theta proposals':>16} {'lik. evals':>11}")
    for r in rows:
        print(f"{r['method']:<8} {r['counts']:<26} {r['seconds_per_chain']:8.2f} {r['theta_proposals']:16,} {r['likelihood_evals']:11,}")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump({"iterations": n, "rows": rows}, fh, indent=2)


if __name__ == "__main__":
    main()
