"""Seconds per chain with the pairwise (paper Eq. 7) and the grouped Plackett-Luce likelihood, and the cost of the
pairwise kernel's wide-spread path before and after it was made cheap.

    python benchmarks/bench_grouped.py            # full run (a few minutes on a loaded 2-core box)
    python benchmarks/bench_grouped.py --quick    # fewer iterations everywhere
    python benchmarks/bench_grouped.py --json out.json

Sections (every chain is timed after compiling on a few iterations; one process, one core):

1. 3 groups x 60 trajectories (``make_problem(60, labels="violations")``, margins (0, 2.9) as in
   ``bench_sampler.py``): ``paper`` and ``pbicrl`` chains of ``--iterations`` (400,000) per likelihood, timed whole.
2. 3 groups x 20,000 trajectories (synthetic mean features, ranked by a noisy return): a pairwise evaluation
   visits 1.2e9 pairs, so only ``--big-pairwise`` / ``--big-grouped`` iterations are run and the time is
   **extrapolated linearly** to 400,000 iterations (printed as such).
3. Wide spreads: the shipped ``point_mass`` data with a flat prior on [-10000, 10000] (``pbicrl infer point_mass
   --prior-bounds=-10000,10000``): returns spread over thousands of nats, so most blocks leave the one-centre
   kernel. The chain (``--wide-iterations`` x 2 chains, pbicrl) runs with the current kernel; the old
   per-pair ``softplus`` fallback (still callable as ``_kernels._block_softplus``) is timed per evaluation on
   states the chain visited and scaled by the chain's number of likelihood evaluations.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
from numba import njit

import pbicrl
from pbicrl.inference import likelihood_kernels as _kernels
from pbicrl.inference.codes import C_EVALS
from pbicrl.inference.likelihood import PreferenceLikelihood
from pbicrl.inference.preferences import Preferences
from pbicrl.inference.priors import WeightPrior
from pbicrl.inference.samplers import build_kernel
from pbicrl.inference.synthetic import make_problem

FULL = 400_000


def time_chain(lik: PreferenceLikelihood, method: str, n: int, prior: WeightPrior) -> tuple[float, int]:
    """Seconds for ``n`` iterations from a fixed initial state, and the likelihood evaluations they made."""
    kernel = build_kernel(lik, sampler=method, iterations=max(n, 2), weight_prior=prior)
    state = kernel.init(0)
    kernel.run(np.random.default_rng(1), state, 2)  # compile outside the timing
    t = time.perf_counter()
    end = kernel.run(np.random.default_rng(1), state, n)
    return time.perf_counter() - t, int(end.counts[C_EVALS])


def big_problem(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Mean features (3n, 4) and groups of a large synthetic ranking (best n first)."""
    rng = np.random.default_rng(seed)
    F = np.abs(rng.normal(size=(3 * n, 4))) * [1.0, 0.2, 0.2, 0.5]
    score = F @ np.array([1.0, -5.0, -10.0, -1.0]) + rng.gumbel(size=3 * n)
    group = np.empty(3 * n, dtype=np.int64)
    group[np.argsort(-score)] = np.repeat([1, 2, 3], n)
    return F, group


@njit(cache=True, error_model="numpy")
def old_total_loglik(a, brows, broff, bcols, bcoff, bm, b, Q, Qinv, E, Einv):  # noqa: ANN001, ANN201
    """The pairwise blocks as before: narrow blocks on the (unchanged) one-centre path, wide ones pair by pair."""
    total = 0.0
    for k in range(bm.size):
        rows = brows[broff[k]:broff[k + 1]]
        cols = bcols[bcoff[k]:bcoff[k + 1]]
        lo = np.inf
        hi = -np.inf
        for j in range(cols.size):
            lo = min(lo, a[cols[j]])
            hi = max(hi, a[cols[j]])
        for r in range(rows.size):
            lo = min(lo, a[rows[r]])
            hi = max(hi, a[rows[r]])
        if hi - lo <= _kernels._SPREAD and abs(bm[k]) <= _kernels._MMAX:
            total += _kernels.block_loglik(a, rows, cols, bm[k], b, Q, Qinv, E, Einv)
        else:
            total += _kernels._block_softplus(a, rows, cols, bm[k])
    return total


def per_eval(fn, a_list: list[np.ndarray], *args) -> float:  # noqa: ANN001
    fn(a_list[0], *args)
    t = time.perf_counter()
    for a in a_list:
        fn(a, *args)
    return (time.perf_counter() - t) / len(a_list)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--iterations", type=int, default=FULL)
    ap.add_argument("--big-pairwise", type=int, default=40)
    ap.add_argument("--big-grouped", type=int, default=1000)
    ap.add_argument("--wide-iterations", type=int, default=40_000)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--json", help="also write the numbers to this file")
    args = ap.parse_args()
    if args.quick:
        args.iterations, args.big_pairwise, args.big_grouped, args.wide_iterations = 40_000, 10, 200, 10_000
    out: dict = {}

    # 1. 3 x 60 -----------------------------------------------------------------------------------------
    prob = make_problem(60, labels="violations", violation_rate=0.4, seed=0)
    prior = WeightPrior("flat", -1000.0, 1000.0)
    n = args.iterations
    print(f"1. 3 groups x 60 trajectories, {n:,} iterations per chain (timed whole)")
    print(f"   {'likelihood':<10} {'method':<7} {'s/chain':>9} {'s per 400k':>11} {'lik. evals':>11} {'us/eval':>8}")
    rows = []
    for kind in ("pairwise", "grouped"):
        lik = PreferenceLikelihood.from_dataset(prob.dataset, margins=[0.0, 2.9], likelihood=kind)
        for method in ("paper", "pbicrl"):
            dt, evals = time_chain(lik, method, n, prior)
            rows.append({"likelihood": kind, "method": method, "iterations": n, "seconds": dt,
                         "seconds_per_400k": dt * FULL / n, "evals": evals, "us_per_eval": dt / max(evals, 1) * 1e6})
            r = rows[-1]
            print(f"   {kind:<10} {method:<7} {dt:9.2f} {r['seconds_per_400k']:11.2f} {evals:11,} {r['us_per_eval']:8.1f}")
    out["3x60"] = rows

    # 2. 3 x 20,000 -------------------------------------------------------------------------------------
    F, group = big_problem(20_000)
    print("\n2. 3 groups x 20,000 trajectories (1.2e9 pairs), pbicrl; "
          "EXTRAPOLATED linearly from the iterations shown to 400,000")
    print(f"   {'likelihood':<10} {'iters run':>9} {'s run':>8} {'s per 400k (extrap.)':>21} {'lik. evals':>11} {'ms/eval':>8}")
    rows = []
    for kind, m in (("pairwise", args.big_pairwise), ("grouped", args.big_grouped)):
        lik = PreferenceLikelihood(F, Preferences.from_groups(group), np.array([1.0, 0.0, 0.0, -1.0]), kind=kind)
        dt, evals = time_chain(lik, "pbicrl", m, prior)
        rows.append({"likelihood": kind, "iterations_run": m, "seconds_run": dt, "seconds_per_400k_extrapolated":
                     dt * FULL / m, "evals": evals, "ms_per_eval": dt / max(evals, 1) * 1e3})
        r = rows[-1]
        print(f"   {kind:<10} {m:9,} {dt:8.2f} {r['seconds_per_400k_extrapolated']:21.0f} {evals:11,} "
              f"{r['ms_per_eval']:8.2f}")
    out["3x20000"] = rows

    # 3. wide spreads -----------------------------------------------------------------------------------
    ds = pbicrl.load_dataset(Path(pbicrl.__file__).resolve().parent / "data" / "point_mass.npz")
    lik = PreferenceLikelihood.from_dataset(ds)
    wide = WeightPrior("flat", -10_000.0, 10_000.0)
    m = args.wide_iterations
    print(f"\n3. point_mass ({ds.n_trajectories} trajectories, {lik.preferences.n_pairs:,} pairs), flat prior "
          f"[-10000, 10000], pbicrl, {m:,} iterations x 2 chains")
    times, evals, states = [], 0, []
    for seed in (0, 1):
        kernel = build_kernel(lik, sampler="pbicrl", iterations=m, weight_prior=wide)
        state = kernel.init(seed)
        kernel.run(np.random.default_rng(seed), state, 2)
        buf = kernel.new_buffers(kernel.settings.n_draws)
        t = time.perf_counter()
        end = kernel.run(np.random.default_rng(seed), state, m, buf)
        times.append(time.perf_counter() - t)
        evals += int(end.counts[C_EVALS])
        k = int(buf[5][0])
        for r in np.linspace(0, k - 1, 50).astype(int):  # states the chain visited (kept draws)
            w = np.concatenate([lik.nominal_weights]) + buf[0][r] * buf[1][r]
            states.append(np.ascontiguousarray(lik.beta * ds.mean_features @ w))
    kargs = lik.kernel_args()
    pair_args = kargs[1:9]
    scratch = kargs[9:14]
    spread = np.array([np.ptp(a) for a in states])
    t_new = per_eval(_kernels.total_loglik, states, *pair_args, *scratch)
    t_old = per_eval(old_total_loglik, states, *kargs[1:6], *scratch)
    new_vals = np.array([_kernels.total_loglik(a, *pair_args, *scratch) for a in states])
    old_vals = np.array([old_total_loglik(a, *kargs[1:6], *scratch) for a in states])
    chain_s = sum(times)
    other_s = max(chain_s - evals * t_new, 0.0)  # everything but the likelihood
    before_s = other_s + evals * t_old
    print(f"   visited states: returns spread median {np.median(spread):,.0f} nats, "
          f"{np.mean(spread > _kernels._SPREAD):.0%} beyond the one-centre range")
    rel = np.max(np.abs(old_vals - new_vals) / np.maximum(np.abs(old_vals), 1e-300))
    print(f"   per evaluation: old per-pair fallback {t_old * 1e3:.2f} ms, new {t_new * 1e3:.3f} ms "
          f"({t_old / t_new:.0f}x); max |old - new| / |old| = {rel:.1e}")
    print(f"   2 chains: now {chain_s:.1f} s measured ({evals:,} evaluations); before ~{before_s:.0f} s "
          "(same chains, old per-evaluation time x evaluations)")
    out["wide"] = {"iterations": m, "chains": 2, "seconds_now": chain_s, "seconds_before_estimated": before_s,
                   "evals": evals, "ms_per_eval_old": t_old * 1e3, "ms_per_eval_new": t_new * 1e3,
                   "median_spread": float(np.median(spread)), "max_rel_diff_old_new": float(rel)}
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(out, fh, indent=2)


if __name__ == "__main__":
    main()
