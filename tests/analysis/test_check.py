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
    assert "nominal only" in res.table() and res.log_score > res.log_score_nominal
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
    # log scores of disjoint held-out folds add
    assert res.log_score == pytest.approx(sum(f["log_score"]["posterior"] for f in res.folds))
    assert sum(b["n"] for b in res.reliability) == ds.n_trajectories * ds.n_groups


# ---------------------------------------------------------------------------------------------- log score
def _gumbel_groups(n=90, w=-10.0, seed=0):
    """One feature b; the latent utility w b + Gumbel noise (the Plackett-Luce model with beta 1) sorted into
    three equal groups, best first. Every negative weight orders the data identically."""
    import pbicrl

    rng = np.random.default_rng(seed)
    b = rng.uniform(0, 1, n)
    u = w * b + rng.gumbel(size=n)
    g = 3 - np.searchsorted(np.quantile(u, [1 / 3, 2 / 3]), u)
    return pbicrl.Dataset.from_trajectories([np.array([[1.0, x]]) for x in b], group=g,
                                            feature_names=("const", "b"), nominal_weights=[0.0, 0.0])


def _point_posterior(w_b, names=("const", "b"), draws=40, method="pbicrl", prior_scale=20.0):
    from tests.inference.test_results import make_post, quiet

    ind = np.zeros((1, draws, 2), np.int8)
    ind[..., 1] = 1
    wp = np.zeros((1, draws, 2))
    wp[..., 1] = w_b + np.random.default_rng(1).normal(0, 0.3, draws)
    prior = {"kind": "student_t", "support": [None, 0.0], "mean": 0.0, "scale": prior_scale, "df": 3.0}
    return quiet(make_post, ind, wp, names=names, settings={"weight_prior": prior, "nominal_weights": [0.0, 0.0],
                                                            "candidates": [1]})


def test_log_score_separates_posteriors_that_pair_accuracy_cannot():
    held = _gumbel_groups(seed=5)
    right, weak, huge = (predictive_check(_point_posterior(w), held, n_draws=40, calibration_draws=10)
                         for w in (-10.0, -1.0, -300.0))
    # identical orderings: pair accuracy cannot tell them apart
    assert right.accuracy_mean == pytest.approx(weak.accuracy_mean) == pytest.approx(huge.accuracy_mean)
    # the log score can: the generating weight wins by many nats over a too weak and a too strong one
    assert right.log_score > weak.log_score + 5 and right.log_score > huge.log_score + 5
    assert right.log_score > right.log_score_nominal + 5
    assert right.log_score_prior is not None and right.log_score > right.log_score_prior
    assert right.expected_log_likelihood <= right.log_score + 1e-9  # Jensen
    d = right.to_dict()
    assert d["log_score"]["posterior_minus_nominal"] == pytest.approx(right.log_score - right.log_score_nominal)
    t = right.table()
    assert "log score" in t and "reliability" in t and t.count("pair accuracy") == 1


def test_log_score_matches_the_grouped_likelihood_by_hand():
    from pbicrl.inference.likelihood import PreferenceLikelihood
    from pbicrl.inference.preferences import Preferences

    held = _gumbel_groups(n=30, seed=2)
    post = _point_posterior(-10.0, draws=5)
    res = predictive_check(post, held, n_draws=5, calibration_draws=0)
    lik = PreferenceLikelihood(held.mean_features, Preferences.from_groups(held.group), np.zeros(2), 1.0,
                               kind="grouped")
    ll = np.array([lik(w) for w in post.effective_penalty.reshape(-1, 2)])
    assert res.log_score == pytest.approx(np.log(np.mean(np.exp(ll))), rel=1e-10)
    assert res.log_score_nominal == pytest.approx(lik(np.zeros(2)), rel=1e-10)
    assert res.reliability == []


def test_reliability_of_the_generating_model_is_calibrated():
    held = _gumbel_groups(n=240, seed=7)
    res = predictive_check(_point_posterior(-10.0, draws=8), held, n_draws=8, calibration_draws=8)
    bins = [b for b in res.reliability if b["n"] >= 40]
    assert sum(b["n"] for b in res.reliability) == 240 * 3
    assert bins and all(abs(b["mean_predicted"] - b["observed"]) < 0.15 for b in bins)
