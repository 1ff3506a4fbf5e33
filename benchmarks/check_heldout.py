"""The posterior predictive check separates posteriors that pair accuracy cannot (issue 29, item 3).

Fits the default model on a stratified half of the shipped point-mass demonstrations and scores the other half
with ``pbicrl.analysis.check.predictive_check`` for: the default posterior; the same draws with in_red fixed at
-44 (c = 1); the nominal-only model (the check's own nominal line). Prints each table.

    python benchmarks/check_heldout.py [--iterations 20000] [--chains 2] [--seed 0]
"""

from __future__ import annotations

import argparse
import dataclasses
import time

import numpy as np

import pbicrl
from pbicrl.analysis.check import kfold_split, predictive_check


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--iterations", type=int, default=20_000)
    ap.add_argument("--chains", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--draws", type=int, default=400)
    ap.add_argument("--calibration-draws", type=int, default=50)
    a = ap.parse_args()
    ds = pbicrl.load_dataset("point_mass")
    held = kfold_split(ds.group, 2, seed=a.seed)[0]
    train = np.setdiff1d(np.arange(ds.n_trajectories), held)
    t0 = time.time()
    post = pbicrl.infer(ds.subset(train), iterations=a.iterations, chains=a.chains, seed=a.seed, progress=False)
    print(f"fit on {train.size} trajectories in {time.time() - t0:.0f} s; held out {held.size}")
    print(post.table().split("\n\n")[0].splitlines()[0:6])
    red = post.feature_names.index("in_red")
    ind, wp = post.indicators.copy(), post.penalty_weights.copy()
    ind[..., red], wp[..., red] = 1, -44.0
    fixed = dataclasses.replace(post, indicators=ind, penalty_weights=wp, issue_warnings=False)
    test = ds.subset(held)
    for name, p in (("default posterior", post), ("in_red fixed at -44", fixed)):
        r = predictive_check(p, test, n_draws=a.draws, seed=a.seed, calibration_draws=a.calibration_draws)
        print(f"\n== {name} ==\n{r.table()}")


if __name__ == "__main__":
    main()
