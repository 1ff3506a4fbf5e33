"""Posterior summaries that say what the rankings identify: selection, conditional medians, prior-driven
intervals, honest warnings, strict JSON and schema versions of run directories.

Every expected number here is worked out by hand from small hand-made chains (no sampler runs).
"""

from __future__ import annotations

import dataclasses
import json
import re
import warnings
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from pbicrl.analysis import diagnostics
from pbicrl.errors import PbicrlWarning
from pbicrl.inference.draws import split_rhat
from pbicrl.inference.posterior import Posterior, _non_varying
from pbicrl.inference.priors import prior_quantile as _prior_quantile
from pbicrl.inference.summary import MAP_DEFINITION, SCHEMA_VERSION, json_safe
from pbicrl.io.runs import write_run_dir
from pbicrl.io.runs import RunError, read_run

FLAT = {"kind": "flat", "low": -100.0, "high": 100.0}


def make_post(ind: Any, wp: Any, *, names: tuple[str, ...] | None = None, settings: dict | None = None,
              log_likelihood: Any = None, **kw: Any) -> Posterior:
    """A Posterior from hand-made draws (chains, draws, d); the highest-density draw is chain 0, draw 0."""
    ind = np.asarray(ind, dtype=np.int8)
    wp = np.asarray(wp, dtype=np.float64)
    C, D, d = ind.shape
    ll = np.random.default_rng(0).normal(size=(C, D)) if log_likelihood is None else np.asarray(log_likelihood, float)
    counts = np.tile(np.array([10, 5, 10, 5, C * D, 0, 0], dtype=np.int64), (C, 1))
    base = {"iterations": D, "burn_in": 0, "thin": 1, "beta": 1.0, "weight_prior": dict(FLAT),
            "indicator_prior": {"pi": 0.5}, "constraints": None}
    return Posterior(indicators=ind, penalty_weights=wp, log_likelihood=ll, log_prior=np.zeros((C, D)),
                     map_indicators=ind[0, 0].copy(), map_penalty_weights=wp[0, 0].copy(),
                     map_log_posterior=kw.pop("map_log_posterior", 0.0),
                     map_log_likelihood=kw.pop("map_log_likelihood", 0.0),
                     feature_names=names or tuple("abcdefgh"[:d]), sampler="pbicrl", settings=base | (settings or {}),
                     counts=counts, seed=0, runtime_s=0.5, chain_runtime_s=np.full(C, 0.25), **kw)


def quiet(fn: Any, *args: Any, **kw: Any) -> Any:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return fn(*args, **kw)


# Two chains x five draws over features a, b, c. Active sets per draw:
#   chain 0: {a} {a,b} {a} {a,b,c} {b}      chain 1: {a} {a,b} {a,b} {a} {c}
# {a} 4 times, {a,b} 3, {a,b,c} 1, {b} 1, {c} 1 (10 draws). P(c=1): a 8/10, b 5/10, c 2/10.
IND = np.array([[[1, 0, 0], [1, 1, 0], [1, 0, 0], [1, 1, 1], [0, 1, 0]],
                [[1, 0, 0], [1, 1, 0], [1, 1, 0], [1, 0, 0], [0, 0, 1]]])
# w_p: a's active draws -1 .. -8; b's -2, -4, -6 (chain 0) and -8, -10 (chain 1); c's -30 and -10.
# Inactive entries hold a latent 99 (as the paper sampler keeps it): conditional summaries must ignore them.
WP = np.full(IND.shape, 99.0)
WP[0, :4, 0] = [-1, -2, -3, -4]
WP[1, :4, 0] = [-5, -6, -7, -8]
WP[0, [1, 3, 4], 1] = [-2, -4, -6]
WP[1, [1, 2], 1] = [-8, -10]
WP[0, 3, 2], WP[1, 4, 2] = -30, -10


@pytest.fixture()
def hand() -> Posterior:
    return quiet(make_post, IND, WP)


# ---------------------------------------------------------------------------------------------- selection
def test_selected_is_the_median_probability_set(hand):
    np.testing.assert_allclose(hand.p_constraint, [0.8, 0.5, 0.2])
    assert hand.selected() == ["a"]  # b has exactly 0.5: not selected (strictly more than half)
    s = hand.summary()
    assert s["selected"] == ["a"]
    assert s["schema_version"] == SCHEMA_VERSION == 3
    assert s["sampler"] == "pbicrl" and "method" not in s


def test_most_frequent_set_counts_all_chains(hand):
    assert hand.most_frequent_set() == {"features": ["a"], "frequency": pytest.approx(0.4)}
    assert hand.summary()["most_frequent_set"] == {"features": ["a"], "frequency": pytest.approx(0.4)}


def test_most_frequent_set_ties_go_to_the_smaller_set():
    ind = np.array([[[1, 1], [1, 0], [1, 1], [1, 0]]])  # {a,b} twice, {a} twice
    post = quiet(make_post, ind, np.where(ind == 1, -1.0, 0.0))
    assert post.most_frequent_set() == {"features": ["a"], "frequency": 0.5}


def test_conditional_summaries_use_active_draws_only(hand):
    s = hand.conditional_summary()
    np.testing.assert_allclose(s["median"], [-4.5, -6.0, -20.0])
    np.testing.assert_allclose(s["mean"], [-4.5, -6.0, -20.0])
    np.testing.assert_array_equal(s["active_draws"], [8, 5, 2])
    # numpy's linear quantiles of -8..-1: position 0.05 * 7 = 0.35 -> -7.65; 0.95 * 7 = 6.65 -> -1.35
    assert s["low"][0] == pytest.approx(-7.65) and s["high"][0] == pytest.approx(-1.35)
    np.testing.assert_allclose(hand.conditional_median(), [-4.5, -6.0, -20.0])
    pga = hand.summary()["posterior"]["penalty_given_active"]
    assert pga["median"] == {"a": -4.5, "b": -6.0, "c": -20.0}
    assert pga["ci90"]["a"] == [pytest.approx(-7.65), pytest.approx(-1.35)]
    assert pga["active_draws"] == {"a": 8, "b": 5, "c": 2}
    mean, ci = hand.conditional_penalty()  # the older API gives the same numbers
    np.testing.assert_allclose(mean, [-4.5, -6.0, -20.0])
    assert ci[0, 0] == pytest.approx(-7.65)


def test_never_active_feature_has_null_conditional_summary():
    ind = np.zeros((2, 4, 2), np.int8)
    ind[:, :, 0] = 1
    post = quiet(make_post, ind, np.where(ind == 1, -2.0, 0.0))
    s = post.summary()["posterior"]["penalty_given_active"]
    assert s["median"]["b"] is None and s["ci90"]["b"] == [None, None] and s["prior_driven"]["b"] is None


def test_point_estimates(hand):
    eff, theta = hand.point_estimate()  # selected set, conditional medians
    np.testing.assert_allclose(eff, [-4.5, 0.0, 0.0])
    assert theta.shape == (0,)
    eff, _ = hand.point_estimate("map")  # chain 0, draw 0: {a} with -1
    np.testing.assert_allclose(eff, [-1.0, 0.0, 0.0])
    eff, _ = hand.point_estimate("mean")  # mean of c_j w_pj over 10 draws
    np.testing.assert_allclose(eff, [-36 / 10, -30 / 10, -40 / 10])
    with pytest.raises(ValueError, match="estimator"):
        hand.point_estimate("mode")


def test_parameters_conditional_and_point_estimate():
    # feature 1 is a parametric constraint "wall" with one parameter, on in draws 0-2 of each chain
    ind = np.zeros((2, 4, 2), np.int8)
    ind[:, :, 0] = 1
    ind[:, :3, 1] = 1
    wp = np.where(ind == 1, -5.0, 0.0)
    th = np.full((2, 4, 1), np.nan)
    th[0, :3, 0] = [7.0, 8.0, 9.0]
    th[1, :3, 0] = [8.0, 8.5, 30.0]
    th[1, 3, 0] = 100.0  # not active: ignored even though finite
    cons = {"constraints": [{"family": "axis_halfspace", "name": "wall", "resolved_bounds": [[0.0, 20.0]]}]}
    post = quiet(make_post, ind, wp, names=("a", "wall"), settings=cons, parameters=th,
                 map_parameters=np.array([7.0]), parameter_names=("wall.threshold",), parameter_owner=(1,))
    ps = post.summary()["posterior"]["parameters"]["wall.threshold"]
    assert ps["median"] == pytest.approx(8.25) and ps["active_draws"] == 6  # median of 7, 8, 8, 8.5, 9, 30
    assert ps["mean"] == pytest.approx(70.5 / 6)
    # heuristic: the 95% quantile (lands between 9 and 30) is beyond the uniform prior's 19: prior-driven
    assert ps["prior_driven"] is True and ps["identified_range"] is None
    eff, theta = post.point_estimate()
    np.testing.assert_allclose(eff, [-5.0, -5.0])
    np.testing.assert_allclose(theta, [8.25])


@pytest.mark.parametrize("rng, expected", [([6.5, None], True), ([6.5, 62.0], True), ([7.5, 8.5], False)])
def test_parameter_prior_driven_from_identified_range(rng, expected):
    ind = np.ones((2, 4, 1), np.int8)
    th = np.full((2, 4, 1), 8.0) + np.arange(4)[None, :, None] * 0.1
    cons = {"constraints": [{"family": "axis_halfspace", "name": "wall", "resolved_bounds": [[0.0, 20.0]]}]}
    ident = {"separable": True, "alpha": 0.05, "features": {}, "parameters": {"wall.threshold": rng}}
    post = quiet(make_post, ind, -np.ones((2, 4, 1)), names=("wall",), settings=cons, parameters=th,
                 map_parameters=np.array([8.0]), parameter_names=("wall.threshold",), parameter_owner=(0,),
                 identified=ident)
    ps = post.parameter_summary()["wall.threshold"]
    assert ps["identified_range"] == rng and ps["prior_driven"] is expected


# ---------------------------------------------------------------------------------------------- prior-driven
def test_prior_driven_is_measured_not_copied_from_the_identification():
    # The LP calls a unbounded and b bounded; the draws say otherwise: a sits near -5 whatever the prior, b's
    # draws pile at the flat prior's bound -100. The measurement (reweighting to a tenfold wider prior, bound
    # reached) wins; the identification's flag is only the fallback where nothing can be measured.
    import dataclasses
    rng = np.random.default_rng(1)
    ind = np.ones((2, 50, 2), np.int8)
    wp = np.stack([rng.normal(-5, 0.5, (2, 50)), rng.uniform(-100, -90, (2, 50))], axis=-1)
    ident = {"separable": True, "alpha": 0.05, "unbounded_directions": [], "parameters": {},
             "features": {"a": {"min_penalty": 56.0, "unbounded": True, "direction": "-inf", "identifiable": True,
                                "reason": "separates the groups"},
                          "b": {"min_penalty": 0.0, "unbounded": False, "direction": None, "identifiable": True,
                                "reason": "bounded"}}}
    assert quiet(make_post, ind, wp).prior_driven() == [False, True]
    post = quiet(make_post, ind, wp, identified=ident)
    assert post.prior_driven() == [False, True]
    s = post.summary()
    assert s["posterior"]["penalty_given_active"]["prior_driven"] == {"a": False, "b": True}
    assert s["identified"]["features"]["a"]["min_penalty"] == 56.0
    assert post.min_penalty() == [56.0, 0.0]
    # the paper sampler ignores the prior: nothing to measure, so the identification's flag is used
    paper = dataclasses.replace(post, sampler="paper", issue_warnings=False)
    assert paper.prior_driven() == [True, False]
    assert paper.summary()["posterior"]["penalty_given_active"]["prior_driven"] == {"a": True, "b": False}


def test_prior_driven_measured_without_identification():
    # flat prior on [-100, 100]: given c = 1, a's draws fill [-100, -10] and reach the bound (prior-driven);
    # b's sit near -5 (not); c is never on (unknown).
    ind = np.ones((2, 100, 3), np.int8)
    ind[:, :, 2] = 0
    a = np.linspace(-100, -10, 200).reshape(2, 100)
    b = -5 + 0.01 * np.arange(200).reshape(2, 100)
    wp = np.stack([a, b, np.zeros((2, 100))], axis=-1)
    post = quiet(make_post, ind, wp)
    assert _prior_quantile(FLAT, 0.05) == pytest.approx(-90.0)
    assert post.prior_driven() == [True, False, None]
    msgs = post.warnings()
    sep = [m for m in msgs if "tenfold wider" in m]
    assert len(sep) == 1 and sep[0].startswith("a (") and "b (" not in sep[0]
    assert "margins raise the lower bound only" in sep[0] and "use margins to set the scale" not in sep[0]
    # positive medians look at the upper end
    post = quiet(make_post, ind, -wp)
    assert post.prior_driven() == [True, False, None]


def test_prior_quantiles_of_other_kinds():
    # half-normal on (-inf, 0] with scale 10: its 5% quantile is -10 * z_0.975 = -19.6
    assert _prior_quantile({"kind": "normal", "mean": 0.0, "scale": 10.0, "support": [None, 0.0]}, 0.05) == \
        pytest.approx(-19.59964, abs=1e-4)
    # half-Cauchy on (-inf, 0], scale 1: 5% quantile -tan(0.95 pi / 2) = -12.706
    assert _prior_quantile({"kind": "student_t", "df": 1, "mean": 0.0, "scale": 1.0, "support": [None, 0.0]},
                           0.05) == pytest.approx(-12.7062, rel=1e-4)
    # a flat prior's support overrides its symmetric low / high
    assert _prior_quantile({"kind": "flat", "low": -50, "high": 50, "support": [-50, 0]}, 0.05) == pytest.approx(-47.5)
    assert _prior_quantile({"kind": "improper"}, 0.05) is None
    assert _prior_quantile({"kind": "student_t", "df": 3, "scale": None}, 0.05) is None  # unresolved scale


def test_per_feature_prior_summary_is_used():
    # an attached prior summary with per-feature scales (by index, as a resolved prior writes them)
    prior = {"kind": "normal", "sign": "negative", "mean": 0.0, "scale": None, "support": [None, 0.0],
             "features": {"0": {"scale": 1.0}, "1": {"scale": 1000.0}}}
    ind = np.ones((1, 4000, 2), np.int8)
    draws = np.linspace(-3, -2.5, 4000)  # beyond the 5% quantile -1.96 of a half-normal with scale 1 only
    other = np.random.default_rng(0).permutation(draws)  # independent of the first (the reweighting is joint)
    post = quiet(make_post, ind, np.stack([draws, other], axis=-1)[None], prior=prior)
    assert post.prior_driven() == [True, False]
    assert post.summary()["prior"] == json_safe(prior)


# ---------------------------------------------------------------------------------------------- warnings
def test_identification_warnings_name_every_unbounded_feature():
    ind = np.ones((2, 20, 3), np.int8)
    wp = -np.abs(np.random.default_rng(2).normal(5, 1, (2, 20, 3)))
    ident = {"separable": True, "alpha": 0.05, "parameters": {}, "unbounded_directions": [],
             "features": {"a": {"min_penalty": 56.0, "unbounded": True, "direction": "-inf", "identifiable": True},
                          "b": {"min_penalty": 351.0, "unbounded": True, "direction": "-inf", "identifiable": True},
                          "c": {"min_penalty": 0.0, "unbounded": False, "direction": None, "identifiable": True}}}
    msgs = quiet(make_post, ind, wp, identified=ident).warnings()
    a = [m for m in msgs if m.startswith("a:")]
    b = [m for m in msgs if m.startswith("b:")]
    # issue 30 item 8: one short line per feature (the long explanation is in the docs and summary.json)
    assert a == ["a: |w_p| >= 56 identified; magnitude beyond that is the prior's"]
    assert b == ["b: |w_p| >= 351 identified; magnitude beyond that is the prior's"]
    assert not any(m.startswith("c:") for m in msgs)
    # an older run's long per-feature paragraphs become the short lines; messages about no feature are kept
    given = ident | {"warnings": ["a: penalty unbounded by the data - " + "long " * 80, "rankings are noisy"]}
    msgs = quiet(make_post, ind, wp, identified=given).warnings()
    assert msgs[:3] == [a[0], b[0], "rankings are noisy"] and max(len(m) for m in msgs[:3]) < 80


def test_an_identification_object_is_converted():
    obj = SimpleNamespace(to_dict=lambda: {"separable": False, "alpha": 0.1, "features": {}, "parameters": {}},
                          warnings=lambda: ["rankings are noisy"])
    post = quiet(make_post, IND, WP, identified=obj)
    assert post.identified == {"separable": False, "alpha": 0.1, "features": {}, "parameters": {},
                               "warnings": ["rankings are noisy"]}
    assert "rankings are noisy" in post.warnings()
    with pytest.raises(TypeError, match="identified"):
        make_post(IND, WP, identified=42)


def _pbicrl_messages(rec: list[warnings.WarningMessage]) -> list[str]:
    return [str(r.message) for r in rec if issubclass(r.category, PbicrlWarning)]


def test_warnings_are_issued_once_when_built():
    ind = np.ones((2, 100, 2), np.int8)
    a = np.linspace(-100, -10, 200).reshape(2, 100)
    wp = np.stack([a, np.full((2, 100), -3.0)], axis=-1)
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        post = make_post(ind, wp, log_likelihood=np.zeros((2, 100)))
    issued = _pbicrl_messages(rec)
    expected = post.warnings()
    assert expected and any("tenfold wider" in m for m in expected)
    assert sorted(issued) == sorted(expected) and len(set(issued)) == len(issued)
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        post.warnings(), post.summary(), post.table()
    assert _pbicrl_messages(rec) == []
    # attaching an identification issues its new messages only
    ident = {"separable": True, "alpha": 0.05, "parameters": {},
             "features": {"a": {"min_penalty": 12.0, "unbounded": True, "identifiable": True}}}
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        new = post.attach(identified=ident)
    got = _pbicrl_messages(rec)
    assert len(got) == 1 and "|w_p| >= 12" in got[0]
    assert new.identified["features"]["a"]["min_penalty"] == 12.0 and post.identified is None
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        quiet_post = make_post(ind, wp, issue_warnings=False)
    assert _pbicrl_messages(rec) == [] and quiet_post.warnings()


def test_warnings_can_be_turned_into_errors():
    ind = np.ones((2, 100, 1), np.int8)
    wp = np.linspace(-100, -10, 200).reshape(2, 100, 1)
    with warnings.catch_warnings():
        warnings.simplefilter("error", PbicrlWarning)
        with pytest.raises(PbicrlWarning, match="tenfold wider"):
            make_post(ind, wp)


# ---------------------------------------------------------------------------------------------- not identifiable
def test_constant_features_get_null_rhat_and_no_warning():
    rng = np.random.default_rng(3)
    C, D = 4, 200
    ind = np.ones((C, D, 2), np.int8)
    wp = rng.normal(-5, 1, (C, D, 2))
    wp[:, :, 1] += np.arange(C)[:, None] * 50  # chains far apart: R-hat of "b" would be huge
    ind[0, :, 1] = 0
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        post = make_post(ind, wp, non_varying=("b",), log_likelihood=rng.normal(size=(C, D)))
    assert not any(re.search(r"\bb \(", m) for m in _pbicrl_messages(rec))
    assert post.not_identifiable() == {"b": "constant across trajectories: the likelihood does not depend on its "
                                            "penalty"}
    s = post.summary()
    assert s["not_identifiable"] == post.not_identifiable()
    assert s["posterior"]["rhat"]["effective_penalty"]["b"] is None
    assert s["posterior"]["rhat"]["indicator"]["b"] is None
    assert s["posterior"]["diagnostics"]["penalty"]["b"] == {"rhat": None, "ess_bulk": None, "ess_tail": None}
    assert s["posterior"]["diagnostics"]["indicator"]["b"]["rhat"] is None
    assert s["posterior"]["diagnostics"]["not_identifiable"] == {"b": post.not_identifiable()["b"]}
    assert s["posterior"]["rhat"]["effective_penalty"]["a"] is not None
    assert not any(re.search(r"\bb \(", m) for m in post.warnings())
    table = post.table()
    assert "not identifiable (no R-hat/ESS): b" in table
    row = next(line for line in table.splitlines() if line.startswith("b "))
    assert " n/a " in row
    # without the flag the same draws do raise an R-hat warning: the exclusion is what silences it
    other = quiet(make_post, ind, wp, log_likelihood=rng.normal(size=(C, D)))
    assert any("b (" in m for m in other.warnings() if "R-hat" in m)


def test_identification_marks_features_not_identifiable():
    ident = {"separable": True, "alpha": 0.05, "parameters": {},
             "features": {"c": {"min_penalty": None, "unbounded": False, "identifiable": False,
                                "reason": "constant feature"}}}
    post = quiet(make_post, IND, WP, identified=ident)
    assert post.not_identifiable() == {"c": "constant feature"}
    assert post.diagnostics().values["penalty"]["c"]["rhat"] is None


def test_non_varying_features_are_found_in_the_data():
    F = np.array([[1.0, 0.3, 2.0], [2.0, 0.3, 2.0], [3.0, 0.3, 2.0 + 1e-3]])
    kernel = SimpleNamespace(likelihood=SimpleNamespace(mean_features=F), constraints=None,
                             settings=SimpleNamespace(candidates=None))
    assert _non_varying(kernel, ("x", "y", "z")) == ("y",)
    kernel.settings.candidates = (0, 2)  # non-candidates are not reported
    assert _non_varying(kernel, ("x", "y", "z")) == ()


def test_split_rhat_of_constant_draws_is_undefined():
    assert np.isnan(split_rhat(np.ones((4, 100))))
    x = np.zeros((2, 100))
    x[1] = 1.0
    assert split_rhat(x) == float("inf")


# ---------------------------------------------------------------------------------------------- strict JSON
def _strict_loads(text: str) -> Any:
    def refuse(token: str) -> Any:
        raise ValueError(f"non-finite JSON constant {token}")

    return json.loads(text, parse_constant=refuse)


def test_summary_json_never_holds_nan_or_infinity(tmp_path):
    ll = np.full((2, 5), np.nan)
    ll[0, 0] = -np.inf
    post = quiet(make_post, IND, WP, log_likelihood=ll, map_log_posterior=float("nan"),
                 map_log_likelihood=float("-inf"), extra={"x": float("inf"), "arr": np.array([np.nan, 1.0])})
    s = post.summary()
    json.dumps(s, allow_nan=False)  # raises on NaN / inf
    assert s["map"]["log_posterior"] is None and s["map"]["log_likelihood"] is None
    assert s["extra"] == {"x": None, "arr": [None, 1.0]}
    assert s["map"]["definition"] == MAP_DEFINITION
    assert any("log-likelihood is NaN or infinite in 10 of 10" in m for m in s["warnings"])
    run = post.save(tmp_path / "run")
    back = _strict_loads((run / "summary.json").read_text())
    assert back["map"]["log_posterior"] is None


def test_write_run_dir_converts_non_finite_values(tmp_path):
    out = write_run_dir(tmp_path / "r", {"a.json": {"nan": float("nan"), "v": np.array([1.0, np.inf]),
                                                    "n": np.int64(3), "t": (1, 2)}}, {})
    assert _strict_loads((out / "a.json").read_text()) == {"nan": None, "v": [1.0, None], "n": 3, "t": [1, 2]}
    with pytest.raises(TypeError, match="not JSON serialisable"):
        write_run_dir(tmp_path / "bad", {"a.json": {"x": object()}}, {})
    assert not (tmp_path / "bad").exists()


# ---------------------------------------------------------------------------------------------- tables
def test_table_leads_with_selection_and_fits_100_columns():
    rng = np.random.default_rng(4)
    ind = np.ones((2, 100, 3), np.int8)
    ind[:, :, 2] = rng.random((2, 100)) < 0.2
    wp = np.stack([np.linspace(-100, -10, 200).reshape(2, 100), rng.normal(-5, 0.1, (2, 100)),
                   rng.normal(-1, 0.1, (2, 100))], axis=-1)
    names = ("constraint_with_a_rather_long_name", "b", "c")
    ident = {"separable": True, "alpha": 0.05, "parameters": {},
             "features": {names[0]: {"min_penalty": 56.0, "unbounded": True, "identifiable": True}}}
    post = quiet(make_post, ind, wp, names=names, identified=ident)
    table = post.table()
    lines = table.splitlines()
    assert max(len(line) for line in lines) <= 100
    head = lines[0].split()
    assert head[:4] == ["feature", "P(c=1)", "sel", "min|w_p|"]
    rows = {line.split()[0]: line for line in lines[2:5]}
    long_row = next(r for k, r in rows.items() if k.startswith("constraint_with"))
    assert " yes " in long_row and " 56 " in long_row and "*" in long_row
    assert " no " in rows["c"] and rows["c"].split()[3] == "-"
    assert "* prior-driven (measured:" in table and "constraint_with_a_rather_long_name" in table.split(
        "* prior-driven")[1]
    assert "selected (P(c=1) > 0.5): constraint_with_a_rather_long_name, b" in table
    assert "min|w_p|: smallest penalty" in table


def test_table_without_identification_says_so(hand):
    table = hand.table()
    assert "min|w_p|: '-' (no identification attached)" in table
    row = next(line for line in table.splitlines() if line.startswith("a "))
    # P(c=1) under a flat box moves with its width (a tenfold wider box divides the prior odds by ten): starred
    assert row.split()[1:5] == ["0.800*", "yes", "-", "-4.5"]


# ---------------------------------------------------------------------------------------------- run directories
def _as_version_2(run: Path) -> None:
    """Rewrite a run directory as pbicrl wrote it before the sampler was called ``sampler`` (schema 2)."""
    s = json.loads((run / "summary.json").read_text())
    s["schema_version"] = 2
    s["method"] = s.pop("sampler")
    if "sampler" in s["settings"]:  # runs of the samplers record it there (make_post's hand-made settings do not)
        s["settings"]["method"] = s["settings"].pop("sampler")
    if isinstance(s.get("prior"), dict) and "sampler" in s["prior"]:
        s["prior"]["method"] = s["prior"].pop("sampler")
    (run / "summary.json").write_text(json.dumps(s))


def test_a_version_2_run_loads_with_its_sampler_under_the_new_name(tmp_path):
    post = quiet(make_post, IND, WP, settings={"thin": 1})
    post = dataclasses.replace(post, sampler="paper", issue_warnings=False)
    run = post.save(tmp_path / "run")
    _as_version_2(run)
    rec = read_run(run)
    assert rec.schema_version == 2 and rec.sampler == "paper"
    with pytest.warns(PbicrlWarning, match="RunRecord.method is deprecated"):
        assert rec.method == "paper"
    back = Posterior.load(run, issue_warnings=False)
    assert back.sampler == "paper" and back.indicator_meaning == "chain_frequency"
    assert back.table() == post.table()
    resaved = json.loads((back.save(tmp_path / "again") / "summary.json").read_text())
    assert resaved["schema_version"] == SCHEMA_VERSION and resaved["sampler"] == "paper"


def test_the_old_name_of_the_sampler_still_builds_and_reads_a_posterior():
    post = quiet(make_post, IND, WP)
    given = {f.name: getattr(post, f.name) for f in dataclasses.fields(post) if f.name != "sampler"}
    with pytest.warns(PbicrlWarning, match="Posterior argument 'method' is deprecated.*'sampler'"):
        old = Posterior(**(given | {"issue_warnings": False}), method="paper")
    assert old.sampler == "paper"
    with pytest.warns(PbicrlWarning, match="Posterior.method is deprecated.*Posterior.sampler"):
        assert old.method == "paper"


def _as_version_1(run: Path) -> None:
    """Rewrite a run directory as the previous pbicrl wrote it (no schema_version, no new keys)."""
    s = json.loads((run / "summary.json").read_text())
    for k in ("schema_version", "selected", "most_frequent_set", "not_identifiable", "identified", "prior"):
        s.pop(k)
    s["method"] = s.pop("sampler")
    if "sampler" in s["settings"]:
        s["settings"]["method"] = s["settings"].pop("sampler")
    s["map"].pop("definition")
    pga = s["posterior"]["penalty_given_active"]
    s["posterior"]["penalty_given_active"] = {"mean": pga["mean"], "ci90": pga["ci90"]}
    s["posterior"]["diagnostics"].pop("not_identifiable")
    s["map"]["log_posterior"] = float("nan")  # version 1 could hold a NaN literal (Python's json reads it)
    (run / "summary.json").write_text(json.dumps(s))
    with np.load(run / "chains.npz") as z:
        arrays = {k: z[k] for k in z.files if k != "parameter_owner"}
    np.savez_compressed(run / "chains.npz", **arrays)


def test_version_1_run_directories_still_load(tmp_path, hand):
    run = hand.save(tmp_path / "run")
    _as_version_1(run)
    rec = read_run(run)
    assert rec.schema_version == 1 and rec.identified is None and rec.not_identifiable() == {}
    assert rec.selected() == ["a"]
    assert rec.most_frequent_set() == {"features": ["a"], "frequency": pytest.approx(0.4)}
    np.testing.assert_allclose(rec.conditional_median(), [-4.5, -6.0, -20.0])
    np.testing.assert_allclose(rec.point_estimate()[0], [-4.5, 0.0, 0.0])
    assert diagnostics.compute(rec).to_dict()["penalty"] == hand.diagnostics().to_dict()["penalty"]


def test_version_1_run_directories_load_as_posteriors(tmp_path, hand):
    from pbicrl import load_run as load_posterior
    run = hand.save(tmp_path / "run")
    _as_version_1(run)
    post = load_posterior(run, issue_warnings=False)
    assert isinstance(post, Posterior) and post.identified is None
    assert post.selected() == ["a"] and np.isnan(post.map_log_posterior)  # v1 could hold NaN; now unknown
    np.testing.assert_array_equal(post.indicators, hand.indicators)
    assert post.summary()["schema_version"] == SCHEMA_VERSION  # re-saved in the current layout
    assert "a " in post.table()


def test_hand_posteriors_round_trip_exactly(tmp_path):
    ident = {"separable": True, "alpha": 0.05, "parameters": {},
             "features": {"c": {"min_penalty": None, "unbounded": False, "identifiable": False, "reason": "constant"},
                          "a": {"min_penalty": float("inf"), "unbounded": True, "identifiable": True}}}
    post = quiet(make_post, IND, WP, identified=ident)
    back = Posterior.load(post.save(tmp_path / "run"), issue_warnings=False)
    assert back.table() == post.table()
    assert json.dumps(back.summary(), sort_keys=True) == json.dumps(post.summary(), sort_keys=True)
    assert back.prior_driven() == post.prior_driven() and back.not_identifiable() == post.not_identifiable()


def test_round_trip_keeps_identification(tmp_path):
    ident = {"separable": True, "alpha": 0.05, "parameters": {},
             "features": {"c": {"min_penalty": None, "unbounded": False, "identifiable": False, "reason": "constant"}}}
    post = quiet(make_post, IND, WP, identified=ident)
    rec = read_run(post.save(tmp_path / "run"))
    assert rec.schema_version == SCHEMA_VERSION
    assert rec.identified == json_safe(post.identified)
    assert rec.not_identifiable() == {"c": "constant"}
    assert diagnostics.compute(rec).to_dict()["penalty"]["c"]["rhat"] is None


@pytest.mark.parametrize("version, match", [(4, "newer pbicrl"), ("2", "positive integer"), (0, "positive integer")])
def test_unreadable_schema_versions_are_named(tmp_path, hand, version, match):
    run = hand.save(tmp_path / "run")
    s = json.loads((run / "summary.json").read_text())
    s["schema_version"] = version
    (run / "summary.json").write_text(json.dumps(s))
    with pytest.raises(RunError, match=match):
        read_run(run)


def test_diagnose_command_reads_version_1(tmp_path, hand, capsys):
    from pbicrl.cli import main

    run = hand.save(tmp_path / "run")
    _as_version_1(run)
    assert main(["diagnose", str(run)]) == 0
    assert "penalty[a]" in capsys.readouterr().out


def test_poor_mixing_of_correlated_penalties_points_to_the_joint_step():
    """Single-weight moves on two strongly correlated penalties (r ~ 0.97 here) mix slowly: the warnings say
    which pair and name the joint step; a run that used it gets no such line."""
    import pbicrl
    from pbicrl.inference.synthetic import make_problem

    ds = make_problem(200, labels="violations", violation_rate=0.4, seed=0).dataset
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", PbicrlWarning)
        # the single-site moves on w of earlier releases (log_moves=False): the hint is about them
        single = pbicrl.infer(ds, iterations=3000, chains=2, jobs=1, seed=0, progress=False, log_moves=False)
        joint = pbicrl.infer(ds, iterations=3000, chains=2, jobs=1, seed=0, progress=False, p_joint=0.4,
                             log_moves=False)
    hint = [m for m in single.warnings() if "joint weight step" in m]
    assert len(hint) == 1
    assert "constraint1 and constraint2" in hint[0] and "--p-joint 0.4" in hint[0]
    r = float(re.search(r"r = ([+-][0-9.]+)", hint[0]).group(1))
    assert 0.8 <= abs(r) <= 1.0
    assert not [m for m in joint.warnings() if "joint weight step" in m]
