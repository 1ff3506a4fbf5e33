"""The stopping rule's statistics against ArviZ, and the verdict on made-up chains."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pbicrl.inference.convergence import (check_convergence, ess_bulk, ess_tail, reported_quantities, rhat)


def _ar1(phi: float, chains: int, n: int, seed: int, shift: float = 0.0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    x = np.zeros((chains, n))
    for c in range(chains):
        e = rng.normal(size=n)
        for t in range(1, n):
            e[t] += phi * e[t - 1]
        x[c] = e
    x[0] += shift
    return x


@pytest.mark.parametrize("phi", [0.0, 0.6, 0.95])
def test_statistics_equal_arviz(phi):
    az = pytest.importorskip("arviz")
    x = _ar1(phi, 4, 1500, seed=3, shift=0.2)
    assert rhat(x) == pytest.approx(float(az.rhat(x, method="rank")), rel=1e-9)
    assert ess_bulk(x) == pytest.approx(float(az.ess(x, method="bulk")), rel=1e-6)
    assert ess_tail(x) == pytest.approx(float(az.ess(x, method="tail", prob=(0.05, 0.95))), rel=1e-6)


def test_constant_and_disagreeing_chains():
    assert math.isnan(rhat(np.ones((4, 100))))
    two = np.vstack([np.zeros((2, 100)), np.ones((2, 100))])
    assert rhat(two) == math.inf
    conv = check_convergence({"const": np.ones((4, 100)), "bad": two})
    assert not conv.converged
    assert list(conv.failing()) == ["bad"] and conv.failing()["bad"].startswith("R-hat inf (target < 1.01)")
    assert conv.to_dict()["quantities"]["const"]["ok"] is True


def test_verdict_needs_every_quantity():
    good = _ar1(0.0, 4, 1000, seed=1)
    slow = _ar1(0.99, 4, 1000, seed=2)
    assert check_convergence({"a": good}).converged
    conv = check_convergence({"a": good, "b": [good, slow]})
    assert not conv.converged and list(conv.failing()) == ["b"]
    assert "bulk ESS" in conv.failing()["b"] and "NOT CONVERGED" in conv.line()
    assert check_convergence({"b": slow}, target_ess=5, target_rhat=1.5).converged


def test_reported_quantities_cover_indicators_conditionals_and_loglik():
    rng = np.random.default_rng(0)
    C, N = 4, 400
    c = np.zeros((C, N, 3), np.int8)
    c[:, :, 0] = 1  # always on
    c[:, :, 1] = rng.random((C, N)) < 0.3
    w = -np.exp(rng.normal(size=(C, N, 3))) * c
    ll = rng.normal(size=(C, N))
    q = reported_quantities(c, w, ll, ["a", "b", "never"])
    assert set(q) == {"P(c=1) a", "a | c=1", "log|w| a | c=1", "P(c=1) b", "b | c=1", "P(c=1) never",
                      "log-likelihood"}
    assert len(q["b | c=1"]) == 3  # indicators at the conditional 5/50/95% quantiles, defined for every draw
    assert q["b | c=1"][1].shape == (C, N)
    np.testing.assert_allclose(q["b | c=1"][1].mean(), c[:, :, 1].mean() * 0.5, atol=0.01)
    conv = check_convergence(q)
    assert conv.converged  # independent draws
    assert conv.to_dict()["quantities"]["P(c=1) a"]["rhat"] is None  # constant: converged by definition


def test_average_ranks_equal_scipy_rankdata():
    from scipy.stats import rankdata

    from pbicrl.inference.convergence import _average_ranks

    rng = np.random.default_rng(11)
    cases = [rng.normal(size=(4, 300)), rng.integers(0, 3, size=(4, 80)).astype(float), np.zeros((2, 6)),
             np.array([[1.0, np.inf, -np.inf, 2.0, 1.0]]),
             # two values (indicators: ranked without a sort), also with infinities and a single odd draw
             (rng.random((4, 500)) < 0.3).astype(float), np.where(rng.random((2, 50)) < 0.5, -np.inf, 3.5),
             np.r_[np.zeros(99), 1.0].reshape(4, 25)]
    for x in cases:
        np.testing.assert_array_equal(_average_ranks(x), rankdata(x, method="average").reshape(x.shape))
