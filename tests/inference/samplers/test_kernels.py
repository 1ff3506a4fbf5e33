"""Compiled samplers: same chains as the plain NumPy reference, purity, determinism, validity, recovery."""

import numpy as np
import pytest

from pbicrl.inference.data import Dataset
from pbicrl.inference.likelihood import PreferenceLikelihood
from pbicrl.inference.preferences import Preferences
from pbicrl.inference.priors import IndicatorPrior, PriorError, WeightPrior
from pbicrl.inference.samplers import SamplerSettings, build_kernel, sample
from pbicrl.inference.samplers.reference import reference_chain


def _lik(problem, margins=(0.5, 1.0), layout="blocks"):
    if layout == "sampled":  # explicit pairs: proposals are screened with a bound (same chain, fewer evaluations)
        return PreferenceLikelihood.from_dataset(problem.dataset, margins=list(margins), protocol=30, seed=1)
    if layout == "ranked":  # 15 groups of 5: every cross-group pair as the ranking itself (no blocks)
        ds = problem.dataset
        order = np.argsort(np.argsort(ds.group, kind="stable"), kind="stable")
        prefs = Preferences.from_groups(order // 5, np.linspace(0.1, 0.5, 14))
        assert prefs.ranked
        return PreferenceLikelihood(ds.mean_features, prefs, ds.nominal_weights)
    return PreferenceLikelihood.from_dataset(problem.dataset, margins=list(margins))


@pytest.mark.parametrize("layout", ["blocks", "sampled", "ranked"])
@pytest.mark.parametrize("method", ["paper", "bpl", "pbicrl"])
def test_compiled_chain_equals_reference(ranked_problem, method, layout):
    lik = _lik(ranked_problem, layout=layout)
    n = 1500
    prior = WeightPrior("flat", -50, 50)
    # the Python reference implements the moves on w (log_moves=False); the log-magnitude moves are checked
    # against quadrature (test_log_magnitude_moves_match_quadrature)
    kernel = build_kernel(lik, method=method, n_iterations=n, burn_in=0, thin=1, adapt=False, sigma=0.3,
                          weight_prior=prior, log_moves=False)
    state = kernel.init(1)
    if method == "pbicrl":
        state = state._replace(adaptation=state.adaptation._replace(q_mean=np.array([0.0, -5.0, -20.0, 0.5]),
                                                                    q_scale=np.array([1.0, 3.0, 10.0, 1.0])))
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
    end = kernel.run(np.random.default_rng(7), state, n)
    if layout == "sampled" and method != "bpl":
        assert end.counts[4] < 0.8 * (end.counts[0] + end.counts[2])  # many proposals rejected from the bound


def _flat(state):
    """Every array of a (nested) ChainState, copied, and its scalars."""
    out = []
    for x in state:
        out.extend(_flat(x) if isinstance(x, tuple) else [x.copy() if isinstance(x, np.ndarray) else x])
    return out


def test_step_is_pure_and_the_same_chunking_gives_the_same_chain(ranked_problem):
    kernel = build_kernel(_lik(ranked_problem), n_iterations=3000, burn_in=1000, thin=1)
    s0 = kernel.init(3)
    before = _flat(s0)
    s1, info = kernel.step(np.random.default_rng(0), s0)
    assert len(before) == 23
    for x, y in zip(before, _flat(s0)):
        np.testing.assert_array_equal(x, y)
    assert s1.iteration == 1 and info.move in ("flip", "weight", "none")
    # Randoms are drawn per chunk, so the chunk sizes are part of the chain: the same chunks give the same chain
    runs = []
    for _ in range(2):
        st, rng = s0, np.random.default_rng(5)
        for _ in range(3):
            st = kernel.run(rng, st, 1000)
        runs.append(st)
    for x, y in zip(_flat(runs[0]), _flat(runs[1])):
        np.testing.assert_array_equal(x, y)
    assert runs[0].iteration == 3000 and not np.array_equal(runs[0].penalty_weights, s0.penalty_weights)
    for x, y in zip(before, _flat(s0)):  # run is pure too
        np.testing.assert_array_equal(x, y)


@pytest.mark.parametrize("method,p_joint", [("pbicrl", 0.0), ("pbicrl", 0.3), ("paper", 0.0), ("bpl", 0.3)])
def test_step_info_comes_from_the_loop_and_agrees_with_the_counters(ranked_problem, method, p_joint):
    """StepInfo is the loop's own report of its last move, not read off the counters; both must agree."""
    from pbicrl.inference import codes

    kernel = build_kernel(_lik(ranked_problem), method=method, n_iterations=400, p_joint=p_joint,
                          weight_prior=WeightPrior("flat", -50, 50) if method != "paper" else WeightPrior("improper", sign="any"))
    rng = np.random.default_rng(2)
    st = kernel.init(rng)
    seen = set()
    for _ in range(300):
        new, info = kernel.step(rng, st)
        dc = new.counts - st.counts
        prop = {"flip": codes.C_FLIP_PROP, "weight": codes.C_W_PROP, "parameter": codes.C_T_PROP}
        acc = {"flip": codes.C_FLIP_ACC, "weight": codes.C_W_ACC, "parameter": codes.C_T_ACC}
        if info.move == "none":
            assert dc[[codes.C_FLIP_PROP, codes.C_W_PROP, codes.C_T_PROP]].sum() == 0
        else:
            assert dc[prop[info.move]] == 1 and dc[acc[info.move]] == int(info.accepted)
        assert info.log_likelihood == new.log_likelihood
        seen.add((info.move, info.accepted))
        st = new
    assert {("weight", True), ("weight", False)} <= seen


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


@pytest.mark.parametrize("p_joint", [0.0, pytest.param(0.3, marks=pytest.mark.slow)])
def test_pbicrl_posterior_matches_quadrature(p_joint):
    """P(c) and E[w | c=1] from the reversible-jump sampler equal numerical integration of the model (also with
    the adaptive joint weight move mixed in)."""
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
                 weight_prior=WeightPrior("flat", -B, B, sign="any"), indicator_prior=IndicatorPrior(pi), sigma=0.5,
                 p_joint=p_joint)
    pc = res.p_constraint
    cm, _ = res.conditional_penalty()
    assert pc[0] == pytest.approx(p1, abs=0.03)
    assert pc[1] == pytest.approx(p2, abs=0.05)
    assert cm[0] == pytest.approx(ew1, abs=0.1)


def test_recovers_true_constraint_set_from_random_starts(violations_problem):
    """PBICRL finds {constraint1, constraint2} and finds no evidence for the nominal features; BPL keeps them on.

    The rankings (labelled by the worst constraint entered) say next to nothing about the nominal features, so
    under the default weakly informative prior their P(c=1) stays near the prior pi = 1/2 (with a +-1000 flat
    box it was pushed lower by the box's Occam factor, Lindley's paradox, not by the data).
    """
    lik = PreferenceLikelihood.from_dataset(violations_problem.dataset)
    truth = violations_problem.true_indicators
    res = sample(lik, n_iterations=30_000, n_chains=8, seed=0, progress=False)
    np.testing.assert_array_equal(res.map_indicators, truth)
    assert np.all(res.p_constraint[truth == 1] > 0.95)
    assert np.all(res.p_constraint[truth == 0] < 0.6)
    # every chain on its own (each from a different random initial state) has the constraints on
    per_chain = res.indicators.mean(axis=1)
    assert np.all(per_chain[:, truth == 1] > 0.95)
    bpl = sample(lik, method="bpl", n_iterations=30_000, n_chains=2, seed=0, progress=False, adapt=True)
    assert np.all(np.abs(bpl.mean_effective_penalty[truth == 0]) > 0.05)  # BPL cannot switch features off


def test_settings_validation():
    with pytest.raises(ValueError, match="sampler: unknown sampler 'gibbs'"):
        SamplerSettings(sampler="gibbs")
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


# ------------------------------------------------------------------------------------------ priors in the samplers
def _rescaled(lik, factors):
    """The same model on features rescaled by ``factors`` (nominal weights rescaled inversely)."""
    D = np.asarray(factors, dtype=float)
    return PreferenceLikelihood(lik.mean_features * D, lik.preferences, lik.nominal_weights / D, lik.beta)


def test_rescaling_a_feature_rescales_only_its_penalty(ranked_problem):
    """Default prior: feature j scaled by 10 -> its penalty by 1/10; P(c=1) and everything else unchanged."""
    lik = _lik(ranked_problem)
    D = np.array([1.0, 10.0, 1.0, 10.0])  # a constraint feature and a nominal one
    lik10 = _rescaled(lik, D)
    k, k10 = build_kernel(lik), build_kernel(lik10)
    np.testing.assert_allclose(k10.resolved_prior.scale * D, k.resolved_prior.scale, rtol=1e-12)
    a = sample(lik, n_iterations=10_000, n_chains=2, seed=0, n_jobs=1, progress=False)
    b = sample(lik10, n_iterations=10_000, n_chains=2, seed=0, n_jobs=1, progress=False)
    assert np.max(np.abs(a.p_constraint - b.p_constraint)) <= 0.02
    assert np.any((a.p_constraint > 0.0) & (a.p_constraint < 1.0))  # not a degenerate comparison
    ca, _ = a.conditional_penalty()
    cb, _ = b.conditional_penalty()
    on = np.isfinite(ca)
    np.testing.assert_allclose(cb[on] * D[on], ca[on], rtol=1e-6)


def test_bpl_non_candidates_start_and_stay_at_zero():
    """Regression: BPL gave non-candidate features a random fixed penalty that entered the likelihood."""
    from pbicrl.inference.constraints import AxisHalfspace, ConstraintSet
    from pbicrl.inference.samplers import run_chain
    from pbicrl.inference.synthetic import make_wall_problem

    ds = make_wall_problem(15, seed=0).dataset
    lik = PreferenceLikelihood.from_dataset(ds)
    cs = ConstraintSet((AxisHalfspace(0, direction=">=", name="wall"),), ds)
    kernel = build_kernel(lik, method="bpl", n_iterations=2000, burn_in=500, thin=1, constraints=cs,
                          weight_prior=WeightPrior("flat", -1000, 1000, sign="any"))
    for seed in range(3):
        st = kernel.init(seed)
        np.testing.assert_array_equal(st.penalty_weights[:2], 0.0)  # the known features are not candidates
        assert st.penalty_weights[2] != 0.0
        r = run_chain(kernel, seed)
        np.testing.assert_array_equal(r["penalty_weights"][:, :2], 0.0)
        w, th = r["penalty_weights"][-1], r["parameters"][-1]
        ll = kernel.likelihood.from_scaled_returns(kernel._columns(th).T @ (np.r_[lik.nominal_weights, 0.0] + w))
        assert r["log_likelihood"][-1] == pytest.approx(ll, rel=1e-9)


def test_initial_weights_exact_and_in_support(ranked_problem):
    lik = _lik(ranked_problem)
    d = lik.n_features
    # pbicrl: active weights drawn from the (default, half-t) prior; inactive ones 0
    k = build_kernel(lik)
    for seed in range(20):
        st = k.init(seed)
        assert np.all(st.penalty_weights <= 0.0)
        np.testing.assert_array_equal(st.penalty_weights[st.indicators == 0], 0.0)
        assert np.isfinite(st.log_prior) and st.log_prior == pytest.approx(k._log_prior(st.indicators, st.penalty_weights, st.parameters))
    # paper: Algorithm 1's initialisation, bit for bit (no clipping), whatever the prior
    kp = build_kernel(lik, method="paper", init_scale=3.0)
    rng = np.random.default_rng(4)
    c = rng.integers(0, 2, d).astype(np.int8)
    np.testing.assert_array_equal(kp.init(4).indicators, c)
    np.testing.assert_array_equal(kp.init(4).penalty_weights, rng.normal(0.0, 3.0, d))
    # bpl with the wide flat prior: the same single normal draw as before
    kb = build_kernel(lik, method="bpl", weight_prior=WeightPrior("flat", -1000, 1000, sign="any"), candidates=(1, 2))
    np.testing.assert_array_equal(kb.init(4).penalty_weights, np.where([0, 1, 1, 0], np.random.default_rng(4).normal(0.0, 1.0, d), 0.0))
    # bpl with the half-t: N(0, (init_scale u_j)^2) restricted to w <= 0, exactly -> a half-normal
    kb = build_kernel(lik, method="bpl", init_scale=2.0)
    u = kb.resolved_prior.unit
    rng = np.random.default_rng(0)
    draws = np.array([kb._bpl_initial_weights(rng) for _ in range(3000)]) / (2.0 * u)
    assert np.all(draws <= 0.0)
    grid = np.linspace(0.05, 3.0, 60)
    from math import erf
    cdf = np.array([erf(x / np.sqrt(2.0)) for x in grid])  # half-normal CDF of -draws
    ecdf = (-draws[:, :, None] <= grid).mean(axis=0)
    assert np.max(np.abs(ecdf - cdf)) < 1.63 / np.sqrt(3000)  # KS 1% critical value, per feature


def test_proposals_and_steps_follow_the_prior_scale(ranked_problem):
    """The scale rules of the moves on w (``log_moves=False``; the log-magnitude moves start from the prior's
    quantiles of |w|, test_birth_proposals)."""
    lik = _lik(ranked_problem)
    k = build_kernel(lik, sigma=0.1, log_moves=False)
    rp = k.resolved_prior
    st = k.init(0)
    np.testing.assert_allclose(st.sigma, 0.1 / (lik.beta * lik.mean_features.std(axis=0)), rtol=1e-12)
    med, q_sd = rp.proposal()
    np.testing.assert_allclose(st.q_mean, med)
    assert np.all(st.q_mean < 0) and np.all(st.q_scale >= q_sd) and np.all(st.q_scale > 0)
    # half-t(3): median -0.7649 s_j; its 1% quantile -5.8409 s_j lies one proposal sd below the median
    np.testing.assert_allclose(med / rp.scale, -0.764892328404345, rtol=1e-9)
    np.testing.assert_allclose((med - q_sd) / rp.scale, -5.840909309733355, rtol=1e-9)
    # a flat box keeps its rule: centre, a twentieth of the width (here of the support [-40, 0])
    kf = build_kernel(lik, weight_prior=WeightPrior("flat", -40, 40), log_moves=False)
    np.testing.assert_array_equal(kf.init(0).q_mean, -20.0)
    np.testing.assert_array_equal(kf.init(0).q_scale, 2.0)
    np.testing.assert_array_equal(kf.init(0).sigma, 0.1)
    # rescaling a feature rescales its proposal and step with the default prior
    D = np.array([1.0, 10.0, 1.0, 1.0])
    st10 = build_kernel(_rescaled(lik, D), log_moves=False).init(0)
    np.testing.assert_allclose(st10.q_scale * D, st.q_scale, rtol=1e-12)
    np.testing.assert_allclose(st10.sigma * D, st.sigma, rtol=1e-12)


def test_prior_summary_and_settings_record_every_choice(ranked_problem):
    import json

    lik = _lik(ranked_problem)
    k = build_kernel(lik)
    summ = k.prior_summary()
    json.dumps(summ, allow_nan=False)
    assert summ["kind"] == "student_t" and summ["df"] == 3.0 and summ["prior_scale"] == 2.5
    assert summ["sign"] == "negative" and summ["support"] == [None, 0.0] and summ["indicator_pi"] == 0.5
    sd = lik.mean_features.std(axis=0)
    for j in range(lik.n_features):
        assert summ["features"][str(j)]["scale"] == pytest.approx(2.5 / sd[j])
    assert SamplerSettings().weight_prior == WeightPrior()
    rec = SamplerSettings(weight_prior=WeightPrior("normal", -50, None, scale=4.0, sign="any")).to_dict()["weight_prior"]
    json.dumps(rec, allow_nan=False)
    assert rec == {"kind": "normal", "sign": "any", "low": -50.0, "high": None, "support": [-50.0, None], "mean": 0.0,
                   "scale": 4.0, "df": 3.0, "prior_scale": 2.5, "scale_aware": False}
    assert build_kernel(lik, method="paper").prior_summary()["applied"] is False


def test_compiled_log_prior_tracks_python(ranked_problem):
    """The log prior the compiled loop accumulates equals the Python one (normalised densities in both)."""
    lik = _lik(ranked_problem)
    for prior in (WeightPrior(), WeightPrior("normal", -30, 5, mean=-2.0, scale=6.0, sign="any"),
                  WeightPrior("normal", prior_scale=1.0), WeightPrior("flat", -60, 10)):
        k = build_kernel(lik, weight_prior=prior, n_iterations=3000, burn_in=1000)
        st = k.run(np.random.default_rng(1), k.init(1), 3000)
        assert st.log_prior == pytest.approx(k._log_prior(st.indicators, st.penalty_weights, st.parameters), abs=1e-8)


def _one_feature_problem():
    rng = np.random.default_rng(2)
    N = 24
    F = rng.normal(size=(N, 1))
    score = F[:, 0] * -0.4 + rng.gumbel(size=N)
    group = np.empty(N, int)
    group[np.argsort(-score)] = np.repeat([1, 2, 3], 8)
    return Dataset.from_trajectories([f[None, :] for f in F], group, nominal_weights=[0.0])


@pytest.mark.parametrize("prior", [WeightPrior("normal", -3, 3, scale=3.0, sign="any"), WeightPrior()],
                         ids=["normal(0,3) on [-3,3]", "default half-t"])
def test_truncated_prior_posterior_matches_quadrature(prior):
    """P(c=1) and E[w | c=1] with a truncated prior equal 1-D quadrature of the normalised model.

    Here P(c=1) is about 0.28 for N(0, 3^2) on [-3, 3]; leaving out the truncation mass 2 Phi(1) - 1 = 0.68
    (as before) would give 0.21.
    """
    lik = PreferenceLikelihood.from_dataset(_one_feature_problem())
    rp = build_kernel(lik, weight_prior=prior).resolved_prior
    lo = max(rp.low[0], float(rp.ppf(1e-7)[0]))
    hi = min(rp.high[0], float(rp.ppf(1 - 1e-7)[0]))
    grid = np.linspace(lo, hi, 4001)
    i, j, m = lik.preferences.to_pair_list()
    F = lik.mean_features[:, 0]
    a = grid[:, None] * F[None, :]
    post = np.exp(-np.logaddexp(0.0, a[:, j] + m - a[:, i]).sum(axis=1) + rp.logpdf(grid[:, None])[:, 0])
    z1 = np.trapezoid(post, grid)
    z0 = np.exp(-np.logaddexp(0.0, m + 0.0).sum())
    p1 = z1 / (z1 + z0)  # pi = 1/2
    ew = np.trapezoid(grid * post, grid) / z1
    assert 0.1 < p1 < 0.9, "the test problem should leave the feature uncertain"
    res = sample(lik, weight_prior=prior, n_iterations=60_000, n_chains=2, seed=2, n_jobs=1, progress=False)
    cm, _ = res.conditional_penalty()
    assert res.p_constraint[0] == pytest.approx(p1, abs=0.03)
    assert cm[0] == pytest.approx(ew, abs=0.1 * rp.scale[0])


def test_authors_sampler_resets_switched_off_weights():
    """``authors`` = Algorithm 1 except that a flip to off zeroes the weight (the authors' code)."""
    from pbicrl.inference.samplers import SamplerSettings, sample
    from pbicrl.inference.synthetic import make_problem

    ds = make_problem(15, labels="violations", violation_rate=0.4, seed=3).dataset
    lik = PreferenceLikelihood.from_dataset(ds, likelihood="pairwise")
    runs = {}
    for method in ("authors", "paper"):
        # f_s larger than the run: every iteration is a flip, so weights change only by the reset
        st = SamplerSettings(method=method, n_iterations=3000, burn_in=0, thin=1, f_s=10**9, init_range=(-30, -1))
        runs[method] = sample(lik, st, n_chains=1, seed=4, n_jobs=1, progress=False)
    a = runs["authors"]
    c, w = a.indicators[0], a.penalty_weights[0]
    assert np.all(w[0] <= 0) and np.all(w[0] >= -30)
    reset_seen = 0
    for j in range(c.shape[1]):
        off_after_on = np.flatnonzero((c[1:, j] == 0) & (c[:-1, j] == 1))
        if off_after_on.size:
            first = off_after_on[0] + 1
            assert np.all(w[first:, j] == 0.0)
            reset_seen += 1
        assert set(np.unique(w[:, j])) <= {w[0, j], 0.0}
    assert reset_seen >= 1
    p = runs["paper"]
    assert np.all(p.penalty_weights[0] == p.penalty_weights[0][:1])  # paper keeps every latent weight
    assert a.settings["init_range"] == [-30.0, -1.0]


def test_joint_weight_move_matches_the_posterior_of_correlated_weights():
    """bpl with only joint moves after warm-up: mean and covariance of two strongly correlated weights against
    quadrature on a grid; the adapted covariance follows the posterior's."""
    rng = np.random.default_rng(2)
    F = rng.normal(size=(40, 2))
    F[:, 1] = F[:, 0] + 0.3 * F[:, 1]  # nearly collinear features: correlated weights
    pairs = rng.integers(0, 40, (150, 2))
    pairs = pairs[pairs[:, 0] != pairs[:, 1]]
    wt = np.array([1.0, -1.5])
    r = F @ wt
    keep = rng.random(pairs.shape[0]) < 1.0 / (1.0 + np.exp(-(r[pairs[:, 0]] - r[pairs[:, 1]])))
    pairs = np.where(keep[:, None], pairs, pairs[:, ::-1])
    lik = PreferenceLikelihood(F, Preferences.from_pairs(pairs, 40), np.zeros(2))
    B = 8.0
    g = np.linspace(-B, B, 401)
    W0, W1 = np.meshgrid(g, g, indexing="ij")
    W = np.c_[W0.ravel(), W1.ravel()]
    a = W @ F.T
    ll = -np.logaddexp(0.0, a[:, pairs[:, 1]] - a[:, pairs[:, 0]]).sum(axis=1)
    p = np.exp(ll - ll.max())
    p /= p.sum()
    mean = p @ W
    cov = (W - mean).T @ ((W - mean) * p[:, None])
    assert abs(cov[0, 1]) / np.sqrt(cov[0, 0] * cov[1, 1]) > 0.8
    res = sample(lik, method="bpl", n_iterations=60_000, n_chains=4, seed=3, progress=False, p_joint=0.6,
                 weight_prior=WeightPrior("flat", -B, B, sign="any"), sigma=0.5)
    draws = res.penalty_weights.reshape(-1, 2)
    np.testing.assert_allclose(draws.mean(axis=0), mean, atol=0.06 * np.sqrt(np.diag(cov)).max() + 0.02)
    np.testing.assert_allclose(np.cov(draws.T), cov, rtol=0.15)


def test_joint_move_settings_are_checked():
    with pytest.raises(ValueError, match="p_joint"):
        SamplerSettings(method="paper", p_joint=0.2)
    with pytest.raises(ValueError, match="p_joint"):
        SamplerSettings(method="pbicrl", p_flip=0.6, p_joint=0.5)
    with pytest.raises(ValueError, match="p_joint"):
        SamplerSettings(p_joint=1.0)


@pytest.mark.parametrize("prior", [WeightPrior(), WeightPrior("flat", -6.0, 0.0)], ids=["half-t", "flat [-6, 0]"])
def test_log_magnitude_moves_match_quadrature(prior):
    """The default moves on eta = log|w| (random walk with its Jacobian, mixture birth proposals, joint step)
    target the model: P(c=1) and the conditional median of w against 1-D quadrature."""
    lik = PreferenceLikelihood.from_dataset(_one_feature_problem())
    kern = build_kernel(lik, weight_prior=prior, p_joint=0.3)
    assert kern._moves.log_sign.tolist() == [-1]
    rp = kern.resolved_prior
    lo = max(rp.low[0], float(rp.ppf(1e-7)[0]))
    grid = np.linspace(lo, min(rp.high[0], 0.0), 8001)
    i, j, m = lik.preferences.to_pair_list()
    F = lik.mean_features[:, 0]
    a = grid[:, None] * F[None, :]
    post = np.exp(-np.logaddexp(0.0, a[:, j] + m - a[:, i]).sum(axis=1) + rp.logpdf(grid[:, None])[:, 0])
    z1 = np.trapezoid(post, grid)
    z0 = np.exp(-np.logaddexp(0.0, m + 0.0).sum())
    p1 = z1 / (z1 + z0)
    cdf = np.cumsum(post) / post.sum()
    med = grid[np.searchsorted(cdf, 0.5)]
    assert 0.1 < p1 < 0.9
    res = sample(lik, weight_prior=prior, n_iterations=60_000, n_chains=2, seed=5, n_jobs=1, progress=False,
                 p_joint=0.3)
    assert res.settings["log_moves"] is True
    cmed = res.conditional_summary()["median"]
    assert res.p_constraint[0] == pytest.approx(p1, abs=0.03)
    assert cmed[0] == pytest.approx(med, abs=0.08 * abs(med) + 0.05)


def test_log_moves_are_off_for_two_sided_priors_and_other_samplers(ranked_problem):
    lik = _lik(ranked_problem)
    assert not build_kernel(lik, weight_prior=WeightPrior("flat", -5, 5, sign="any"))._moves.log_sign.any()
    assert not build_kernel(lik, method="bpl")._moves.log_sign.any()
    assert not build_kernel(lik, log_moves=False)._moves.log_sign.any()
    assert build_kernel(lik)._moves.log_sign.tolist() == [-1] * lik.n_features


def test_pbicrl_chains_start_their_parameters_near_the_identified_interval():
    """With identify's interval for a parameter, the pbicrl sampler starts it in the interval widened by twice its
    width each side (a chain started at a wall beyond every state never left it, Blocked Ant); the paper sampler
    and a run without an identification start anywhere in the box, with the same draws as before."""
    from pbicrl.analysis.identify import identify
    from pbicrl.inference.constraints import AxisHalfspace, ConstraintSet
    from pbicrl.inference.samplers.driver import _parameter_ranges
    from pbicrl.inference.synthetic import make_wall_problem

    ds = make_wall_problem(15, seed=0).dataset
    lik = PreferenceLikelihood.from_dataset(ds, likelihood="grouped")
    cs = ConstraintSet((AxisHalfspace(0, direction=">=", name="wall"),), ds)
    idf = identify(ds, constraints=cs)
    ranges = _parameter_ranges(idf, cs)
    (rl, rh), = ranges
    assert np.isfinite(rl) and np.isfinite(rh) and rl < rh
    np.testing.assert_allclose(_parameter_ranges(idf.to_dict(), cs), ranges)  # the summary.json form: the same
    lo, hi = cs.bounds[0]
    w = rh - rl
    assert (rh + 2 * w - max(lo, rl - 2 * w)) < 0.9 * (hi - lo)  # a narrower start than the box: the test can fail
    k = build_kernel(lik, constraints=cs, parameter_ranges=ranges)
    starts = np.array([k.init(seed).parameters[0] for seed in range(40)])
    assert np.all(starts >= max(lo, rl - 2 * w)) and np.all(starts <= min(hi, rh + 2 * w))
    plain = build_kernel(lik, constraints=cs)
    paper = build_kernel(lik, constraints=cs, parameter_ranges=ranges, sampler="paper")
    paper_plain = build_kernel(lik, constraints=cs, sampler="paper")
    for seed in range(5):
        assert paper.init(seed).parameters[0] == paper_plain.init(seed).parameters[0]
    wide = np.array([plain.init(seed).parameters[0] for seed in range(40)])
    assert wide.min() < max(lo, rl - 2 * w) or wide.max() > min(hi, rh + 2 * w)


def test_scale_factor_from_ten_percent_up_is_robbins_monro_and_below_solves_the_gaussian_model():
    from pbicrl.inference.samplers._mcmc import _scale_factor

    for acc, n in ((10, 100), (30, 100), (90, 100)):
        assert _scale_factor(acc, n) == pytest.approx(np.exp(acc / n - 0.3), rel=1e-14)
    # a step of scale sigma on a Gaussian of sd s is accepted with probability (2/pi) atan(2 s / sigma)
    for ratio in (0.03, 0.05, 0.07):  # s / sigma (below 0.025 the factor is clipped at 0.1)
        alpha = 2 / np.pi * np.arctan(2 * ratio)
        assert alpha < 0.1
        f = _scale_factor(round(alpha * 10_000), 10_000)
        assert 2 / np.pi * np.arctan(2 * ratio / f) == pytest.approx(0.3, abs=0.01)
    assert _scale_factor(0, 200) == 0.1  # no acceptance: the largest shrink per window
    assert _scale_factor(0, 20) == pytest.approx(np.exp(-0.3))  # too few steps to say more than Robbins-Monro


def test_warm_up_reaches_the_scale_of_a_narrow_posterior():
    """3 x 5,000 trajectories ranked by a noisy return: the posterior of the penalties is ~50x narrower than the
    start's step; after the default warm-up the weight steps accept 29% (11% with Robbins-Monro alone, whose scale
    shrinks at most 0.74x per window)."""
    from pbicrl.inference.codes import MOVE_WEIGHT

    rng = np.random.default_rng(0)
    n = 5_000
    F = np.abs(rng.normal(size=(3 * n, 4))) * [1.0, 0.2, 0.2, 0.5]
    score = F @ np.array([1.0, -5.0, -10.0, -1.0]) + rng.gumbel(size=3 * n)
    rank = np.empty(3 * n, dtype=np.int64)
    rank[np.argsort(-score)] = np.arange(3 * n)
    ds = Dataset(F, np.arange(3 * n + 1), rank // n + 1, nominal_weights=np.array([1.0, 0.0, 0.0, -1.0]))
    lik = PreferenceLikelihood.from_dataset(ds, likelihood="grouped")
    post = sample(lik, iterations=3000, burn_in=2000, chains=1, seed=0, jobs=1, progress=False)
    weight_steps = np.asarray(post.move) == MOVE_WEIGHT
    assert weight_steps.sum() > 200
    assert np.asarray(post.accepted)[weight_steps].mean() > 0.2
