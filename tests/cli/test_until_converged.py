"""``--iterations auto`` (the default): run until converged, say so, and refuse to suggest from an unconverged run."""

import json

import numpy as np
import pytest

import pbicrl
from pbicrl.cli import main
from pbicrl.errors import PbicrlWarning
from pbicrl.inference.synthetic import make_problem


@pytest.fixture(scope="module")
def data_path(tmp_path_factory):
    p = tmp_path_factory.mktemp("data") / "demo.npz"
    make_problem(20, labels="violations", violation_rate=0.4, seed=2).dataset.save(p)
    return p


def test_default_runs_until_converged(data_path, tmp_path, capsys):
    out = tmp_path / "run"
    rc = main(["infer", str(data_path), "--out", str(out), "--target-ess", "100", "--no-progress"])
    assert rc == 0
    s = json.loads((out / "summary.json").read_text())
    conv = s["extra"]["convergence"]
    assert s["converged"] is True and conv["converged"] is True and conv["iterations"] == "auto"
    assert conv["min_ess"] >= 100 and conv["max_rhat"] < 1.01 and not conv["failing"]
    assert all(q["ok"] for q in conv["quantities"].values())
    assert {"P(c=1) constraint1", "log-likelihood"} <= set(conv["quantities"])
    assert s["iterations"] == conv["iterations_run"] and s["settings"]["p_joint"] == 0.3
    assert "converged in" in capsys.readouterr().out


def test_unconverged_run_says_so_and_suggest_refuses_it(data_path, tmp_path, capsys):
    out = tmp_path / "run"
    rc = main(["infer", str(data_path), "--out", str(out), "--target-ess", "1000000", "--max-time", "1",
               "--no-progress"])
    assert rc == 0
    err = capsys.readouterr().err
    assert "NOT CONVERGED" in err and "--max-time" in err
    s = json.loads((out / "summary.json").read_text())
    assert s["converged"] is False
    assert any("NOT CONVERGED" in w for w in s["warnings"])
    assert "bulk ESS" in " ".join(s["extra"]["convergence"]["failing"].values())
    pool = tmp_path / "pool.npz"
    z = dict(np.load(data_path))
    z["group"] = np.zeros_like(z["group"])  # unlabelled
    np.savez(pool, **z)
    rc = main(["suggest", str(out), "--pool", str(pool)])
    assert rc != 0
    assert "--allow-unconverged" in capsys.readouterr().err


def test_python_api_warns_once_when_not_converged():
    ds = make_problem(15, labels="violations", violation_rate=0.4, seed=3).dataset
    with pytest.warns(PbicrlWarning) as rec:
        post = pbicrl.infer(ds, target_ess=1e6, max_time=1, progress=False)
    assert post.converged is False
    assert sum("NOT CONVERGED" in str(r.message) for r in rec) == 1
    with pytest.raises(pbicrl.config.ConfigError, match="iterations"):
        pbicrl.infer(ds, iterations="forever", progress=False)
    assert np.isfinite(post.log_likelihood).all()
