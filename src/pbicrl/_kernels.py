"""Compiled (Numba) kernels: the margin-respecting Bradley-Terry log-likelihood.

Each pair contributes :math:`\\log\\sigma(a_i - m - a_j) = -\\mathrm{softplus}(z)`, with
:math:`z = a_j + m - a_i` and :math:`a_i = \\beta \\bar r(\\tau_i)` the scaled length-normalised return.
Write :math:`\\mathrm{softplus}(z) = \\max(z, 0) + \\log(1 + e^{-|z|})`. Over a dense block (all rows ``i`` x
all cols ``j``) the exponential factorises: with a block centre :math:`c`,
:math:`e^{-|z|} = \\min(P_i Q^{-1}_j, P^{-1}_i Q_j)`, where
:math:`P_i = e^{a_i - m - c}` and :math:`Q_j = e^{a_j - c}`. The exponentials become per-trajectory work;
per pair only a select, a multiply and an add remain, which vectorise. The row sum of
:math:`\\log(1 + t)` (:math:`0 \\le t \\le 1`) is one ``log`` of a running product, flushed every
``_CHUNK`` factors so it cannot overflow (each factor is at most 2). When the block's returns spread over
more than ``_SPREAD`` nats (or a margin exceeds ``_MMAX``), :math:`P` or :math:`Q` could overflow, first each block
gets its own centre, and a block that still spreads too far falls back to an exact
per-pair softplus: the result stays finite and correct for return differences of 1e6 and beyond.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["block_loglik", "pairs_loglik", "total_loglik", "softplus"]

_CHUNK = 512  # 2**512 < max double: a flushed product of (1 + t <= 2) factors never overflows
_SPREAD = 600.0  # returns within +-300 of the centre and margins within +-300: every factor in e^{+-600}
_MMAX = 300.0

_FM = {"reassoc", "contract", "nsz", "arcp"}  # lets LLVM vectorise the reductions; no nnan/ninf: NaN must propagate


@njit(cache=True, error_model="numpy")
def softplus(z: float) -> float:
    """:math:`\\log(1 + e^z)`, stable for any finite ``z``."""
    if z > 0.0:
        return z + math.log1p(math.exp(-z))
    return math.log1p(math.exp(z))


@njit(cache=True, error_model="numpy", fastmath=_FM)
def _block_narrow(a: np.ndarray, E: np.ndarray, Einv: np.ndarray, rows: np.ndarray, cols: np.ndarray,
                  margin: float, b: np.ndarray, Q: np.ndarray, Qinv: np.ndarray) -> float:
    """Block sum for at most ``_CHUNK`` columns (see :func:`_block_separable`)."""
    nc = cols.size
    for j in range(nc):
        k = cols[j]
        b[j] = a[k]
        Q[j] = E[k]
        Qinv[j] = Einv[k]
    em = math.exp(-margin)
    pos = 0.0
    log_total = 0.0
    prod = 1.0
    count = 0
    for r in range(rows.size):
        i = rows[r]
        ai = a[i] - margin
        Pi = E[i] * em
        Pinv = Einv[i] / em
        rp = 1.0
        for j in range(nc):
            # min/max instead of a branch on sign(z): e^{-|z|} is the smaller product; this vectorises
            pos += max(b[j] - ai, 0.0)
            rp *= 1.0 + min(Pi * Qinv[j], Pinv * Q[j])
        if count + nc > _CHUNK:  # flush before the running product could overflow
            log_total += math.log(prod)
            prod = 1.0
            count = 0
        prod *= rp
        count += nc
    return -(pos + log_total + math.log(prod))


@njit(cache=True, error_model="numpy")
def _block_separable(a: np.ndarray, E: np.ndarray, Einv: np.ndarray, rows: np.ndarray, cols: np.ndarray,
                     margin: float, b: np.ndarray, Q: np.ndarray, Qinv: np.ndarray) -> float:
    """Block sum given E = exp(a - c), Einv = 1/E for a centre c with |a - c| <= _SPREAD/2, |m| <= _MMAX."""
    total = 0.0
    for start in range(0, cols.size, _CHUNK):
        total += _block_narrow(a, E, Einv, rows, cols[start:start + _CHUNK], margin, b, Q, Qinv)
    return total


@njit(cache=True, error_model="numpy")
def block_loglik(a: np.ndarray, rows: np.ndarray, cols: np.ndarray, margin: float,
                 b: np.ndarray, Q: np.ndarray, Qinv: np.ndarray, E: np.ndarray, Einv: np.ndarray) -> float:
    """Sum of ``log sigma(a[i] - margin - a[j])`` over ``i in rows``, ``j in cols`` (its own centre).

    ``b``, ``Q``, ``Qinv`` are scratch buffers of length >= ``len(cols)``; ``E``, ``Einv`` of length ``len(a)``.
    """
    nr = rows.size
    nc = cols.size
    if nr == 0 or nc == 0:
        return 0.0
    lo = np.inf
    hi = -np.inf
    for j in range(nc):
        v = a[cols[j]]
        lo = min(lo, v)
        hi = max(hi, v)
    for r in range(nr):
        v = a[rows[r]]
        lo = min(lo, v)
        hi = max(hi, v)
    if not (hi - lo <= _SPREAD and abs(margin) <= _MMAX):
        if hi - lo != hi - lo:  # NaN in the returns
            return np.nan
        total = 0.0
        for r in range(nr):
            ai = a[rows[r]] - margin
            for j in range(nc):
                total += softplus(a[cols[j]] - ai)
        return -total
    c = 0.5 * (lo + hi)
    for j in range(nc):
        k = cols[j]
        E[k] = math.exp(a[k] - c)
        Einv[k] = 1.0 / E[k]
    for r in range(nr):
        k = rows[r]
        E[k] = math.exp(a[k] - c)
        Einv[k] = 1.0 / E[k]
    return _block_separable(a, E, Einv, rows, cols, margin, b, Q, Qinv)


@njit(cache=True, error_model="numpy")
def pairs_loglik(a: np.ndarray, pi: np.ndarray, pj: np.ndarray, pm: np.ndarray) -> float:
    """Sum of ``log sigma(a[pi] - pm - a[pj])`` over explicit pairs."""
    total = 0.0
    for p in range(pi.size):
        total += softplus(a[pj[p]] + pm[p] - a[pi[p]])
    return -total


@njit(cache=True, error_model="numpy")
def total_loglik(a: np.ndarray, brows: np.ndarray, broff: np.ndarray, bcols: np.ndarray, bcoff: np.ndarray,
                 bm: np.ndarray, pi: np.ndarray, pj: np.ndarray, pm: np.ndarray,
                 b: np.ndarray, Q: np.ndarray, Qinv: np.ndarray, E: np.ndarray, Einv: np.ndarray) -> float:
    """Log-likelihood of all blocks and explicit pairs for scaled returns ``a``.

    Scratch: ``b``, ``Q``, ``Qinv`` of length >= the largest block's column count; ``E``, ``Einv`` of ``len(a)``.
    """
    total = 0.0
    nb = bm.size
    if nb:
        # One exponential per trajectory when one centre serves every block (the common case).
        lo = np.inf
        hi = -np.inf
        for i in range(a.size):
            lo = min(lo, a[i])
            hi = max(hi, a[i])
        mmax = 0.0
        for k in range(nb):
            mmax = max(mmax, abs(bm[k]))
        if hi - lo <= _SPREAD and mmax <= _MMAX:
            c = 0.5 * (lo + hi)
            for i in range(a.size):
                E[i] = math.exp(a[i] - c)
                Einv[i] = 1.0 / E[i]
            for k in range(nb):
                total += _block_separable(a, E, Einv, brows[broff[k]:broff[k + 1]], bcols[bcoff[k]:bcoff[k + 1]],
                                          bm[k], b, Q, Qinv)
        else:
            for k in range(nb):
                total += block_loglik(a, brows[broff[k]:broff[k + 1]], bcols[bcoff[k]:bcoff[k + 1]], bm[k],
                                      b, Q, Qinv, E, Einv)
    if pi.size:
        total += pairs_loglik(a, pi, pj, pm)
    return total
