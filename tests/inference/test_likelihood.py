"""The compiled likelihood against a plain brute-force double loop (the oracle)."""

import math

import numpy as np
import pytest

from pbicrl.inference.data import Dataset
from pbicrl.inference.likelihood import PreferenceLikelihood, log_likelihood, log_likelihood_numpy
from pbicrl.inference.preferences import PreferenceError, Preferences


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
    from pbicrl.inference.likelihood import pairwise_power

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


def _softplus_sum(a, rows, cols, margin):
    """The per-pair oracle: -sum softplus(a_j + m - a_i), summed exactly (math.fsum)."""
    z = a[cols][None, :] + margin - a[rows][:, None]
    return -math.fsum((np.maximum(z, 0.0) + np.log1p(np.exp(-np.abs(z)))).ravel())


@pytest.mark.parametrize("seed", range(10))
def test_wide_spread_blocks_match_per_pair_softplus(seed):
    """Blocks spreading over more than _SPREAD nats take the sorted/banded path: exact to float precision."""
    from pbicrl.inference import likelihood_kernels as _kernels
    rng = np.random.default_rng(seed)
    nr, nc = (int(v) for v in rng.integers(1, 900, 2))
    spread = 10 ** rng.uniform(np.log10(700), 6)
    kind = seed % 3
    if kind == 0:  # uniform over the spread
        a = rng.uniform(0, spread, nr + nc)
    elif kind == 1:  # a few tight clusters far apart, with ties
        centres = rng.uniform(0, spread, 4)
        a = np.round(centres[rng.integers(0, 4, nr + nc)] + rng.normal(size=nr + nc) * 5, 1)
    else:  # mostly close pairs plus outliers
        a = rng.normal(size=nr + nc) * 20
        a[rng.integers(0, nr + nc, 3)] += spread * np.array([1, -1, 0.5])
    a += rng.uniform(-1e5, 1e5)  # an offset: the path must not depend on absolute returns
    rows, cols = np.arange(nr), nr + np.arange(nc)
    margin = float(rng.uniform(-50, 50))
    expect = _softplus_sum(a, rows, cols, margin)
    got = _kernels._block_wide(a, rows, cols, margin)
    assert np.ptp(a) > _kernels._SPREAD
    assert got == pytest.approx(expect, rel=1e-12, abs=nr * nc * 4e-16)
    # the old per-pair loop, for comparison: its long sequential sum drifts a little more (seen: 1.03e-12)
    assert _kernels._block_softplus(a, rows, cols, margin) == pytest.approx(expect, rel=1e-11, abs=nr * nc * 4e-16)
    # and through the likelihood (blocks of three groups, each spreading wide)
    group = rng.integers(1, 4, nr + nc)
    group[:3] = [1, 2, 3]
    p = Preferences.from_groups(group, [margin, 2.0 * abs(margin)] if seed % 2 else None)
    i, j, m = p.to_pair_list()
    z = a[j] + m - a[i]
    lik = PreferenceLikelihood(a[:, None], p, np.ones(1))
    total = -math.fsum(np.maximum(z, 0.0) + np.log1p(np.exp(-np.abs(z))))
    assert lik.from_scaled_returns(a) == pytest.approx(total, rel=1e-12, abs=z.size * 4e-16)


def test_wide_spread_path_handles_chunks_and_nan():
    from pbicrl.inference import likelihood_kernels as _kernels
    rng = np.random.default_rng(11)
    a = np.concatenate([rng.normal(size=1500) * 3, [1e4, -1e4]])  # > _CHUNK close columns in one band
    rows, cols = np.arange(0, 1502, 3), np.setdiff1d(np.arange(1502), np.arange(0, 1502, 3))
    expect = _softplus_sum(a, rows, cols, 0.25)
    assert _kernels._block_wide(a, rows, cols, 0.25) == pytest.approx(expect, rel=1e-12)
    b = a.copy()
    b[cols[5]] = np.nan
    scratch = [np.empty(cols.size) for _ in range(3)] + [np.empty(a.size) for _ in range(2)]
    assert np.isnan(_kernels.block_loglik(b, rows, cols, 0.25, *scratch))


@pytest.mark.parametrize("gap", [5.0, 30.0, 45.0, 300.0])
def test_wide_spread_blocks_keep_relative_precision_when_pairs_are_decided(gap):
    """Nearly every pair decided (the log-likelihood is a sum of tiny terms): still exact relative to its size."""
    from pbicrl.inference import likelihood_kernels as _kernels
    rng = np.random.default_rng(int(gap))
    rows_a = gap + rng.uniform(0, 2000, 400)  # the preferred side, at least `gap` nats above every column
    cols_a = -rng.uniform(0, 1000, 300)
    a = np.concatenate([rows_a, cols_a])
    rows, cols = np.arange(400), 400 + np.arange(300)
    z = a[cols][None, :] - a[rows][:, None]
    expect = -math.fsum(np.log1p(np.exp(z)).ravel())
    assert expect < 0.0
    assert _kernels._block_wide(a, rows, cols, 0.0) == pytest.approx(expect, rel=1e-13)


# ------------------------------------------------------------------------------------- speed paths (issue 18)
def _fsum_oracle(a: np.ndarray, prefs: Preferences) -> float:
    """Every pair of ``to_pair_list`` summed exactly rounded (``math.fsum`` of ``-logaddexp``)."""
    i, j, m = prefs.to_pair_list()
    return -math.fsum(np.logaddexp(0.0, a[j] + m - a[i]).tolist())


def test_softplus_shortcuts_give_the_same_bits():
    from pbicrl.inference.likelihood_kernels import softplus

    z = np.concatenate([np.linspace(-800, 800, 4001), np.linspace(-40, -35, 501), np.linspace(35, 40, 501)])
    for v in z.tolist():
        general = v + math.log1p(math.exp(-v)) if v > 0 else math.log1p(math.exp(v))
        assert softplus(v) == general, v


@pytest.mark.parametrize("scale", [1e-3, 0.3, 3.0, 40.0, 2000.0])
def test_explicit_pairs_match_the_exactly_rounded_sum(scale):
    """pairs_loglik (product of 1 + e^{-|z|}, series for small terms) against math.fsum of per-pair logaddexp,
    relative to the sum itself: also when nearly every pair is decided and the sum is tiny, and beyond _CHUNK."""
    from pbicrl.inference.likelihood_kernels import pairs_loglik

    rng = np.random.default_rng(int(scale * 1000) + 1)
    for P in (1, 7, 511, 512, 513, 3000):
        N = 200
        a = rng.normal(size=N) * scale
        pi, pj = rng.integers(0, N, P), rng.integers(0, N, P)
        pm = rng.uniform(-2, 2, P)
        expect = -math.fsum(np.logaddexp(0.0, a[pj] + pm - a[pi]).tolist())
        assert pairs_loglik(a, pi, pj, pm) == pytest.approx(expect, rel=2e-14, abs=0.0)
        # every pair decided by 6 .. 40 nats: a sum of terms 1e-18 .. 2.5e-3
        pm2 = -(np.abs(a[pj] - a[pi]) + rng.uniform(6.0, 40.0, P)) - (a[pj] - a[pi])
        expect2 = -math.fsum(np.logaddexp(0.0, a[pj] + pm2 - a[pi]).tolist())
        assert pairs_loglik(a, pi, pj, pm2) == pytest.approx(expect2, rel=1e-13, abs=0.0)
    one = np.array([0]), np.array([1])
    assert pairs_loglik(np.array([np.inf, 0.0]), *one, np.zeros(1)) == 0.0
    assert pairs_loglik(np.array([-np.inf, 0.0]), *one, np.zeros(1)) == -np.inf
    assert np.isnan(pairs_loglik(np.array([np.nan, 0.0]), *one, np.zeros(1)))
    assert np.isnan(pairs_loglik(np.array([np.inf, np.inf]), *one, np.zeros(1)))


@pytest.mark.parametrize("scale", [0.1, 3.0, 40.0, 2000.0])
def test_pairs_bound_is_an_upper_bound_and_tight(scale):
    from pbicrl.inference.likelihood_kernels import pairs_loglik, pairs_loglik_bound

    rng = np.random.default_rng(int(scale * 10))
    for _ in range(20):
        N = int(rng.integers(2, 300))
        P = int(rng.integers(1, 400))
        a = rng.normal(size=N) * scale
        pi, pj = rng.integers(0, N, P), rng.integers(0, N, P)
        pm = rng.uniform(-3, 3, P)
        exact = pairs_loglik(a, pi, pj, pm)
        u, slack = pairs_loglik_bound(a, pi, pj, pm)
        assert exact <= u + slack
        assert u - exact <= 6e-4 * P  # the tangents are at most f'' h^2 / 8 below softplus


def _ranked_case(rng: np.random.Generator, N: int, K: int, scale: float, gaps: bool):
    group = np.sort(np.concatenate([np.arange(K), rng.integers(0, K, N - K)]))
    rng.shuffle(group)
    a = rng.normal(size=N) * scale
    prefs = Preferences.from_groups(group * 3 + 1, rng.uniform(0, 3, K - 1) if gaps else None)
    return a, group, prefs


@pytest.mark.parametrize("scale", [0.3, 5.0, 200.0, 1e4])
def test_ranked_layout_matches_every_pair(scale):
    from pbicrl.inference.preferences import RANKED_MIN_GROUPS

    rng = np.random.default_rng(int(scale))
    for N, K in ((12, RANKED_MIN_GROUPS), (40, 25), (150, 150), (300, 40), (300, 12)):
        a, group, prefs = _ranked_case(rng, N, K, scale, gaps=bool(rng.integers(0, 2)))
        assert prefs.ranked and prefs.n_blocks == 0 and prefs.group_margins.shape == (K, K)
        i, j, _ = prefs.to_pair_list()
        assert i.size == prefs.n_pairs == sum(int(np.sum(group < g)) for g in group)
        lik = PreferenceLikelihood(a[:, None], prefs, np.ones(1))
        expect = _fsum_oracle(a, prefs)
        assert lik.from_scaled_returns(a) == pytest.approx(expect, rel=1e-12)
        assert log_likelihood_numpy(a, prefs) == pytest.approx(expect, rel=1e-12)


def test_ranked_layout_equals_the_block_layout_and_handles_nan_and_inf():
    from pbicrl.inference.preferences import Margins

    rng = np.random.default_rng(3)
    a, group, prefs = _ranked_case(rng, 60, 20, 2.0, gaps=True)
    M = Margins.from_offsets(prefs.margin_offsets).matrix
    off, items = prefs.group_offsets, prefs.group_items
    members = [items[off[k]:off[k + 1]] for k in range(20)]
    kl = [(k, l) for k in range(20) for l in range(k + 1, 20)]
    empty = np.zeros(0, np.int64)
    blocks = Preferences(60, np.concatenate([members[k] for k, _ in kl]),
                         np.cumsum([0] + [members[k].size for k, _ in kl]),
                         np.concatenate([members[l] for _, l in kl]), np.cumsum([0] + [members[l].size for _, l in kl]),
                         np.array([M[k, l] for k, l in kl]), empty, empty, np.zeros(0))  # the dense layout, by hand
    assert not blocks.ranked and blocks.n_blocks == 20 * 19 // 2 and blocks.n_pairs == prefs.n_pairs
    ranked = PreferenceLikelihood(a[:, None], prefs, np.ones(1)).from_scaled_returns(a)
    dense = PreferenceLikelihood(a[:, None], blocks, np.ones(1)).from_scaled_returns(a)
    assert ranked == pytest.approx(dense, rel=1e-13)
    lik = PreferenceLikelihood(a[:, None], prefs, np.ones(1))
    b = a.copy()
    b[5] = np.nan
    assert math.isnan(lik.from_scaled_returns(b))
    for i in (int(np.argmin(group)), int(np.argmax(group))):  # infinitely good: finite if best, else -inf
        b = a.copy()
        b[i] = np.inf
        expect = _fsum_oracle(b, prefs)
        assert lik.from_scaled_returns(b) == (pytest.approx(expect, rel=1e-12) if np.isfinite(expect) else expect)


def test_many_groups_need_no_k_by_k_structure():
    from pbicrl.inference.likelihood import pairwise_power
    from pbicrl.inference.preferences import Margins

    K = 20_000
    prefs = Preferences.from_groups(np.arange(K)[::-1])  # a total ranking, label 0 best
    assert prefs.ranked and prefs.group_margins.size == 0 and prefs.margin_offsets.shape == (K,)
    assert prefs.block_rows.size == prefs.block_cols.size == prefs.pair_i.size == 0
    assert prefs.n_pairs == K * (K - 1) // 2
    assert pairwise_power(prefs) == pytest.approx(K / prefs.n_pairs)
    m = Margins.from_gaps(np.full(K - 1, 0.5))
    assert m._matrix is None and m.n_groups == K and len(m.as_dict()) == K - 1
    lik = PreferenceLikelihood(np.linspace(1, 0, K)[:, None] * 3, prefs, np.ones(1), kind="grouped")
    a = lik.scaled_features_T[0]
    full = sum(a[::-1][k] - np.logaddexp.reduce(a[::-1][k:]) for k in range(0, K - 1, 997))  # spot terms
    assert np.isfinite(lik.from_scaled_returns(a)) and np.isfinite(full)


def test_margins_offsets_and_additivity():
    from pbicrl.inference.preferences import Margins

    g = Margins.from_gaps([1.0, 0.5, 2.0])
    np.testing.assert_array_equal(g.offsets, [0.0, 1.0, 1.5, 3.5])
    np.testing.assert_array_equal(Margins(g.matrix).offsets, g.offsets)  # a matrix that is additive is seen as such
    assert Margins.from_dict({(1, 2): 0.0, (2, 3): 2.9, (1, 3): 6.0}, 3).offsets is None
    np.testing.assert_array_equal(Margins.zeros(4).matrix, np.zeros((4, 4)))
    assert Margins.from_offsets([2.0, 3.0, 5.0]).as_dict() == {"m12": 1.0, "m13": 3.0, "m23": 2.0}
    big = Margins.from_gaps(np.arange(1.0, 70.0))
    assert big.as_dict() == {f"m{k + 1}_{k + 2}": float(k + 1) for k in range(69)}
    with pytest.raises(PreferenceError, match="NaN"):
        Margins.from_offsets([0.0, np.nan])
