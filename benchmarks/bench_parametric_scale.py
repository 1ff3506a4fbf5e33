"""Parametric constraints at scale (issue 18, target 4): effective samples per wall-clock second.

Workload: 2 groups x 10,000 trajectories x 500 steps (``make_wall_problem``: group 1 stops short of a wall at
x >= 8, group 2 crosses it), the wall's location sampled (one axis half-space on x, bounds = the data's range),
``pbicrl.infer`` with its default settings (grouped likelihood, ``pbicrl`` sampler, 4 chains, default warm-up
and move probabilities) except the number of iterations, which the time budget sets. Target: every reported
quantity with bulk ESS >= 400 and R-hat < 1.01 within 5 minutes of wall time.

    python benchmarks/bench_parametric_scale.py --iterations 8000 [--jobs 2] [--json FILE]
    python benchmarks/bench_parametric_scale.py --iterations 8000 --set p_joint=0.2   # a non-default setting

After the run it profiles what a move costs at kept draws spread over the posterior (first, middle and last of
each chain): one grouped-likelihood evaluation and one recount of the wall feature (``param_column``, O(N log T)),
and, from the move counts, their shares of all CPU time. Measured: ``benchmarks/reports/speed.md``, section 5. Wall time includes the identifiability analysis ``infer`` runs first; data
generation is timed separately.
"""

from __future__ import annotations

import argparse
import json
import resource
import time
import warnings
from typing import Any

import numpy as np


def _timed(fn: Any, min_s: float = 0.5) -> float:
    """Seconds per call of ``fn`` (CPU time of this process, at least ``min_s`` in all)."""
    fn()
    c, n = time.process_time(), 0
    while n < 3 or time.process_time() - c < min_s:
        fn()
        n += 1
    return (time.process_time() - c) / n


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n-per-group", type=int, default=10_000)
    ap.add_argument("--length", type=int, default=500)
    ap.add_argument("--iterations", type=int, default=8_000, help="per chain (default warm-up: a quarter)")
    ap.add_argument("--chains", type=int, default=4)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                    help="a non-default infer() setting (number), e.g. p_joint=0.2; repeatable")
    ap.add_argument("--json")
    args = ap.parse_args()
    warnings.simplefilter("ignore")  # identifiability warnings etc.: the numbers below are the point

    import pbicrl
    from pbicrl.inference import likelihood_kernels as _kernels
    from pbicrl.inference.codes import C_EVALS, C_T_PROP, COUNTERS
    from pbicrl.inference.constraints import AxisHalfspace, ConstraintSet
    from pbicrl.inference.likelihood import PreferenceLikelihood
    from pbicrl.inference.samplers import build_kernel
    from pbicrl.inference.synthetic import make_wall_problem

    extra = {k: float(v) for k, v in (s.split("=", 1) for s in args.set)}
    t = time.perf_counter()
    ds = make_wall_problem(args.n_per_group, length=args.length, seed=args.seed).dataset
    t_data = time.perf_counter() - t
    print(f"workload: {ds.n_trajectories:,} trajectories x {args.length} steps ({ds.group_counts()}), data built in "
          f"{t_data:.1f} s; {args.chains} chains x {args.iterations:,} iterations, {args.jobs} workers, "
          f"settings: defaults{'' if not extra else ' + ' + str(extra)}", flush=True)
    wall_con = {"family": "axis_halfspace", "dims": [0], "direction": ">=", "name": "wall"}
    ch0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t, c = time.perf_counter(), time.process_time()
    post = pbicrl.infer(ds, constraints=[wall_con], iterations=args.iterations, chains=args.chains, jobs=args.jobs,
                        seed=args.seed, progress=False, **extra)
    wall = time.perf_counter() - t
    ch1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = time.process_time() - c + (ch1.ru_utime + ch1.ru_stime) - (ch0.ru_utime + ch0.ru_stime)
    diag = post.diagnostics()
    print(post.table())
    rows = []
    for kind, kv in diag.values.items():
        for name, v in kv.items():
            rows.append({"quantity": f"{kind}[{name}]", **{k: v.get(k) for k in ("rhat", "ess_bulk", "ess_tail")}})
    print(f"\n{'quantity':<32} {'R-hat':>7} {'bulk ESS':>9} {'tail ESS':>9}")
    for r in rows:
        f = (lambda x, spec: "-" if x is None else format(x, spec))
        print(f"{r['quantity']:<32} {f(r['rhat'], '.4f'):>7} {f(r['ess_bulk'], '.0f'):>9} {f(r['ess_tail'], '.0f'):>9}")
    worst = diag.worst()
    counts = np.asarray(post.counts).sum(axis=0)
    ess_min = worst["ess_bulk"]
    print(f"\nwall {wall:.0f} s (identify + sampling), CPU {cpu:.0f} s (all processes); worst R-hat {worst['rhat']}, "
          f"smallest bulk ESS {ess_min}, tail ESS {worst['ess_tail']}"
          + (f"; {ess_min / wall:.2f} bulk effective samples per wall second" if ess_min else ""))
    print(f"move counts over all chains: {dict(zip(COUNTERS, counts.tolist()))}")

    # ---- profile: what one move costs at kept draws spread over the posterior (the cost of an evaluation grows
    # with the spread of the returns, i.e. with the wall's penalty), and the share of the chains' CPU it explains
    from pbicrl.inference.samplers._parametric import param_column

    lik = PreferenceLikelihood.from_dataset(ds, likelihood="grouped")
    cs = ConstraintSet((AxisHalfspace(0, name="wall"),), ds)
    kern = build_kernel(lik, constraints=cs, iterations=10)
    A = kern._param_arrays()
    kargs = lik.kernel_bundle()
    col = np.empty(ds.n_trajectories)
    ind = np.asarray(post.indicators, dtype=float)
    wp = np.asarray(post.penalty_weights, dtype=float)
    th = np.asarray(post.parameters, dtype=float)
    C, D = ind.shape[:2]
    dk = lik.nominal_weights.size
    picks = [(c, d) for c in range(C) for d in np.linspace(0, D - 1, 3).astype(int)]
    prof = []
    for c_, d_ in picks:
        theta = np.nan_to_num(th[c_, d_].reshape(-1))
        eff = ind[c_, d_] * wp[c_, d_]
        param_column(0, theta, lik.beta, A["fam"], A["sign"], A["poff"], A["dims_off"], A["dims"],
                     A["sorted_vals"], A["states"], A["offsets"], A["inv_len"], col, False)
        a = np.ascontiguousarray(lik.scaled_features_T.T @ (lik.nominal_weights + eff[:dk]) + eff[dk] * col)
        prof.append({"penalty": float(eff[dk]), "theta": float(theta[0]), "spread": float(np.ptp(a)),
                     "ms_eval": 1e3 * _timed(lambda: _kernels.loglik(a, kargs), 0.2),
                     "ms_recount": 1e3 * _timed(lambda: param_column(
                         0, theta, lik.beta, A["fam"], A["sign"], A["poff"], A["dims_off"], A["dims"],
                         A["sorted_vals"], A["states"], A["offsets"], A["inv_len"], col, False), 0.2)})
    per_eval = float(np.mean([p_["ms_eval"] for p_ in prof])) / 1e3
    per_col = float(np.mean([p_["ms_recount"] for p_ in prof])) / 1e3
    share_eval = counts[C_EVALS] * per_eval / cpu
    share_col = counts[C_T_PROP] * per_col / cpu
    print("profile at kept draws (first, middle, last of each chain):")
    for p_ in prof:
        print(f"  penalty {p_['penalty']:9.2f}  theta {p_['theta']:6.3f}  spread {p_['spread']:7.1f} nats  "
              f"{p_['ms_eval']:7.3f} ms per evaluation  {p_['ms_recount']:6.3f} ms per recount")
    print(f"mean {per_eval * 1e3:.3f} ms per grouped evaluation, {per_col * 1e3:.3f} ms per recount of the wall "
          f"feature (param_column); {counts[C_EVALS]:,} evaluations ~ {share_eval:.0%} and {counts[C_T_PROP]:,} recounts ~ "
          f"{share_col:.0%} of all CPU (the rest: identify, start-up, compilation cache, diagnostics, bookkeeping)")
    out = {"n_per_group": args.n_per_group, "length": args.length, "iterations": args.iterations,
           "chains": args.chains, "jobs": args.jobs, "settings": extra, "data_s": t_data, "wall_s": wall,
           "cpu_s": cpu, "rhat_max": worst["rhat"], "ess_bulk_min": ess_min, "ess_tail_min": worst["ess_tail"],
           "quantities": rows, "counts": counts.tolist(), "ms_per_eval": per_eval * 1e3,
           "ms_per_recount": per_col * 1e3, "profile": prof, "share_eval": share_eval,
           "share_recount": share_col,
           "max_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e3,
           "max_rss_children_mb": ch1.ru_maxrss / 1e3}
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(out, fh, indent=2, default=float)


if __name__ == "__main__":
    main()
