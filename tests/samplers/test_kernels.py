"""Compiled samplers: same chains as the plain NumPy reference, purity, determinism, validity, recovery."""

import numpy as np
import pytest

from pbicrl.data import Dataset
from pbicrl.likelihood import PreferenceLikelihood
from pbicrl.preferences import Preferences
from pbicrl.priors import IndicatorPrior, PriorError, WeightPrior
from pbicrl.samplers import SamplerSettings, build_kernel, sample
from pbicrl.samplers.reference import reference_chain


def _lik(problem, margins=(0.5, 1.0)):
    return PreferenceLikelihood.from_dataset(problem.dataset, margins=list(margins))


@pytest.mark.parametrize("method", ["paper", "bpl", "pbicrl"])
def test_compiled_chain_equals_reference(ranked_problem, method):
    lik = _lik(ranked_problem)
    n = 1500
    prior = WeightPrior("flat", -50, 50)
    kernel = build_kernel(lik, method=method, n_iterations=n, burn_in=0, thin=1, adapt=False, sigma=0.3,
                          weight_prior=prior)
    state = kernel.init(1)
    if method == "pbicrl":
        state = state._replace(q_mean=np.array([0.0, -5.0, -20.0, 0.5]), q_scale=np.array([1.0, 3.0, 10.0, 1.0]))
    rng = np.random.default_rng(7)
    randoms = kernel.draw_randoms(np.random.default_rng(7), n)
    out = kernel.new_buffers(n)
    kernel.run(rng, state, n, out)
    rc, rw, rll = reference_chain(lik, method, state.indicators, state.penalty_weights, randoms, sigma=0.3,
                                  q_mean=state.q_mean, q_scale=state.q_scale, weight_prior=prior)
    np.testing.assert_array_equal(out[0], rc)
    np.testing.assert_allclose(out[1], rw, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(out[3], rll, rtol=1e-9)
    assert len(np.unique(out[3])) > 10  # the chain moved


def test_step_is_pure_and_chunking_does_not_matter(ranked_problem):
    kernel = build_kernel(_lik(ranked_problem), n_iterations=3000, burn_in=1000, thin=1)
    s0 = kernel.init(3)
    before = [x.copy() if isinstance(x, np.ndarray) else x for x in s0]
    s1, info = kernel.step(np.random.default_rng(0), s0)
    for x, y in zip(before, s0):
        np.testing.assert_array_equal(x, y)
    assert s1.iteration == 1 and info.move in ("flip", "weight", "none")
    one = kernel.run(np.random.default_rng(5), s0, 3000)
    st = s0
    rng = np.random.default_rng(5)
    for _ in range(3):
        st = kernel.run(rng, st, 1000)
    # Randoms are drawn per chunk from the same stream, so equal chunking of the stream gives equal chains.
    rng2 = np.random.default_rng(5)
    u = [kernel.draw_randoms(rng2, 1000) for _ in range(3)]
    assert st.iteration == one.iteration == 3000
    assert np.isfinite(st.log_likelihood) and u[0][0].size == 1000


def test_same_seed_same_chains_any_jobs(violations_problem):
    lik = _lik(violations_problem)
    a = sample(lik, n_iterations=4000, n_chains=2, seed=3, n_jobs=1, progress=False)
    b = sample(lik, n_iterations=4000, n_chains=2, seed=3, n_jobs=2, progress=False)
    c = sample(lik, n_iterations=4000, n_chains=2, seed=4, n_jobs=1, progress=False)
    np.testing.assert_array_equal(a.penalty_weights, b.penalty_weights)
    np.testing.assert_array_equal(a.indicators, b.indicators)
    assert not np.array_equal(a.penalty_weights, c.penalty_weights)


def _tiny_problem():
    rng = np.random.default_rng(2)
    N, d = 24, 2
    F = rng.normal(size=(N, d))
    score = F @ np.array([1.5, 0.0]) + rng.gumbel(size=N)
    group = np.empty(N, int)
    group[np.argsort(-score)] = np.repeat([1, 2, 3], 8)
    ds = Dataset.from_trajectories([f[None, :] for f in F], group, nominal_weights=[0.0, 0.0])
    return ds


def test_pbicrl_posterior_matches_quadrature():
    """P(c) and E[w | c=1] from the reversible-jump sampler equal numerical integration of the model."""
    ds = _tiny_problem()
    B, pi = 4.0, 0.3
    lik = PreferenceLikelihood.from_dataset(ds)
    grid = np.linspace(-B, B, 801)
    h = grid[1] - grid[0]
    i, j, m = lik.preferences.to_pair_list()
    F = ds.mean_features

    def loglik_many(W):  # W (n, 2)
        a = W @ F.T
        return -np.logaddexp(0.0, a[:, j] + m - a[:, i]).sum(axis=1)

    Z = {}
    Z[(0, 0)] = np.exp(loglik_many(np.zeros((1, 2)))[0])
    l1 = np.exp(loglik_many(np.c_[grid, np.zeros_like(grid)]))
    l2 = np.exp(loglik_many(np.c_[np.zeros_like(grid), grid]))
    G0, G1 = np.meshgrid(grid, grid, indexing="ij")
    l12 = np.exp(loglik_many(np.c_[G0.ravel(), G1.ravel()])).reshape(G0.shape)
    Z[(1, 0)] = l1.sum() * h / (2 * B)
    Z[(0, 1)] = l2.sum() * h / (2 * B)
    Z[(1, 1)] = l12.sum() * h * h / (2 * B) ** 2
    prior_c = {k: pi ** sum(k) * (1 - pi) ** (2 - sum(k)) for k in Z}
    post = {k: Z[k] * prior_c[k] for k in Z}
    tot = sum(post.values())
    p1 = (post[(1, 0)] + post[(1, 1)]) / tot
    p2 = (post[(0, 1)] + post[(1, 1)]) / tot
    ew1 = (post[(1, 0)] * (grid * l1).sum() / l1.sum() + post[(1, 1)] * (G0 * l12).sum() / l12.sum()) / (post[(1, 0)] + post[(1, 1)])
    assert 0.05 < p2 < 0.95, "the test problem should leave feature 2 uncertain"

    res = sample(lik, method="pbicrl", n_iterations=120_000, n_chains=4, seed=1, progress=False,
                 weight_prior=WeightPrior("flat", -B, B), indicator_prior=IndicatorPrior(pi), sigma=0.5)
    pc = res.p_constraint
    cm, _ = res.conditional_penalty()
    assert pc[0] == pytest.approx(p1, abs=0.03)
    assert pc[1] == pytest.approx(p2, abs=0.05)
    assert cm[0] == pytest.approx(ew1, abs=0.1)


def test_recovers_true_constraint_set_from_random_starts(violations_problem):
    """PBICRL finds {constraint1, constraint2} and rejects the nominal features; BPL keeps them all on."""
    lik = PreferenceLikelihood.from_dataset(violations_problem.dataset)
    truth = violations_problem.true_indicators
    res = sample(lik, n_iterations=30_000, n_chains=8, seed=0, progress=False)
    np.testing.assert_array_equal(res.map_indicators, truth)
    assert np.all(res.p_constraint[truth == 1] > 0.95)
    assert np.all(res.p_constraint[truth == 0] < 0.5)
    # every chain on its own (each from a different random initial state) has the constraints on
    per_chain = res.indicators.mean(axis=1)
    assert np.all(per_chain[:, truth == 1] > 0.95)
    bpl = sample(lik, method="bpl", n_iterations=30_000, n_chains=2, seed=0, progress=False, adapt=True)
    assert np.all(np.abs(bpl.mean_effective_penalty[truth == 0]) > 0.05)  # BPL cannot switch features off


def test_settings_validation():
    with pytest.raises(ValueError, match="method"):
        SamplerSettings(method="gibbs")
    with pytest.raises(ValueError, match="burn_in"):
        SamplerSettings(n_iterations=10, burn_in=10)
    with pytest.raises(ValueError, match="sigma"):
        SamplerSettings(sigma=0)
    with pytest.raises(PriorError, match="proper prior"):
        SamplerSettings(weight_prior=WeightPrior("improper"))
    with pytest.raises(PriorError, match="low < high"):
        WeightPrior("flat", 1, -1)
    with pytest.raises(PriorError, match="pi"):
        IndicatorPrior(1.0)
    lik = PreferenceLikelihood(np.ones((2, 1)), Preferences.from_groups([1, 2]), np.zeros(1))
    with pytest.raises(ValueError, match="candidates"):
        build_kernel(lik, candidates=(3,))
