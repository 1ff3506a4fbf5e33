"""Issue 27's targets, as a user meets them: wall time to convergence with every default.

    python benchmarks/bench_targets.py                       # all rows, 1 repetition
    python benchmarks/bench_targets.py --rows point_mass fetch_reach --repeat 3 --json out.json

Rows:

* ``point_mass``, ``fetch_reach``: ``pbicrl infer DATA --out DIR`` in a fresh process (the command line, start-up
  included: imports, identification, loading the compiled sampler, writing the run);
* ``large``: :func:`pbicrl.infer` with defaults on 3 x 100,000 trajectories (the data of
  ``bench_speed.py large``: one state per trajectory, ranked by a noisy true return);
* ``label_page``: the labelling page's inference call (:mod:`pbicrl.ui.inference`: ``jobs=1``, its default
  chains) on 100 point-mass demonstrations drawn from the shipped set (the same number from each group where it
  can).

A throwaway ``pbicrl infer example`` first fills the compile cache, so every row is measured warm. The wall time,
whether the run converged, its smallest ESS and largest R-hat and the selected set are printed and, with
``--json``, written. Say in the report what ran beside the measurement: a shared machine changes the seconds.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from typing import Any

import numpy as np

TARGETS = {"point_mass": 10.0, "fetch_reach": 10.0, "large": 60.0, "label_page": 15.0}


def _summary_row(summary: dict[str, Any], wall: float) -> dict[str, Any]:
    conv = (summary.get("extra") or {}).get("convergence") or {}
    return {"wall_s": wall, "converged": summary.get("converged"), "min_ess": conv.get("min_ess"),
            "max_rhat": conv.get("max_rhat"), "iterations_run": conv.get("iterations_run"),
            "rounds": conv.get("rounds"), "sampling_s": conv.get("wall_s"), "selected": summary.get("selected")}


def _cli_row(data: str, seed: int) -> dict[str, Any]:
    out = tempfile.mkdtemp(prefix="pbicrl-target-")
    try:
        t = time.perf_counter()
        subprocess.run([sys.executable, "-m", "pbicrl.cli", "infer", data, "--out", os.path.join(out, "run"),
                        "--seed", str(seed), "--no-progress"], check=True, stdout=subprocess.DEVNULL)
        wall = time.perf_counter() - t
        with open(os.path.join(out, "run", "summary.json")) as fh:
            return _summary_row(json.load(fh), wall)
    finally:
        shutil.rmtree(out, ignore_errors=True)


def _large_dataset(n: int, seed: int = 0) -> Any:
    from pbicrl.inference.data import Dataset

    rng = np.random.default_rng(seed)
    F = np.abs(rng.normal(size=(3 * n, 4))) * [1.0, 0.2, 0.2, 0.5]
    score = F @ np.array([1.0, -5.0, -10.0, -1.0]) + rng.gumbel(size=3 * n)
    rank = np.empty(3 * n, dtype=np.int64)
    rank[np.argsort(-score)] = np.arange(3 * n)
    return Dataset(F, np.arange(3 * n + 1), rank // n + 1, nominal_weights=np.array([1.0, 0.0, 0.0, -1.0]))


def _api_row(dataset: Any, seed: int, **kw: Any) -> dict[str, Any]:
    import warnings

    from pbicrl import infer

    t = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        post = infer(dataset, seed=seed, progress=False, **kw)
    wall = time.perf_counter() - t
    return _summary_row(post.summary(), wall)


def _label_page_row(seed: int) -> dict[str, Any]:
    from pbicrl.inference.data import load_dataset
    from pbicrl.ui.inference import _PAGE_MAX_TIME, InferenceSettings

    ds = load_dataset("point_mass")
    rng = np.random.default_rng(seed)
    labels = np.unique(ds.group)
    per = 100 // labels.size
    idx = np.concatenate([rng.choice(np.flatnonzero(ds.group == g), per, replace=False) for g in labels])
    rest = np.setdiff1d(np.arange(ds.group.size), idx)
    idx = np.sort(np.concatenate([idx, rng.choice(rest, 100 - idx.size, replace=False)]))
    s = InferenceSettings()
    return _api_row(ds.subset(idx), seed, iterations=s.iterations, chains=s.chains, jobs=1, max_time=_PAGE_MAX_TIME)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", nargs="+", choices=tuple(TARGETS), default=list(TARGETS))
    ap.add_argument("--repeat", type=int, default=1, help="seeds 0..repeat-1 per row")
    ap.add_argument("--large-n", type=int, default=100_000)
    ap.add_argument("--json", help="write every number here")
    args = ap.parse_args(argv)
    warm = tempfile.mkdtemp(prefix="pbicrl-warm-")
    subprocess.run([sys.executable, "-m", "pbicrl.cli", "infer", "example", "--out", os.path.join(warm, "run"),
                    "--iterations", "2000", "--chains", "2", "--no-progress"], check=True, stdout=subprocess.DEVNULL)
    shutil.rmtree(warm, ignore_errors=True)
    large = _large_dataset(args.large_n) if "large" in args.rows else None
    rows = []
    for seed in range(args.repeat):
        for name in args.rows:
            if name in ("point_mass", "fetch_reach"):
                r = _cli_row(name, seed)
            elif name == "large":
                r = _api_row(large, seed)
            else:
                r = _label_page_row(seed)
            r |= {"row": name, "seed": seed, "target_s": TARGETS[name], "load_before": os.getloadavg()[0]}
            rows.append(r)
            ok = "met" if r["converged"] and r["wall_s"] <= TARGETS[name] else "MISSED"
            print(f"{name:12s} seed {seed}: {r['wall_s']:6.1f} s wall (target {TARGETS[name]:g} s: {ok}), converged "
                  f"{r['converged']}, {r['iterations_run']} iterations/chain in {r['rounds']} rounds, min ESS "
                  f"{r['min_ess']:.0f}, max R-hat {r['max_rhat']:.4f}, selected {r['selected']}", flush=True)
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(rows, fh, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
