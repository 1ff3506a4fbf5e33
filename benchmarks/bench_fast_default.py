"""Fast default inference (issue 27): effective draws per second and time to convergence, side by side.

    python benchmarks/bench_fast_default.py --baseline-src /tmp/base/src --json benchmarks/reports/fast_default.json

Rows, per dataset (shipped ``point_mass`` and ``fetch_reach`` by default), each run in a fresh worker process after
a warm compile (a throwaway run first), alternating so that every row meets the same load:

* ``before``: the default sampler of the ``--baseline-src`` tree (``git archive <commit> src | tar -x -C DIR``), at a
  fixed number of iterations (``--before-iterations``; ESS per second is rate-like, so a shorter run than the old
  400,000 estimates it);
* ``after``: the default of this tree, ``iterations="auto"``: wall time to convergence and ESS per second;
* ``after_fixed`` (``--rows before,after,after_fixed,paper``): this tree's sampler with the moves of ``auto``
  (``p_flip`` 0.3, ``p_joint`` 0.3) at the ``before`` row's fixed length and burn-in: ESS per second at the same
  share of warm-up as ``before`` (a run that stops at ESS 400 pays its warm-up and start-up out of fewer draws);
* ``paper``: the paper's Algorithm 1 with the pairwise likelihood (Eq. 7, margins 0), fixed iterations.

Effective draws per second = the smallest bulk or tail ESS over the reported quantities
(:func:`pbicrl.inference.convergence.reported_quantities`: P(c=1) of every feature, the conditional quantile
indicators of every penalty and log|w| of the selected ones, the log-likelihood) divided by the sampling wall time
(compile excluded). NumPyro's row comes from ``benchmarks/bench_numpyro.py`` (its JSON, ``--numpyro-json``).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from typing import Any

HERE = os.path.dirname(os.path.abspath(__file__))
SRC = os.path.join(os.path.dirname(HERE), "src")


def _worker(row: str, data: str, iterations: int, seed: int) -> dict[str, Any]:
    import warnings

    warnings.simplefilter("ignore")
    import numpy as np

    import importlib.util

    import pbicrl

    # the statistics of this tree for every row (the 'before' tree has no such module): a standalone file
    spec = importlib.util.spec_from_file_location("_convergence", os.path.join(SRC, "pbicrl", "inference",
                                                                               "convergence.py"))
    conv_mod = importlib.util.module_from_spec(spec)
    sys.modules["_convergence"] = conv_mod  # dataclasses look the module up
    spec.loader.exec_module(conv_mod)  # type: ignore[union-attr]
    check_convergence, reported_quantities = conv_mod.check_convergence, conv_mod.reported_quantities

    ds = pbicrl.load_dataset(data)
    kw: dict[str, Any] = {"chains": 4, "seed": seed, "progress": False}
    if row == "paper":
        kw.update(sampler="paper", likelihood="pairwise", iterations=iterations)
    elif row == "before":
        kw.update(iterations=iterations)
    elif row == "after_fixed":  # today's sampler and moves at the before row's fixed length: ESS/s at steady state
        kw.update(iterations=iterations, p_flip=0.3, p_joint=0.3)
    # a short throwaway run compiles (or loads from the cache) every function the row uses
    pbicrl.infer(ds, **{**kw, "iterations": 2_000, "chains": 1})
    t0 = time.perf_counter()
    post = pbicrl.infer(ds, **kw)
    wall = time.perf_counter() - t0
    names = list(post.feature_names)
    q = reported_quantities(post.indicators, post.penalty_weights, post.log_likelihood, names,
                            post.parameters if np.size(post.parameters) else None)
    conv = check_convergence(q)
    sel = [n for n, p in zip(names, post.p_constraint) if p > 0.5]
    rec = getattr(post, "convergence", None)
    return {"row": row, "data": data, "wall_s": wall, "min_ess": conv.min_ess, "max_rhat": conv.max_rhat,
            "ess_per_s": conv.min_ess / wall, "converged": conv.converged, "selected": sel,
            "p_constraint": dict(zip(names, map(float, post.p_constraint))),
            "iterations_per_chain": int(post.settings["iterations"]),
            "auto_converged": None if rec is None else rec.get("converged"),
            "failing": conv.failing()}


def _run(row: str, data: str, iterations: int, seed: int, src: str) -> dict[str, Any]:
    env = dict(os.environ, PYTHONPATH=src)
    cmd = [sys.executable, __file__, "--worker", row, "--data", data, "--iterations", str(iterations),
           "--seed", str(seed)]
    out = subprocess.run(cmd, env=env, capture_output=True, text=True, check=False)
    if out.returncode != 0:
        raise RuntimeError(f"{row} on {data} failed:\n{out.stderr[-3000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--worker")
    ap.add_argument("--data", default="point_mass,fetch_reach")
    ap.add_argument("--iterations", type=int, default=0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--seeds", type=int, default=1, help="repetitions (seeds) per row")
    ap.add_argument("--baseline-src", help="src/ of the code before (for the 'before' row)")
    ap.add_argument("--before-iterations", type=int, default=40_000)
    ap.add_argument("--paper-iterations", type=int, default=100_000)
    ap.add_argument("--rows", default="before,after,paper")
    ap.add_argument("--numpyro-json", help="bench_numpyro.py's JSON, for the table")
    ap.add_argument("--json")
    a = ap.parse_args()
    if a.worker:
        print(json.dumps(_worker(a.worker, a.data, a.iterations, a.seed)))
        return
    rows = a.rows.split(",")
    results = []
    for seed in range(a.seeds):
        for data in a.data.split(","):
            for row in rows:
                if row == "before" and not a.baseline_src:
                    continue
                src = a.baseline_src if row == "before" else SRC
                it = {"before": a.before_iterations, "after_fixed": a.before_iterations,
                      "paper": a.paper_iterations}.get(row, 0)
                r = _run(row, data, it, seed, src)
                results.append(r)
                print(f"{data:12s} {row:7s} seed {seed}: wall {r['wall_s']:7.1f} s, min ESS {r['min_ess']:7.0f}, "
                      f"max R-hat {r['max_rhat']:.3f}, ESS/s {r['ess_per_s']:7.2f}, converged {r['converged']}, "
                      f"selected {r['selected']}, iterations/chain {r['iterations_per_chain']:,}", flush=True)
    out = {"results": results, "cpu_count": os.cpu_count(), "load_avg": os.getloadavg(),
           "numpyro": json.load(open(a.numpyro_json)) if a.numpyro_json else None}
    if a.json:
        with open(a.json, "w") as f:
            json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
