"""Cost of one grouped-likelihood evaluation at given wall states, this checkout against another one, side by side.

Workload: ``make_wall_problem(10_000, length=500)`` (the workload of ``bench_parametric_scale.py``); each state is a
wall location ``theta`` and a penalty; its scaled returns are built once per process, then ``loglik`` is timed
(CPU time, at least ``--min-s`` per state). Rows of the current ``src/`` and of ``--baseline-src`` run in fresh
processes, alternating state by state, so both see the same load.

    git archive <old commit> src | tar -x -C /tmp/base
    python benchmarks/bench_grouped_states.py --baseline-src /tmp/base/src
    python benchmarks/bench_grouped_states.py --states-from benchmarks/reports/parametric_scale_24k_after.json

Default states: the 12 kept draws profiled in ``parametric_scale_24k_after.json`` when it exists.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np

HERE = Path(__file__).resolve().parent
DEFAULT_STATES = HERE / "reports" / "parametric_scale_24k_after.json"


def worker(states: list[list[float]], min_s: float) -> list[dict[str, Any]]:
    """Per state: ms per evaluation and the value (this process's ``pbicrl``)."""
    warnings.simplefilter("ignore")
    from pbicrl.inference import likelihood_kernels as _kernels
    from pbicrl.inference.constraints import AxisHalfspace, ConstraintSet
    from pbicrl.inference.likelihood import PreferenceLikelihood
    from pbicrl.inference.samplers import build_kernel
    from pbicrl.inference.samplers._parametric import param_column
    from pbicrl.inference.synthetic import make_wall_problem

    ds = make_wall_problem(10_000, length=500, seed=0).dataset
    lik = PreferenceLikelihood.from_dataset(ds, likelihood="grouped")
    A = build_kernel(lik, constraints=ConstraintSet((AxisHalfspace(0, name="wall"),), ds), iterations=10)._param_arrays()
    kargs = lik.kernel_bundle()
    col = np.empty(ds.n_trajectories)
    out = []
    for theta, penalty in states:
        param_column(0, np.array([theta]), lik.beta, A["fam"], A["sign"], A["poff"], A["dims_off"], A["dims"],
                     A["sorted_vals"], A["states"], A["offsets"], A["inv_len"], col, False)
        a = np.ascontiguousarray(lik.scaled_features_T.T @ lik.nominal_weights + penalty * col)
        value = float(_kernels.loglik(a, kargs))  # also compiles
        c, n = time.process_time(), 0
        while n < 3 or time.process_time() - c < min_s:
            _kernels.loglik(a, kargs)
            n += 1
        out.append({"theta": theta, "penalty": penalty, "spread": float(np.ptp(a)),
                    "ms": 1e3 * (time.process_time() - c) / n, "value": value})
    return out


def _run(states: list[list[float]], min_s: float, src: str | None) -> list[dict[str, Any]]:
    env = dict(os.environ)
    if src:
        env["PYTHONPATH"] = src + os.pathsep + env.get("PYTHONPATH", "")
    proc = subprocess.run([sys.executable, __file__, "--worker", json.dumps(states), "--min-s", str(min_s)],
                          env=env, capture_output=True, text=True)
    if proc.returncode != 0:
        raise RuntimeError(proc.stderr[-2000:])
    return json.loads(proc.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--baseline-src", help="a src/ directory of another version of pbicrl")
    ap.add_argument("--states-from", default=str(DEFAULT_STATES),
                    help="a bench_parametric_scale.py --json file: its profiled (theta, penalty) states")
    ap.add_argument("--state", action="append", default=[], metavar="THETA,PENALTY", help="a state (repeatable)")
    ap.add_argument("--min-s", type=float, default=0.3, help="CPU seconds of timing per state")
    ap.add_argument("--json")
    ap.add_argument("--worker", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:
        print(json.dumps(worker(json.loads(args.worker), args.min_s)))
        return
    states = [[float(v) for v in s.split(",")] for s in args.state]
    if not states:
        prof = json.loads(Path(args.states_from).read_text())["profile"]
        states = [[p["theta"], p["penalty"]] for p in prof]
    rows = []
    for st in states:  # state by state, alternating, so that load drifts hit both
        row = {"new": _run([st], args.min_s, None)[0]}
        if args.baseline_src:
            row["old"] = _run([st], args.min_s, args.baseline_src)[0]
        rows.append(row)
    print(f"{'theta':>7} {'penalty':>9} {'spread':>7} {'ms now':>8}" + (f" {'ms base':>8} {'ratio':>6} {'rel. diff':>9}"
                                                                       if args.baseline_src else ""))
    for r in rows:
        n = r["new"]
        line = f"{n['theta']:7.3f} {n['penalty']:9.2f} {n['spread']:7.1f} {n['ms']:8.3f}"
        if "old" in r:
            o = r["old"]
            rel = abs(n["value"] - o["value"]) / max(abs(o["value"]), 1e-300)
            line += f" {o['ms']:8.3f} {o['ms'] / n['ms']:6.1f} {rel:9.1e}"
        print(line)
    mean_new = float(np.mean([r["new"]["ms"] for r in rows]))
    msg = f"mean over states: {mean_new:.3f} ms now"
    if args.baseline_src:
        mean_old = float(np.mean([r["old"]["ms"] for r in rows]))
        msg += f", {mean_old:.3f} ms baseline ({mean_old / mean_new:.1f}x)"
    print(msg)
    if args.json:
        Path(args.json).write_text(json.dumps({"states": rows}, indent=2))


if __name__ == "__main__":
    main()
