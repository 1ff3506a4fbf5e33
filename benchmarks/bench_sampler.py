"""Speed of the compiled sampler vs a straightforward vectorised NumPy implementation, side by side.

Workload (issue spec): 3 groups x 60 trajectories, all 10,800 cross-group pairs, 400,000 iterations.

    python benchmarks/bench_sampler.py            # full run
    python benchmarks/bench_sampler.py --quick    # 40,000 iterations

Prints seconds per chain, likelihood evaluations, pair evaluations per second, the ratio against the NumPy
version (run in the same process for a fraction of the iterations and scaled), and compile times
(cold: empty Numba cache, in a subprocess; warm: loading the on-disk cache).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

from pbicrl.inference.codes import C_EVALS
from pbicrl.inference.likelihood import PreferenceLikelihood
from pbicrl.inference.samplers import build_kernel
from pbicrl.inference.samplers.reference import reference_chain
from pbicrl.inference.synthetic import make_problem

_COMPILE_SNIPPET = """
import time, numpy as np
t = time.perf_counter()
from pbicrl.inference.likelihood import PreferenceLikelihood
from pbicrl.inference.samplers import build_kernel
from pbicrl.inference.synthetic import make_problem
lik = PreferenceLikelihood.from_dataset(make_problem(5, labels="violations", violation_rate=0.5, seed=0).dataset)
k = build_kernel(lik, iterations=10, burn_in=0)
k.run(np.random.default_rng(0), k.init(0), 10)
print(time.perf_counter() - t)
"""


def compile_time(cold: bool) -> float:
    env = dict(os.environ)
    with tempfile.TemporaryDirectory() as d:
        if cold:
            env["NUMBA_CACHE_DIR"] = d
        out = subprocess.run([sys.executable, "-c", _COMPILE_SNIPPET], env=env, capture_output=True, text=True, check=True)
    return float(out.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--iterations", type=int, default=400_000)
    ap.add_argument("--numpy-iterations", type=int, default=4_000)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--json", help="also write the numbers to this file")
    args = ap.parse_args()
    n = 40_000 if args.quick else args.iterations

    prob = make_problem(60, labels="violations", violation_rate=0.4, seed=0)
    lik = PreferenceLikelihood.from_dataset(prob.dataset, margins=[0.0, 2.9])
    pairs = lik.preferences.n_pairs
    print(f"workload: {prob.dataset.n_trajectories} trajectories in 3 groups, {pairs:,} pairs, {n:,} iterations per chain")

    cold = compile_time(cold=True)
    warm = compile_time(cold=False)
    rows = []
    for method in ("paper", "pbicrl"):
        kernel = build_kernel(lik, sampler=method, iterations=n)
        state = kernel.init(0)
        kernel.run(np.random.default_rng(1), state, 10)  # compile outside the timing
        t = time.perf_counter()
        end = kernel.run(np.random.default_rng(1), state, n)
        dt = time.perf_counter() - t
        evals = int(end.counts[C_EVALS])
        rows.append({"implementation": f"compiled ({method})", "seconds_per_chain": dt, "likelihood_evals": evals,
                     "pair_evals_per_s": evals * pairs / dt, "us_per_iteration": dt / n * 1e6})

    m = args.numpy_iterations
    k = build_kernel(lik, sampler="paper", iterations=m)
    s = k.init(0)
    randoms = k.draw_randoms(np.random.default_rng(1), m)
    t = time.perf_counter()
    reference_chain(lik, "paper", s.indicators, s.penalty_weights, randoms)
    dt = time.perf_counter() - t
    rows.append({"implementation": "NumPy, per-iteration broadcast (paper)", "seconds_per_chain": dt * n / m,
                 "likelihood_evals": n, "pair_evals_per_s": m * pairs / dt, "us_per_iteration": dt / m * 1e6,
                 "note": f"measured on {m:,} iterations, scaled to {n:,}"})

    base = rows[-1]["seconds_per_chain"]
    print(f"\n{'implementation':<42} {'s/chain':>9} {'us/iter':>8} {'lik. evals':>11} {'Gpair/s':>8} {'vs NumPy':>9}")
    for r in rows:
        r["speedup_vs_numpy"] = base / r["seconds_per_chain"]
        print(f"{r['implementation']:<42} {r['seconds_per_chain']:9.2f} {r['us_per_iteration']:8.2f} "
              f"{r['likelihood_evals']:11,} {r['pair_evals_per_s'] / 1e9:8.2f} {r['speedup_vs_numpy']:8.1f}x")
    print(f"\ncompile: cold {cold:.1f} s (empty Numba cache, incl. imports), warm {warm:.1f} s (on-disk cache)")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump({"pairs": pairs, "iterations": n, "rows": rows, "compile_cold_s": cold, "compile_warm_s": warm}, fh, indent=2)


if __name__ == "__main__":
    main()
