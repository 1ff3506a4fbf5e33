"""Smoke versions of every reproduction (the full runs are `pytest -m slow`)."""

import json

import pytest

from pbicrl.experiments.reproduce import EXPERIMENTS, reproduce
from pbicrl.synthetic import make_problem, make_wall_problem


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
                        datasets=stand_ins)
    res = json.loads((tmp_path / "point-mass" / "results.json").read_text())
    assert set(res["methods"]) >= {"BPL", "PBICRL, m = 0", "PBICRL, tuned margins"}
    assert res["tuning"]["relation_target"] == [1.0, 4.0]
    assert (tmp_path / "point-mass" / "weights.png").exists()
    reproduce("halfcheetah", out=tmp_path, iterations=3000, seeds=2, executor="serial", progress=False, datasets=stand_ins)
    wall = json.loads((tmp_path / "halfcheetah" / "results.json").read_text())
    assert set(wall["sizes"]) == {"20", "50", "100", "200"}
    assert "CMSE" in (tmp_path / "halfcheetah" / "report.md").read_text()
    # resumable: a second call finds every run done and reruns nothing
    before = sorted(p.name for p in (tmp_path / "runs").iterdir())
    reproduce("halfcheetah", out=tmp_path, iterations=3000, seeds=2, executor="serial", progress=False, datasets=stand_ins)
    assert sorted(p.name for p in (tmp_path / "runs").iterdir()) == before
    assert reports[0].exists()


def test_unknown_experiment():
    with pytest.raises(ValueError, match="unknown"):
        reproduce("moon", progress=False)
    assert "sensitivity" in EXPERIMENTS


def test_sensitivity_fetch_ant_smoke(tmp_path, stand_ins):
    for name in ("fetch-reach", "ant", "sensitivity"):
        reproduce(name, out=tmp_path, iterations=2000, seeds=1, executor="serial", progress=False, datasets=stand_ins)
        assert (tmp_path / name / "report.md").exists()
    sens = json.loads((tmp_path / "sensitivity" / "results.json").read_text())
    assert set(sens["point-mass"]) == {"20", "60", "100"}


@pytest.mark.slow
def test_reproduce_all_full(tmp_path):
    """The full reproduction on the shipped demonstrations (about 3 minutes on 2 cores)."""
    reports = reproduce("all", out=tmp_path, progress=False)
    assert {p.parent.name for p in reports} == {"grid", "point-mass", "fetch-reach", "halfcheetah", "ant", "sensitivity"}
    pm = json.loads((tmp_path / "point-mass" / "results.json").read_text())
    assert pm["iterations"] == 400_000 and pm["seeds"] == 5
