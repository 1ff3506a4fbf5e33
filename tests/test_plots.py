"""Figures of a run: files written, truth parsing, parametric pairs, MAP rewards."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest

pytest.importorskip("matplotlib")

import pbicrl  # noqa: E402
from pbicrl import plots  # noqa: E402
from pbicrl.cli import main  # noqa: E402
from pbicrl.synthetic import make_problem  # noqa: E402

PNG = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    prob = make_problem(12, labels="violations", violation_rate=0.4, seed=8)
    d = tmp_path_factory.mktemp("plots")
    data = d / "data.npz"
    prob.dataset.save(data)
    post = pbicrl.infer(prob.dataset, n_iterations=3000, n_chains=2, seed=1, n_jobs=1, progress=False,
                        weight_prior=pbicrl.WeightPrior("flat", -50, 50))
    post.extra["data"]["path"] = str(data)
    return post.save(d / "run"), prob, post


def test_plot_run_writes_readable_pngs(run, tmp_path):
    run_dir, prob, _ = run
    truth = dict(zip(prob.dataset.feature_names, prob.true_penalty.tolist()))
    files = plots.plot_run(run_dir, tmp_path / "figs", truth=truth)
    assert sorted(f.stem for f in files) == ["p_constraint", "posterior", "rewards", "trace"]  # no parameters: no pairs
    for f in files:
        head = f.read_bytes()[:8]
        assert head == PNG and f.stat().st_size > 5000
    assert not list((tmp_path / "figs").glob(".plots.tmp-*"))


def test_default_out_dir_and_cli(run, capsys):
    run_dir, _, _ = run
    assert main(["plot", str(run_dir), "--truth", "0,-10,-100,0", "--format", "svg"]) == 0
    out = capsys.readouterr().out
    assert "trace.svg" in out and (run_dir / "plots" / "posterior.svg").is_file()
    assert main(["plot", str(run_dir), "--truth", "1,2"]) == 2
    assert "expected 4 values" in capsys.readouterr().err


def test_rewards_order_groups_under_the_map(run):
    _, prob, post = run
    r = plots.map_returns(post, prob.dataset)
    means = [r[prob.dataset.group == g].mean() for g in prob.dataset.group_labels]
    assert means[0] > means[-1]  # the best group gets the highest MAP reward
    other = make_problem(5, nominal_weights=(1.0, 0.0, -1.0), penalty=(0.0, -5.0, 0.0), seed=1).dataset
    with pytest.raises(ValueError, match="do not match"):
        plots.map_returns(post, other)


def test_parse_truth(tmp_path):
    names = ["a", "b"]
    assert plots.parse_truth("0,-3", names) == {"a": 0.0, "b": -3.0}
    assert plots.parse_truth("b=-3, wall.threshold=8", names) == {"b": -3.0, "wall.threshold": 8.0}
    f = tmp_path / "t.json"
    f.write_text(json.dumps({"true_penalty": [1, 2]}))
    assert plots.parse_truth(str(f), names) == {"a": 1.0, "b": 2.0}
    with pytest.raises(ValueError, match="not a number"):
        plots.parse_truth("a=x", names)
    with pytest.raises(FileNotFoundError):
        plots.parse_truth(str(tmp_path / "missing.json"), names)


def test_pairs_plot_for_parametric_constraints():
    rng = np.random.default_rng(0)
    C, D = 2, 300
    ind = np.ones((C, D, 2), np.int8)
    ind[:, ::4, 1] = 0
    th = rng.normal(8.0, 0.5, (C, D, 1))
    th[ind[:, :, 1] == 0] = np.nan
    post = SimpleNamespace(indicators=ind, penalty_weights=rng.normal(-5, 1, (C, D, 2)),
                           log_likelihood=rng.normal(size=(C, D)), feature_names=("speed", "wall"),
                           parameters=th, parameter_names=("wall.threshold",), parameter_owner=(1,))
    fig = plots.plot_pairs(post, truth={"wall": -5.0, "wall.threshold": 8.0})
    ax = fig.axes[0]
    assert ax.get_xlabel() == "wall.threshold" and "wall" in ax.get_ylabel()
    assert "450 active draws" in ax.get_title()  # 3 of every 4 draws in 2 chains
    assert plots.plot_pairs(SimpleNamespace(parameters=None, feature_names=("a",))) is None
    plots.plot_traces(post)
    plots.plot_posteriors(post, truth={"wall.threshold": 8.0})


def test_parametric_run_end_to_end(tmp_path):
    """A run with a parametric constraint: diagnostics, export and plots all carry its parameter."""
    from pbicrl import diagnostics
    from pbicrl.runs import load_run
    from pbicrl.synthetic import make_wall_problem

    prob = make_wall_problem(10, seed=0)
    data = prob.dataset.save(tmp_path / "wall.npz")
    post = pbicrl.infer(prob.dataset, n_iterations=3000, n_chains=2, seed=0, n_jobs=1, progress=False,
                        constraints=[{"family": "axis_halfspace", "dims": [0], "name": "wall"}],
                        weight_prior=pbicrl.WeightPrior("flat", -50, 50))
    post.extra["data"]["path"] = str(data)
    run = load_run(post.save(tmp_path / "run"))
    assert run.parameter_names == ("wall.threshold",) and run.parameter_owner == (2,)
    assert "wall.threshold" in diagnostics.compute(run).values["parameter"]
    files = plots.plot_run(run, truth={"wall.threshold": 8.0})
    assert sorted(f.stem for f in files) == ["p_constraint", "pairs", "posterior", "rewards", "trace"]
    r = plots.map_returns(run, prob.dataset)  # the wall feature is recomputed at the MAP threshold
    assert r.shape == (20,) and np.all(np.isfinite(r))
