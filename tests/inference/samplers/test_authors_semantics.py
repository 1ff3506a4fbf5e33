"""``--sampler authors`` follows the authors' code (issue 29, item 1): a feature that starts switched off has
weight 0, and ``summary.json`` reports the authors' statistic (mean of the last 500 iterations) beside the
mean over all kept draws."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from pbicrl.inference.likelihood import PreferenceLikelihood
from pbicrl.inference.samplers import SamplerSettings
from pbicrl.inference.samplers.kernels import Kernel
from pbicrl.inference.synthetic import make_problem


@pytest.mark.parametrize("seed", range(6))
def test_features_starting_off_have_weight_zero(seed):
    ds = make_problem(10, violation_rate=0.4, seed=1).dataset
    lik = PreferenceLikelihood.from_dataset(ds, likelihood="pairwise")
    st = SamplerSettings(method="authors", n_iterations=10, burn_in=0, thin=1, init_range=(-30, -1))
    pos = Kernel(lik, st).init(seed).position
    c, w = np.asarray(pos[0]), np.asarray(pos[1])
    assert np.all(w[c == 0] == 0.0)
    assert np.all((w[c == 1] <= -1) & (w[c == 1] >= -30))
    # the other samplers' initial states are untouched (the reference chains pin them)
    paper = Kernel(lik, dataclasses.replace(st, method="paper")).init(seed).position
    assert np.all(np.asarray(paper[0]) == c)


def test_authors_statistic_is_the_mean_of_the_last_500_iterations():
    from tests.inference.test_results import make_post, quiet

    rng = np.random.default_rng(0)
    ind = np.ones((2, 1000, 1), np.int8)
    wp = np.cumsum(rng.normal(size=(2, 1000, 1)), axis=1) - 50.0  # a drifting chain
    post = dataclasses.replace(quiet(make_post, ind, wp), method="authors", issue_warnings=False)
    st = post.summary()["posterior"]["authors_statistic"]
    expect = wp[:, -500:, 0].mean(axis=1)
    assert st["per_chain"]["a"] == pytest.approx(expect.tolist())
    assert st["value"]["a"] == pytest.approx(expect.mean())
    assert st["posterior_mean"]["a"] == pytest.approx(wp.mean())
    assert "authors' statistic" in post.table()
    thinned = dataclasses.replace(post, settings=post.settings | {"thin": 10})
    assert thinned.authors_statistic()["draws_per_chain"] == 50
    assert "authors_statistic" not in quiet(make_post, ind, wp).summary()["posterior"]


def test_authors_pairs_are_distinct_and_seeded_by_pairs_seed():
    import pbicrl
    from pbicrl.inference.preferences import PreferenceError, Preferences

    g = np.repeat([1, 2, 3], [4, 5, 6])
    p = Preferences.from_groups(g, None, protocol=20, seed=3, distinct=True)
    I, J, _ = p.to_pair_list()
    pairs = set(zip(I.tolist(), J.tolist()))
    assert len(pairs) == I.size == 60  # 20 per group pair, none twice
    assert all(g[i] < g[j] for i, j in pairs)
    again = Preferences.from_groups(g, None, protocol=20, seed=3, distinct=True).to_pair_list()
    assert np.array_equal(again[0], I) and np.array_equal(again[1], J)
    with pytest.raises(PreferenceError, match="only 20"):
        Preferences.from_groups(g, None, protocol=21, seed=3, distinct=True)
    # the default (paper) protocol is unchanged: each side drawn with replacement
    assert Preferences.from_groups(g, None, protocol=20, seed=3).protocol == "20 per group pair"
    ds = make_problem(10, violation_rate=0.4, seed=1).dataset
    post = pbicrl.infer(ds, sampler="authors", likelihood="pairwise", pairs=8, pairs_seed=5, iterations=200, chains=1,
                        seed=0, progress=False)
    assert post.settings["protocol"] == "8 per group pair (distinct)" and post.identified["pairs"]["seed"] == 5


def test_authors_chain_keeps_switched_off_weights_at_zero_and_steps_a_weight_first():
    from pbicrl.inference.samplers import sample

    ds = make_problem(15, labels="violations", violation_rate=0.4, seed=3).dataset
    lik = PreferenceLikelihood.from_dataset(ds, likelihood="pairwise")
    out = {}
    for method in ("authors", "paper"):
        st = SamplerSettings(method=method, n_iterations=4000, burn_in=0, thin=1, f_s=4, init_range=(-30, -1))
        out[method] = sample(lik, st, n_chains=1, seed=4, n_jobs=1, progress=False)
    a = out["authors"]
    c, w = a.indicators[0], a.penalty_weights[0]
    assert np.all(w[c == 0] == 0.0)  # no latent weight survives while off, so a feature is switched on at 0
    assert c.min() == 0  # the check above is not vacuous
    mv = a.move[0]
    # the authors' code steps a weight at iterations 0, 4, 8, ...; the paper (counting from 1) at 3, 7, 11, ...
    assert mv[0] == 2 and np.all(mv[4::4] == 2) and np.all(mv[1:4] == 1)
    assert out["paper"].move[0][0] == 1 and out["paper"].move[0][3] == 2
    # paper keeps latent weights while off
    pc, pw = out["paper"].indicators[0], out["paper"].penalty_weights[0]
    assert np.any(pw[pc == 0] != 0.0)
