"""The Python API a new user meets first: a saved run loads back into the same :class:`~pbicrl.Posterior`,
objects print short readable reprs, tables come as DataFrames and HTML, errors speak Python (not CLI flags)."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pytest

import pbicrl
from pbicrl.errors import PbicrlWarning
from pbicrl.inference.posterior import Posterior
from pbicrl.io.runs import OutputExistsError
from pbicrl.inference.synthetic import make_problem, make_wall_problem


def _infer(ds, **kw):
    kw = {"iterations": 2000, "chains": 2, "jobs": 1, "seed": 3, "progress": False} | kw
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", PbicrlWarning)  # short chains warn about R-hat / ESS by design
        return pbicrl.infer(ds, **kw)


@pytest.fixture(scope="module")
def fresh():
    prob = make_problem(15, labels="violations", violation_rate=0.4, seed=3)
    return prob.dataset, _infer(prob.dataset, margins=[0.5, 1.0])


# ---------------------------------------------------------------------------------------------- load
def _same_posterior(a: Posterior, b: Posterior) -> None:
    for key in ("indicators", "penalty_weights", "log_likelihood", "log_prior", "parameters", "map_indicators",
                "map_penalty_weights", "move", "accepted", "acceptance_fraction", "counts"):
        np.testing.assert_array_equal(getattr(a, key), getattr(b, key), err_msg=key)
    assert a.feature_names == b.feature_names and a.parameter_names == b.parameter_names
    assert a.table() == b.table()
    assert json.dumps(a.summary(), sort_keys=True) == json.dumps(b.summary(), sort_keys=True)
    assert a.warnings() == b.warnings()
    for est in ("selected", "map", "mean"):
        for x, y in zip(a.point_estimate(est), b.point_estimate(est)):
            np.testing.assert_array_equal(x, y)


def test_a_saved_run_loads_back_into_the_same_posterior(fresh, tmp_path):
    _, post = fresh
    run = post.save(tmp_path / "run")
    back = pbicrl.load_run(run)
    assert type(back) is Posterior and back.path == run
    _same_posterior(post, back)
    assert back.move is not None and back.move.shape == back.log_likelihood.shape
    # and again: saving the loaded posterior writes the same files' content
    again = Posterior.load(back.save(tmp_path / "again"), issue_warnings=False)
    _same_posterior(post, again)


def test_a_loaded_run_issues_the_warnings_of_a_fresh_one(fresh, tmp_path):
    _, post = fresh
    run = post.save(tmp_path / "run")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", PbicrlWarning)
        back = pbicrl.load_run(run)
    assert [str(w.message) for w in caught if w.category is PbicrlWarning] == post.warnings()
    assert all(w.filename == __file__ for w in caught if w.category is PbicrlWarning)  # attributed to the caller
    with warnings.catch_warnings():
        warnings.simplefilter("error", PbicrlWarning)
        pbicrl.load_run(run, issue_warnings=False)
    assert back.warnings() == post.warnings()


def test_a_loaded_run_exports_to_arviz(fresh, tmp_path):
    pytest.importorskip("arviz")
    ds, post = fresh
    data = pbicrl.load_run(post.save(tmp_path / "run"), issue_warnings=False).to_arviz(dataset=ds,
                                                                                        pointwise_draws=20)
    stats = data["sample_stats"]
    np.testing.assert_array_equal(stats["move"].values, post.move)
    ll = data["log_likelihood"]["preferences"]
    np.testing.assert_allclose(ll.sum("trajectory").values, post.log_likelihood[:, ll["draw"].values], rtol=1e-9)


def test_parametric_runs_round_trip(tmp_path):
    prob = make_wall_problem(6, seed=0)
    post = _infer(prob.dataset, iterations=1500,
                  constraints=[{"family": "axis_halfspace", "dims": [0], "name": "wall"}])
    back = pbicrl.load_run(post.save(tmp_path / "run"), issue_warnings=False)
    _same_posterior(post, back)
    np.testing.assert_array_equal(back.map_parameters, post.map_parameters)
    assert back.parameter_owner == post.parameter_owner


def test_runs_saved_without_counts_or_per_draw_records_still_load(fresh, tmp_path):
    """Runs written before chains.npz held counts and per-draw records: rates come from summary.json."""
    _, post = fresh
    run = post.save(tmp_path / "run")
    with np.load(run / "chains.npz") as z:
        arrays = {k: z[k] for k in z.files if k not in ("counts", "move", "accepted", "acceptance_fraction")}
    np.savez_compressed(run / "chains.npz", **arrays)
    back = pbicrl.load_run(run, issue_warnings=False)
    assert back.move is None and back.accepted is None
    assert back.acceptance_rate() == pytest.approx(post.acceptance_rate())
    assert back.summary()["likelihood_evaluations"] == post.summary()["likelihood_evaluations"]
    assert back.table() == post.table()


def test_missing_and_malformed_runs_are_named(tmp_path):
    from pbicrl.io.runs import RunError

    with pytest.raises(FileNotFoundError, match="no such directory"):
        pbicrl.load_run(tmp_path / "nope")
    (tmp_path / "r").mkdir()
    (tmp_path / "r" / "summary.json").write_text("[]")
    (tmp_path / "r" / "chains.npz").write_bytes(b"")
    with pytest.raises(RunError, match="chains.npz|summary.json"):
        pbicrl.load_run(tmp_path / "r")


# ---------------------------------------------------------------------------------------------- wording
def test_saving_twice_says_overwrite_true_and_the_cli_says_its_flag(fresh, tmp_path, capsys):
    ds, post = fresh
    run = post.save(tmp_path / "run")
    with pytest.raises(OutputExistsError) as exc:
        post.save(run)
    msg = str(exc.value)
    assert "overwrite=True" in msg and "--overwrite" not in msg and isinstance(exc.value, FileExistsError)
    assert post.save(run, overwrite=True) == run
    from pbicrl.cli import main

    data = ds.save(tmp_path / "d.npz")
    assert main(["infer", str(data), "--out", str(run), "--iterations", "50", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "pass --overwrite" in err and "overwrite=True" not in err


def test_netcdf_export_onto_an_existing_file_speaks_python(fresh, tmp_path):
    pytest.importorskip("arviz")
    pytest.importorskip("h5netcdf")
    _, post = fresh
    target = tmp_path / "p.nc"
    target.write_text("x")
    from pbicrl.analysis.export import to_netcdf

    with pytest.raises(OutputExistsError, match="overwrite=True") as exc:
        to_netcdf(post, target, pointwise=False)
    assert "--" not in str(exc.value)
    assert target.read_text() == "x"


# ---------------------------------------------------------------------------------------------- display
def test_reprs_are_short_and_never_dump_arrays(fresh, tmp_path):
    ds, post = fresh
    from pbicrl.inference.preferences import Preferences
    from pbicrl.inference.samplers import build_kernel

    big = pbicrl.load_dataset("point_mass")
    prefs = Preferences.from_groups(big.group)
    state = build_kernel(pbicrl.PreferenceLikelihood.from_dataset(big)).init(0)
    loaded = pbicrl.load_run(post.save(tmp_path / "run"), issue_warnings=False)
    for obj in (post, loaded, prefs, state, big, loaded.attach()):
        r = repr(obj)
        assert len(r) < 400 and "array(" not in r and "\n" not in r, r
    n = {k: int((big.group == k).sum()) for k in (1, 2, 3)}
    pairs = n[1] * n[2] + n[1] * n[3] + n[2] * n[3]  # every cross-group pair, thousands separated
    assert repr(prefs) == f"Preferences(N={big.n_trajectories}, groups=3, pairs={pairs:,}, blocks=3, protocol='all')"
    assert f"chains={post.n_chains}" in repr(post) and f"draws={post.n_draws}" in repr(post)
    assert "path=" in repr(loaded) and "path=" not in repr(post)
    assert repr(state).startswith("ChainState(iteration=0, d=4,") and f"N={big.n_trajectories}" in repr(state)
    from pbicrl.io.runs import read_run as load_record

    assert len(repr(load_record(tmp_path / "run"))) < 300


def test_to_dataframe_holds_the_tables_numbers(fresh):
    pd = pytest.importorskip("pandas")
    _, post = fresh
    df = post.to_dataframe()
    assert isinstance(df, pd.DataFrame) and list(df.index) == list(post.feature_names)
    np.testing.assert_allclose(df["p_constraint"].to_numpy(), post.p_constraint)
    np.testing.assert_allclose(df["median"].to_numpy(), post.conditional_median(), equal_nan=True)
    assert list(df.index[df["selected"].astype(bool)]) == post.selected()
    assert {"rhat", "ess_bulk", "ci90_low", "ci90_high", "prior_driven", "min_penalty"} <= set(df.columns)


def test_to_dataframe_without_pandas_names_the_install(fresh, monkeypatch):
    import builtins

    _, post = fresh
    real = builtins.__import__

    def no_pandas(name, *args, **kwargs):
        if name == "pandas" or name.startswith("pandas."):
            raise ImportError("No module named 'pandas'")
        return real(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_pandas)
    with pytest.raises(ImportError, match="pip install pandas"):
        post.to_dataframe()


def test_html_repr_is_the_table_escaped(fresh):
    _, post = fresh
    page = post._repr_html_()
    assert page.count("<tr>") == 1 + post.n_features and "<table>" in page
    for n in post.feature_names:
        assert f"<td>{n}</td>" in page
    hostile = Posterior(**{**{f: getattr(post, f) for f in post.__dataclass_fields__},
                           "feature_names": ("<script>alert(1)</script>",) + post.feature_names[1:],
                           "identified": None, "issue_warnings": False})
    page = hostile._repr_html_()
    assert "<script>" not in page and "&lt;script&gt;" in page


def test_py_typed_ships_with_the_package():
    import tomllib

    root = Path(pbicrl.__file__).resolve().parent
    assert (root / "py.typed").is_file()
    pyproject = Path(__file__).resolve().parents[1] / "pyproject.toml"
    if pyproject.is_file():  # a source checkout: the marker must be package data
        data = tomllib.loads(pyproject.read_text())["tool"]["setuptools"]["package-data"]["pbicrl"]
        assert "py.typed" in data


# ---------------------------------------------------------------------------------------------- p_joint
def test_p_joint_is_a_setting_of_infer(tmp_path):
    prob = make_problem(15, labels="violations", violation_rate=0.4, seed=3)
    ds = prob.dataset
    default = _infer(ds, iterations=600)
    explicit = _infer(ds, iterations=600, p_joint=0.0)
    np.testing.assert_array_equal(default.penalty_weights, explicit.penalty_weights)  # 0 is the default
    joint = _infer(ds, iterations=600, p_joint=0.3)
    assert joint.settings["p_joint"] == 0.3 and default.settings["p_joint"] == 0.0
    assert not np.array_equal(joint.penalty_weights, default.penalty_weights)  # the joint move is used
    from pbicrl.api import infer_from_config
    from pbicrl.config import ConfigError, InferConfig

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", PbicrlWarning)
        cfg = InferConfig(iterations=600, chains=2, jobs=1, seed=3, p_joint=0.3)
        np.testing.assert_array_equal(infer_from_config(ds, cfg, progress=False).penalty_weights,
                                      joint.penalty_weights)
    for bad in (-0.1, 1.0, float("nan"), "0.3", True):
        with pytest.raises(ConfigError, match=r"p_joint'?: expected (a number in \[0, 1\)|int or float)"):
            pbicrl.infer(ds, p_joint=bad, iterations=10, progress=False)
    with pytest.raises(ConfigError, match="p_joint: the joint weight step belongs to the pbicrl and bpl"):
        pbicrl.infer(ds, sampler="paper", p_joint=0.2, iterations=10, progress=False)
    assert pbicrl.infer(ds, sampler="paper", p_joint=0, iterations=10, chains=1, jobs=1,
                        progress=False).settings["p_joint"] == 0.0


# ---------------------------------------------------------------------------------------------- many groups
def test_a_total_ranking_of_twenty_thousand_runs_and_exports_in_modest_memory(monkeypatch):
    # infer (identify + sampler) and the pointwise log-likelihood of a run over 20,000 single-trajectory groups:
    # nothing of size K x K (3.2 GB) anywhere outside the samplers. Dataset caps the groups (another module).
    import tracemalloc

    import pbicrl.inference.data as data_mod
    from pbicrl.analysis.export import pointwise_log_likelihood, run_likelihood
    from pbicrl.inference.data import Dataset

    monkeypatch.setattr(data_mod, "MAX_GROUPS", 10**6)
    n = 20_000
    rng = np.random.default_rng(5)
    F = rng.uniform(0, 1, (n, 2))
    group = np.empty(n, dtype=np.int64)
    group[np.argsort(-(F @ np.array([1.0, -2.0]) + 0.3 * rng.standard_normal(n)))] = np.arange(1, n + 1)
    ds = Dataset(features=F, offsets=np.arange(n + 1), group=group, feature_names=["a", "f"],
                 nominal_weights=[1.0, 0.0])
    tracemalloc.start()
    try:
        post = _infer(ds, iterations=60, chains=1, candidates=["f"])
        lik, cset = run_likelihood(post, ds)  # margins read back from the run: 19,999 gaps, not a K x K matrix
        shares = pointwise_log_likelihood(post, lik, constraints=cset, draws=[0, 10])
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 200e6, f"peak {peak / 1e6:.0f} MB"
    assert len(post.extra["margins"]) == n - 1
    assert lik.preferences.margin_offsets.size == n and lik.preferences.group_margins.size == 0
    np.testing.assert_allclose(shares.sum(axis=-1), post.log_likelihood[:, [0, 10]], rtol=1e-9)


# ---------------------------------------------------------------------------------------------- the run's dataset
def test_an_api_run_exports_the_pointwise_log_likelihood_for_loo(fresh, tmp_path):
    """issue 30 item 9: ``az.loo(pbicrl.infer(ds).to_arviz())`` used to see "1.0 observations" (the total in
    ``sample_stats.log_likelihood``, ArviZ's fallback name) because an API run had no log_likelihood group."""
    az = pytest.importorskip("arviz")
    ds, post = fresh
    assert post.extra["data"]["sha256"] == ds.content_hash()
    data = post.to_arviz(pointwise_draws=50)  # the dataset infer() kept
    assert "log_likelihood" in (set(data.children) if hasattr(data, "children") else set(data.groups()))
    assert "log_likelihood" not in data["sample_stats"]  # never the name ArviZ falls back to
    np.testing.assert_array_equal(data["sample_stats"]["total_log_likelihood"].values, post.log_likelihood)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # Pareto-k of short chains
        loo = az.loo(data, pointwise=True)
    n = loo["n_data_points"] if hasattr(loo, "__getitem__") else loo.n_data_points
    assert int(n) == ds.n_trajectories
    # saved: the in-memory dataset is stored with the run, and the loaded run exports the same group
    run = post.save(tmp_path / "run")
    assert (run / "dataset.npz").is_file()
    back = pbicrl.load_run(run, issue_warnings=False).to_arviz(pointwise_draws=50)
    np.testing.assert_allclose(back["log_likelihood"]["preferences"].values,
                               data["log_likelihood"]["preferences"].values)


def test_an_export_without_the_dataset_is_an_error_not_a_silent_omission(fresh, tmp_path):
    pytest.importorskip("arviz")
    ds, post = fresh
    run = post.save(tmp_path / "run")
    (run / "dataset.npz").unlink()
    back = pbicrl.load_run(run, issue_warnings=False)
    with pytest.raises(ValueError, match=r"records no dataset file.*sha256.*pass the run's dataset"):
        back.to_arviz()
    assert "log_likelihood" in back.to_arviz(dataset=ds, pointwise_draws=10)
    other = make_problem(15, labels="violations", violation_rate=0.4, seed=4).dataset
    with pytest.raises(ValueError, match="not the data this run was inferred from"):
        back.to_arviz(dataset=other)
    # pointwise=False is the explicit way to export without it
    assert "log_likelihood" not in pbicrl.load_run(run, issue_warnings=False).to_arviz(pointwise=False)


def test_cli_export_of_an_api_run(fresh, tmp_path, capsys):
    """``pbicrl export API_RUN --netcdf x.nc``: with the stored dataset copy it has the pointwise group; without
    any dataset it is an error that names --data and writes nothing."""
    az = pytest.importorskip("arviz")
    pytest.importorskip("h5netcdf")
    from pbicrl.cli import main

    ds, post = fresh
    run = post.save(tmp_path / "run")
    assert main(["export", str(run), "--netcdf", str(tmp_path / "x.nc")]) == 0
    back = az.from_netcdf(tmp_path / "x.nc")
    assert back["log_likelihood"]["preferences"].shape[2] == ds.n_trajectories
    (run / "dataset.npz").unlink()
    capsys.readouterr()
    assert main(["export", str(run), "--netcdf", str(tmp_path / "y.nc")]) != 0
    assert "--data" in capsys.readouterr().err and not (tmp_path / "y.nc").exists()
    path = ds.save(tmp_path / "d.npz")
    assert main(["export", str(run), "--netcdf", str(tmp_path / "y.nc"), "--data", str(path)]) == 0


def test_infer_takes_dataset_names_and_paths_like_the_cli(tmp_path):
    """issue 30 item 10: ``pbicrl.infer("example")`` raised AttributeError."""
    from pbicrl.inference.data import load_dataset, resolve_dataset_path

    post = _infer("example", iterations=300)
    assert post.extra["data"]["path"] == str(resolve_dataset_path("example").resolve())
    assert post.extra["data"]["sha256"] == load_dataset("example").content_hash()
    prob = make_problem(8, seed=1)
    path = prob.dataset.save(tmp_path / "demos.npz")
    assert _infer(path, iterations=300).extra["data"]["path"] == str(path.resolve())
    assert _infer(str(path), iterations=300).feature_names == prob.dataset.feature_names
    with pytest.raises(FileNotFoundError, match="no shipped dataset of that name"):
        pbicrl.infer("no_such_dataset", progress=False)
    with pytest.raises(TypeError, match="expected a Dataset, a .npz path"):
        pbicrl.infer(42, progress=False)


def test_loading_a_run_warns_once_per_message_in_one_line_per_feature(fresh, tmp_path):
    """issue 30 item 8: load_run and table() repeated the identification's paragraphs; one short line per
    feature now, each issued once per call, the full text in summary.json."""
    _, post = fresh
    run = post.save(tmp_path / "run")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", PbicrlWarning)
        back = pbicrl.load_run(run)
    msgs = [str(w.message) for w in caught if w.category is PbicrlWarning]
    assert len(msgs) == len(set(msgs))
    per_feature = [m for m in msgs if m.split(":", 1)[0] in back.feature_names]
    assert per_feature and all(len(m) < 100 for m in per_feature)
    s = json.loads((run / "summary.json").read_text())
    ident = s["identified"]
    assert ident["warnings"] == [m for m in s["warnings"] if m in ident["warnings"]]
    assert set(ident["explanations"]) >= {m.split(":", 1)[0] for m in ident["warnings"]}
    table_lines = [ln for ln in back.table(width=200).splitlines() if ln.startswith("warning: ")]
    assert len(table_lines) == len(back.warnings())
