"""Convergence diagnostics, run directories and ArviZ / NetCDF export."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest

import pbicrl
from pbicrl.analysis import diagnostics
from pbicrl.cli import main
from pbicrl.io.runs import RunError, read_run
from pbicrl.inference.synthetic import make_problem


def fake_posterior(penalty, indicators=None, *, log_likelihood=None, parameters=None, parameter_names=()):
    """A Posterior-like object with given draws (chains, draws, d)."""
    penalty = np.asarray(penalty, dtype=float)
    C, D, d = penalty.shape
    ind = np.ones((C, D, d), np.int8) if indicators is None else np.asarray(indicators, np.int8)
    ll = np.random.default_rng(99).normal(size=(C, D)) if log_likelihood is None else log_likelihood
    return SimpleNamespace(indicators=ind, penalty_weights=penalty, log_likelihood=ll, log_prior=np.zeros((C, D)),
                           feature_names=tuple(f"x{j}" for j in range(d)), parameters=parameters,
                           parameter_names=parameter_names, map_indicators=np.ones(d, np.int8),
                           map_penalty_weights=np.zeros(d), sampler="pbicrl", settings={}, seed=0)


@pytest.fixture(scope="module")
def small_post():
    prob = make_problem(15, labels="violations", violation_rate=0.4, seed=3)
    post = pbicrl.infer(prob.dataset, iterations=6000, chains=4, seed=2, jobs=1, progress=False,
                        margins=[0.5, 1.0], weight_prior=pbicrl.WeightPrior("flat", -50, 50))
    return post, prob


@pytest.fixture(scope="module")
def run_dir(small_post, tmp_path_factory):
    post, prob = small_post
    d = tmp_path_factory.mktemp("run")
    data = d / "data.npz"
    prob.dataset.save(data)
    post.extra["data"]["path"] = str(data)
    return post.save(d / "run")


def test_default_backend_needs_no_arviz_and_explicit_arviz_names_the_extra(monkeypatch):
    def missing():
        raise ImportError("no arviz: pip install \"pbicrl[diag]\"")

    monkeypatch.setattr(diagnostics, "require_arviz", missing)
    rng = np.random.default_rng(0)
    d = diagnostics.compute(fake_posterior(rng.normal(size=(4, 500, 2))), cache=False)
    assert d.backend == "pbicrl" and d.message is None
    assert all(v["ess_bulk"] > 1000 and v["ess_tail"] > 500 and v["rhat"] < 1.01 for v in d.values["penalty"].values())
    with pytest.raises(ImportError, match="pbicrl"):
        diagnostics.compute(fake_posterior(rng.normal(size=(4, 500, 2))), backend="arviz", cache=False)
    d = diagnostics.compute(fake_posterior(rng.normal(size=(4, 500, 2))), backend="numpy", cache=False)
    assert d.backend == "numpy" and all(v["ess_bulk"] is None for v in d.values["penalty"].values())
    assert "classic split R-hat" in d.footer()


def test_default_backend_equals_arviz():
    pytest.importorskip("arviz")
    rng = np.random.default_rng(5)
    x = rng.normal(size=(4, 700, 2)).cumsum(axis=1) * 0.05 + rng.normal(size=(4, 700, 2))
    ind = (rng.random((4, 700, 2)) < 0.7).astype(np.int8)
    ours = diagnostics.compute(fake_posterior(x, ind), cache=False)
    theirs = diagnostics.compute(fake_posterior(x, ind), backend="arviz", cache=False)
    assert theirs.backend.startswith("arviz")
    for kind in ("penalty", "indicator", "log_likelihood"):
        for name, v in theirs.values[kind].items():
            for stat, ref in v.items():
                if kind == "indicator" and stat == "ess_tail":
                    # a 0/1 draw's 95% quantile is 1, so 1[x >= q95] is constant: ArviZ counts that tail as n draws,
                    # pbicrl leaves it out (only the other tail measures anything)
                    assert ours.values[kind][name][stat] >= 0.9 * ref
                    continue
                assert ours.values[kind][name][stat] == pytest.approx(ref, rel=1e-8), (kind, name, stat)


def test_well_mixed_chains_pass_and_disagreeing_chains_warn():
    pytest.importorskip("arviz")
    rng = np.random.default_rng(1)
    x = rng.normal(size=(4, 1000, 2))
    x[1, :, 1] += 3.0  # chain 1 sits elsewhere for feature x1
    d = diagnostics.compute(fake_posterior(x), cache=False)
    assert d.backend == "pbicrl"
    good, bad = d.values["penalty"]["x0"], d.values["penalty"]["x1"]
    assert good["rhat"] < 1.01 and good["ess_bulk"] > 2000 and good["ess_tail"] > 1000
    assert bad["rhat"] > 1.2
    msgs = d.warnings()
    assert any("R-hat > 1.01" in m and "x1" in m and "x0 (" not in m for m in msgs)
    assert d.worst()["rhat"] == pytest.approx(bad["rhat"])


def test_low_ess_warns():
    pytest.importorskip("arviz")
    rng = np.random.default_rng(2)
    # AR(1) with rho = 0.99: ESS of ~4 x 1000 draws is a few dozen
    x = np.zeros((4, 1000, 1))
    for t in range(1, 1000):
        x[:, t, 0] = 0.99 * x[:, t - 1, 0] + rng.normal(size=4) * np.sqrt(1 - 0.99 ** 2)
    d = diagnostics.compute(fake_posterior(x), cache=False)
    assert d.values["penalty"]["x0"]["ess_bulk"] < 400
    assert any("bulk ESS < 400" in m and "x0" in m for m in d.warnings())


@pytest.mark.parametrize("backend", ["auto", "numpy"])
def test_constant_quantities_are_undefined_and_stuck_chains_are_infinite(backend):
    C, D = 4, 200
    x = np.random.default_rng(3).normal(size=(C, D, 2))
    ind = np.ones((C, D, 2), np.int8)
    ind[0, :, 1] = 0  # chain 0 never switches x1 on, the others never switch it off
    d = diagnostics.compute(fake_posterior(x, ind), backend=backend, cache=False)
    assert d.values["indicator"]["x0"] == {"rhat": None, "ess_bulk": None, "ess_tail": None}
    assert d.values["indicator"]["x1"]["rhat"] == float("inf")
    assert any("indicator c of x1 (inf)" in m for m in d.warnings())
    assert not any("of x0" in m for m in d.warnings())


def test_parameters_use_active_draws_only():
    pytest.importorskip("arviz")
    rng = np.random.default_rng(4)
    th = rng.normal(5.0, 1.0, size=(4, 600, 1))
    th[:, ::3, 0] = np.nan  # inactive every third draw
    d = diagnostics.compute(fake_posterior(rng.normal(size=(4, 600, 1)), parameters=th,
                                           parameter_names=("wall.threshold",)), cache=False)
    v = d.values["parameter"]["wall.threshold"]
    assert v["rhat"] is not None and v["rhat"] < 1.02 and v["ess_bulk"] > 1000


def test_single_chain_warns():
    d = diagnostics.compute(fake_posterior(np.random.default_rng(5).normal(size=(1, 300, 1))), cache=False)
    assert d.values["penalty"]["x0"]["rhat"] is None
    assert any("only 1 chain" in m for m in d.warnings())


def test_posterior_summary_table_and_warnings(small_post):
    post, _ = small_post
    s = post.summary()
    diag = s["posterior"]["diagnostics"]
    assert diag["chains"] == 4
    assert set(diag["penalty"]) == set(post.feature_names) == set(diag["indicator"])
    assert set(diag["penalty"]["constraint1"]) == {"rhat", "ess_bulk", "ess_tail"}
    json.dumps(s)  # serialisable (no NaN objects)
    table = post.table()
    assert "R-hat" in table and "ESS" in table
    assert "smaller of bulk and tail" in table or "no ESS" in table  # the table's ESS column, explained
    # 6000 iterations x 4 chains is short: the flags, when raised, must agree with the numbers in the summary
    d = post.diagnostics()
    flagged = any(v["rhat"] is not None and v["rhat"] > 1.01 for kv in d.values.values() for v in kv.values())
    assert flagged == any("R-hat > 1.01" in m for m in post.warnings())


def test_short_run_is_flagged():
    pytest.importorskip("arviz")
    prob = make_problem(10, labels="violations", violation_rate=0.4, seed=4)
    post = pbicrl.infer(prob.dataset, iterations=400, chains=4, seed=0, jobs=1, progress=False)
    assert any("bulk ESS < 400" in m for m in post.warnings())
    assert "warning: bulk ESS < 400" in post.table()


def test_load_run_round_trip(small_post, run_dir):
    post, _ = small_post
    run = read_run(run_dir)
    np.testing.assert_array_equal(run.indicators, post.indicators)
    np.testing.assert_allclose(run.penalty_weights, post.penalty_weights)
    np.testing.assert_allclose(run.log_likelihood, post.log_likelihood)
    assert run.feature_names == post.feature_names
    np.testing.assert_allclose(run.map_effective_penalty, post.map_effective_penalty)
    assert run.data_path is not None and run.data_path.is_file()
    a = diagnostics.compute(run).to_dict()
    b = post.diagnostics().to_dict()
    assert a["penalty"] == b["penalty"] and a["indicator"] == b["indicator"]


def test_load_run_errors(tmp_path, run_dir):
    with pytest.raises(FileNotFoundError, match="no such directory"):
        read_run(tmp_path / "nope")
    (tmp_path / "r").mkdir()
    (tmp_path / "r" / "summary.json").write_text("{}")
    with pytest.raises(FileNotFoundError, match="chains.npz"):
        read_run(tmp_path / "r")
    (tmp_path / "r" / "chains.npz").write_bytes(b"not a zip")
    with pytest.raises(RunError, match="not a readable"):
        read_run(tmp_path / "r")
    (tmp_path / "r" / "summary.json").write_text("{")
    with pytest.raises(RunError, match="not valid JSON"):
        read_run(tmp_path / "r")


def test_to_arviz_variables_named_after_features(small_post):
    pytest.importorskip("arviz")
    post, _ = small_post
    data = post.to_arviz()
    p = data["posterior"]
    names = list(post.feature_names)
    varying = [n for j, n in enumerate(names) if np.ptp(post.effective_penalty[:, :, j]) > 0]
    assert list(p["penalty"].coords["feature"].values) == varying  # the constant ones are in constant_data
    assert p["penalty"].shape == (post.n_chains, post.n_draws, len(varying))
    assert list(data["constant_data"]["feature"].values) == names
    assert "penalty_weight" not in p  # identical to penalty for the pbicrl sampler
    np.testing.assert_allclose(p["penalty"].sel(feature="constraint2").values, post.effective_penalty[:, :, 2])
    np.testing.assert_allclose(data["sample_stats"]["total_log_likelihood"].values, post.log_likelihood)
    np.testing.assert_allclose(data["sample_stats"]["lp"].values, post.log_likelihood + post.log_prior)
    assert "parameter" not in p


def test_to_arviz_includes_parameters():
    pytest.importorskip("arviz")
    from pbicrl.analysis.export import to_arviz

    rng = np.random.default_rng(6)
    th = rng.normal(size=(2, 50, 2))
    data = to_arviz(fake_posterior(rng.normal(size=(2, 50, 3)), parameters=th, parameter_names=("box.lower0", "box.upper0")),
                     pointwise=False)  # a fake posterior: no dataset
    assert list(data["posterior"]["parameter"].coords["param"].values) == ["box.lower0", "box.upper0"]
    np.testing.assert_allclose(data["posterior"]["parameter"].values, th)


def test_netcdf_round_trip_and_cli(run_dir, tmp_path, capsys):
    az = pytest.importorskip("arviz")
    pytest.importorskip("h5netcdf")
    out = tmp_path / "post.nc"
    assert main(["export", str(run_dir), "--netcdf", str(out)]) == 0
    back = az.from_netcdf(out)
    run = read_run(run_dir)
    names = list(run.feature_names)
    pen = back["posterior"]["penalty"]
    np.testing.assert_allclose(pen.values, run.effective_penalty[:, :, [names.index(n) for n in pen["feature"].values]])
    assert list(back["constant_data"]["feature"].values) == names
    assert main(["export", str(run_dir), "--netcdf", str(out)]) == 2
    assert "already exists" in capsys.readouterr().err
    assert not list(tmp_path.glob(".post.nc*"))
    assert main(["diagnose", str(run_dir)]) == 0
    text = capsys.readouterr().out
    assert "penalty[constraint1]" in text and "ESS bulk" in text
    assert main(["diagnose", str(run_dir), "--json"]) == 0
    assert "penalty" in json.loads(capsys.readouterr().out)


def test_summary_json_is_strict_json_with_stuck_chains():
    ind = np.ones((4, 100, 1), np.int8)
    ind[0] = 0
    d = diagnostics.compute(fake_posterior(np.random.default_rng(7).normal(size=(4, 100, 1)), ind), cache=False)
    assert d.values["indicator"]["x0"]["rhat"] == float("inf")
    out = json.dumps(d.to_dict(), allow_nan=False)  # raises on inf / NaN
    assert json.loads(out)["indicator"]["x0"]["rhat"] is None


def test_not_identifiable_features_are_not_diagnosed():
    rng = np.random.default_rng(8)
    x = rng.normal(size=(4, 200, 2))
    x[:, :, 1] += np.arange(4)[:, None] * 10.0  # chains disagree on x1
    post = fake_posterior(x)
    post.not_identifiable = lambda: {"x1": "constant across trajectories"}
    for backend in ("auto", "numpy"):
        d = diagnostics.compute(post, backend=backend, cache=False)
        assert d.values["penalty"]["x1"] == {"rhat": None, "ess_bulk": None, "ess_tail": None}
        assert d.values["indicator"]["x1"]["rhat"] is None
        assert d.values["penalty"]["x0"]["rhat"] is not None
        assert d.excluded == {"x1": "constant across trajectories"}
        assert d.to_dict()["not_identifiable"] == {"x1": "constant across trajectories"}
        assert not any("x1" in m for m in d.warnings())
        assert "not diagnosed (not identifiable): x1" in d.table()
    post.not_identifiable = {}  # a plain mapping works too, and nothing is left out
    assert diagnostics.compute(post, cache=False).values["penalty"]["x1"]["rhat"] > 1.1


def test_compact_cells_show_the_smaller_ess():
    pytest.importorskip("arviz")
    d = diagnostics.compute(fake_posterior(np.random.default_rng(9).normal(size=(4, 300, 1))), cache=False)
    v = d.worst_of(("penalty", "indicator"), "x0")  # the indicator is constant (all on): penalty only
    cell = d.cells("feature", "x0", compact=True)
    assert len(cell) == 14
    assert cell.split() == [f"{v['rhat']:.3f}", f"{min(v['ess_bulk'], v['ess_tail']):.0f}"]
    assert "smaller of bulk and tail" in d.footer(compact=True)
