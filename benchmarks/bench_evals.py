"""Seconds per 10^5 evaluations of the default (grouped Plackett-Luce) log-likelihood at the sizes of issue 27
item 4, on posterior states, side by side with another checkout.

    python benchmarks/bench_evals.py [--baseline-src OLD/src] [--rows 180,point_mass,fetch_reach,large]
        [--states 300] [--repeat 2] [--json FILE]

Rows: ``180`` (3 x 60 trajectories, ``make_problem(60, labels="violations")`` as in ``bench_grouped.py``, margins
(0, 2.9)), the shipped ``point_mass`` (1,100) and ``fetch_reach`` (1,681), and ``large`` (3 x 100,000,
``bench_targets.py``'s data). The states are ``--states`` draws of a short default run of this checkout (seed 3;
for ``large`` 600 iterations of one chain), saved once, so that both checkouts evaluate the same returns. Each
(row, checkout) is timed in its own process (CPU time of ``PreferenceLikelihood.from_scaled_returns`` over every
state, three passes, after one warm-up pass), the checkouts alternating ``--repeat`` times: the host's speed
drifts, so compare within a round. The two checkouts' values are compared too (largest relative difference).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np

ROWS = ("180", "point_mass", "fetch_reach", "large")


def _dataset(row: str) -> tuple[Any, Any]:
    """``(dataset, margins)`` of a row."""
    from pbicrl.api import _as_dataset

    if row == "180":
        from pbicrl.inference.synthetic import make_problem

        return make_problem(60, labels="violations", violation_rate=0.4, seed=0).dataset, [0.0, 2.9]
    if row == "large":
        sys.path.insert(0, str(Path(__file__).parent))
        from bench_targets import _large_dataset

        return _large_dataset(100_000), None
    return _as_dataset(row), None


def _likelihood(row: str) -> Any:
    from pbicrl.inference.likelihood import PreferenceLikelihood
    from pbicrl.inference.preferences import Margins

    ds, margins = _dataset(row)
    return ds, PreferenceLikelihood.from_dataset(ds, margins=Margins.parse(margins, ds.n_groups),
                                                 likelihood="grouped")


def _make_states(row: str, path: Path, n_states: int) -> None:
    import pbicrl

    ds, margins = _dataset(row)
    kw: dict[str, Any] = {"iterations": 600, "chains": 1} if row == "large" else {"iterations": 4000, "chains": 2}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a short run: its convergence warnings are expected
        post = pbicrl.infer(ds, margins=margins, progress=False, seed=3, **kw)
    c = np.asarray(post.indicators).reshape(-1, post.n_features)
    w = np.asarray(post.penalty_weights).reshape(-1, post.n_features)
    idx = np.random.default_rng(0).choice(len(c), min(n_states, len(c)), replace=False)
    np.savez(path, c=c[idx], w=w[idx])


def _worker(row: str, states: Path) -> dict[str, Any]:
    warnings.simplefilter("ignore")
    _, lik = _likelihood(row)
    st = np.load(states)
    A = [lik.returns(w, c) for c, w in zip(st["c"], st["w"])]
    values = [float(lik.from_scaled_returns(a)) for a in A]  # also the warm-up (compile cache load)
    t0 = time.process_time()
    for _ in range(3):
        for a in A:
            lik.from_scaled_returns(a)
    us = (time.process_time() - t0) / (3 * len(A)) * 1e6
    return {"us_per_eval": us, "s_per_1e5": us * 0.1, "values": values}


def _run(src: str | None, row: str, states: Path) -> dict[str, Any]:
    env = dict(os.environ)
    if src is not None:
        env["PYTHONPATH"] = src
    out = subprocess.run([sys.executable, __file__, "--worker", row, "--states-file", str(states)], env=env,
                         capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--worker", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--states-file", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--baseline-src", default=None, help="src/ of the checkout to compare with")
    ap.add_argument("--rows", default=",".join(ROWS))
    ap.add_argument("--states", type=int, default=300)
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    if args.worker is not None:
        print(json.dumps(_worker(args.worker, Path(args.states_file))))
        return
    rows = [r for r in args.rows.split(",") if r]
    for r in rows:
        if r not in ROWS:
            raise SystemExit(f"--rows: unknown row {r!r} (choose from {', '.join(ROWS)})")
    sides = [("this", None)] + ([("baseline", args.baseline_src)] if args.baseline_src else [])
    here = str(Path(__file__).resolve().parent.parent / "src")
    results: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory() as tmp:
        for row in rows:
            states = Path(tmp) / f"{row}.npz"
            _make_states(row, states, args.states)
            for rnd in range(args.repeat):
                got: dict[str, dict[str, Any]] = {}
                for name, src in (sides if rnd % 2 == 0 else sides[::-1]):
                    got[name] = _run(src or here, row, states)
                line = f"{row:<12} round {rnd + 1}: this {got['this']['us_per_eval']:8.1f} us/eval " \
                       f"({got['this']['s_per_1e5']:7.1f} s per 10^5)"
                rec: dict[str, Any] = {"row": row, "round": rnd + 1, "states": args.states,
                                       "this_us": got["this"]["us_per_eval"]}
                if "baseline" in got:
                    a, b = np.array(got["this"]["values"]), np.array(got["baseline"]["values"])
                    rel = float(np.max(np.abs(a - b) / np.maximum(np.abs(b), 1e-300)))
                    ratio = got["baseline"]["us_per_eval"] / got["this"]["us_per_eval"]
                    line += f", baseline {got['baseline']['us_per_eval']:8.1f} us/eval: {ratio:.2f}x; " \
                            f"values within {rel:.1e} relative"
                    rec |= {"baseline_us": got["baseline"]["us_per_eval"], "ratio": ratio, "max_rel_diff": rel}
                print(line, flush=True)
                results.append(rec)
    if args.json:
        Path(args.json).write_text(json.dumps({"baseline_src": args.baseline_src, "rows": results}, indent=1))


if __name__ == "__main__":
    main()
