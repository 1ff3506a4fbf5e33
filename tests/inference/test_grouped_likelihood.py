"""The grouped Plackett-Luce likelihood against brute force: permutations, the defining integral, extremes, chains."""

from __future__ import annotations

import itertools
import math
import warnings

import numpy as np
import pytest

from pbicrl.inference import likelihood_kernels as _kernels
from pbicrl.inference.data import Dataset
from pbicrl.inference.likelihood import PreferenceLikelihood
from pbicrl.inference.preferences import PreferenceError, Preferences
from pbicrl.inference.priors import WeightPrior
from pbicrl.inference.samplers import build_kernel, sample


def _grouped(a: np.ndarray, group: np.ndarray, margins=None) -> PreferenceLikelihood:
    """Likelihood whose single feature is the scaled return itself (w = 1)."""
    return PreferenceLikelihood(a[:, None], Preferences.from_groups(group, margins), np.ones(1), kind="grouped")


def _brute_force(a: np.ndarray, group: np.ndarray) -> float:
    """log P(every group above every worse one), summing Plackett-Luce probabilities of all permutations."""
    sizes = np.unique(group, return_counts=True)[1]
    logs = []
    for perm in itertools.permutations(range(a.size)):
        ranks = group[list(perm)]
        if np.any(np.diff(ranks) < 0):
            continue  # not consistent with the grouped ranking
        lp = 0.0
        for r in range(a.size):
            rest = a[list(perm[r:])]
            m = rest.max()
            lp += a[perm[r]] - m - math.log(np.exp(rest - m).sum())
        logs.append(lp)
    assert len(logs) == math.prod(math.factorial(int(s)) for s in sizes)
    m = max(logs)
    return m + math.log(math.fsum(math.exp(v - m) for v in logs))


@pytest.mark.parametrize("seed", range(12))
def test_matches_permutation_brute_force(seed):
    rng = np.random.default_rng(seed)
    N = int(rng.integers(2, 8))
    K = int(rng.integers(2, min(3, N) + 1))
    group = np.sort(np.concatenate([np.arange(1, K + 1), rng.integers(1, K + 1, N - K)]))
    rng.shuffle(group)
    a = rng.normal(size=N) * 10 ** rng.uniform(-1, 1.3) + rng.normal(size=N) * 0.1
    lik = _grouped(a, group)
    expect = _brute_force(a, group)
    assert lik.from_scaled_returns(a) == pytest.approx(expect, rel=1e-10, abs=1e-13)


def test_singletons_reduce_to_the_pairwise_terms():
    a = np.array([0.3, -1.2])
    for m in (0.0, 0.7, -2.0, 40.0):
        pw = PreferenceLikelihood(a[:, None], Preferences.from_groups([1, 2], [m]), np.ones(1))
        gr = PreferenceLikelihood(a[:, None], Preferences.from_groups([1, 2], [m]), np.ones(1), kind="grouped")
        assert gr.from_scaled_returns(a) == pytest.approx(pw.from_scaled_returns(a), rel=1e-15)
    # a full ranking (K = N singletons) is the Plackett-Luce probability of that order
    rng = np.random.default_rng(0)
    a = rng.normal(size=6) * 3
    full = sum(a[k] - np.logaddexp.reduce(a[k:]) for k in range(a.size - 1))
    assert _grouped(a, np.arange(a.size)).from_scaled_returns(a) == pytest.approx(full, rel=1e-13)


def _quad_term(x: np.ndarray) -> float:
    """log P_k by scipy.integrate.quad of the defining integral (or of 1 - P_k when P_k is close to 1).

    Integrated in s = log t (each item's race is decided around t = e^{-x_i}, which spans many decades), over
    unit intervals from well below the smallest such t to where e^{-t} has vanished.
    """
    integrate = pytest.importorskip("scipy.integrate", reason="scipy gives the independent quadrature oracle")

    def h(s: float) -> float:  # log prod (1 - exp(-t e^{x_i})), t = e^s
        return float(np.sum(np.log(-np.expm1(-np.exp(s + x)))))

    lo = min(-float(np.max(x)), 0.0) - 45.0
    hi = math.log(x.size + 1.0) + 5.0
    edges = np.linspace(lo, hi, int(hi - lo) + 2)
    top = max(s - math.exp(s) + h(s) for s in np.linspace(lo, hi, 2000))  # scale: tiny P must not underflow
    opts = dict(epsabs=0.0, epsrel=1e-13, limit=200)
    with warnings.catch_warnings():  # "roundoff error detected": expected when asking for 1e-13
        warnings.simplefilter("ignore")
        return _quad_sums(h, top, edges, opts)


def _quad_sums(h, top: float, edges: np.ndarray, opts: dict) -> float:  # noqa: ANN001
    integrate = pytest.importorskip("scipy.integrate")
    p = math.fsum(integrate.quad(lambda s: math.exp(s - math.exp(s) + h(s) - top), a, b, **opts)[0]
                  for a, b in zip(edges[:-1], edges[1:]))
    if top + math.log(p) < math.log(0.5):
        return top + math.log(p)
    q = math.fsum(integrate.quad(lambda s: math.exp(s - math.exp(s)) * -math.expm1(h(s)), a, b, **opts)[0]
                  for a, b in zip(edges[:-1], edges[1:]))
    return math.log1p(-q)


@pytest.mark.parametrize("seed", range(10))
def test_terms_with_margins_match_quadrature(seed):
    rng = np.random.default_rng(100 + seed)
    K = int(rng.integers(2, 5))
    sizes = rng.integers(1, 40, K)
    group = np.repeat(np.arange(K), sizes)
    a = rng.normal(size=group.size) * rng.uniform(0.2, 3) - 2.0 * group * rng.uniform(0, 2)
    M = np.triu(rng.uniform(-1, 4, (K, K)), 1)
    got = _grouped(a, group, M).from_scaled_returns(a)
    expect = 0.0
    for k in range(K - 1):
        lam = np.concatenate([a[group == l] + M[k, l] for l in range(k + 1, K)])
        x = a[group == k] - np.logaddexp.reduce(lam)
        term = _quad_term(x)
        assert _kernels.group_term(x, np.empty((2, x.size))) == pytest.approx(term, rel=1e-10, abs=1e-300)
        expect += term
    assert got == pytest.approx(expect, rel=1e-10)


def test_margins_shift_the_lower_groups():
    """In term k, group l's returns count as a_j + m_kl: a margin equals moving that group up in that term."""
    rng = np.random.default_rng(3)
    group = np.repeat([0, 1], [5, 7])
    a = rng.normal(size=12)
    shifted = a + np.where(group == 1, 1.5, 0.0)
    assert _grouped(a, group, [1.5]).from_scaled_returns(a) == pytest.approx(
        _grouped(shifted, group).from_scaled_returns(shifted), rel=1e-14)


@pytest.mark.parametrize("n", [2, 300, 10_000])
def test_extreme_orderings_are_finite_and_monotone(n):
    rng = np.random.default_rng(n)
    base = rng.normal(size=2 * n) * 2
    group = np.repeat([0, 1], n)
    lik = _grouped(base, group)
    shifts = [-1e6, -1e4, -300.0, -30.0, -3.0, 0.0, 3.0, 30.0, 300.0, 1e4, 1e6]
    values = []
    for d in shifts:
        a = base + np.where(group == 0, d, 0.0)
        v = lik.from_scaled_returns(a)
        assert np.isfinite(v) and v <= 0.0
        values.append(v)
    assert all(x <= y for x, y in zip(values, values[1:]))  # moving the top group up never lowers the likelihood
    assert values[-1] == 0.0 and values[-3] > -1e-100  # near-certain: log P rounds to (or towards) 0
    assert values[0] < -0.99e6 * n  # near-impossible: about n * shift
    # spreads of 1e6 inside a group, ties and tiny differences
    a = np.concatenate([rng.uniform(-1e6, 1e6, n), np.zeros(n)])
    assert np.isfinite(lik.from_scaled_returns(a))
    a = np.concatenate([np.full(n, 1e-9), np.zeros(n)])
    assert np.isfinite(lik.from_scaled_returns(a))


def test_large_groups_and_near_certain_orders_match_quadrature():
    rng = np.random.default_rng(7)
    for n, mu, sd in [(10_000, 0.0, 1.0), (10_000, 14.0, 2.0), (3000, -3.0, 30.0), (2, 11.7, 0.2), (5, 21.0, 0.3),
                      (100, 20.0, 0.5), (1000, 15.0, 2.0), (20, 30.0, 1.0)]:
        x = rng.normal(size=n) * sd + mu
        assert _kernels.group_term(x, np.empty((2, n))) == pytest.approx(_quad_term(x), rel=1e-10)


def test_nan_propagates_and_infinities_are_handled():
    group = np.repeat([0, 1, 2], 3)
    a = np.linspace(-1, 1, 9)
    lik = _grouped(a, group)
    for i in (0, 4, 8):
        b = a.copy()
        b[i] = np.nan
        assert np.isnan(lik.from_scaled_returns(b))
    x = np.array([0.5, np.inf, -0.2])
    buf = np.empty((2, 3))
    assert _kernels.group_term(x, buf) == pytest.approx(_kernels.group_term(x[[0, 2]], buf), rel=1e-15)
    assert _kernels.group_term(np.array([0.5, -np.inf]), buf) == -np.inf


def test_pairwise_only_options_are_errors():
    ds = Dataset.from_trajectories([np.ones((2, 1)) * i for i in range(6)], [1, 1, 2, 2, 3, 3])
    with pytest.raises(PreferenceError, match=r"^pairs: .*applies to likelihood='pairwise' only"):
        PreferenceLikelihood.from_dataset(ds, protocol=10, likelihood="grouped")
    with pytest.raises(ValueError, match=r"^power: .*applies to likelihood='pairwise' only"):
        PreferenceLikelihood.from_dataset(ds, power=0.5, likelihood="grouped")
    with pytest.raises(ValueError, match=r"^power: "):
        PreferenceLikelihood.from_dataset(ds, power="pairs", likelihood="grouped")
    with pytest.raises(PreferenceError, match=r"^pairs: "):
        PreferenceLikelihood(ds.mean_features, Preferences.from_groups(ds.group, protocol=5), np.zeros(1),
                             kind="grouped")
    with pytest.raises(PreferenceError, match="ranked groups"):
        PreferenceLikelihood(ds.mean_features, Preferences.from_pairs([[0, 2]], 6), np.zeros(1), kind="grouped")
    with pytest.raises(ValueError, match="likelihood: unknown kind"):
        PreferenceLikelihood.from_dataset(ds, likelihood="listwise")
    assert PreferenceLikelihood.from_dataset(ds).kind == "pairwise"  # existing callers unchanged


def test_call_and_scaled_returns_agree_for_both_kinds():
    rng = np.random.default_rng(5)
    F = rng.normal(size=(30, 3))
    group = np.repeat([1, 2, 3], 10)
    ds = Dataset.from_trajectories([f[None, :] for f in F], group, nominal_weights=[1.0, 0.0, 0.0])
    wp, c = np.array([0.0, -2.0, 0.5]), np.array([0, 1, 1])
    for kind in ("pairwise", "grouped"):
        lik = PreferenceLikelihood.from_dataset(ds, margins=[0.5, 1.0], beta=2.0, likelihood=kind)
        a = 2.0 * F @ (np.array([1.0, 0.0, 0.0]) + c * wp)
        assert lik(wp, c) == pytest.approx(lik.from_scaled_returns(a), rel=1e-13)
    grouped = PreferenceLikelihood.from_dataset(ds, margins=[0.5, 1.0], beta=2.0, likelihood="grouped")
    pairwise = PreferenceLikelihood.from_dataset(ds, margins=[0.5, 1.0], beta=2.0)
    assert grouped(wp, c) > pairwise(wp, c)  # one term per group instead of one per pair


@pytest.mark.parametrize("method", ["pbicrl", "paper", "bpl"])
def test_grouped_chain_tracks_the_likelihood(ranked_problem, method):
    lik = PreferenceLikelihood.from_dataset(ranked_problem.dataset, margins=[0.5, 1.0], likelihood="grouped")
    kernel = build_kernel(lik, method=method, n_iterations=3000, burn_in=500, thin=1,
                          weight_prior=WeightPrior("flat", -50.0, 50.0))
    state = kernel.init(1)
    out = kernel.new_buffers(kernel.settings.n_draws)
    end = kernel.run(np.random.default_rng(2), state, 3000, out)
    assert end.counts[4] > 100 and len(np.unique(out[3])) > 10  # it evaluated and moved
    assert end.log_likelihood == pytest.approx(lik.from_scaled_returns(end.scaled_returns), rel=1e-12)
    w = np.where(end.indicators == 1, end.penalty_weights, 0.0) if method != "bpl" else end.penalty_weights
    assert end.log_likelihood == pytest.approx(lik(w, end.indicators if method != "bpl" else None), rel=1e-9)


@pytest.mark.filterwarnings("ignore")  # convergence warnings of a deliberately short run
def test_grouped_sample_runs(violations_problem):
    lik = PreferenceLikelihood.from_dataset(violations_problem.dataset, likelihood="grouped")
    post = sample(lik, n_iterations=3000, n_chains=2, seed=0, n_jobs=1, progress=False)
    assert np.all(np.isfinite(post.log_likelihood))


def test_many_groups_use_margin_offsets_like_the_matrix():
    """Additive margins over many groups: the O(K) running logsumexp equals the K x K form."""
    from pbicrl.inference.preferences import Margins

    rng = np.random.default_rng(4)
    for K, N in ((12, 12), (30, 80), (60, 200)):
        group = np.sort(np.concatenate([np.arange(K), rng.integers(0, K, N - K)]))
        gaps = rng.uniform(0, 2, K - 1)
        a = rng.normal(size=N) * 3
        ranked = Preferences.from_groups(group, gaps)
        assert ranked.ranked and ranked.margin_offsets.size == K
        dense = Preferences(N, ranked.block_rows, ranked.block_row_offsets, ranked.block_cols,
                            ranked.block_col_offsets, ranked.block_margins, np.array([0]), np.array([N - 1]),
                            np.zeros(1), protocol="all", group_items=ranked.group_items,
                            group_offsets=ranked.group_offsets,
                            group_margins=Margins.from_gaps(gaps).matrix)
        got = PreferenceLikelihood(a[:, None], ranked, np.ones(1), kind="grouped").from_scaled_returns(a)
        expect = PreferenceLikelihood(a[:, None], dense, np.ones(1), kind="grouped").from_scaled_returns(a)
        assert got == pytest.approx(expect, rel=1e-13)
    # a total ranking is the Plackett-Luce probability of the order, margins shifting the lower items
    a = rng.normal(size=15) * 2
    o = np.cumsum(rng.uniform(0, 1, 15))
    full = sum(a[k] - np.logaddexp.reduce(a[k:] + o[k:] - o[k]) for k in range(14))
    got = _grouped(a, np.arange(15), np.diff(o)).from_scaled_returns(a)
    assert got == pytest.approx(full, rel=1e-13)


@pytest.mark.parametrize("scale", [0.3, 3.0, 40.0, 400.0])
def test_large_groups_binned_match_the_per_item_terms(scale):
    """Groups of >= _GB_MIN items go through binned moments: the same log P_k as the per-item integral (itself
    checked against quadrature above), and the whole likelihood equals the sum of per-item terms."""
    rng = np.random.default_rng(int(scale * 10))
    n = 12_000
    for shift in (-3.0, 2.0, 25.0):
        a = rng.normal(size=n) * scale + rng.normal()
        cen, mom, nb, sp = _kernels._gb_moments(a, np.arange(n), np.empty((2, n)))
        assert nb > 0  # binning pays for these spreads
        assert _kernels._gb_logsumexp(cen, mom, nb, sp) == pytest.approx(np.logaddexp.reduce(a), rel=1e-13)
        log_lam = np.logaddexp.reduce(a) + shift
        expect = _kernels.group_term(a - log_lam, np.empty((4, n)))
        got = _kernels._gb_direct(n, -log_lam, cen, mom, nb, sp, np.empty((3, n)))
        assert got == pytest.approx(expect, rel=1e-12)
    # three groups, two of them binned: the likelihood is the sum of the per-item terms
    a = rng.normal(size=3 * n) * scale
    group = np.repeat([1, 2, 3], n)
    rng.shuffle(group)
    lik = _grouped(a, group, [0.5, 1.0])
    off = np.array([0.0, 0.5, 1.5])
    members = [np.flatnonzero(group == g) for g in (1, 2, 3)]
    lse = [np.logaddexp.reduce(a[m]) for m in members]
    expect = 0.0
    for k in range(2):
        log_lam = np.logaddexp.reduce([off[l] - off[k] + lse[l] for l in range(k + 1, 3)])
        expect += _kernels.group_term(a[members[k]] - log_lam, np.empty((4, n)))
    assert lik.from_scaled_returns(a) == pytest.approx(expect, rel=1e-12)


@pytest.mark.parametrize("scale", [0.0, 1e-3, 0.3, 3.0, 40.0, 1e4])
def test_logsumexp_of_a_group_without_an_exp_per_item(scale):
    """The last group's logsumexp (one ``exp`` per bin, a polynomial per item) equals the exact one; spreads too
    wide for its bins, small groups and non-finite returns take the exact path with its conventions."""
    rng = np.random.default_rng(int(scale * 7) + 3)
    for n in (10, 64, 5_000):
        a = rng.normal(size=n) * scale + rng.normal() * 50.0
        idx = rng.permutation(n)[: n - n // 3]
        got = _kernels._logsumexp_fast(a, idx)
        assert got == pytest.approx(np.logaddexp.reduce(a[idx]), rel=1e-14, abs=1e-13)
    a = rng.normal(size=200)
    for bad in (np.inf, -np.inf, np.nan):
        b = a.copy()
        b[17] = bad
        idx = np.arange(200)
        got, ref = _kernels._logsumexp_fast(b, idx), _kernels._logsumexp_at(b, idx)
        assert got == ref or (np.isnan(got) and np.isnan(ref))
    assert _kernels._logsumexp_fast(np.full(100, -np.inf), np.arange(100)) == -np.inf


@pytest.mark.parametrize("scale", [0.01, 1.0, 10.0])
def test_large_groups_near_certain_use_the_binned_complement(scale):
    """A large group far above the lower ones (P_k close to 1: the direct form declines) gets the complement form on
    binned moments: the same log P_k as the per-item path, including tiny ones (relative precision kept)."""
    rng = np.random.default_rng(int(scale * 100) + 7)
    n = 12_000
    seen = 0
    for shift in (4.0, 8.0, 14.0, 25.0):
        a = rng.normal(size=n) * scale
        cen, mom, nb, sp = _kernels._gb_moments(a, np.arange(n), np.empty((2, n)))
        assert nb > 0
        log_lam = a.min() - shift
        assert np.isnan(_kernels._gb_direct(n, -log_lam, cen, mom, nb, sp, np.empty((3, n))))  # the complement's case
        expect = _kernels.group_term(a - log_lam, np.empty((4, n)))
        got = _kernels._gb_comp(-log_lam, cen, mom, nb, sp, np.empty((3, n)))
        assert got == pytest.approx(expect, rel=1e-12, abs=0.0)
        seen += expect < -1e-300
    assert seen >= 2  # not only terms that round to 0
    # through the likelihood: one binned group far above another
    a = np.concatenate([rng.normal(size=n) * scale + 12.0, rng.normal(size=n) * scale])
    lik = _grouped(a, np.repeat([1, 2], n), [0.0])
    expect = _kernels.group_term(a[:n] - np.logaddexp.reduce(a[n:]), np.empty((4, n)))
    assert lik.from_scaled_returns(a) == pytest.approx(expect, rel=1e-12, abs=0.0)


def test_large_groups_keep_the_per_item_path_when_binning_does_not_pay():
    rng = np.random.default_rng(1)
    n = 3000
    a = rng.normal(size=n) * 1e4  # spread thinly over many bins
    assert _kernels._gb_moments(a, np.arange(n), np.empty((2, n)))[2] == 0
    a[5] = np.inf
    assert _kernels._gb_moments(a, np.arange(n), np.empty((2, n)))[2] == 0


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_groups_with_dense_and_sparse_bins_match_the_per_item_terms(seed):
    """A dense cluster and a thin spread (the shipped point mass's second group: ~300 returns over 27 nats): the
    dense bins carry moments, the other items are summed one by one; equal to the per-item terms to 1e-12, through
    the direct and the complement form, and the group's logsumexp to 1e-13."""
    rng = np.random.default_rng(seed)
    a = np.concatenate([rng.normal(size=250) * 0.15, rng.uniform(-15.0, 12.0, size=120)])
    n = a.size
    cen, mom, nb, sp = _kernels._gb_moments(a, np.arange(n), np.empty((2, n)))
    assert nb > 0 and 100 <= sp.size < n  # binned, with sparse items beside the bins
    assert mom[:, 0].sum() + sp.size == n
    assert _kernels._gb_logsumexp(cen, mom, nb, sp) == pytest.approx(np.logaddexp.reduce(a), rel=1e-13)
    forms = set()
    for shift in (-45.0, -35.0, -4.0, 2.0, 8.0):
        log_lam = np.logaddexp.reduce(a) + shift
        expect = _kernels.group_term(a - log_lam, np.empty((4, n)))
        got = _kernels._gb_direct(n, -log_lam, cen, mom, nb, sp, np.empty((3, n)))
        if np.isnan(got):
            forms.add("complement")
            got = _kernels._gb_comp(-log_lam, cen, mom, nb, sp, np.empty((3, n)))
        else:
            forms.add("direct")
        assert got == pytest.approx(expect, rel=1e-12, abs=1e-300)
    assert forms == {"direct", "complement"}


@pytest.mark.parametrize("n", [128, 316, 1500])
def test_small_concentrated_groups_binned_match_the_per_item_terms(n):
    """From _GB_MIN = 64 items a group whose returns are concentrated (the shipped point mass: 316 items within 0.1)
    is binned; the likelihood equals the per-item terms to 1e-12 (direct and complement forms)."""
    assert _kernels._GB_MIN <= n
    rng = np.random.default_rng(n)
    for spread, shift in ((0.02, -2.0), (0.3, 1.0), (0.02, 12.0)):
        a = rng.normal(size=n) * spread + rng.normal()
        cen, mom, nb, sp = _kernels._gb_moments(a, np.arange(n), np.empty((2, n)))
        if spread == 0.02:
            assert nb > 0  # binning pays for a tight group
        elif nb == 0:
            continue  # too spread for its size: the per-item path (the cost rule of _gb_moments)
        log_lam = np.logaddexp.reduce(a) + shift
        expect = _kernels.group_term(a - log_lam, np.empty((4, n)))
        got = _kernels._gb_direct(n, -log_lam, cen, mom, nb, sp, np.empty((3, n)))
        if np.isnan(got):
            got = _kernels._gb_comp(-log_lam, cen, mom, nb, sp, np.empty((3, n)))
        assert got == pytest.approx(expect, rel=1e-12)


@pytest.mark.parametrize("seed", range(6))
def test_grouped_bound_is_above_the_likelihood(seed):
    """The tangent-line bound the sampler screens death moves with (``grouped_loglik_bound``) is never below the
    exact log-likelihood: groups of 2 to 3,000 (per item, binned, dense and sparse bins), margin matrices and additive
    margins, returns spread from 0.01 to 200 nats, near-certain to near-impossible orders."""
    rng = np.random.default_rng(seed)
    for _ in range(12):
        K = int(rng.integers(2, 6))
        sizes = rng.integers(2, 3000 if rng.random() < 0.4 else 120, size=K)
        group = np.repeat(np.arange(1, K + 1), sizes)
        spread = 10.0 ** rng.uniform(-2, 2.3)
        a = rng.normal(size=group.size) * spread - (group - 1) * rng.uniform(-3.0, 30.0)
        if rng.random() < 0.3:
            a[rng.integers(group.size)] += 50.0 * spread  # an outlier: sparse bins
        margins = None if rng.random() < 0.5 else list(rng.uniform(0.0, 5.0, size=K - 1))
        lik = _grouped(a, group, margins)
        kb = lik.kernel_bundle()
        exact = lik.from_scaled_returns(a)
        b = _kernels.grouped_loglik_bound(a, kb.gitems, kb.goff, kb.gmarg, kb.gbuf, kb.moff)
        assert b >= exact, (K, sizes, spread, margins)
        assert b <= 0.0


def test_death_screen_leaves_the_default_chain_unchanged():
    """The grouped likelihood's death moves are screened by that bound (fewer exact evaluations): the draws equal
    those recorded before the screen existed (tests/data/screen_reference.npz, 2 chains x 3,000 iterations, seed
    11). Regenerate that file only with a change meant to change the default sampler's chains."""
    from pathlib import Path

    import pbicrl

    ref = np.load(Path(__file__).parent.parent / "data" / "screen_reference.npz")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for data in ("point_mass", "example"):
            p = pbicrl.infer(data, iterations=3000, chains=2, seed=11, progress=False, p_joint=0.3)
            assert np.array_equal(np.asarray(p.indicators, dtype=np.int8), ref[f"{data}_c"])
            assert np.array_equal(np.asarray(p.penalty_weights), ref[f"{data}_w"])
            # the log-likelihoods to rounding only: a fresh Numba cache may compile the reassociated sums of the
            # inlined kernel differently from the one that recorded them (the decisions, hence the draws, are equal)
            np.testing.assert_allclose(np.asarray(p.log_likelihood), ref[f"{data}_ll"], rtol=1e-12, atol=0.0)
            if data == "point_mass":  # deaths of in_orange and in_red are screened, not evaluated
                assert np.all(p.counts[:, 4] < 0.92 * 3000)
