"""Prior-driven is decided per reported number by measurement (issue 29, item 5): the draws are reweighted to the
fitted prior made tenfold wider, and a number that moves (or an interval that reaches a bounded prior's end) is
flagged. A penalty the data pin down is not flagged even when the LP calls its direction unbounded; one whose
far end the prior sets is. A feature the rankings require but the run switches off raises a warning.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from pbicrl.inference.sensitivity import WIDER, log_prior_density, prior_sensitivity
from tests.inference.test_results import make_post, quiet

T = {"kind": "student_t", "support": [None, 0.0], "low": None, "high": 0.0, "mean": 0.0, "scale": 10.0, "df": 3.0}


def _draws(prior_kind: str = "t", n: int = 4000):
    """Two chains over (a, b): a pinned by the data near -5; b's likelihood a step (any w < -3 explains the data),
    so given c = 1 its draws are the prior cut at -3 and its far end is the prior's."""
    rng = np.random.default_rng(1)
    a = rng.normal(-5.0, 0.3, 2 * n)
    if prior_kind == "t":
        b = -np.abs(10.0 * rng.standard_t(3.0, 20 * n))
    else:
        b = rng.uniform(-100.0, 0.0, 20 * n)
    b = b[b < -3.0][: 2 * n]
    ind = np.ones((2, n, 2), dtype=np.int8)
    wp = np.stack([a, b], axis=1).reshape(2, n, 2)
    return ind, wp


def test_log_density_integrates_and_widens():
    x = np.linspace(-2000, 0, 400_001)
    for widen in (1.0, WIDER):
        p = np.exp(log_prior_density(T, x, widen=widen))
        assert np.trapezoid(p, x) == pytest.approx(1.0, abs=2e-3 if widen == 1 else 2e-2)
    flat = {"kind": "flat", "low": -100.0, "high": 0.0}
    assert np.exp(log_prior_density(flat, np.array([-50.0]), widen=WIDER))[0] == pytest.approx(1e-3)


def test_data_pinned_penalty_is_not_flagged_and_a_prior_tail_is():
    ind, wp = _draws()
    s = prior_sensitivity(ind, wp, lambda j: T, np.ones(2, bool))
    assert s.measured
    f = s.flags
    for k in ("given_active_low", "given_active_high", "given_active_median", "given_active_mean",
              "mean_effective_penalty", "ci90_low", "ci90_high"):
        assert f[k][0] is False, k  # a: the data set every number
    assert f["given_active_low"][1] is True and f["given_active_mean"][1] is True  # b: far end and mean
    # b's near end moves too (less): with a step likelihood every quantile above the cut is the prior's
    assert s.wider["given_active_low"][1] - s.fitted["given_active_low"][1] < \
        s.wider["given_active_high"][1] - s.fitted["given_active_high"][1] < 0


def test_posterior_flags_every_reported_number_and_overrides_the_lp_flag():
    ind, wp = _draws()
    # the LP calls both unbounded (a joint direction): only the measurement tells the pinned one apart
    ident = {"alpha": 0.05, "features": {"a": {"min_penalty": 4.0, "unbounded": True},
                                         "b": {"min_penalty": 3.0, "unbounded": True}}}
    post = quiet(make_post, ind, wp, settings={"weight_prior": T}, identified=ident)
    assert post.prior_driven() == [False, True]
    s = json.loads(json.dumps(post.summary()))
    pd = s["posterior"]["prior_driven"]
    assert set(pd) >= {"basis", "p_constraint", "mean_effective_penalty", "ci90", "penalty_given_active"}
    assert pd["mean_effective_penalty"] == {"a": False, "b": True}
    assert pd["ci90"]["a"] == [False, False] and pd["ci90"]["b"][0] is True
    assert pd["penalty_given_active"]["ci90"]["a"] == [False, False]
    assert pd["penalty_given_active"]["ci90"]["b"][0] is True
    assert "tenfold" in pd["basis"] or "10 times wider" in pd["basis"]
    q = s["posterior"]["prior_sensitivity"]["quantities"]["given_active_low"]["b"]
    assert q["wider_prior"] < q["fitted"]  # the far end runs out with the prior
    row_a = next(line for line in post.table().splitlines() if line.startswith("a "))
    assert "*" not in row_a


def test_bounded_prior_flags_an_interval_that_reaches_the_bound():
    ind, wp = _draws("flat")
    flat = {"kind": "flat", "low": -100.0, "high": 0.0, "support": [-100.0, 0.0]}
    post = quiet(make_post, ind, wp, settings={"weight_prior": flat})
    ends = post.end_flags()
    assert ends[0] == (False, False, False)
    assert ends[1][0] is True  # b's draws run to the box's end at -100


def test_latent_samplers_are_not_measured():
    import dataclasses
    ind, wp = _draws()
    post = dataclasses.replace(quiet(make_post, ind, wp, settings={"weight_prior": T}), method="paper",
                               issue_warnings=False)
    assert not post.prior_sensitivity().measured
    assert post.summary()["posterior"]["prior_driven"]["ci90"]["a"] == [None, None]


def test_required_feature_switched_off_is_warned_about():
    rng = np.random.default_rng(0)
    ind = np.zeros((2, 50, 2), dtype=np.int8)
    ind[..., 0] = 1
    ind[:, :10, 1] = 1  # b on in 20% of draws
    wp = np.where(ind == 1, -rng.uniform(1, 60, ind.shape), 0.0)
    ident = {"alpha": 0.05, "features": {"a": {"min_penalty": 0.0, "unbounded": False},
                                         "b": {"min_penalty": 56.25, "unbounded": True}}}
    flat = {"kind": "flat", "low": -1000.0, "high": 0.0}
    post = quiet(make_post, ind, wp, settings={"weight_prior": flat}, identified=ident)
    w = [m for m in post.warnings() if "require" in m and "< 0.5" in m]
    assert len(w) == 1 and w[0].startswith("b:") and "56.25" in w[0] and "0.200" in w[0]
    assert "warning: b: the rankings require" in post.table(width=400)


def test_standard_distributions_equal_scipy_stats():
    from scipy import stats

    from pbicrl.inference.sensitivity import _standard_dist

    z = np.linspace(-40.0, 40.0, 161)
    u = np.linspace(1e-4, 1 - 1e-4, 77)
    for kind, spec, ref in (("normal", {}, stats.norm), ("student_t", {"df": 3.0}, stats.t(3.0)),
                            ("cauchy", {}, stats.t(1.0))):
        d = _standard_dist(kind, spec)
        np.testing.assert_allclose(d.cdf(z), ref.cdf(z), rtol=1e-12, atol=1e-300)
        np.testing.assert_allclose(d.logpdf(z), ref.logpdf(z), rtol=1e-12)
        np.testing.assert_allclose(d.ppf(u), ref.ppf(u), rtol=1e-10)
    assert _standard_dist("student_t", {"df": -1}) is None and _standard_dist("laplace", {}) is None
