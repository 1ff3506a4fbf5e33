"""Smoke versions of every reproduction (the full runs are `pytest -m slow`)."""

import json

import numpy as np
import pytest

from pbicrl.experiments.reproduce import EXPERIMENTS, reproduce
from pbicrl.inference.synthetic import make_problem, make_wall_problem


@pytest.fixture(scope="module")
def stand_ins(tmp_path_factory):
    d = tmp_path_factory.mktemp("data")
    nav = d / "nav.npz"
    make_problem(70, labels="violations", violation_rate=0.4, seed=0).dataset.save(nav)
    wall = d / "wall.npz"
    make_wall_problem(200, length=60, seed=0).dataset.save(wall)
    return {"point_mass": str(nav), "fetch_reach": str(nav), "halfcheetah": str(wall), "ant": str(wall)}


def test_grid_smoke(tmp_path):
    (report,) = reproduce("grid", out=tmp_path, iterations=2000, seeds=1, executor="serial", progress=False)
    text = report.read_text()
    assert "BPL with margins" in text
    res = json.loads((tmp_path / "grid" / "results.json").read_text())
    assert len(res["weights"]["BPL"]["mean"]) == 3


def test_navigation_and_wall_smoke(tmp_path, stand_ins):
    reports = reproduce("point-mass", out=tmp_path, iterations=3000, seeds=2, executor="serial", progress=False,
                        data=stand_ins)
    res = json.loads((tmp_path / "point-mass" / "results.json").read_text())
    assert set(res["methods"]) >= {"BPL", "PBICRL, m = 0", "PBICRL, tuned margins"}
    assert res["tuning"]["relation_target"] == [1.0, 4.0]
    assert (tmp_path / "point-mass" / "weights.png").exists()
    reproduce("halfcheetah", out=tmp_path, iterations=3000, seeds=2, executor="serial", progress=False, data=stand_ins)
    wall = json.loads((tmp_path / "halfcheetah" / "results.json").read_text())
    assert set(wall["sizes"]) == {"20", "50", "100", "200"}
    assert "CMSE" in (tmp_path / "halfcheetah" / "report.md").read_text()
    # resumable: a second call finds every run done and reruns nothing
    before = sorted(p.name for p in (tmp_path / "runs").iterdir())
    reproduce("halfcheetah", out=tmp_path, iterations=3000, seeds=2, executor="serial", progress=False, data=stand_ins)
    assert sorted(p.name for p in (tmp_path / "runs").iterdir()) == before
    assert reports[0].exists()
    _navigation_numbers_are_its_runs(tmp_path, res)
    _wall_numbers_are_its_runs(tmp_path, wall)


def _runs(root, name):
    """``(config, result)`` of the finished runs named ``name`` under ``root/runs``, in seed order."""
    recs = [json.loads(p.read_text()) for p in sorted((root / "runs").glob("*/result.json"))]
    recs = sorted((r for r in recs if r["name"] == name), key=lambda r: r["config"]["seed"])
    return [(r["config"], r["result"]) for r in recs]


def _ms(values):
    return f"{np.mean(values):.3g} ± {np.std(values):.3g}"


def _navigation_numbers_are_its_runs(root, res):
    """The BPL row of results.json and of report.md is computed from the BPL runs' own result.json files."""
    runs = _runs(root, "point-mass-bpl")
    assert [c["seed"] for c, _ in runs] == [0, 1] and all(c["demos_per_group"] == 60 for c, _ in runs)
    W = np.array([r["map_effective_penalty"] for _, r in runs])
    row = res["methods"]["BPL"]
    np.testing.assert_allclose(row["per_seed"], W)
    np.testing.assert_allclose(row["mean"], W.mean(0))
    np.testing.assert_allclose(row["std"], W.std(0))
    line = next(ln for ln in (root / "point-mass" / "report.md").read_text().splitlines() if ln.startswith("| BPL |"))
    cells = [c.strip() for c in line.strip("|").split("|")]
    assert cells[1:1 + W.shape[1]] == [_ms(W[:, j]) for j in range(W.shape[1])]
    truth = np.array(res["paper"]["true_weights"], float) - np.array(res["paper"]["nominal_weights"], float)
    on = truth != 0
    within = sum(bool(np.all(np.abs(w[on] - truth[on]) <= 0.15 * np.abs(truth[on]))) for w in W)
    assert cells[-1] == f"{within}/2" and row["within_15pct"] == within


def _wall_numbers_are_its_runs(root, wall):
    """Each size's CMSE in results.json is the runs' MAP walls against the true wall, and the report's
    sensitivity table prints exactly those numbers."""
    from pbicrl.analysis.metrics import cmse_location

    true_wall = wall["paper"]["wall"]
    lines = (root / "halfcheetah" / "report.md").read_text().splitlines()
    for n in (20, 50, 100, 200):
        runs = _runs(root, f"halfcheetah-n{n}")
        assert len(runs) == 2 and all(c["demos_per_group"] == n and c["sampler"] == "paper" for c, _ in runs)
        theta = [r["map_parameters"][0] for _, r in runs]
        entry = wall["sizes"][str(n)]
        assert entry["theta"] == theta
        errs = [cmse_location(t, true_wall) for t in theta if t is not None]
        assert entry["wall_off_seeds"] == 2 - len(errs)
        if errs:
            np.testing.assert_allclose(entry["cmse"], [np.mean(errs), np.std(errs)])
        row = next(ln for ln in lines if ln.startswith(f"| {n} | "))
        cell = [c.strip() for c in row.strip("|").split("|")][1]
        assert cell.startswith(_ms(errs) if errs else "no seed found a wall")
        default = _runs(root, f"halfcheetah-default-n{n}")
        assert len(default) == 2 and all(c["sampler"] == "pbicrl" and c["likelihood"] == "grouped" for c, _ in default)
        assert wall["default"][str(n)]["theta"] == [r["map_parameters"][0] for _, r in default]


def test_unknown_experiment_lists_the_registry():
    with pytest.raises(ValueError, match="unknown 'moon'; choose one of grid, point-mass, fetch-reach, halfcheetah, "
                                         "ant, sensitivity, icl or all"):
        reproduce("moon", progress=False)


def test_the_registry_is_what_the_command_line_offers_and_all_runs_all_but_icl(tmp_path, monkeypatch):
    from pbicrl.cli import build_parser

    sub = next(a for a in build_parser()._subparsers._group_actions if a.dest == "command")
    choices = next(a.choices for a in sub.choices["reproduce"]._actions if a.dest == "experiment")
    assert list(choices) == [*EXPERIMENTS, "all"]
    called = []
    for name in EXPERIMENTS:  # stand-ins that record the order and the context they get
        def fake(ctx, name=name):
            called.append((name, ctx.pairs, ctx.iterations, ctx.seeds))
            return ctx.out / name / "report.md"
        monkeypatch.setitem(EXPERIMENTS, name, fake)
    reports = reproduce("all", out=tmp_path, pairs="sampled", iterations=123, seeds=2, progress=False)
    expected = [n for n in EXPERIMENTS if n != "icl"]
    assert [c[0] for c in called] == expected and all(c[1:] == ("sampled", 123, 2) for c in called)
    assert reports == [tmp_path / n / "report.md" for n in expected]


def test_old_argument_names_still_work_with_a_warning(tmp_path, monkeypatch):
    from pbicrl.errors import PbicrlWarning

    seen = []
    monkeypatch.setitem(EXPERIMENTS, "grid", lambda ctx: seen.append((ctx.pairs, ctx.data)) or tmp_path / "r.md")
    with pytest.warns(PbicrlWarning, match="'protocol' is deprecated.*use 'pairs'"):
        reproduce("grid", out=tmp_path, protocol="sampled", datasets={"grid": "x.npz"}, progress=False)
    assert seen == [("sampled", {"grid": "x.npz"})]
    with pytest.raises(TypeError, match="unexpected keyword argument 'sedes'"):
        reproduce("grid", out=tmp_path, sedes=3)
    with pytest.raises(ValueError, match="pairs: expected 'all' or 'sampled'"):
        reproduce("grid", out=tmp_path, pairs="some")


def test_protocol_flag_is_a_deprecated_spelling_of_pairs(tmp_path, monkeypatch, capsys):
    from pbicrl.cli import main

    seen = []
    monkeypatch.setitem(EXPERIMENTS, "grid", lambda ctx: seen.append(ctx.pairs) or tmp_path / "r.md")
    assert main(["reproduce", "grid", "--out", str(tmp_path), "--protocol", "sampled", "--no-progress"]) == 0
    assert main(["reproduce", "grid", "--out", str(tmp_path), "--pairs", "sampled", "--no-progress"]) == 0
    assert main(["reproduce", "grid", "--out", str(tmp_path), "--no-progress"]) == 0
    assert seen == ["sampled", "sampled", "all"]
    err = capsys.readouterr().err
    assert err.count("--protocol is deprecated") == 1 and "use --pairs" in err


def test_sensitivity_fetch_ant_smoke(tmp_path, stand_ins):
    for name in ("fetch-reach", "ant", "sensitivity"):
        reproduce(name, out=tmp_path, iterations=2000, seeds=1, executor="serial", progress=False, data=stand_ins)
        assert (tmp_path / name / "report.md").exists()
    sens = json.loads((tmp_path / "sensitivity" / "results.json").read_text())
    assert set(sens["point-mass"]) == {"20", "60", "100", "paper", "default"}
    assert set(sens["point-mass"]["default"]) == {"20", "60", "100"}
    assert 0 <= sens["point-mass"]["default"]["20"]["exact_set"] <= 1
    assert (tmp_path / "sensitivity" / "sensitivity.png").stat().st_size > 0
    wall = json.loads((tmp_path / "ant" / "results.json").read_text())
    assert set(wall["default"]) == {"20", "50", "100", "200"}
    row = wall["default"]["100"]
    lo, hi = row["identified"][0]
    assert lo < hi  # the identified wall interval of seed 0's subsample
    assert (tmp_path / "ant" / "ant_cmse.png").stat().st_size > 0


@pytest.mark.slow
def test_reproduce_all_full(tmp_path):
    """The full reproduction on the shipped demonstrations (about 3 minutes on 2 cores)."""
    reports = reproduce("all", out=tmp_path, progress=False)
    assert {p.parent.name for p in reports} == {"grid", "point-mass", "fetch-reach", "halfcheetah", "ant", "sensitivity"}
    pm = json.loads((tmp_path / "point-mass" / "results.json").read_text())
    assert pm["iterations"] == 400_000 and pm["seeds"] == 5


def test_identified_interval_prints_rounded_outward():
    from pbicrl.experiments.reproduce.markdown import fmt_interval

    # the Ant data's furthest good state 9.9978 once printed as "(10.00, ...]", seemingly excluding the wall at 10
    assert fmt_interval([9.9978, 11.2]) == "(9.99, 11.20]"
    assert fmt_interval([9.99, 10.0201]) == "(9.99, 10.03]"
    assert fmt_interval([7.97, 62.5]) == "(7.97, 62.50]"
    assert fmt_interval([1.5, float("inf")]) == "(1.50, inf]"
    assert fmt_interval(None) == "-" and fmt_interval([None, None]) == "-"
