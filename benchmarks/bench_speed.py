"""Speed and scale of the compiled sampler (issue 18): small problems, total rankings, large data, scaling.

    python benchmarks/bench_speed.py small                 # 3 x 60: 180 sampled pairs, 10,800 pairs, grouped
    python benchmarks/bench_speed.py small --baseline-src DIR   # ... and the same rows from another checkout's src/
    python benchmarks/bench_speed.py ranking               # 1,000 trajectories in 3 groups vs 1,000 groups
    python benchmarks/bench_speed.py large                 # 3 x 100,000 trajectories, grouped: ESS, R-hat, wall
    python benchmarks/bench_speed.py large --large-p-joint 0 --large-no-pairwise   # ... single-weight steps only
    python benchmarks/bench_speed.py scaling               # seconds per effective sample vs N (scaling.png)

Every row is timed in a fresh worker process (``--worker``) after compiling on a few iterations, so rows of the
current code and of ``--baseline-src`` (e.g. ``git archive HEAD src | tar -x -C /tmp/base``) alternate under the
same load. Times are wall clock and CPU (process time: what the chain got of a core on a shared machine).
``--json FILE`` writes every number.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from typing import Any

import numpy as np

FULL = 400_000


# ------------------------------------------------------------------------------------------------ workers
def _small_likelihood(protocol: str, kind: str) -> Any:
    from pbicrl.inference.likelihood import PreferenceLikelihood
    from pbicrl.inference.synthetic import make_problem

    prob = make_problem(60, labels="violations", violation_rate=0.4, seed=0)
    proto: str | int = "all" if protocol == "all" else int(protocol)
    return PreferenceLikelihood.from_dataset(prob.dataset, margins=[0.0, 2.9], protocol=proto, likelihood=kind)


def _ranking_likelihood(n: int, groups: int, kind: str) -> Any:
    from pbicrl.inference.likelihood import PreferenceLikelihood
    from pbicrl.inference.preferences import Preferences

    F, rank = _ranked_features(n, seed=0)
    return PreferenceLikelihood(F, Preferences.from_groups(rank * groups // n), np.array([1.0, 0.0, 0.0, -1.0]),
                                kind=kind)


def _ranked_features(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Mean features (n, 4) and each trajectory's rank (0 best) by a noisy true return."""
    rng = np.random.default_rng(seed)
    F = np.abs(rng.normal(size=(n, 4))) * [1.0, 0.2, 0.2, 0.5]
    score = F @ np.array([1.0, -5.0, -10.0, -1.0]) + rng.gumbel(size=n)
    rank = np.empty(n, dtype=np.int64)
    rank[np.argsort(-score)] = np.arange(n)
    return F, rank


def _time_chain(lik: Any, method: str, n: int, reps: int) -> dict[str, float]:
    from pbicrl.inference.codes import C_EVALS
    from pbicrl.inference.samplers import build_kernel

    kernel = build_kernel(lik, sampler=method, iterations=n)
    state = kernel.init(0)
    kernel.run(np.random.default_rng(1), state, 10)  # compile outside the timing
    wall, cpu = [], []
    for _ in range(reps):
        t, c = time.perf_counter(), time.process_time()
        end = kernel.run(np.random.default_rng(1), state, n)
        wall.append(time.perf_counter() - t)
        cpu.append(time.process_time() - c)
    return {"wall_s": min(wall), "cpu_s": min(cpu), "evals": int(end.counts[C_EVALS]), "iterations": n}


def _numpy_loop(lik: Any, m: int) -> dict[str, float]:
    """The plain per-iteration NumPy loop (``samplers.reference``, paper), ``m`` iterations."""
    from pbicrl.inference.samplers import build_kernel
    from pbicrl.inference.samplers.reference import reference_chain

    k = build_kernel(lik, sampler="paper", iterations=m)
    s = k.init(0)
    randoms = k.draw_randoms(np.random.default_rng(1), m)
    t, c = time.perf_counter(), time.process_time()
    reference_chain(lik, "paper", s.indicators, s.penalty_weights, randoms)
    return {"wall_s": time.perf_counter() - t, "cpu_s": time.process_time() - c, "iterations": m}


def worker(spec: dict[str, Any]) -> dict[str, Any]:
    """One timing row in this process (``spec`` from the driver)."""
    if spec["what"] == "small":
        lik = _small_likelihood(spec["protocol"], spec["kind"])
    else:
        lik = _ranking_likelihood(spec["n"], spec["groups"], spec["kind"])
    if spec["method"] == "numpy":
        out = _numpy_loop(lik, spec["iterations"])
    else:
        out = _time_chain(lik, spec["method"], spec["iterations"], spec.get("reps", 1))
    out["pairs"] = int(lik.preferences.n_pairs)
    return out


def _run_worker(spec: dict[str, Any], src: str | None) -> dict[str, Any]:
    env = dict(os.environ)
    if src:
        env["PYTHONPATH"] = src + os.pathsep + env.get("PYTHONPATH", "")
    proc = subprocess.run([sys.executable, __file__, "--worker", json.dumps(spec)], env=env, capture_output=True,
                          text=True)
    if proc.returncode != 0:
        raise RuntimeError(proc.stderr[-2000:])
    return json.loads(proc.stdout.strip().splitlines()[-1])


# ------------------------------------------------------------------------------------------------ sections
def section_small(args: argparse.Namespace) -> list[dict[str, Any]]:
    n = args.iterations
    rows = []
    print(f"3 groups x 60 trajectories (make_problem(60, labels='violations', seed=0), margins 0 / 2.9), "
          f"{n:,} iterations per chain; best of {args.reps}")
    print(f"{'likelihood':<30} {'sampler':<7} {'code':<9} {'wall s':>7} {'cpu s':>7} {'us/it':>6} {'evals':>8} "
          f"{'vs NumPy':>9}")
    for protocol, kind, label in (("60", "pairwise", "pairwise, 180 sampled pairs"),
                                  ("all", "pairwise", "pairwise, all 10,800 pairs"),
                                  ("all", "grouped", "grouped (exact Plackett-Luce)")):
        base = None
        if kind == "pairwise":
            m = args.numpy_iterations if protocol != "all" else max(args.numpy_iterations // 10, 500)
            r = _run_worker({"what": "small", "protocol": protocol, "kind": kind, "method": "numpy",
                             "iterations": m}, None)
            base = r["cpu_s"] * FULL / m
            rows.append({"likelihood": label, "method": "paper", "code": "numpy", **r,
                         "cpu_s_per_400k": base, "wall_s_per_400k": r["wall_s"] * FULL / m})
            print(f"{label:<30} {'paper':<7} {'numpy':<9} {r['wall_s'] * FULL / m:7.2f} {base:7.2f} "
                  f"{r['cpu_s'] / m * 1e6:6.2f} {'-':>8} {'1.0x':>9}   (measured on {m:,} iterations, scaled)")
        for method in ("paper", "pbicrl"):
            codes = [("current", None)] + ([("baseline", args.baseline_src)] if args.baseline_src else [])
            for code, src in codes:
                r = _run_worker({"what": "small", "protocol": protocol, "kind": kind, "method": method,
                                 "iterations": n, "reps": args.reps}, src)
                scale = FULL / n
                row = {"likelihood": label, "method": method, "code": code, **r,
                       "cpu_s_per_400k": r["cpu_s"] * scale, "wall_s_per_400k": r["wall_s"] * scale}
                row["speedup_vs_numpy_cpu"] = base / row["cpu_s_per_400k"] if base else None
                rows.append(row)
                vs = f"{row['speedup_vs_numpy_cpu']:.1f}x" if base else "-"
                print(f"{label:<30} {method:<7} {code:<9} {row['wall_s_per_400k']:7.2f} {row['cpu_s_per_400k']:7.2f} "
                      f"{r['cpu_s'] / n * 1e6:6.2f} {r['evals']:8,} {vs:>9}", flush=True)
    return rows


def section_ranking(args: argparse.Namespace) -> list[dict[str, Any]]:
    n, it = args.ranking_n, args.ranking_iterations
    print(f"{n:,} trajectories ranked by a noisy return, in 3 groups or {n:,} (a total ranking), "
          f"{it:,} iterations per chain")
    print(f"{'likelihood':<10} {'sampler':<7} {'groups':>6} {'pairs':>9} {'wall s':>7} {'cpu s':>7} {'us/eval':>8} "
          f"{'vs 3 groups':>11}")
    rows = []
    for kind in ("pairwise", "grouped"):
        for method in ("pbicrl", "paper"):
            ref = None
            for groups in (3, n):
                r = _run_worker({"what": "ranking", "n": n, "groups": groups, "kind": kind, "method": method,
                                 "iterations": it, "reps": args.reps}, None)
                per = r["cpu_s"] / max(r["evals"], 1)
                ref = per if groups == 3 else ref
                rows.append({"likelihood": kind, "method": method, "groups": groups, **r, "cpu_s_per_eval": per,
                             "ratio_to_3_groups": per / ref})
                print(f"{kind:<10} {method:<7} {groups:6,} {r['pairs']:9,} {r['wall_s']:7.2f} {r['cpu_s']:7.2f} "
                      f"{per * 1e6:8.1f} {per / ref:10.2f}x", flush=True)
    return rows


def _large_likelihood(n: int, kind: str, seed: int = 0) -> Any:
    """3 groups of ``n`` trajectories (best first), ranked by a noisy true return (``bench_grouped.big_problem``)."""
    from pbicrl.inference.likelihood import PreferenceLikelihood
    from pbicrl.inference.preferences import Preferences

    F, rank = _ranked_features(3 * n, seed)
    return PreferenceLikelihood(F, Preferences.from_groups(rank // n), np.array([1.0, 0.0, 0.0, -1.0]), kind=kind)


def _posterior_run(n: int, kind: str, iterations: int, chains: int, jobs: int, settings: dict[str, Any],
                   seed: int = 0, burn_in: int | None = None) -> dict[str, Any]:
    """Chains on 3 x ``n`` trajectories in this process (workers for ``jobs`` > 1): times, ESS, R-hat, memory."""
    import resource

    from pbicrl.inference import likelihood_kernels as _kernels
    from pbicrl.inference.samplers import sample

    lik = _large_likelihood(n, kind, seed)
    a = np.ascontiguousarray(lik.scaled_features_T.T @ (lik.nominal_weights + np.array([0.0, -5.0, -10.0, 0.0])))
    args = lik.kernel_bundle()
    _kernels.loglik(a, args)
    c = time.process_time()
    reps = 0
    while reps < 3 or time.process_time() - c < 0.5:
        _kernels.loglik(a, args)
        reps += 1
    per_eval = (time.process_time() - c) / reps
    t, c = time.perf_counter(), time.process_time()
    ch0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    burn = int(BURN_IN * iterations) if burn_in is None else int(burn_in)
    post = sample(lik, chains=chains, iterations=iterations, burn_in=burn, seed=seed, jobs=jobs,
                  progress=False, **settings)
    wall = time.perf_counter() - t
    ch1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = time.process_time() - c + (ch1.ru_utime + ch1.ru_stime) - (ch0.ru_utime + ch0.ru_stime)
    diag = post.diagnostics()
    worst = diag.worst()
    per_quantity = {f"{kind_}[{name}]": v for kind_, kv in diag.values.items() for name, v in kv.items()}
    evals = int(np.asarray(post.counts)[:, 4].sum())
    ess = min(x for x in (worst["ess_bulk"], worst["ess_tail"]) if x is not None) if worst["ess_bulk"] else None
    return {"n_per_group": n, "likelihood": kind, "iterations": iterations, "chains": chains, "jobs": jobs,
            "settings": settings, "burn_in": burn, "wall_s": wall, "cpu_s": cpu, "ms_per_eval": per_eval * 1e3,
            "rhat_max": worst["rhat"], "ess_bulk_min": worst["ess_bulk"], "ess_tail_min": worst["ess_tail"],
            "ess_min": ess, "cpu_s_per_effective_sample": cpu / ess if ess else None, "evals": evals,
            "per_quantity": per_quantity, "max_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e3,
            "max_rss_children_mb": ch1.ru_maxrss / 1e3, "table": post.table()}


LARGE_SETTINGS = {"p_joint": 0.4}  # joint weight steps beside the default flips (p_flip 0.5) and single steps
BURN_IN = 0.4  # of the iterations: the chains start from the prior, far from a posterior this narrow


def section_large(args: argparse.Namespace) -> list[dict[str, Any]]:
    from pbicrl.inference import likelihood_kernels as _kernels
    n = args.large_n
    settings = {"p_joint": args.large_p_joint} if args.large_p_joint else {}
    print(f"3 groups x {n:,} trajectories, grouped likelihood, {args.large_chains} chains x "
          f"{args.large_iterations:,} iterations (warm-up {args.large_burn_in or 'default'}), {args.jobs} worker "
          f"processes, settings {settings}")
    r = _posterior_run(n, "grouped", args.large_iterations, args.large_chains, args.jobs, settings,
                       burn_in=args.large_burn_in)
    print(r["table"])
    print(f"wall {r['wall_s']:.0f} s, CPU {r['cpu_s']:.0f} s (all processes), {r['ms_per_eval']:.2f} ms per "
          f"evaluation; worst R-hat {r['rhat_max']}, smallest bulk / tail ESS {r['ess_bulk_min']} / "
          f"{r['ess_tail_min']}; max RSS {r['max_rss_mb']:.0f} MB (driver), {r['max_rss_children_mb']:.0f} MB "
          "(largest worker)")
    for q, v in r["per_quantity"].items():
        print(f"  {q:<22} R-hat {v['rhat']}  ESS bulk {v['ess_bulk']}  tail {v['ess_tail']}")
    rows = [r]
    if args.large_no_pairwise:
        return rows
    # the paper's all-pairs likelihood on the same data: one evaluation, timed
    lik = _large_likelihood(n, "pairwise")
    a = np.ascontiguousarray(lik.scaled_features_T.T @ (lik.nominal_weights + np.array([0.0, -5.0, -10.0, 0.0])))
    kargs = lik.kernel_bundle()
    _kernels.loglik(a[:300], _large_likelihood(100, "pairwise").kernel_bundle())  # compile on a small case
    c = time.process_time()
    _kernels.loglik(a, kargs)
    pw = time.process_time() - c
    evals_per_ess = (r["evals"] or 0) / r["ess_min"] if r["ess_min"] else None
    rows.append({"likelihood": "pairwise (all pairs)", "pairs": int(lik.preferences.n_pairs), "cpu_s_per_eval": pw,
                 "extrapolated_cpu_s_for_400_ess": pw * evals_per_ess * 400 if evals_per_ess else None})
    print(f"pairwise (paper Eq. 7), all {lik.preferences.n_pairs:.3g} pairs: {pw:.1f} s CPU per evaluation"
          + (f"; at the grouped chain's {evals_per_ess:.0f} evaluations per effective sample, 400 effective "
             f"samples would take ~{rows[-1]['extrapolated_cpu_s_for_400_ess'] / 3600:.0f} CPU hours "
             "(extrapolated)" if evals_per_ess else ""))
    return rows


def section_scaling(args: argparse.Namespace) -> list[dict[str, Any]]:
    if args.from_json:  # re-plot a saved run
        with open(args.from_json) as fh:
            rows = json.load(fh)["rows"]
        if args.plot:
            _plot_scaling(rows, args.plot)
        return rows
    rows = []
    sizes = [int(x) for x in args.scaling_sizes.split(",")]
    print(f"seconds (CPU) per effective sample vs trajectories per group (3 groups), {args.scaling_chains} chains x "
          f"{args.scaling_iterations:,} iterations, settings {LARGE_SETTINGS}; effective samples = the smallest bulk "
          "or tail ESS over all reported quantities")
    print(f"{'likelihood':<9} {'N/group':>8} {'ms/eval':>8} {'cpu s':>7} {'ESS min':>8} {'R-hat':>6} {'s/ESS':>8}")
    for kind in ("grouped", "pairwise"):
        for n in sizes:
            if kind == "pairwise" and 3 * n * n > args.scaling_max_pairs:
                continue
            r = _posterior_run(n, kind, args.scaling_iterations, args.scaling_chains, args.jobs, LARGE_SETTINGS)
            r.pop("table")
            rows.append(r)
            spe = r["cpu_s_per_effective_sample"]
            print(f"{kind:<9} {n:8,} {r['ms_per_eval']:8.3f} {r['cpu_s']:7.1f} {r['ess_min'] or float('nan'):8.0f} "
                  f"{r['rhat_max'] or float('nan'):6.3f} {spe if spe else float('nan'):8.4f}", flush=True)
    if args.plot:
        _plot_scaling(rows, args.plot)
    return rows


def _plot_scaling(rows: list[dict[str, Any]], path: str) -> None:
    """Left: CPU seconds per effective sample (hollow: worst R-hat above 1.01); right: CPU ms per evaluation."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(10.0, 4.2))
    for kind, marker, colour in (("grouped", "o", "C0"), ("pairwise", "s", "C1")):
        sel = [r for r in rows if r["likelihood"] == kind]
        if not sel:
            continue
        label = "grouped (exact Plackett-Luce)" if kind == "grouped" else "pairwise, all pairs (paper Eq. 7)"
        pts = [(3 * r["n_per_group"], r["cpu_s_per_effective_sample"], (r["rhat_max"] or np.inf) < 1.01)
               for r in sel if r["cpu_s_per_effective_sample"]]
        if pts:
            x, y, ok = zip(*pts)
            ax.plot(x, y, color=colour, lw=1, label=label)
            for xi, yi, oki in pts:
                ax.plot(xi, yi, marker=marker, color=colour, mfc=colour if oki else "white", ls="none")
        ax2.plot([3 * r["n_per_group"] for r in sel], [r["ms_per_eval"] for r in sel], marker=marker, color=colour,
                 label=label)
    for a_ in (ax, ax2):
        a_.set_xscale("log")
        a_.set_yscale("log")
        a_.set_xlabel("trajectories (3 groups)")
        a_.grid(True, which="both", alpha=0.3)
    ax.set_ylabel("CPU seconds per effective sample")
    ax.set_title(f"pbicrl sampler, {LARGE_SETTINGS}; hollow: R-hat > 1.01", fontsize=9)
    ax2.set_ylabel("CPU ms per likelihood evaluation")
    ax2.set_title("cost of one evaluation", fontsize=9)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    print(f"wrote {path}")


# ------------------------------------------------------------------------------------------------ main
def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("section", nargs="?", choices=("small", "ranking", "large", "scaling"), default="small")
    ap.add_argument("--jobs", type=int, default=2, help="worker processes for the chains (large, scaling)")
    ap.add_argument("--large-n", type=int, default=100_000)
    ap.add_argument("--large-iterations", type=int, default=10_000)
    ap.add_argument("--large-chains", type=int, default=4)
    ap.add_argument("--large-burn-in", type=int, default=None, help=f"warm-up iterations (default {BURN_IN * 100:.0f}%% of the iterations)")
    ap.add_argument("--large-p-joint", type=float, default=LARGE_SETTINGS["p_joint"],
                    help="probability of the joint weight step (0: single-weight steps only, the sampler's default)")
    ap.add_argument("--large-no-pairwise", action="store_true", help="skip timing the all-pairs likelihood")
    ap.add_argument("--scaling-sizes", default="100,300,1000,3000,10000,30000,100000")
    ap.add_argument("--scaling-iterations", type=int, default=8000)
    ap.add_argument("--scaling-chains", type=int, default=2)
    ap.add_argument("--scaling-max-pairs", type=float, default=3e7, help="pairwise runs only up to this many pairs")
    ap.add_argument("--plot", default=None, help="scaling: write the log-log plot here")
    ap.add_argument("--from-json", default=None, help="scaling: re-plot the rows of a saved --json file")
    ap.add_argument("--worker", help=argparse.SUPPRESS)
    ap.add_argument("--iterations", type=int, default=FULL)
    ap.add_argument("--numpy-iterations", type=int, default=20_000)
    ap.add_argument("--reps", type=int, default=2)
    ap.add_argument("--baseline-src", help="a src/ directory of another version of pbicrl, timed row by row too")
    ap.add_argument("--ranking-n", type=int, default=1000)
    ap.add_argument("--ranking-iterations", type=int, default=20_000)
    ap.add_argument("--json", help="also write the numbers to this file")
    args = ap.parse_args()
    if args.worker:
        print(json.dumps(worker(json.loads(args.worker))))
        return
    t0 = time.perf_counter()
    load0 = os.getloadavg()[0]
    rows = {"small": section_small, "ranking": section_ranking, "large": section_large,
            "scaling": section_scaling}[args.section](args)
    info = {"section": args.section, "args": vars(args), "rows": rows, "load_avg_start": load0,
            "load_avg_end": os.getloadavg()[0], "total_s": time.perf_counter() - t0}
    print(f"\nload average {load0:.1f} -> {info['load_avg_end']:.1f}, {info['total_s']:.0f} s in all")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(info, fh, indent=2)


if __name__ == "__main__":
    main()
