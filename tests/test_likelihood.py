"""The compiled likelihood against a plain brute-force double loop (the oracle)."""

import math

import numpy as np
import pytest

from pbicrl.data import Dataset
from pbicrl.likelihood import PreferenceLikelihood, log_likelihood, log_likelihood_numpy
from pbicrl.preferences import Preferences


def oracle(F, group, wn, wp, c, beta, margins):
    """Paper Eq. 7 written out: every (tau_i in G_k, tau_j in G_l), k < l."""
    labels = sorted(set(group.tolist()))
    r = F @ (wn + c * wp)
    total = 0.0
    for i in range(len(group)):
        for j in range(len(group)):
            k, l = labels.index(group[i]), labels.index(group[j])
            if k < l:
                x = beta * r[i] - margins[k][l]
                y = beta * r[j]
                total += x - max(x, y) - math.log(math.exp(x - max(x, y)) + math.exp(y - max(x, y)))
    return total


@pytest.mark.parametrize("seed", range(8))
def test_matches_oracle_on_random_problems(seed):
    rng = np.random.default_rng(seed)
    K = int(rng.integers(2, 5))
    sizes = rng.integers(1, 12, K)
    group = np.repeat(np.arange(1, K + 1) * 2, sizes)  # labels 2, 4, ...: only their order matters
    d = int(rng.integers(1, 6))
    F = rng.normal(size=(group.size, d)) * 10 ** rng.uniform(-1, 2)
    wn, wp = rng.normal(size=d), rng.normal(size=d) * 5
    c = rng.integers(0, 2, d)
    beta = float(rng.uniform(0.1, 3))
    M = np.triu(rng.uniform(0, 4, (K, K)), 1)
    lik = PreferenceLikelihood(F, Preferences.from_groups(group, M), wn, beta)
    expect = oracle(F, group, wn, wp, c, beta, M)
    assert lik(wp, c) == pytest.approx(expect, rel=1e-9)
    assert log_likelihood_numpy(beta * F @ (wn + c * wp), lik.preferences) == pytest.approx(expect, rel=1e-9)


def test_large_blocks_and_sampled_pairs_match_pairwise_sum():
    rng = np.random.default_rng(1)
    group = np.repeat([1, 2], [700, 600])  # > 512 columns: exercises the chunked product
    a = rng.normal(size=group.size) * 3
    p = Preferences.from_groups(group, [0.7])
    i, j, m = p.to_pair_list()
    expect = -np.logaddexp(0.0, a[j] + m - a[i]).sum()
    lik = PreferenceLikelihood(np.eye(group.size)[:, :1] * 0 + a[:, None], p, np.ones(1))
    assert lik.from_scaled_returns(a) == pytest.approx(expect, rel=1e-10)
    ps = Preferences.from_groups(group, [0.7], protocol=50, seed=3)
    exp2 = -np.logaddexp(0.0, a[ps.pair_j] + ps.pair_margins - a[ps.pair_i]).sum()
    lik2 = PreferenceLikelihood(a[:, None], ps, np.ones(1))
    assert lik2.from_scaled_returns(a) == pytest.approx(exp2, rel=1e-12)


@pytest.mark.parametrize("scale", [1e2, 1e4, 1e6, 1e9])
def test_extreme_return_differences_are_finite_and_exact(scale):
    a = np.array([0.0, scale, -scale, 1.0, 2.0])
    group = np.array([1, 1, 2, 2, 3])
    p = Preferences.from_groups(group, [0.5, 100.0])
    lik = PreferenceLikelihood(a[:, None], p, np.ones(1))
    got = lik.from_scaled_returns(a)
    i, j, m = p.to_pair_list()
    z = a[j] + m - a[i]
    expect = -np.sum(np.maximum(z, 0) + np.log1p(np.exp(-np.abs(z))))
    assert np.isfinite(got)
    assert got == pytest.approx(expect, rel=1e-12)


def test_large_margins_use_the_stable_path():
    a = np.zeros(4)
    p = Preferences.from_groups([1, 1, 2, 2], [800.0])
    lik = PreferenceLikelihood(a[:, None], p, np.ones(1))
    assert lik.from_scaled_returns(a) == pytest.approx(-4 * 800.0, rel=1e-12)


def test_nan_propagates():
    p = Preferences.from_groups([1, 2], None)
    lik = PreferenceLikelihood(np.ones((2, 1)), p, np.ones(1))
    assert np.isnan(lik.from_scaled_returns(np.array([np.nan, 0.0])))


def test_bt_probability_and_convenience():
    ds = Dataset.from_trajectories([np.array([[2.0], [0.0]]), np.array([[0.0]])], [1, 2], nominal_weights=[1.0])
    # mean reward 1 vs 0, margin 0.5: log sigma(1 - 0.5)
    assert log_likelihood(ds, [0.0], margins=[0.5]) == pytest.approx(math.log(1 / (1 + math.exp(-0.5))))
    assert log_likelihood(ds, [1.0], [0]) == pytest.approx(math.log(1 / (1 + math.exp(-1.0))))
    with pytest.raises(ValueError, match="beta"):
        PreferenceLikelihood(np.ones((2, 1)), Preferences.from_groups([1, 2]), np.ones(1), beta=0.0)
    with pytest.raises(ValueError, match="nominal_weights"):
        PreferenceLikelihood(np.ones((2, 1)), Preferences.from_groups([1, 2]), np.ones(2))


def test_power_tempers_the_log_likelihood():
    from pbicrl.likelihood import pairwise_power

    ds = Dataset.from_trajectories([np.array([[1.0]]), np.array([[0.5]]), np.array([[0.0]]), np.array([[-1.0]])],
                                   [1, 1, 2, 2], nominal_weights=[1.0])
    full = PreferenceLikelihood.from_dataset(ds)
    half = PreferenceLikelihood.from_dataset(ds, power=0.5)
    assert half([0.3]) == pytest.approx(0.5 * full([0.3]))
    # 4 trajectories, 4 pairs: one comparison's worth of evidence per trajectory
    assert pairwise_power(full.preferences) == pytest.approx(1.0)
    big = Preferences.from_groups(np.repeat([1, 2, 3], 10))
    assert pairwise_power(big) == pytest.approx(30 / 300)
    with pytest.raises(ValueError, match="power"):
        PreferenceLikelihood.from_dataset(ds, power=1.5)
    with pytest.raises(ValueError, match="power"):
        PreferenceLikelihood.from_dataset(ds, power="half")
