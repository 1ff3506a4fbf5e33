"""Plain NumPy implementations of the samplers, one iteration at a time.

They consume the same per-iteration random numbers as the compiled kernel, so tests can check that the
compiled chains are the same chains, and ``benchmarks/`` uses them as the straightforward vectorised
baseline (the likelihood recomputed by broadcasting over all pairs at every iteration). No adaptation.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from pbicrl.inference.likelihood import PreferenceLikelihood, log_likelihood_numpy
from pbicrl.inference.priors import IndicatorPrior, WeightPrior

__all__ = ["reference_chain"]


def reference_chain(
    lik: PreferenceLikelihood,
    method: str,
    c0: NDArray,
    w0: NDArray,
    randoms: tuple[NDArray, NDArray, NDArray, NDArray],
    *,
    sigma: float = 0.1,
    f_s: int = 4,
    p_flip: float = 0.5,
    q_mean: NDArray | None = None,
    q_scale: NDArray | None = None,
    weight_prior: WeightPrior | None = None,
    indicator_prior: IndicatorPrior | None = None,
) -> tuple[NDArray[np.int8], NDArray[np.float64], NDArray[np.float64]]:
    """Run ``len(randoms[0])`` iterations; returns per-iteration (c, w, log-likelihood) after each step."""
    u_j, u_mv, z, u_acc = randoms[:4]
    n = u_j.size
    d = lik.n_features
    prior = (weight_prior or WeightPrior()).resolve(lik.mean_features, beta=lik.beta)
    log_odds = (indicator_prior or IndicatorPrior()).log_odds
    qm = np.zeros(d) if q_mean is None else q_mean
    qs = np.ones(d) if q_scale is None else q_scale
    c = np.array(c0, dtype=np.int8)
    w = np.array(w0, dtype=np.float64)

    def loglik(cc: NDArray, ww: NDArray) -> float:
        a = lik.beta * (lik.mean_features @ (lik.nominal_weights + cc * ww))
        return log_likelihood_numpy(a, lik.preferences)

    def lpw(x: float, j: int) -> float:
        return float(prior.logpdf(np.array(x), j=j))

    def lq(x: float, j: int) -> float:
        return -0.5 * ((x - qm[j]) / qs[j]) ** 2 - math.log(qs[j]) - 0.5 * math.log(2 * math.pi)

    ll = loglik(c, w)
    out_c = np.zeros((n, d), np.int8)
    out_w = np.zeros((n, d))
    out_ll = np.zeros(n)
    for t in range(n):
        j = min(int(u_j[t] * d), d - 1)
        if method == "paper":
            c2, w2 = c.copy(), w.copy()
            if (t + 1) % f_s != 0:
                c2[j] = 1 - c2[j]
            else:
                w2[j] += sigma * z[t]
            ll2 = loglik(c2, w2)
            if ll2 - ll >= 0 or math.log(u_acc[t]) < ll2 - ll:
                c, w, ll = c2, w2, ll2
        elif method == "bpl":
            w2 = w.copy()
            w2[j] += sigma * z[t]
            lr = loglik(c, w2) - ll + lpw(w2[j], j) - lpw(w[j], j)
            if lpw(w2[j], j) > -np.inf and (lr >= 0 or math.log(u_acc[t]) < lr):
                w, ll = w2, loglik(c, w2)
        else:
            if u_mv[t] < p_flip:
                c2, w2 = c.copy(), w.copy()
                if c[j] == 0:
                    w2[j] = qm[j] + qs[j] * z[t]
                    c2[j] = 1
                    if lpw(w2[j], j) > -np.inf:
                        ll2 = loglik(c2, w2)
                        if math.log(u_acc[t]) < ll2 - ll + log_odds + lpw(w2[j], j) - lq(w2[j], j):
                            c, w, ll = c2, w2, ll2
                else:
                    c2[j] = 0
                    w2[j] = 0.0
                    ll2 = loglik(c2, w2)
                    if math.log(u_acc[t]) < ll2 - ll - log_odds - lpw(w[j], j) + lq(w[j], j):
                        c, w, ll = c2, w2, ll2
            else:
                on = np.flatnonzero(c == 1)
                if on.size:
                    j = on[min(int(u_j[t] * on.size), on.size - 1)]
                    w2 = w.copy()
                    w2[j] += sigma * z[t]
                    if lpw(w2[j], j) > -np.inf:
                        ll2 = loglik(c, w2)
                        lr = ll2 - ll + lpw(w2[j], j) - lpw(w[j], j)
                        if lr >= 0 or math.log(u_acc[t]) < lr:
                            w, ll = w2, ll2
        out_c[t], out_w[t], out_ll[t] = c, w, ll
    return out_c, out_w, out_ll
