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
from pbicrl.inference.synthetic import make_problem  # noqa: E402

PNG = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    prob = make_problem(12, labels="violations", violation_rate=0.4, seed=8)
    d = tmp_path_factory.mktemp("plots")
    data = d / "data.npz"
    prob.dataset.save(data)
    post = pbicrl.infer(prob.dataset, iterations=3000, chains=2, seed=1, jobs=1, progress=False,
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
    assert ax.get_xlabel() == "wall.threshold (state units)" and "wall" in ax.get_ylabel()
    assert "450 active draws" in ax.get_title()  # 3 of every 4 draws in 2 chains
    assert plots.plot_pairs(SimpleNamespace(parameters=None, feature_names=("a",))) is None
    plots.plot_traces(post)
    plots.plot_posteriors(post, truth={"wall.threshold": 8.0})


def test_parametric_run_end_to_end(tmp_path):
    """A run with a parametric constraint: diagnostics, export and plots all carry its parameter."""
    from pbicrl.analysis import diagnostics
    from pbicrl.io.runs import read_run
    from pbicrl.inference.synthetic import make_wall_problem

    prob = make_wall_problem(10, seed=0)
    data = prob.dataset.save(tmp_path / "wall.npz")
    post = pbicrl.infer(prob.dataset, iterations=3000, chains=2, seed=0, jobs=1, progress=False,
                        constraints=[{"family": "axis_halfspace", "dims": [0], "name": "wall"}],
                        weight_prior=pbicrl.WeightPrior("flat", -50, 50))
    post.extra["data"]["path"] = str(data)
    run = read_run(post.save(tmp_path / "run"))
    assert run.parameter_names == ("wall.threshold",) and run.parameter_owner == (2,)
    assert "wall.threshold" in diagnostics.compute(run).values["parameter"]
    files = plots.plot_run(run, truth={"wall.threshold": 8.0})
    assert sorted(f.stem for f in files) == ["p_constraint", "pairs", "posterior", "rewards", "trace"]
    r = plots.map_returns(run, prob.dataset)  # the wall feature is recomputed at the MAP threshold
    assert r.shape == (20,) and np.all(np.isfinite(r))


# ------------------------------------------------------------------------------------------------------
# Figure code paths: what is drawn where (axis ranges, labels, annotations), never pixels.

def fake_post(C=2, D=400, *, p_on=(0.75, 1.0), seed=0, settings=None, method="pbicrl", params=False):
    """A posterior-like object: feature 'a' active in p_on[0] of the draws, 'b' in p_on[1]."""
    rng = np.random.default_rng(seed)
    d = len(p_on)
    ind = (rng.random((C, D, d)) < np.asarray(p_on)).astype(np.int8)
    wp = rng.normal(-5.0, 1.0, (C, D, d)) * ind  # reversible jump: w_p = 0 while inactive
    names = tuple("abcdefgh"[:d])
    out = SimpleNamespace(indicators=ind, penalty_weights=wp, log_likelihood=rng.normal(-10, 1, (C, D)),
                          log_prior=np.zeros((C, D)), feature_names=names, sampler=method,
                          settings=settings if settings is not None else {}, parameters=None, parameter_names=(),
                          parameter_owner=())
    if params:
        th = rng.normal(8.0, 0.5, (C, D, 1))
        th[ind[:, :, d - 1] == 0] = np.nan
        out.parameters, out.parameter_names, out.parameter_owner = th, (f"{names[-1]}.threshold",), (d - 1,)
    return out


def _texts(ax):
    return [t.get_text() for t in ax.texts]


def test_far_truth_is_written_at_the_edge_and_near_truth_is_taken_in():
    post = fake_post(p_on=(1.0, 1.0))
    fig = plots.plot_traces(post, truth={"a": -500.0, "b": -8.5})
    ax_a, ax_b = fig.axes[0], fig.axes[2]
    lo, hi = ax_a.get_ylim()
    assert lo > -20 and hi < 10  # the trace keeps its own range ...
    assert any("truth -500" in t and "\u2193" in t for t in _texts(ax_a))  # ... the truth is an arrow at the edge
    lo_b, _ = ax_b.get_ylim()
    assert lo_b <= -8.5 and not any("truth" in t for t in _texts(ax_b))  # close enough: drawn as a line
    dens = plots.plot_posteriors(post, truth={"a": 500.0})
    axd = dens.subfigs[0].axes[1]
    assert axd.get_xlim()[1] < 10 and any("truth 500" in t and "\u2192" in t for t in _texts(axd))


def test_density_is_conditional_and_the_atom_is_a_separate_bar():
    post = fake_post(D=4000, p_on=(0.75, 1.0))
    fig = plots.plot_posteriors(post)
    sf = fig.subfigs[0]
    axb, axd = sf.axes
    p = post.indicators[:, :, 0].mean()
    assert f"P(c=1) = {p:.2f}" in sf._suptitle.get_text()
    heights = sorted(b.get_height() for b in axb.patches)
    np.testing.assert_allclose(heights, sorted([p, 1 - p]))
    # the stairs integrate to 1: the density given c = 1, not scaled by P(c=1) and without the atom at 0
    st = [a for a in axd.patches if hasattr(a, "get_data")][0]
    vals, edges = st.get_data()[:2]
    assert np.isclose(np.sum(vals * np.diff(edges)), 1.0)
    assert axd.get_xlim()[1] < -0.5  # the atom at 0 is not in the density's range
    assert axd.get_ylabel() == "density | c=1" and axd.get_xlabel() == "penalty w_p (reward units per unit feature)"
    w, h = fig.get_size_inches()
    assert h >= 4 and w / h < 2.5  # two panels side by side, not a thin strip


def test_never_active_features_say_so():
    post = fake_post(p_on=(0.0, 1.0))
    for fig in (plots.plot_posteriors(post), plots.plot_traces(post)):
        assert any("never active (P(c=1)=0)" in t for ax in fig.axes for t in _texts(ax))
    assert not plots.plot_traces(post).axes[1].get_visible()  # no empty histogram beside it


def _dotted_at(ax, value, axis):
    get = (lambda ln: ln.get_xdata()) if axis == "x" else (lambda ln: ln.get_ydata())
    return any(ln.get_linestyle() == ":" and np.allclose(np.asarray(get(ln), float), value) for ln in ax.lines)


def test_prior_bounds_are_marked_where_the_draws_reach_them():
    post = fake_post(p_on=(1.0, 1.0), settings={"weight_prior": {"kind": "flat", "low": -6.0, "high": 50.0}})
    post.penalty_weights[:, :, 0] = np.clip(post.penalty_weights[:, :, 0], -6.0, None)  # piles up at -6
    axd = plots.plot_posteriors(post).subfigs[0].axes[1]
    assert _dotted_at(axd, -6.0, "x") and not _dotted_at(axd, 50.0, "x")  # 50 lies far outside the range
    assert _dotted_at(plots.plot_traces(post).axes[0], -6.0, "y")
    post.sampler = "paper"  # Algorithm 1 samples with an improper prior: nothing to mark
    assert not _dotted_at(plots.plot_posteriors(post).subfigs[0].axes[1], -6.0, "x")
    post.sampler, post.settings = "pbicrl", {}  # no prior recorded
    assert not _dotted_at(plots.plot_posteriors(post).subfigs[0].axes[1], -6.0, "x")


def test_parameter_prior_bounds_and_units():
    settings = {"weight_prior": {"kind": "flat", "low": -50.0, "high": 50.0},
                "constraints": [{"family": "axis_halfspace", "name": "b", "resolved_bounds": [[7.0, 20.0]]}]}
    post = fake_post(p_on=(1.0, 0.8), settings=settings, params=True)
    post.parameters = np.clip(post.parameters, 7.0, None)
    fig = plots.plot_pairs(post, units={"reward": "points", "b": "fraction of steps", "state": "m"})
    ax = fig.axes[0]
    assert ax.get_xlabel() == "b.threshold (m)" and "points per fraction of steps" in ax.get_ylabel()
    assert _dotted_at(ax, 7.0, "x") and not _dotted_at(ax, 20.0, "x")
    labels = [sf.axes[1].get_xlabel() for sf in plots.plot_posteriors(post).subfigs if len(sf.axes) == 2]
    assert labels[-1] == "b.threshold (state units)" and labels[0] == "penalty w_p (reward units per unit feature)"


def test_truth_names_are_checked(run, capsys):
    run_dir, _, _ = run
    known = "feature0, constraint1, constraint2, feature3"
    with pytest.raises(ValueError, match=rf"unknown name 'bogus'; known names: {known}$"):
        plots.plot_run(run_dir, truth={"bogus": 1.0, "constraint1": -10.0})
    assert main(["plot", str(run_dir), "--truth", "constraint1=-10,bogus=3"]) == 2
    err = capsys.readouterr().err
    assert "'bogus'" in err and "constraint2" in err  # the unknown name and the known ones
    names = ["a", "b"]
    assert plots.parse_truth("b=-3,b.threshold=8", names, ("b.threshold",)) == {"b": -3.0, "b.threshold": 8.0}
    with pytest.raises(ValueError, match="unknown names 'x', 'y'"):
        plots.parse_truth("x=1,y=2", names, ())
    with pytest.raises(ValueError, match="not finite"):
        plots.check_truth({"a": float("nan")}, names)
    assert plots.parse_truth("x=1", names) == {"x": 1.0}  # names unchecked without the parameter names


def test_rewards_every_group_on_its_own_scale_and_the_true_order(run):
    _, prob, post = run
    ds = prob.dataset
    truth = dict(zip(ds.feature_names, prob.true_penalty.tolist()))
    fig = plots.plot_rewards(post, ds, truth=truth)
    K = ds.n_groups
    assert len(fig.axes) == 1 + K + 1  # all groups, one per group, MAP vs true
    for k, g in enumerate(ds.group_labels):
        zx = fig.axes[1 + k]
        r = plots.estimate_returns(post, ds)[ds.group == g]  # the selected-set estimate (issue 30)
        lo, hi = zx.get_ylim()
        assert lo <= r.min() and hi >= r.max() and (hi - lo) < 2 * max(np.ptp(r), 1e-9) + 1.0  # zoomed on the group
    assert "Spearman" in fig.axes[-1].get_title()
    rt, missing = plots.true_returns(post, ds, truth)
    wn = ds.nominal_weights if ds.nominal_weights is not None else np.zeros(ds.n_features)
    np.testing.assert_allclose(rt, ds.mean_features @ (wn + prob.true_penalty))
    assert missing == []
    partial = plots.plot_rewards(post, ds, truth={ds.feature_names[0]: 0.0})
    assert len(partial.axes) == 1 + K and "lacks" in partial._suptitle.get_text()


def _png_size(path):
    head = path.read_bytes()[:24]
    assert head[:8] == PNG
    return int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big")


def test_default_resolution_and_sizes(run, tmp_path):
    run_dir, _, _ = run
    files = {f.stem: f for f in plots.plot_run(run_dir, tmp_path / "hi")}
    w, h = _png_size(files["trace"])
    assert w == 11 * plots.DEFAULT_DPI  # 11 inches wide at the default 200 dpi
    w, h = _png_size(files["posterior"])
    assert w >= 1600 and h >= 1200
    low = {f.stem: f for f in plots.plot_run(run_dir, tmp_path / "lo", dpi=50)}
    assert _png_size(low["trace"])[0] == 11 * 50
    with pytest.raises(ValueError, match="^dpi: expected a positive number"):
        plots.plot_run(run_dir, tmp_path / "bad", dpi=0)
    pdf = plots.plot_run(run_dir, tmp_path / "pdf", fmt="pdf")
    assert all(f.read_bytes()[:4] == b"%PDF" for f in pdf)
