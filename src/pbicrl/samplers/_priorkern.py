"""Compiled prior densities of the penalty weights, shared by the sampler loop (:mod:`pbicrl.samplers._mcmc`).

``_logprior_w(kind, prm, j, w)`` takes the prior kind code of feature ``j`` and its row ``prm[j]`` of
parameters, as produced by :meth:`pbicrl.priors.WeightPrior.as_arrays`.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

_LOG_SQRT_2PI = 0.5 * math.log(2.0 * math.pi)


@njit(cache=True)
def _logprior_w(kind: int, prm: np.ndarray, j: int, w: float) -> float:
    lo = prm[j, 0]
    hi = prm[j, 1]
    if w < lo or w > hi or w != w:
        return -np.inf
    if kind == 0:
        return -math.log(hi - lo)
    if kind == 1:
        z = (w - prm[j, 2]) / prm[j, 3]
        return -0.5 * z * z - math.log(prm[j, 3]) - _LOG_SQRT_2PI
    return 0.0


@njit(cache=True)
def _lognormal(w: float, mu: float, s: float) -> float:
    z = (w - mu) / s
    return -0.5 * z * z - math.log(s) - _LOG_SQRT_2PI
