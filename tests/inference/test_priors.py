"""Weight priors: validation, normalised truncated densities, exact sampling, scale resolution."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from pbicrl.inference.priors import (
    PARAMETRIC_FEATURE_SD,
    IndicatorPrior,
    PriorError,
    WeightPrior,
    feature_sd,
    truncated_normal_ppf,
)

# one-feature priors covering every kind, sign and truncation shape (including far-tail supports)
PRIORS = {
    "default half-t": WeightPrior(scale=2.0),
    "t any df3": WeightPrior(scale=2.0, sign="any"),
    "t df1 [-50,-1]": WeightPrior(low=-50.0, high=-1.0, scale=0.5, df=1.0),
    "t df30 shifted": WeightPrior(low=-10.0, mean=-3.0, scale=1.5, df=30.0, sign="any"),
    "t far tail [40,400]": WeightPrior(low=40.0, high=400.0, scale=1.0, sign="any"),
    "normal(0,3) [-3,3]": WeightPrior("normal", -3.0, 3.0, scale=3.0, sign="any"),
    "half-normal": WeightPrior("normal", scale=5.0),
    "normal far tail [-60,-50]": WeightPrior("normal", -60.0, -50.0, scale=1.0),
    "normal mean>0 negative": WeightPrior("normal", mean=2.0, scale=1.0),
    "flat negative": WeightPrior("flat", -8.0, 8.0),
}


def _scipy_cdf(prior: WeightPrior):
    """Oracle CDF of the truncated one-feature prior from scipy.stats (in logs: the far-tail cases underflow)."""
    stats = pytest.importorskip("scipy.stats")
    lo, hi = prior.support
    if prior.kind == "flat":
        return lambda x: np.clip((np.asarray(x) - lo) / (hi - lo), 0.0, 1.0)
    base = (stats.norm(prior.mean, prior.scale) if prior.kind == "normal"
            else stats.t(prior.df, prior.mean, prior.scale))

    def cdf(x):
        x = np.clip(np.asarray(x, dtype=float), lo, hi)
        with np.errstate(divide="ignore", invalid="ignore"):
            if hi <= prior.mean:  # lower tail: from log F
                lf = base.logcdf(x)
                num = np.exp(lf - base.logcdf(hi)) * -np.expm1(base.logcdf(lo) - lf)
                out = num / -np.expm1(base.logcdf(lo) - base.logcdf(hi))
            elif lo >= prior.mean:  # upper tail: from log S
                ls = base.logsf(lo)
                out = -np.expm1(base.logsf(x) - ls) / -np.expm1(base.logsf(hi) - ls)
            else:
                out = (base.cdf(x) - base.cdf(lo)) / (base.cdf(hi) - base.cdf(lo))
        return np.clip(np.nan_to_num(out, nan=0.0), 0.0, 1.0)

    return cdf


def test_defaults():
    p = WeightPrior()
    assert (p.kind, p.sign, p.df, p.prior_scale, p.scale, p.mean) == ("student_t", "negative", 3.0, 2.5, None, 0.0)
    assert p.support == (-math.inf, 0.0) and p.scale_aware
    assert WeightPrior("flat").support == (-1000.0, 0.0)
    assert WeightPrior("flat", sign="any").support == (-1000.0, 1000.0)
    assert WeightPrior("flat", -5, 5).support == (-5.0, 0.0)
    assert WeightPrior("student-t").kind == "student_t" and WeightPrior("uniform").kind == "flat"
    assert WeightPrior("improper", sign="any").support == (-math.inf, math.inf)
    d = WeightPrior().to_dict()
    json.dumps(d, allow_nan=False)
    assert d["support"] == [None, 0.0] and d["low"] is None and d["high"] is None


@pytest.mark.parametrize("kwargs, message", [
    ({"kind": "cauchy"}, "unknown kind"),
    ({"sign": "positive"}, "sign"),
    ({"kind": "flat", "low": 1.0, "high": 5.0}, "empty"),
    ({"low": 0.0}, "empty"),
    ({"kind": "flat", "low": -math.inf}, "finite bounds"),
    ({"low": 2.0, "high": 1.0, "sign": "any"}, "low < high"),
    ({"scale": 0.0}, "scale"),
    ({"df": 0.0}, "df"),
    ({"df": 1e9}, "df"),
    ({"prior_scale": -1.0}, "prior_scale"),
    ({"mean": math.nan}, "mean"),
])
def test_validation(kwargs, message):
    with pytest.raises(PriorError, match=message):
        WeightPrior(**kwargs)


def test_scale_aware_prior_needs_data():
    with pytest.raises(PriorError, match="scale-aware"):
        WeightPrior().logpdf(-1.0)
    with pytest.raises(PriorError, match="scale-aware"):
        WeightPrior("normal").sample(np.random.default_rng(0), 3)
    with pytest.raises(PriorError, match="improper"):
        WeightPrior("improper").sample(np.random.default_rng(0), 3)


def test_far_tail_support_is_normalised_in_logs():
    """N(0, 1) on [1e4, 1e4 + 1]: the mass (~exp(-5e7)) underflows, its log does not; density ~ a e^{-a(w-a)}."""
    p = WeightPrior("normal", 1e4, 1e4 + 1, scale=1.0, sign="any")
    assert float(p.logpdf(1e4)) == pytest.approx(math.log(1e4), rel=1e-6)
    assert float(p.logpdf(1e4 + 1e-4)) == pytest.approx(math.log(1e4) - 1.0, rel=1e-4)
    x = p.sample(np.random.default_rng(0), 200)
    assert np.all((x >= 1e4) & (x <= 1e4 + 1)) and np.mean(x - 1e4) == pytest.approx(1e-4, rel=0.2)


def test_scale_resolution_and_feature_sd():
    rng = np.random.default_rng(0)
    F = np.c_[rng.normal(0, 2.0, 50), rng.normal(5, 0.1, 50), np.full(50, 3.0)]
    sd, src = feature_sd(F, n_parametric=2)
    np.testing.assert_allclose(sd[:2], F[:, :2].std(axis=0))
    assert sd[2] == 0.0 and np.all(sd[3:] == PARAMETRIC_FEATURE_SD)
    assert src == ("data", "data", "constant", "parametric", "parametric")
    rp = WeightPrior().resolve(F, beta=2.0, n_parametric=2)
    expected = 2.5 / (2.0 * np.array([sd[0], sd[1], 1.0, 0.5, 0.5]))  # constant feature: sd 1 fallback
    np.testing.assert_allclose(rp.scale, expected)
    np.testing.assert_allclose(rp.unit, expected / 2.5)
    # rescaling one feature rescales its scale only
    D = np.array([10.0, 1.0, 1.0])
    rp10 = WeightPrior().resolve(F * D, beta=2.0, n_parametric=2)
    np.testing.assert_allclose(rp10.scale * np.r_[D, 1.0, 1.0], rp.scale, rtol=1e-12)
    np.testing.assert_allclose(rp10.log_norm + np.log(np.r_[D, 1.0, 1.0]), rp.log_norm, rtol=0, atol=1e-12)
    # absolute scales and flat priors ignore the data
    np.testing.assert_array_equal(WeightPrior(scale=4.0).resolve(F).scale, 4.0)
    assert np.all(WeightPrior("flat", -10, 10).resolve(F).unit == 1.0)
    summary = rp.to_dict()
    json.dumps(summary, allow_nan=False)
    assert summary["features"]["2"]["sd_source"] == "constant" and summary["features"]["3"]["scale"] == pytest.approx(2.5)


@pytest.mark.parametrize("name", list(PRIORS))
def test_density_integrates_to_one(name):
    integrate = pytest.importorskip("scipy.integrate")
    prior = PRIORS[name]
    lo, hi = prior.support
    # split at the location and a few scales around it so quad sees the bulk of the mass
    pts = sorted({x for x in (lo, hi, prior.mean, prior.mean - 5 * (prior.scale or 1), prior.mean + 5 * (prior.scale or 1))
                  if lo <= x <= hi})
    total = 0.0
    for a, b in zip(pts[:-1], pts[1:]):
        total += integrate.quad(lambda x: math.exp(prior.logpdf(x)), a, b, epsabs=1e-13, epsrel=1e-11, limit=200)[0]
    if math.isinf(lo):
        total += integrate.quad(lambda x: math.exp(prior.logpdf(x)), -math.inf, pts[0], epsabs=1e-13, limit=200)[0]
    if math.isinf(hi):
        total += integrate.quad(lambda x: math.exp(prior.logpdf(x)), pts[-1], math.inf, epsabs=1e-13, limit=200)[0]
    assert total == pytest.approx(1.0, abs=1e-7)
    # and nothing outside the support
    if math.isfinite(lo):
        assert prior.logpdf(lo - 1e-9) == -math.inf
    if math.isfinite(hi):
        assert prior.logpdf(hi + 1e-9) == -math.inf


def test_truncated_normal_is_normalised():
    """N(0, 3^2) on [-3, 3]: the density at 0 is phi(0)/3 / (2 Phi(1) - 1), not phi(0)/3."""
    p = WeightPrior("normal", -3, 3, scale=3.0, sign="any")
    mass = math.erf(1.0 / math.sqrt(2.0))
    assert float(p.logpdf(0.0)) == pytest.approx(-math.log(3.0 * math.sqrt(2 * math.pi)) - math.log(mass), abs=1e-14)
    # half-t is twice the t density on the half line
    ht = WeightPrior(scale=1.0)
    t3_0 = math.gamma(2.0) / (math.sqrt(3 * math.pi) * math.gamma(1.5))
    assert float(ht.logpdf(0.0)) == pytest.approx(math.log(2 * t3_0), abs=1e-14)


@pytest.mark.parametrize("name", list(PRIORS))
def test_samples_match_cdf(name):
    stats = pytest.importorskip("scipy.stats")
    prior = PRIORS[name]
    x = prior.sample(np.random.default_rng(12345), 3000)
    lo, hi = prior.support
    assert np.all((x >= lo) & (x <= hi))
    assert stats.kstest(x, _scipy_cdf(prior)).pvalue > 0.001
    # the quantile function inverts the oracle CDF (tails included)
    rp = prior.resolve(n_features=1)
    q = np.array([1e-12, 1e-6, 0.01, 0.3, 0.5, 0.9, 1 - 1e-6])
    # atol: the oracle's own cancellation near the ends of a far-tail support
    np.testing.assert_allclose(_scipy_cdf(prior)(rp.ppf(q)[:, 0]), q, rtol=1e-7, atol=1e-13)


def test_far_tail_quantiles_against_closed_forms():
    # half-Cauchy (t, 1 df) on (-inf, 0]: F^{-1}(u) = tan(pi (u/2 - 1/2)) = -1 / tan(pi u / 2)
    rp = WeightPrior(scale=1.0, df=1.0).resolve(n_features=1)
    for u in (1e-300, 1e-12, 0.25, 0.5, 0.999999):
        assert rp.ppf(u)[0] == pytest.approx(-1.0 / math.tan(math.pi * u / 2), rel=1e-12)
    # normal on [50, inf): the upper-tail quantile from the survival function
    z = WeightPrior("normal", 50.0, scale=1.0, sign="any").resolve(n_features=1).ppf(0.5)[0]
    assert 0.5 * math.erfc(z / math.sqrt(2)) == pytest.approx(0.25 * math.erfc(50 / math.sqrt(2)), rel=1e-10)


def test_truncated_normal_ppf():
    stats = pytest.importorskip("scipy.stats")
    u = np.array([0.001, 0.2, 0.5, 0.8, 0.999])
    got = truncated_normal_ppf(u, 1.0, 2.0, -3.0, 0.0)
    np.testing.assert_allclose(got, stats.truncnorm.ppf(u, -2.0, -0.5, loc=1.0, scale=2.0), rtol=1e-10)


@pytest.mark.parametrize("name", list(PRIORS) + ["improper negative", "improper any"])
def test_python_and_compiled_densities_agree(name):
    from pbicrl.inference.samplers._priorkern import logprior_w

    prior = PRIORS.get(name) or WeightPrior("improper", sign=name.split()[1])
    rp = prior.resolve(n_features=1)
    kind, prm = rp.as_arrays()
    lo, hi = prior.support
    grid = np.r_[np.linspace(-80, 450, 2001), lo, hi, -1e200, 1e200, 0.0, -0.0, np.nan]
    grid = grid[np.isfinite(grid) | np.isnan(grid)]
    py = rp.logpdf(grid[:, None])[:, 0]
    nb = np.array([logprior_w(int(kind[0]), prm, 0, float(w)) for w in grid])
    np.testing.assert_array_equal(np.isfinite(py), np.isfinite(nb))
    np.testing.assert_allclose(nb[np.isfinite(py)], py[np.isfinite(py)], rtol=1e-13, atol=1e-13)


def test_kind_codes_match_compiled_kernel():
    from pbicrl.inference import codes
    from pbicrl.inference.priors import _CODES
    from pbicrl.inference.samplers import _priorkern as pk

    assert _CODES == {"flat": codes.PRIOR_FLAT, "normal": codes.PRIOR_NORMAL, "improper": codes.PRIOR_IMPROPER,
                      "student_t": codes.PRIOR_STUDENT_T}
    assert WeightPrior().resolve(np.ones((3, 2)) * [[1], [2], [3]]).as_arrays()[1].shape == (2, pk.N_PRIOR_PARAMS)


def test_multi_feature_logpdf_and_sample_shapes():
    F = np.random.default_rng(1).normal(size=(40, 3)) * [1.0, 10.0, 0.1]
    rp = WeightPrior().resolve(F)
    x = rp.sample(np.random.default_rng(0), 500)
    assert x.shape == (500, 3) and np.all(x <= 0)
    # the empirical spread follows the per-feature scales
    ratio = np.median(x, axis=0) / rp.scale
    np.testing.assert_allclose(ratio, -0.7649, atol=0.1)
    lp = rp.logpdf(x)
    assert lp.shape == (500, 3) and np.all(np.isfinite(lp))
    np.testing.assert_allclose(rp.logpdf(x[:, 1], j=1), lp[:, 1])


def test_indicator_prior():
    assert IndicatorPrior(0.2).log_odds == pytest.approx(math.log(0.25))
    with pytest.raises(PriorError, match="pi"):
        IndicatorPrior(0.0)
