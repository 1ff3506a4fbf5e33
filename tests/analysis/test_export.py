"""ArviZ export: each variable once, a pointwise log-likelihood per trajectory that sums to the total, and
``az.loo`` / ``az.summary`` on the result."""

from __future__ import annotations

import warnings
from types import SimpleNamespace

import numpy as np
import pytest

import pbicrl
from pbicrl.analysis import export
from pbicrl.errors import PbicrlWarning
from pbicrl.inference.constraints import ConstraintSet, constraint_from_dict
from pbicrl.inference.likelihood import PreferenceLikelihood
from pbicrl.inference.preferences import Margins, Preferences
from pbicrl.io.runs import read_run
from pbicrl.inference.samplers import sample
from pbicrl.inference.synthetic import make_problem, make_wall_problem


def _groups(data):
    """Group names of an InferenceData (arviz < 1) or a DataTree (arviz >= 1)."""
    return set(data.children) if hasattr(data, "children") else set(data.groups())


def _full(data, var):
    """(chains, draws, d) draws of ``indicator`` / ``penalty`` over every feature: the posterior group's varying
    features, the constants of constant_data elsewhere."""
    const = data["constant_data"][f"{var}_constant"]
    C, D = data["posterior"].sizes["chain"], data["posterior"].sizes["draw"]
    out = np.broadcast_to(const.values, (C, D, const.size)).copy()
    if var in data["posterior"]:
        x = data["posterior"][var]
        dim = x.dims[2]
        names = list(const["feature"].values)
        idx = [names.index(n) for n in x[dim].values]
        out[:, :, idx] = x.values
    return out


def _stat(elpd, *names):
    """A field of az.loo's result under its arviz 0.x or 1.x name."""
    for n in names:
        try:
            return elpd[n]
        except (KeyError, TypeError, IndexError):
            if hasattr(elpd, n):
                return getattr(elpd, n)
    raise AttributeError(names)


def _sample_run(ds, *, margins=None, constraints=None, power=1.0, **kw):
    """What ``pbicrl.infer`` does for the pairwise likelihood, through the lower-level API: the export needs a
    pairwise run and the run's record (margins, data path), nothing of ``infer``'s other choices."""
    lik = PreferenceLikelihood.from_dataset(ds, margins=margins, power=power)
    cset = ConstraintSet(tuple(constraint_from_dict(c) for c in constraints), ds) if constraints else None
    kw = {"n_iterations": 4000, "weight_prior": pbicrl.WeightPrior("flat", -50, 50)} | kw
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", PbicrlWarning)  # short chains: R-hat / ESS warnings are expected
        post = sample(lik, n_chains=2, seed=1, n_jobs=1, progress=False, feature_names=ds.feature_names,
                      constraints=cset, **kw)
    post.extra.update({"data": {}, "margins": Margins.parse(margins, ds.n_groups).as_dict()})
    return post


@pytest.fixture(scope="module")
def ranked():
    """Groups ranked by a noisy return: no trajectory is certain, so PSIS-LOO is well defined."""
    prob = make_problem(12, noise=1.0, seed=5)
    return prob, _sample_run(prob.dataset, margins=[0.5, 1.0])


@pytest.fixture(scope="module")
def run_dir(ranked, tmp_path_factory):
    prob, post = ranked
    d = tmp_path_factory.mktemp("export")
    post.extra["data"]["path"] = str(prob.dataset.save(d / "data.npz"))
    return post.save(d / "run")


# --------------------------------------------------------------------------------------- pointwise_loglik
def _brute_force(lik, a):
    """Per trajectory: half of every pair term it takes part in, one pair at a time."""
    I, J, M = lik.preferences.to_pair_list()
    out = np.zeros(a.size)
    for i, j, m in zip(I, J, M):
        t = -np.logaddexp(0.0, a[j] + m - a[i])
        out[i] += 0.5 * t
        out[j] += 0.5 * t
    return lik.power * out


@pytest.mark.parametrize("protocol, power", [("all", 1.0), (7, 1.0), ("all", 0.3)])
def test_shares_sum_to_the_total_log_likelihood(protocol, power):
    prob = make_problem(20, seed=2)
    ds = prob.dataset
    lik = PreferenceLikelihood.from_dataset(ds, margins=[0.5, 2.0], protocol=protocol, power=power, seed=4)
    rng = np.random.default_rng(0)
    for scale in (0.1, 3.0, 300.0):  # overlapping returns up to returns 1e3 apart (exact-fallback regime)
        a = rng.normal(0.0, scale, ds.n_trajectories)
        pw = export.pointwise_loglik(lik, a)
        assert pw.shape == (ds.n_trajectories,) and np.all(pw <= 0)
        np.testing.assert_allclose(pw.sum(), lik.from_scaled_returns(a), rtol=1e-10, atol=1e-9)
        np.testing.assert_allclose(pw, _brute_force(lik, a), rtol=1e-10, atol=1e-12)


def test_explicit_pairs_with_repeats_and_unused_trajectories():
    pairs = np.array([[0, 1], [0, 1], [2, 0], [1, 2]])  # a repeated comparison counts twice; 3 is in none
    lik = PreferenceLikelihood(np.eye(4)[:, :2], Preferences.from_pairs(pairs, 4, margins=0.5), np.zeros(2))
    a = np.array([1.0, -0.5, 2.0, 7.0])
    pw = export.pointwise_loglik(lik, a)
    np.testing.assert_allclose(pw, _brute_force(lik, a), rtol=1e-12)
    assert pw[3] == 0.0
    np.testing.assert_allclose(pw.sum(), lik.from_scaled_returns(a), rtol=1e-12)


def _grouped_by_hand(lik, a):
    """The documented grouped split, one group term at a time, with log P_k from the grouped likelihood itself."""
    p = lik.preferences
    off, items, M = p.group_offsets, p.group_items, p.group_margins
    K = off.size - 1
    out = np.zeros(a.size)
    for k in range(K - 1):
        upper = items[off[k]:off[k + 1]]
        rest = [(j, l) for l in range(k + 1, K) for j in items[off[l]:off[l + 1]]]
        lam = np.array([np.exp(a[j] + M[k, l]) for j, l in rest])
        log_lam = np.log(lam.sum())
        # log P_k depends on x_i = a_i - log Lambda_k only: group k above one lower item with Lambda = e^0
        sub = Preferences.from_groups(np.r_[np.zeros(upper.size), 1.0], [0.0])
        x = np.r_[a[upper] - log_lam, 0.0]
        term = PreferenceLikelihood(np.zeros((x.size, 1)), sub, np.zeros(1), kind="grouped").from_scaled_returns(x)
        own = np.log1p(-1.0 / (1.0 + np.exp(a[upper] - log_lam)))  # log sigma(x_i)
        out[upper] += 0.5 * term * own / own.sum()
        for (j, _), w in zip(rest, lam / lam.sum()):
            out[j] += 0.5 * term * w
    return out


@pytest.mark.parametrize("margins", [None, [0.5, 2.0]])
def test_grouped_shares_sum_to_the_total_and_follow_the_documented_split(margins):
    prob = make_problem(9, seed=2)
    ds = prob.dataset
    lik = PreferenceLikelihood.from_dataset(ds, margins=margins, likelihood="grouped")
    rng = np.random.default_rng(3)
    for scale in (0.1, 3.0, 300.0):  # overlapping groups up to near-certain orderings
        a = rng.normal(0.0, scale, ds.n_trajectories) - scale * np.asarray(ds.group, dtype=float)
        pw = export.pointwise_loglik(lik, a)
        assert pw.shape == (ds.n_trajectories,) and np.all(pw <= 0)
        np.testing.assert_allclose(pw.sum(), lik.from_scaled_returns(a), rtol=1e-10, atol=1e-12)
        if scale < 100:  # the hand version's exp() overflows far apart
            np.testing.assert_allclose(pw, _grouped_by_hand(lik, a), rtol=1e-8, atol=1e-12)
    # the bottom group takes part too (az.loo gets no constant-zero columns from it)
    a = rng.normal(0.0, 1.0, ds.n_trajectories)
    assert np.all(export.pointwise_loglik(lik, a)[np.asarray(ds.group) == ds.group.max()] < 0)


def test_grouped_shares_of_singleton_groups_are_the_pairwise_split():
    prefs = Preferences.from_groups([1, 2], [0.7])
    a = np.array([0.3, 1.1])
    grouped = PreferenceLikelihood(np.ones((2, 1)), prefs, np.zeros(1), kind="grouped")
    pairwise = PreferenceLikelihood(np.ones((2, 1)), prefs, np.zeros(1))
    np.testing.assert_allclose(export.pointwise_loglik(grouped, a), export.pointwise_loglik(pairwise, a),
                               rtol=1e-13)
    np.testing.assert_allclose(export.pointwise_loglik(grouped, a), 0.5 * -np.logaddexp(0, 1.1 + 0.7 - 0.3))


def test_kinds_and_shapes_are_checked():
    prefs = Preferences.from_groups([1, 1, 2, 2])
    with pytest.raises(ValueError, match="unknown likelihood kind 'listwise'"):
        export.pointwise_loglik(SimpleNamespace(kind="listwise", preferences=prefs), np.zeros(4))
    lik = PreferenceLikelihood(np.ones((4, 1)), prefs, np.zeros(1))
    with pytest.raises(ValueError, match="expected 4 scaled returns"):
        export.pointwise_loglik(lik, np.zeros(3))


# --------------------------------------------------------------------------------------- to_arviz
def test_each_variable_once_and_a_pointwise_log_likelihood(run_dir, ranked):
    pytest.importorskip("arviz")
    prob, post = ranked
    run = read_run(run_dir)
    data = export.to_arviz(run, pointwise_draws=40)  # the dataset is found from the run's recorded path
    p = data["posterior"]
    assert set(p.data_vars) <= {"indicator", "penalty"}  # pbicrl stores w_p = 0 while off: no duplicate
    np.testing.assert_allclose(_full(data, "penalty"), run.effective_penalty)
    np.testing.assert_array_equal(_full(data, "indicator"), run.indicators)
    ll = data["log_likelihood"]["preferences"]
    N = prob.dataset.n_trajectories
    assert ll.dims == ("chain", "draw", "trajectory") and ll.shape == (run.n_chains, 40, N)
    draws = ll["draw"].values
    assert draws[0] == 0 and draws[-1] == run.n_draws - 1 and np.all(np.diff(draws) > 0)
    np.testing.assert_allclose(ll.sum("trajectory").values, run.log_likelihood[:, draws], rtol=1e-9, atol=1e-9)
    stats = data["sample_stats"]
    np.testing.assert_allclose(stats["total_log_likelihood"].values, run.log_likelihood)
    assert "log_likelihood" not in stats  # ArviZ's fallback name for the pointwise log-likelihood
    np.testing.assert_allclose(stats["lp"].values, run.log_likelihood + run.log_prior)
    np.testing.assert_array_equal(data["constant_data"]["group"].values, prob.dataset.group)
    full = export.to_arviz(run, pointwise_draws=None)
    assert full["log_likelihood"]["preferences"].shape[1] == run.n_draws
    with pytest.raises(ValueError, match="pointwise_draws"):  # an error, not a warning, even in "auto" mode
        export.to_arviz(run, pointwise_draws=0)


def test_az_loo_and_summary(run_dir, ranked):
    az = pytest.importorskip("arviz", reason="the ArviZ checks need arviz (pip install \"pbicrl[diag]\")")
    prob, _ = ranked
    data = export.to_arviz(read_run(run_dir), pointwise_draws=200)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # Pareto-k warnings of short chains are not the point here
        loo = az.loo(data, pointwise=True)
    # one observation per trajectory (the export used to give ArviZ "1.0 observations")
    assert int(_stat(loo, "n_data_points")) == prob.dataset.n_trajectories
    elpd, p_loo = float(_stat(loo, "elpd_loo", "elpd")), float(_stat(loo, "p_loo", "p"))
    assert np.isfinite(elpd) and elpd < 0
    assert 0 < p_loo < 10 * prob.dataset.n_features
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)  # no constant left for ArviZ to divide by zero on
        summ = az.summary(data)
    p = data["posterior"]
    want = {f"penalty[{n}]" for n in p["penalty"]["feature"].values}
    if "indicator" in p:
        want |= {f"indicator[{n}]" for n in p["indicator"]["indicator_feature"].values}
    assert want == set(summ.index) and summ["r_hat"].notna().all()
    assert {"mean", "sd"} <= set(summ.columns)


def test_paper_sampler_keeps_its_latent_weight():
    pytest.importorskip("arviz")
    prob = make_problem(10, seed=3)
    post = _sample_run(prob.dataset, method="paper", n_iterations=3000)
    data = export.to_arviz(post, dataset=prob.dataset, pointwise_draws=20)
    p = data["posterior"]
    assert {"indicator", "penalty", "penalty_weight"} == set(p.data_vars)
    np.testing.assert_allclose(p["penalty_weight"].values, post.penalty_weights)
    ll = data["log_likelihood"]["preferences"]
    np.testing.assert_allclose(ll.sum("trajectory").values, post.log_likelihood[:, ll["draw"].values], rtol=1e-9)


def test_parametric_constraints_follow_each_draws_location():
    pytest.importorskip("arviz")
    prob = make_wall_problem(8, seed=0)
    post = _sample_run(prob.dataset, n_iterations=3000,
                  constraints=[{"family": "axis_halfspace", "dims": [0], "name": "wall"}])
    data = export.to_arviz(post, dataset=prob.dataset, pointwise_draws=30)
    assert list(data["posterior"]["parameter"].coords["param"].values) == ["wall.threshold"]
    ll = data["log_likelihood"]["preferences"]
    np.testing.assert_allclose(ll.sum("trajectory").values, post.log_likelihood[:, ll["draw"].values],
                               rtol=1e-9, atol=1e-9)


def test_without_the_likelihood_there_is_no_log_likelihood_group(ranked):
    pytest.importorskip("arviz")
    prob, post = ranked
    bare = SimpleNamespace(**{k: getattr(post, k) for k in (
        "indicators", "penalty_weights", "log_likelihood", "log_prior", "feature_names", "map_indicators",
        "map_penalty_weights", "sampler", "settings", "seed")}, extra={})
    with pytest.warns(PbicrlWarning, match="pass the run's dataset"):
        data = export.to_arviz(bare, pointwise="auto")
    assert "log_likelihood" not in _groups(data) and "total_log_likelihood" in data["sample_stats"]
    with warnings.catch_warnings():
        warnings.simplefilter("error", PbicrlWarning)
        assert "log_likelihood" not in _groups(export.to_arviz(bare, pointwise=False))
    for how in ({}, {"pointwise": True}):  # the default is an error, never an export az.loo would misread
        with pytest.raises(ValueError, match=r"the run records no dataset file; pass the run's dataset \(dataset="):
            export.to_arviz(bare, **how)


def test_settings_that_do_not_reproduce_the_run_are_refused(ranked):
    pytest.importorskip("arviz")
    prob, post = ranked
    wrong = SimpleNamespace(**{k: getattr(post, k) for k in (
        "indicators", "penalty_weights", "log_likelihood", "log_prior", "feature_names", "map_indicators",
        "map_penalty_weights", "sampler", "seed", "extra")}, settings=post.settings | {"beta": 2.0})
    with pytest.raises(ValueError, match="the run recorded"):
        export.run_likelihood(wrong, prob.dataset)
    with pytest.raises(ValueError, match="the run recorded"):
        export.to_arviz(wrong, dataset=prob.dataset)
    with pytest.warns(PbicrlWarning, match="the run recorded"):
        data = export.to_arviz(wrong, dataset=prob.dataset, pointwise="auto")
    assert "log_likelihood" not in _groups(data)
    lik = PreferenceLikelihood.from_dataset(prob.dataset, margins=[0.5, 1.0])  # the right one, given explicitly
    data = export.to_arviz(wrong, likelihood=lik, pointwise_draws=10)
    ll = data["log_likelihood"]["preferences"]
    np.testing.assert_allclose(ll.sum("trajectory").values, post.log_likelihood[:, ll["draw"].values], rtol=1e-9)


def test_a_tempered_run_needs_its_power_recorded():
    pytest.importorskip("arviz")
    prob = make_problem(8, noise=1.0, seed=4)
    post = _sample_run(prob.dataset, power=0.25, n_iterations=2000)
    if "power" not in post.settings:  # a run that does not record its power cannot be rebuilt: refused
        with pytest.raises(ValueError, match="the run recorded"):
            export.run_likelihood(post, prob.dataset)
        post.extra["power"] = 0.25
    data = export.to_arviz(post, dataset=prob.dataset, pointwise_draws=10, pointwise=True)
    ll = data["log_likelihood"]["preferences"]
    assert ll.attrs["power"] == 0.25
    np.testing.assert_allclose(ll.sum("trajectory").values, post.log_likelihood[:, ll["draw"].values], rtol=1e-9)


def test_a_grouped_run_exports_per_trajectory_shares_for_loo(tmp_path):
    az = pytest.importorskip("arviz")
    prob = make_problem(12, noise=1.0, seed=5)
    data_path = prob.dataset.save(tmp_path / "data.npz")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", PbicrlWarning)
        post = pbicrl.infer(prob.dataset, margins=[0.5, 1.0], iterations=3000, chains=2, jobs=1, seed=2,
                            progress=False, weight_prior=pbicrl.WeightPrior("flat", -50, 50))
    assert post.settings["likelihood"] == "grouped"
    post.extra["data"]["path"] = str(data_path)
    run = read_run(post.save(tmp_path / "run"))
    lik, _ = export.run_likelihood(run, prob.dataset)  # rebuilt and checked against the recorded totals
    assert lik.kind == "grouped"
    data = export.to_arviz(run, pointwise_draws=100, pointwise=True)
    ll = data["log_likelihood"]["preferences"]
    assert ll.attrs["likelihood_kind"] == "grouped" and ll.shape == (2, 100, prob.dataset.n_trajectories)
    np.testing.assert_allclose(ll.sum("trajectory").values, run.log_likelihood[:, ll["draw"].values],
                               rtol=1e-9, atol=1e-9)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # Pareto-k warnings of short chains are not the point here
        loo = az.loo(data)
    assert int(_stat(loo, "n_data_points")) == prob.dataset.n_trajectories
    assert np.isfinite(float(_stat(loo, "elpd_loo", "elpd")))
    summ = az.summary(data)
    assert {f"penalty[{n}]" for n in data["posterior"]["penalty"]["feature"].values} <= set(summ.index)
    assert not any(i.startswith("penalty_weight") for i in summ.index)  # no duplicate rows


def test_per_draw_move_and_acceptance_go_to_sample_stats(ranked):
    pytest.importorskip("arviz")
    _, post = ranked
    C, D = post.log_likelihood.shape
    real = export.to_arviz(post, pointwise=False)["sample_stats"]  # recorded by the sampler
    np.testing.assert_array_equal(real["move"].values, post.move)
    np.testing.assert_array_equal(real["accepted"].values, post.accepted)
    assert set(np.unique(post.move)) <= {0, 1, 2} and 0 < post.accepted.mean() < 1
    rng = np.random.default_rng(1)
    fake = SimpleNamespace(**{k: getattr(post, k) for k in (
        "indicators", "penalty_weights", "log_likelihood", "log_prior", "feature_names", "map_indicators",
        "map_penalty_weights", "sampler", "settings", "seed")}, extra={},
        move=rng.integers(1, 3, (C, D)), accepted=rng.random((C, D)) < 0.3,
        acceptance_fraction=rng.random((C, D)))
    stats = export.to_arviz(fake, pointwise=False)["sample_stats"]
    np.testing.assert_array_equal(stats["move"].values, fake.move)
    assert stats["accepted"].dtype == bool and stats["move"].attrs["flag_meanings"] == "none flip weight parameter"
    np.testing.assert_allclose(stats["acceptance_rate"].values, fake.acceptance_fraction)
    # chains that do not record them: only the per-draw totals
    bare = SimpleNamespace(**{k: getattr(post, k) for k in (
        "indicators", "penalty_weights", "log_likelihood", "log_prior", "feature_names", "map_indicators",
        "map_penalty_weights", "sampler", "settings", "seed")}, extra={})
    plain = export.to_arviz(bare, pointwise=False)["sample_stats"]
    assert set(plain.data_vars) == {"total_log_likelihood", "lp", "log_prior"}


@pytest.mark.parametrize("constraints", [None, [{"family": "axis_halfspace", "dims": [0], "name": "wall"}]])
@pytest.mark.parametrize("method", ["pbicrl", "paper", "bpl"])
def test_per_draw_moves_and_acceptances_match_the_samplers_counters(method, constraints):
    """With every iteration kept, the per-draw records must add up to the compiled loop's own counters."""
    prob = make_wall_problem(8, seed=0) if constraints else make_problem(8, seed=1)
    post = _sample_run(prob.dataset, method=method, n_iterations=1500, burn_in=0, thin=1, constraints=constraints)
    tot = post.counts.sum(axis=0)
    mv, acc = post.move, post.accepted
    got = [(mv == 1).sum(), (acc & (mv == 1)).sum(), (mv == 2).sum(), (acc & (mv == 2)).sum(), (mv == 3).sum(),
           (acc & (mv == 3)).sum()]
    assert got == [tot[0], tot[1], tot[2], tot[3], tot[5], tot[6]]
    assert not acc[mv == 0].any()
    np.testing.assert_array_equal(post.acceptance_fraction, acc.astype(float))  # thin 1: one iteration each


@pytest.mark.parametrize("replay", [False, True])
def test_thinned_per_draw_records_are_the_iterations_they_stand_for(monkeypatch, replay):
    """A thinned chain with warm-up ending inside a chunk records what the unthinned chain did at its kept
    iterations; both ways of finding the state before the first kept draw (storing it, or replaying the warm-up
    when the last warm-up iteration adapts) agree. The paper sampler does not adapt, so warm-up changes nothing."""
    from pbicrl.inference.samplers import driver

    monkeypatch.setattr(driver, "_CHUNK", 400)  # several chunk boundaries in a short chain
    if replay:
        monkeypatch.setattr(driver, "_last_warmup_adapts", lambda settings: True)
    ds = make_problem(8, seed=1).dataset
    full = _sample_run(ds, method="paper", n_iterations=3000, burn_in=0, thin=1)
    for burn_in, thin in [(1234, 7), (1, 500), (799, 1)]:
        part = _sample_run(ds, method="paper", n_iterations=3000, burn_in=burn_in, thin=thin)
        its = np.arange(burn_in, 3000, thin)
        np.testing.assert_array_equal(part.penalty_weights, full.penalty_weights[:, its])
        np.testing.assert_array_equal(part.move, full.move[:, its])
        np.testing.assert_array_equal(part.accepted, full.accepted[:, its])
        acc = full.accepted.astype(float)
        frac = np.stack([[acc[c, its[0]]] + [acc[c, its[k - 1] + 1:its[k] + 1].mean() for k in range(1, its.size)]
                         for c in range(acc.shape[0])])
        np.testing.assert_allclose(part.acceptance_fraction, frac)


def test_netcdf_round_trip_keeps_the_thinned_draws(run_dir, tmp_path):
    az = pytest.importorskip("arviz")
    pytest.importorskip("h5netcdf")
    out = export.to_netcdf(read_run(run_dir), tmp_path / "post.nc", pointwise_draws=25)
    back = az.from_netcdf(out)
    assert back["log_likelihood"]["preferences"].shape[1] == 25
    assert back["posterior"]["penalty"].shape[1] == read_run(run_dir).n_draws
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert np.isfinite(float(_stat(az.loo(back), "elpd_loo", "elpd")))


def test_arviz_1_layout_is_a_datatree(run_dir, monkeypatch, tmp_path):
    pytest.importorskip("arviz")
    xr = pytest.importorskip("xarray")
    if not hasattr(xr, "DataTree"):
        pytest.skip("xarray without DataTree (arviz >= 1 needs it)")
    monkeypatch.setattr(export, "arviz_major", lambda az: 1)
    tree = export.to_arviz(read_run(run_dir), pointwise_draws=10)
    assert isinstance(tree, xr.DataTree)
    assert {"posterior", "log_likelihood", "sample_stats", "constant_data"} <= set(tree.children)
    assert tree.attrs["inference_library"] == "pbicrl"
    assert tree["log_likelihood"]["preferences"].dims == ("chain", "draw", "trajectory")
    pytest.importorskip("h5netcdf")
    path = export.to_netcdf(read_run(run_dir), tmp_path / "tree.nc", pointwise_draws=10)
    back = xr.open_datatree(path, engine="h5netcdf")
    assert back["log_likelihood"]["preferences"].shape[1] == 10


def test_constant_indicators_are_not_applicable_for_rhat_not_nan(ranked):
    """issue 30 item 11: ``az.summary`` gave NaN R-hat and a RuntimeWarning for an indicator on in every draw (and a
    feature that is not a candidate); the export keeps such constants in constant_data, as summary.json gives null."""
    az = pytest.importorskip("arviz")
    _, post = ranked
    C, D, d = post.indicators.shape
    rng = np.random.default_rng(0)
    c = (rng.random((C, D, 3)) < 0.5).astype(np.int8)
    c[:, :, 0] = 1  # always on: its penalty varies
    c[:, :, 1] = 0  # not a candidate: indicator and penalty constant
    wp = -np.abs(rng.normal(size=(C, D, 3))) * c
    fake = SimpleNamespace(indicators=c, penalty_weights=wp, log_likelihood=post.log_likelihood,
                           log_prior=post.log_prior, feature_names=("on", "off", "mixed"),
                           map_indicators=np.array([1, 0, 1], np.int8), map_penalty_weights=np.array([-1.0, 0, -2]),
                           sampler="pbicrl", settings={}, seed=0, extra={})
    data = export.to_arviz(fake, pointwise=False)
    p = data["posterior"]
    assert list(p["indicator"].coords["indicator_feature"].values) == ["mixed"]
    assert list(p["penalty"].coords["feature"].values) == ["on", "mixed"]
    const = data["constant_data"]
    np.testing.assert_array_equal(const["indicator_constant"].values, [1.0, 0.0, np.nan])
    np.testing.assert_array_equal(const["penalty_constant"].values, [np.nan, 0.0, np.nan])
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        summ = az.summary(data)
    assert set(summ.index) == {"indicator[mixed]", "penalty[on]", "penalty[mixed]"}
    assert summ["r_hat"].notna().all()
