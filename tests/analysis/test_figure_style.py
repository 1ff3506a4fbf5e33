"""Every figure follows pbicrl.analysis.style (issue 30 item 12): rendered on small data, matplotlib's own layout
puts no legend over an axes' data area and every axis that shows values has a label."""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np
import pytest

pytest.importorskip("matplotlib")

import pbicrl  # noqa: E402
from pbicrl import plots  # noqa: E402
from pbicrl.analysis import style  # noqa: E402
from pbicrl.errors import PbicrlWarning  # noqa: E402
from pbicrl.inference.synthetic import make_problem, make_wall_problem  # noqa: E402


def _infer(ds, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", PbicrlWarning)
        return pbicrl.infer(ds, iterations=1500, chains=2, seed=1, jobs=1, progress=False, **kw)


@pytest.fixture(scope="module")
def plain():
    prob = make_problem(10, labels="violations", violation_rate=0.4, seed=8)
    ds = dataclasses.replace(prob.dataset, group_names=("good", "bad", "very bad"))
    return ds, prob, _infer(ds)


@pytest.fixture(scope="module")
def wall():
    prob = make_wall_problem(8, seed=0)
    post = _infer(prob.dataset, constraints=[{"family": "axis_halfspace", "dims": [0], "name": "wall"}])
    return prob, post


def test_layout_check_finds_what_it_should():
    """The check itself: a legend on the data and an unlabelled axis are reported, their fixes are not."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(4, 3))
    ax = fig.subplots()
    ax.plot(np.arange(10), np.arange(10), label="data")
    ax.legend(loc="center")
    problems = style.layout_problems(fig)
    assert any("overlaps the data area" in p for p in problems)
    assert any("x axis shows values but has no label" in p for p in problems)
    fig = Figure(figsize=(4, 3), layout="constrained")
    ax = fig.subplots()
    ax.plot(np.arange(10), np.arange(10), label="data")
    ax.set_xlabel("x")
    ax.set_ylabel("y")
    style.legend_outside(ax)
    assert style.layout_problems(fig) == []


def test_run_figures_keep_legends_off_the_data_and_label_every_axis(plain, wall):
    ds, prob, post = plain
    truth = dict(zip(ds.feature_names, prob.true_penalty.tolist()))
    wprob, wpost = wall
    figures = {"trace": plots.plot_traces(post, truth=truth), "posterior": plots.plot_posteriors(post, truth=truth),
               "p_constraint": plots.plot_p_constraint(post, truth=truth),
               "rewards": plots.plot_rewards(post, ds, truth=truth),
               "pairs": plots.plot_pairs(wpost), "wall trace": plots.plot_traces(wpost)}
    for name, fig in figures.items():
        assert style.layout_problems(fig) == [], name


def test_trace_labels_p_active_also_at_one_and_rewards_use_group_names_and_colours(plain):
    ds, _, post = plain
    fig = plots.plot_traces(post)
    titles = [ax.get_title() for ax in fig.get_axes()]
    p = post.p_constraint
    assert sum(t.startswith("P(c=1) = ") for t in titles) == int(np.sum(p > 0))  # 1.00 included
    rew = plots.plot_rewards(post, ds)
    ticks = [t.get_text() for ax in rew.get_axes() for t in ax.get_xticklabels()]
    assert any("very bad" in t for t in ticks) and not any(t.startswith("G1") for t in ticks)
    r = plots.estimate_returns(post, ds)
    eff, _ = post.point_estimate("selected")
    np.testing.assert_allclose(r, ds.mean_features @ (np.asarray(ds.nominal_weights) + eff))
    assert style.group_colours(3) == [style.GROUP_GOOD, style.GROUP_MID, style.GROUP_BAD]


def test_posterior_marks_the_identified_min_penalty(plain):
    _, _, post = plain
    fig = plots.plot_posteriors(post)
    texts = [t.get_text() for lg in fig.legends for t in lg.get_texts()]
    if any(m is not None and m > 0 for m in post.min_penalty()):
        assert any(t.startswith("min|w_p|") for t in texts)


def test_report_figures_keep_legends_off_the_data_and_label_every_axis(tmp_path, monkeypatch):
    """The reproduction figures (weights, CMSE, sensitivity) and the close-the-loop figure, drawn again from the
    results in docs/ (the same call that regenerated them): every one passes the layout check."""
    import json
    import shutil
    from pathlib import Path

    import matplotlib.pyplot as plt

    from pbicrl.experiments.close_loop import plot as close_loop_plot
    from pbicrl.experiments.reproduce.figures import redraw

    caught = []
    real_close = plt.close
    monkeypatch.setattr(plt, "close", lambda fig=None: (caught.append(fig), real_close(fig))[1])
    docs = Path(__file__).resolve().parents[2] / "docs"
    for name in ("point-mass", "fetch-reach", "grid", "halfcheetah", "ant", "sensitivity"):
        d = tmp_path / name
        d.mkdir()
        shutil.copy(docs / "reproduction" / name / "results.json", d / "results.json")
        files = redraw(d)
        assert files and all((d / f).stat().st_size > 10_000 for f in files)
    close_loop_plot(json.loads((docs / "figures" / "close_loop_results.json").read_text()), tmp_path / "cl.png")
    assert len(caught) == 9  # weights and reward distributions of two, grid, two CMSE, sensitivity, close the loop
    for fig in caught:
        assert style.layout_problems(fig) == [], fig.axes[0].get_title()
