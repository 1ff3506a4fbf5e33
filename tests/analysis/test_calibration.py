"""Simulation-based calibration: the machinery (fast) and the sampler's calibration (slow)."""

from __future__ import annotations

import numpy as np
import pytest

from pbicrl.analysis.calibration import SBCProblem, rank_statistics, run_sbc, simulate, uniformity


def test_simulators_match_their_designs():
    rng = np.random.default_rng(0)
    lik, c, wp = simulate(SBCProblem(design="pairs"), rng)
    assert lik.preferences.n_pairs == 300 and lik.preferences.pair_i.size == 300  # 3 group pairs x 10 x 10
    assert np.all(lik.preferences.pair_i != lik.preferences.pair_j)
    assert c.shape == wp.shape == (2,) and np.all(np.abs(wp) <= 3)
    lik_g, _, _ = simulate(SBCProblem(design="groups"), rng)
    assert lik_g.preferences.n_blocks == 3 and lik_g.preferences.n_pairs == 300
    with pytest.raises(ValueError, match="design"):
        SBCProblem(design="triples")


def test_pairs_follow_bradley_terry():
    """With one strong feature, the simulated winner has the higher return about sigma(diff) of the time."""
    rng = np.random.default_rng(1)
    agree, expect = [], []
    for _ in range(40):
        lik, c, wp = simulate(SBCProblem(design="pairs", pi=0.999), rng)
        a = lik.mean_features @ (c * wp)
        i, j = lik.preferences.pair_i, lik.preferences.pair_j
        agree.append(np.mean(a[i] > a[j]))
        expect.append(np.mean(1 / (1 + np.exp(-np.abs(a[i] - a[j])))))
    assert abs(np.mean(agree) - np.mean(expect)) < 0.02


def test_ties_are_broken_uniformly():
    rng = np.random.default_rng(2)
    draws = np.zeros((9, 1))  # posterior all at 0, truth 0: rank uniform on 0..9
    ranks = np.array([rank_statistics(np.zeros(1), draws, rng)[0] for _ in range(5000)])
    counts = np.bincount(ranks, minlength=10)
    assert counts.min() > 400 and counts.max() < 600
    assert rank_statistics(np.array([0.5]), np.array([[0.0], [1.0], [0.2]]), rng)[0] == 2


def test_uniformity_detects_skew():
    rng = np.random.default_rng(3)
    flat = rng.integers(0, 81, size=(500, 1))
    skew = np.minimum(rng.integers(0, 81, size=(500, 1)), rng.integers(0, 81, size=(500, 1)))
    assert uniformity(flat, 80)["tests"][0]["chi2_p"] > 0.01
    assert uniformity(skew, 80)["tests"][0]["chi2_p"] < 1e-6
    with pytest.raises(ValueError, match="must divide"):
        uniformity(flat, 80, bins=10)


def test_run_sbc_smoke():
    res = run_sbc(SBCProblem(per_group=4), n_replicates=3, n_iterations=1200, seed=5)
    assert res.ranks.shape == (3, 4) and res.ranks.min() >= 0 and res.ranks.max() <= res.L == 80
    d = res.to_dict()
    assert set(d["tests"]) == {"penalty[f0]", "penalty[f1]", "indicator[f0]", "indicator[f1]"}
    assert d["settings"]["draws_per_chain"] == 20
    again = run_sbc(SBCProblem(per_group=4), n_replicates=3, n_iterations=1200, seed=5)
    np.testing.assert_array_equal(res.ranks, again.ranks)  # seeded end to end


@pytest.mark.slow
def test_sampler_is_calibrated_on_the_pairwise_model():
    """SBC of the pbicrl sampler where the simulator is exactly the likelihood's model (about 2-4 minutes)."""
    res = run_sbc(SBCProblem(design="pairs"), n_replicates=400, n_iterations=20_000, seed=1)
    ps = {n: (t["chi2_p"], t["ks_p"]) for n, t in zip(res.names, res.tests["tests"])}
    assert res.passed(0.01), ps


@pytest.mark.slow
def test_grouped_likelihood_is_calibrated_on_grouped_rankings():
    """The grouped likelihood on data from a grouped ranking process: 90% intervals given c_j = 1 cover the
    truth about 90% of the time and P(c=1) is reliable (the report in benchmarks/reports uses 300 replicates)."""
    pytest.importorskip("scipy")
    res = run_sbc(SBCProblem(design="groups", likelihood="grouped"), n_replicates=120, n_iterations=20_000, seed=3)
    for name, e in res.conditional["features"].items():
        assert 0.80 <= e["coverage90"] <= 0.97, (name, e)
        assert e["rank_ks_p"] > 1e-3, (name, e)
    assert res.conditional["brier"] < 0.15
