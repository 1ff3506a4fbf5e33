"""Automated margin tuning."""

import json
import math

import numpy as np
import pytest

from pbicrl.cli import main
from pbicrl.analysis.margins import group_mean_returns, relation_error, tune_margins
from pbicrl.inference.synthetic import make_problem


def test_relation_error():
    err, ach = relation_error([0.0, -1.0, -5.0], [1, 4])
    assert err == pytest.approx(0.0) and ach.tolist() == [1.0, 4.0]
    err, ach = relation_error([0.0, -1.0, -3.0], [1, 4])
    assert err == pytest.approx(math.log(2) ** 2)
    assert relation_error([0.0, 1.0, -3.0], [1, 4])[0] == math.inf  # groups out of order
    with pytest.raises(ValueError, match="relative gap sizes"):
        relation_error([0.0, -1.0, -2.0], [1, 2, 3])


def test_group_means():
    p = make_problem(10, labels="violations", violation_rate=0.5, seed=0)
    mu = group_mean_returns(p.dataset, p.true_weights)
    r = p.dataset.mean_features @ p.true_weights
    assert mu[0] == pytest.approx(r[p.dataset.group == 1].mean())
    assert mu[0] > mu[1] > mu[2]


def test_tune_picks_the_best_candidate(tmp_path):
    p = make_problem(25, labels="violations", violation_rate=0.4, seed=3)
    res = tune_margins(p.dataset, [1, 4], gap_grid=(0.0, 1.0, 3.0), iterations=6000, chains=1, seed=0, progress=False)
    errs = [row["error"] if row["error"] is not None else np.inf for row in res.table]
    assert len(res.table) == 9
    assert res.error == pytest.approx(min(errs))
    assert res.relation_achieved[1] == pytest.approx(
        (res.group_means[1] - res.group_means[2]) / (res.group_means[0] - res.group_means[1]))
    with pytest.raises(ValueError, match="positive relative gap"):
        tune_margins(p.dataset, [1, -4])


def test_cli_tune_margins(tmp_path, capsys):
    data = tmp_path / "d.npz"
    make_problem(15, labels="violations", violation_rate=0.5, seed=1).dataset.save(data)
    out = tmp_path / "tm"
    rc = main(["tune-margins", str(data), "--relation", "1,4", "--out", str(out), "--grid", "0,2", "--iterations", "3000",
               "--no-progress"])
    assert rc == 0
    t = json.loads((out / "tuning.json").read_text())
    assert len(t["candidates"]) == 4 and set(t["margins"]) == {"m12", "m13", "m23"}
    assert "chosen margins" in capsys.readouterr().out
    assert main(["tune-margins", str(data), "--relation", "1,2,3", "--out", str(tmp_path / "x"), "--no-progress"]) == 2
    assert not (tmp_path / "x").exists()
