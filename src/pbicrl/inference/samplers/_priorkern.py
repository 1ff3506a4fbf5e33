"""Compiled prior densities of the penalty weights, shared by the sampler loop (:mod:`pbicrl.inference.samplers._mcmc`).

``logprior_w(kind, prm, j, w)`` takes the prior kind code of feature ``j`` and its row ``prm[j]`` of
parameters ``[low, high, loc, scale, df, log_norm]``, as produced by
:meth:`pbicrl.inference.priors.ResolvedWeightPrior.as_arrays`. The log normaliser ``log_norm`` (which holds the
truncation mass :math:`F(b) - F(a)`) is computed once in Python, where the tail-accurate CDFs live; the
kernel here only evaluates :math:`\\log f(z) - \\text{log\\_norm}` at :math:`z = (w - \\mu_j)/s_j`.

Kind codes: ``PRIOR_*`` of :mod:`pbicrl.inference.codes` .
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from pbicrl.inference.codes import PRIOR_FLAT, PRIOR_IMPROPER, PRIOR_NORMAL

__all__ = ["lognormal", "logprior_w", "N_PRIOR_PARAMS"]

_LOG_SQRT_2PI = 0.5 * math.log(2.0 * math.pi)

#: Columns of the parameter matrix: low, high, loc, scale, df, log_norm.
N_PRIOR_PARAMS = 6


@njit(cache=True)
def logprior_w(kind: int, prm: np.ndarray, j: int, w: float) -> float:
    """Normalised log prior density of weight ``w`` of feature ``j`` (``-inf`` outside its support)."""
    lo = prm[j, 0]
    hi = prm[j, 1]
    if w < lo or w > hi or w != w:
        return -np.inf
    if kind == PRIOR_FLAT:
        return -prm[j, 5]
    if kind == PRIOR_IMPROPER:
        return 0.0
    z = (w - prm[j, 2]) / prm[j, 3]
    if kind == PRIOR_NORMAL:
        return -0.5 * z * z - prm[j, 5]
    # Student-t: -(nu+1)/2 log(1 + z^2/nu); for huge |z| the square would overflow
    nu = prm[j, 4]
    az = abs(z)
    if az > 1e150:
        l1p = 2.0 * math.log(az) - math.log(nu) + math.log1p(nu / az / az)
    else:
        l1p = math.log1p(z * z / nu)
    return -0.5 * (nu + 1.0) * l1p - prm[j, 5]


@njit(cache=True)
def lognormal(w: float, mu: float, s: float) -> float:
    z = (w - mu) / s
    return -0.5 * z * z - math.log(s) - _LOG_SQRT_2PI
