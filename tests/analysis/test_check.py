"""Posterior predictive check: pair accuracy against brute force, and a seeded end-to-end check."""

from __future__ import annotations

import numpy as np
import pytest

from pbicrl.analysis.check import kfold_split, pair_accuracy, predictive_check
from pbicrl.inference.synthetic import make_problem


def _brute(r, g):
    good = total = 0.0
    for i in range(r.size):
        for j in range(r.size):
            if g[i] < g[j]:
                total += 1
                good += 1.0 if r[i] > r[j] else (0.5 if r[i] == r[j] else 0.0)
    return good / total


@pytest.mark.parametrize("seed", range(5))
def test_pair_accuracy_matches_brute_force(seed):
    rng = np.random.default_rng(seed)
    g = rng.integers(1, 4, 40)
    r = np.round(rng.normal(size=40), 1)  # rounding makes ties
    assert pair_accuracy(r, g) == pytest.approx(_brute(r, g), abs=1e-12)


def test_kfold_split_is_stratified_and_disjoint():
    g = np.repeat([1, 2, 3], [10, 7, 5])
    folds = kfold_split(g, 5, seed=1)
    allidx = np.concatenate(folds)
    assert np.array_equal(np.sort(allidx), np.arange(g.size))
    for f in folds:
        assert set(np.unique(g[f])) == {1, 2, 3}
    with pytest.raises(ValueError, match="group 3 has 5 trajectories"):
        kfold_split(g, 6)
    with pytest.raises(ValueError, match="folds must be >= 2"):
        kfold_split(g, 1)


def test_constraints_explain_heldout_rankings_better_than_nominal():
    import pbicrl

    prob = make_problem(40, labels="violations", violation_rate=0.4, seed=3)
    ds = prob.dataset
    folds = kfold_split(ds.group, 2, seed=0)
    train = np.setdiff1d(np.arange(ds.n_trajectories), folds[0])
    post = pbicrl.infer(ds.subset(train), iterations=6000, chains=2, jobs=1, seed=1, progress=False)
    res = predictive_check(post, ds.subset(folds[0]), n_draws=100, seed=0)
    assert res.accuracy_draws.shape == (100,)
    assert res.accuracy_mean > res.accuracy_nominal + 0.05
    d = res.to_dict()
    assert d["n_pairs"] == res.n_pairs > 0 and 0 <= d["pair_accuracy"]["mean"] <= 1
    assert "nominal reward" in res.table()
    bad = ds.subset(folds[0])
    with pytest.raises(ValueError, match="features"):
        predictive_check(post, pbicrl.Dataset.from_trajectories(
            [bad.trajectory(i)[:, :2] for i in range(bad.n_trajectories)], group=bad.group))


def test_cross_validate_pools_folds():
    import pbicrl
    from pbicrl.analysis.check import cross_validate

    ds = make_problem(30, labels="violations", violation_rate=0.4, seed=4).dataset
    res = cross_validate(ds, 3, lambda d: pbicrl.infer(d, iterations=3000, chains=1, jobs=1, seed=2,
                                                       progress=False), n_draws=50)
    assert len(res.folds) == 3 and res.n_trajectories == ds.n_trajectories
    assert res.n_pairs == sum(f["n_pairs"] for f in res.folds)
    assert min(f["nominal_pair_accuracy"] for f in res.folds) <= res.accuracy_nominal <= max(
        f["nominal_pair_accuracy"] for f in res.folds)
