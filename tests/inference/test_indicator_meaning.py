"""P(c=1) and "selected" are shown only where they are posterior probabilities of a valid model (issue 29, item 2).

``paper`` / ``authors``: the share of draws with c_j = 1 is a frequency in a chain whose indicator moves do not
target a posterior, so tables, ``summary.json``, figures and the labelling page name it so and select nothing.
``bpl``: no indicators; non-candidates are not in the model and show nothing.
"""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest

from pbicrl.analysis.report import records
from pbicrl.inference.draws import INDICATOR_MEANINGS, indicator_meaning
from tests.inference.test_results import IND, WP, make_post, quiet


def post_of(method: str, **settings):
    return quiet(make_post, IND, WP, settings=settings) if method == "pbicrl" else \
        _with_method(quiet(make_post, IND, WP, settings=settings), method)


def _with_method(post, method):
    import dataclasses
    return dataclasses.replace(post, method=method, issue_warnings=False)


def test_every_sampler_has_a_meaning():
    from pbicrl.inference.samplers.kernels import METHODS
    assert set(METHODS) == set(INDICATOR_MEANINGS)
    assert indicator_meaning("pbicrl") == "posterior"
    assert indicator_meaning("paper") == indicator_meaning("authors") == "chain_frequency"
    assert indicator_meaning("bpl") == "fixed"


def test_pbicrl_shows_p_and_selection():
    post = post_of("pbicrl")
    s = post.summary()
    assert s["selected"] == ["a"] and s["posterior"]["p_constraint"]["a"] == pytest.approx(0.8)
    assert s["indicators"]["meaning"] == "posterior"
    head = post.table().splitlines()[0]
    assert "P(c=1)" in head and "sel" in head


@pytest.mark.parametrize("method", ["paper", "authors"])
def test_latent_samplers_show_a_chain_frequency_and_no_selection(method):
    post = post_of(method)
    s = json.loads(json.dumps(post.summary()))
    assert s["selected"] is None
    assert "p_constraint" not in s["posterior"]
    assert s["posterior"]["frequency_on"]["a"] == pytest.approx(0.8)
    assert s["indicators"] == {"meaning": "chain_frequency", "label": "frequency on in the chain"}
    table = post.table()
    assert "P(c=1)" not in table.splitlines()[0] and "sel" not in table.splitlines()[0].split()
    assert "freq on" in table.splitlines()[0]
    assert "selected (P(c=1) > 0.5)" not in table
    assert "not P(c=1)" in table and "no set is selected" in table
    # the MAP column holds the highest-density draw's indicators (chain 0, draw 0: {a})
    rows = {line.split()[0]: line.split() for line in table.splitlines()[2:5]}
    assert rows["a"][2] == "on" and rows["b"][2] == "off"
    assert "selected=" not in repr(post)
    df = records(post)
    assert "p_constraint" not in df[0] and df[0]["frequency_on"] == pytest.approx(0.8)
    assert "P(c=1)" not in post._repr_html_().split("</thead>")[0]


def test_bpl_non_candidates_show_nothing():
    # b is not a candidate: bpl stores c = 1 and w = 0 for it, which must not read as "1.000 yes [0, 0]"
    ind = np.ones_like(IND)
    wp = np.where(np.arange(3) == 1, 0.0, np.abs(WP) * -1.0)
    post = _with_method(quiet(make_post, ind, wp, settings={"candidates": [0, 2]}), "bpl")
    s = post.summary()
    assert s["selected"] is None and "p_constraint" not in s["posterior"]
    assert s["posterior"]["in_model"] == {"a": True, "b": False, "c": True}
    pga = s["posterior"]["penalty_given_active"]
    assert pga["median"]["b"] is None and pga["ci90"]["b"] == [None, None] and pga["active_draws"]["b"] == 0
    row_b = next(line for line in post.table().splitlines() if line.startswith("b "))
    assert "1.000" not in row_b and "yes" not in row_b and "[0" not in row_b
    assert row_b.split()[1] == "no"
    assert post.selected() == ["a", "c"]


def test_p_constraint_figures_name_the_frequency(tmp_path):
    pytest.importorskip("matplotlib")
    from pbicrl.analysis.plots import plot_p_constraint, plot_posteriors, plot_run

    def texts(fig):
        out = [fig._suptitle.get_text() if fig._suptitle else ""]
        for ax in fig.axes:
            out += [ax.get_ylabel(), ax.get_title()]
        for sf in getattr(fig, "subfigs", []):
            out.append(sf._suptitle.get_text() if sf._suptitle else "")
        return " ".join(out)

    paper = post_of("paper")
    t = texts(plot_p_constraint(paper)) + texts(plot_posteriors(paper))
    assert "P(c=1)" not in t and "P(constraint" not in t and "frequency on in the chain" in t
    t = texts(plot_p_constraint(post_of("pbicrl")))
    assert "P(constraint | data)" in t
    ind = np.ones_like(IND)
    bpl = _with_method(quiet(make_post, ind, -np.abs(WP), settings={"candidates": [0, 2]}), "bpl")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        files = plot_run(bpl, tmp_path / "plots")
    assert not any(f.stem == "p_constraint" for f in files)  # bpl has no indicators to plot
    assert "P(c=1)" not in texts(plot_posteriors(bpl))


def test_labelling_page_result_names_the_meaning(tmp_path):
    from pbicrl.inference.data import Dataset
    from pbicrl.io.runs import read_run
    from pbicrl.ui.inference import summarise

    def saved(post, name):
        post.save(tmp_path / name)
        return read_run(tmp_path / name)

    rng = np.random.default_rng(0)
    ds = Dataset.from_trajectories([rng.normal(size=(5, 3)) for _ in range(6)], group=[1, 1, 2, 2, 3, 3],
                                   feature_names=("a", "b", "c"))
    res = summarise(saved(post_of("paper"), "paper"), ds)
    assert res["indicator_meaning"] == "chain_frequency" and res["indicator_label"] == "frequency on in the chain"
    assert res["selected"] is None and all("p_constraint" not in f and "selected" not in f for f in res["features"])
    assert res["features"][0]["frequency_on"] == pytest.approx(0.8)
    res = summarise(saved(post_of("pbicrl"), "pbicrl"), ds)
    assert res["selected"] == ["a"] and res["features"][0]["p_constraint"] == pytest.approx(0.8)


def test_bpl_non_candidates_get_no_effective_penalty_or_map_indicator():
    ind = np.ones_like(IND)
    wp = np.where(np.arange(3) == 1, 0.0, -np.abs(WP))
    post = _with_method(quiet(make_post, ind, wp, settings={"candidates": [0, 2]}), "bpl")
    s = post.summary()
    assert s["posterior"]["mean_effective_penalty"]["b"] is None and s["posterior"]["ci90"]["b"] == [None, None]
    assert s["map"]["indicators"]["b"] is None and s["map"]["indicators"]["a"] == 1
    assert s["posterior"]["mean_effective_penalty"]["a"] is not None
