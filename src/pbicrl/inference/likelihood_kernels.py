"""Compiled (Numba) kernels: the margin-respecting Bradley-Terry log-likelihood (paper Eq. 7) and the exact
grouped Plackett-Luce log-likelihood, with :func:`loglik` dispatching between them for the sampler.

**Pairwise.** Each pair contributes :math:`\\log\\sigma(a_i - m - a_j) = -\\mathrm{softplus}(z)`, with
:math:`z = a_j + m - a_i` and :math:`a_i = \\beta \\bar r(\\tau_i)` the scaled length-normalised return.
Write :math:`\\mathrm{softplus}(z) = \\max(z, 0) + \\log(1 + e^{-|z|})`. Over a dense block (all rows ``i`` x
all cols ``j``) the exponential factorises: with a block centre :math:`c`,
:math:`e^{-|z|} = \\min(P_i Q^{-1}_j, P^{-1}_i Q_j)`, where
:math:`P_i = e^{a_i - m - c}` and :math:`Q_j = e^{a_j - c}`. The exponentials become per-trajectory work;
per pair only a select, a multiply and an add remain, which vectorise. The row sum of
:math:`\\log(1 + t)` (:math:`0 \\le t \\le 1`) is one ``log`` of a running product, flushed every
``_CHUNK`` factors so it cannot overflow (each factor is at most 2). When the returns spread over more than
``_SPREAD`` nats (or a margin exceeds ``_MMAX``), :math:`P` or :math:`Q` could overflow: first each block gets its
own centre; a block that still spreads too far is evaluated over its sorted returns (:func:`_block_wide`:
distant pairs from prefix sums, close ones by the same separable product within bands), exact to float
precision for return differences of 1e6 and beyond at a cost close to the narrow path's. A narrow block with a
large margin keeps the original per-pair loop (:func:`_block_softplus`).

**Explicit pairs** (the sampled protocol) go pair by pair (:func:`pairs_loglik`: one exponential per pair, the
logarithms of :math:`1 + t` taken once per product). :func:`pairs_loglik_bound` is a rigorous upper bound without transcendental
functions (piecewise-linear minorant of ``softplus``) with which the sampler rejects hopeless proposals before the
exact evaluation, without changing a single decision.

**Rankings.** :func:`ranked_loglik` sums all cross-group pairs of a ranking stored as the ranking itself
(``Preferences.ranked``, many groups, additive margins): rows against contiguous suffixes, O(N) memory.

**Grouped.** :func:`grouped_loglik`; the method is described in the comment that opens its section below, large
groups (binned moments) in the comment before :func:`_gb_moments`.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit
from numba.extending import overload

from pbicrl.inference.codes import LIK_GROUPED, LIK_RANKED

__all__ = ["block_loglik", "pairs_loglik", "pairs_loglik_bound", "total_loglik", "ranked_loglik", "softplus",
           "grouped_loglik", "group_term", "loglik", "LikelihoodArrays"]

_CHUNK = 512  # 2**512 < max double: a flushed product of (1 + t <= 2) factors never overflows
_SPREAD = 600.0  # returns within +-300 of the centre and margins within +-300: every factor in e^{+-600}
_MMAX = 300.0

_FM = {"reassoc", "contract", "nsz", "arcp"}  # lets LLVM vectorise the reductions; no nnan/ninf: NaN must propagate


_SP_BIG = 37.5  # e^{-37.5} < 2^-54: below ulp(z)/2 for z > 37.5, and log1p(y) returns y itself for y < 2^-54


@njit(cache=True, error_model="numpy")
def softplus(z: float) -> float:
    """:math:`\\log(1 + e^z)`, stable for any finite ``z``.

    Beyond ``|z| > _SP_BIG`` the shortcuts give the very same bits as the general formula (``z + log1p(e^{-z})``
    rounds to ``z``; ``log1p`` of a number below :math:`2^{-54}` is that number), without the logarithm.
    """
    if z > 0.0:
        if z > _SP_BIG:
            return z
        return z + math.log1p(math.exp(-z))
    if z < -_SP_BIG:
        return math.exp(z)
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


_NEAR = 37.5  # |z| > _NEAR: softplus(z) is z (z > 0; e^{-z} < 2^-54 z) or e^z (z < 0) to float precision
_BAND = 64.0  # width of a band of sorted columns; with its own centre every factor stays within e^{+-(_NEAR + _BAND)}
_FAR = 745.0  # z > _FAR: summed from prefix sums (cancellation ~eps * spread / _FAR); z < -_FAR: e^z underflows


@njit(cache=True, error_model="numpy")
def _block_softplus(a: np.ndarray, rows: np.ndarray, cols: np.ndarray, margin: float) -> float:
    """Per-pair ``-softplus`` sum: the original fallback (still used for large margins on a narrow block)."""
    total = 0.0
    for r in range(rows.size):
        ai = a[rows[r]] - margin
        for j in range(cols.size):
            total += softplus(a[cols[j]] - ai)
    return -total


@njit(cache=True, error_model="numpy", fastmath=_FM)
def _band_run(y: np.ndarray, Q: np.ndarray, Qinv: np.ndarray, j0: int, j1: int, x: float, P: float,
              Pinv: float) -> tuple[float, float, float]:
    """Over ``j0 <= j < j1`` (at most ``_CHUNK``): ``sum max(y_j - x, 0)``, and :math:`\\log(1 + t_j)`,
    :math:`t_j = e^{-|y_j - x|}`, split into a series sum for small :math:`t_j` and a product of the others.

    The series (five terms, relative error below 2e-16 for :math:`t < 10^{-3}`) keeps tiny terms that
    :math:`1 + t` would round away, so a block whose pairs are nearly all decided keeps its relative precision.
    """
    pos = 0.0
    ser = 0.0
    rp = 1.0
    for j in range(j0, j1):
        pos += max(y[j] - x, 0.0)
        t = min(P * Qinv[j], Pinv * Q[j])
        small = t < 1e-3
        ser += t * (1.0 - t * (0.5 - t * (1.0 / 3.0 - t * (0.25 - t * 0.2)))) if small else 0.0
        rp *= 1.0 if small else 1.0 + t
    return pos, ser, rp


@njit(cache=True, error_model="numpy")
def _block_wide(a: np.ndarray, rows: np.ndarray, cols: np.ndarray, margin: float) -> float:
    """Exact block sum for returns spread over more than ``_SPREAD`` nats, in O((R + C) log C + close pairs).

    With :math:`x_i = a_i - m` and the columns' returns :math:`y` sorted and cut into bands at most ``_BAND`` nats
    wide, each pair contributes :math:`\\mathrm{softplus}(z)`, :math:`z = y_j - x_i`. For row :math:`i`:

    * bands entirely more than ``_NEAR`` below :math:`x_i` contribute :math:`\\sum_j e^{y_j - x_i}` (each term below
      :math:`2^{-54}`), one exponential per band from the band's :math:`\\sum_j e^{y_j - c_b}`, down to underflow;
    * bands entirely more than ``_NEAR`` above :math:`x_i` contribute :math:`\\sum_j (y_j - x_i)`, from the band's
      sum about its own centre (no cancellation), up to the first band beyond :math:`x_i +` ``_FAR``; everything
      beyond is one difference of double-double prefix sums (pairs that far apart give exactly :math:`z`);
    * the other bands (at most three) hold the pairs with :math:`|z| \\le` ``_NEAR``: the narrow path's separable
      exponentials with the band's own centre (no factor can overflow), :math:`\\log(1 + t)` by a short series for
      small :math:`t` and one logarithm per product of the others.

    Every pair is exact to a few units of 1e-16 relative to its own size (the narrow path rounds terms under
    :math:`2^{-53}` away), so blocks of nearly decided pairs keep their relative precision too.
    """
    nr = rows.size
    nc = cols.size
    y = np.empty(nc)
    for j in range(nc):
        y[j] = a[cols[j]]
    y.sort()
    # Prefix sums of y - c0 as double-double (TwoSum): the far-side sums then only pay one final rounding.
    c0 = 0.5 * (y[0] + y[nc - 1])
    ph = np.empty(nc + 1)
    pl = np.empty(nc + 1)
    ph[0] = 0.0
    pl[0] = 0.0
    for j in range(nc):
        d = y[j] - c0
        t = ph[j] + d
        bb = t - ph[j]
        pl[j + 1] = pl[j] + ((ph[j] - (t - bb)) + (d - bb))
        ph[j + 1] = t
    # Bands: greedy runs of at most _BAND nats, each with its centre, local sum and scaled exponentials.
    bstart = np.empty(nc + 1, dtype=np.int64)
    nb = 0
    j = 0
    while j < nc:
        bstart[nb] = j
        nb += 1
        first = y[j]
        j += 1
        while j < nc and y[j] - first <= _BAND:
            j += 1
    bstart[nb] = nc
    bmin = np.empty(nb)
    bmax = np.empty(nb)
    bcen = np.empty(nb)
    bsum = np.empty(nb)
    bexp = np.empty(nb)
    Q = np.empty(nc)
    Qinv = np.empty(nc)
    for b in range(nb):
        j0 = bstart[b]
        j1 = bstart[b + 1]
        bmin[b] = y[j0]
        bmax[b] = y[j1 - 1]
        cb = 0.5 * (y[j0] + y[j1 - 1])
        bcen[b] = cb
        acc = 0.0
        eacc = 0.0
        for k in range(j0, j1):
            acc += y[k] - cb
            Q[k] = math.exp(y[k] - cb)
            Qinv[k] = 1.0 / Q[k]
            eacc += Q[k]
        bsum[b] = acc
        bexp[b] = eacc
    pos = 0.0
    ser = 0.0
    log_total = 0.0
    prod = 1.0
    count = 0
    for r in range(nr):
        x = a[rows[r]] - margin
        b = np.searchsorted(bmax, x - _NEAR)  # first band that reaches within _NEAR below x
        bfar = np.searchsorted(bmin, x + _FAR, side="right")  # first band entirely beyond _FAR above x
        # bands entirely below: log(1 + e^z) = e^z to 3e-17 relative, e^{c_b - x} sum_j Q_j per band, until
        # the terms underflow (what 1 + t rounds away on the narrow path, kept here: see _band_run)
        lowb = b - 1
        while lowb >= 0 and bmax[lowb] - x > -_FAR:
            ser += math.exp(bcen[lowb] - x) * bexp[lowb]
            lowb -= 1
        while b < bfar:
            j0 = bstart[b]
            j1 = bstart[b + 1]
            if bmin[b] - x > _NEAR:
                pos += bsum[b] + (j1 - j0) * (bcen[b] - x)
            else:
                P = math.exp(x - bcen[b])
                Pinv = 1.0 / P
                for k0 in range(j0, j1, _CHUNK):
                    k1 = min(k0 + _CHUNK, j1)
                    if count + (k1 - k0) > _CHUNK:  # flush before the running product could overflow
                        log_total += math.log(prod)
                        prod = 1.0
                        count = 0
                    dp, ds, rp = _band_run(y, Q, Qinv, k0, k1, x, P, Pinv)
                    pos += dp
                    ser += ds
                    prod *= rp
                    count += k1 - k0
            b += 1
        jf = bstart[bfar]
        if jf < nc:
            pos += ((ph[nc] - ph[jf]) + (pl[nc] - pl[jf])) - (nc - jf) * (x - c0)
    return -(pos + (ser + (log_total + math.log(prod))))


@njit(cache=True, error_model="numpy", inline="always")
def _extend_range(a: np.ndarray, idx: np.ndarray, lo: float, hi: float) -> tuple[float, float]:
    """``(lo, hi)`` widened to hold ``a[idx]``."""
    for r in range(idx.size):
        v = a[idx[r]]
        lo = min(lo, v)
        hi = max(hi, v)
    return lo, hi


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
    lo, hi = _extend_range(a, cols, np.inf, -np.inf)
    lo, hi = _extend_range(a, rows, lo, hi)
    if not (hi - lo <= _SPREAD and abs(margin) <= _MMAX):
        if hi - lo != hi - lo:  # NaN in the returns
            return np.nan
        if hi - lo <= _SPREAD or hi - lo == np.inf:
            # only the margin is large (rare; this result stays as it always was, bit for bit), or infinite returns
            return _block_softplus(a, rows, cols, margin)
        return _block_wide(a, rows, cols, margin)
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


@njit(cache=True, error_model="numpy", fastmath=_FM)
def pairs_loglik(a: np.ndarray, pi: np.ndarray, pj: np.ndarray, pm: np.ndarray) -> float:
    """Sum of ``log sigma(a[pi] - pm - a[pj])`` over explicit pairs.

    ``softplus(z) = max(z, 0) + log(1 + t)``, :math:`t = e^{-|z|}`: one exponential per pair and one logarithm per
    ``_CHUNK`` pairs (the product of the factors :math:`1 + t \\le 2`); factors with :math:`t < 10^{-3}` go into a
    short series instead, which keeps the relative precision of nearly decided pairs (as :func:`_band_run`). NaN
    propagates through the product. Absolute error below ``(n + 2) * 2.3e-16`` plus ``n eps`` relative to the sum:
    inside the rounding allowance of :func:`pairs_loglik_bound`.
    """
    pos = 0.0
    ser = 0.0
    lt = 0.0
    n = pi.size
    for p0 in range(0, n, _CHUNK):
        p1 = min(p0 + _CHUNK, n)
        rp = 1.0
        for p in range(p0, p1):
            z = a[pj[p]] + pm[p] - a[pi[p]]
            pos += max(z, 0.0)
            t = math.exp(-abs(z))
            small = t < 1e-3
            ser += t * (1.0 - t * (0.5 - t * (1.0 / 3.0 - t * (0.25 - t * 0.2)))) if small else 0.0
            rp *= 1.0 if small else 1.0 + t
        lt += math.log(rp)
    return -(pos + (ser + lt))


# Tangents of the convex f(x) = log1p(e^{-x}), x >= 0, one per interval [k h, (k + 1) h) touching at its midpoint:
# a tangent of a convex function lies below it everywhere, and within its interval it is at most f'' h^2 / 8 <= 5e-4
# below (f'' <= 1/4); beyond _TAN_H * _TAN_N, f < 1.2e-7 and the bound uses 0. So
# softplus(z) >= max(z, 0) + max(0, c_k - s_k |z|), k = floor(|z| / h): a multiply-add and a table lookup per pair.
_TAN_H = 0.125
_TAN_N = 128
_TAN_XM = (np.arange(_TAN_N) + 0.5) * _TAN_H
_TAN_S = 1.0 / (1.0 + np.exp(_TAN_XM))  # -f'(x_k)
_TAN_C = np.log1p(np.exp(-_TAN_XM)) + _TAN_S * _TAN_XM


@njit(cache=True, error_model="numpy", fastmath=_FM)
def pairs_loglik_bound(a: np.ndarray, pi: np.ndarray, pj: np.ndarray, pm: np.ndarray) -> tuple[float, float]:
    """An upper bound on :func:`pairs_loglik` without transcendental functions, and its rounding allowance.

    Returns ``(u, slack)`` with ``pairs_loglik(a, ...) <= u + slack`` as both are computed in floating point, from
    the piecewise-linear minorant of ``softplus`` above. ``slack`` covers the rounding of both sums (positive terms:
    relative error below (n + 4) eps in any order, so this loop may vectorise), of the tangents, and of ``z`` (which
    re-association may compute differently here; ``softplus`` and its minorant change by at most ``|dz|``). The
    sampler rejects a proposal without the exact evaluation when even ``u + slack`` fails the acceptance test, so its
    decisions, hence the chain, are those of the exact kernel.
    """
    total = 0.0
    mag = 0.0
    xlast = (_TAN_N - 0.5) * _TAN_H  # clamp before the table index (also keeps NaN in range)
    for p in range(pi.size):
        ai = a[pi[p]]
        aj = a[pj[p]]
        z = aj + pm[p] - ai
        x = abs(z)
        xc = x if x < xlast else xlast
        k = int(xc * (1.0 / _TAN_H))
        total += max(z, 0.0) + max(_TAN_C[k] - _TAN_S[k] * x, 0.0)
        mag += abs(ai) + abs(aj) + abs(pm[p])
    n = pi.size
    return -total, (4.0 * n + 64.0) * 2.3e-16 * total + 4.5e-16 * mag + 1e-14 * (n + 1.0)


@njit(cache=True, error_model="numpy", inline="always")  # no call: its ~20 array arguments cost refcounts
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


@njit(cache=True, error_model="numpy", fastmath=_FM)
def _ranked_rows(xs: np.ndarray, Q: np.ndarray, Qinv: np.ndarray, r0: int, r1: int, j0: int) -> float:
    """Sum of ``-softplus(xs[j] - xs[r])`` for rows ``r0 <= r < r1`` against columns ``j0 <= j < len(xs)``, given
    ``Q = exp(xs - c)``, ``Qinv = 1/Q`` for a centre ``c`` within ``_SPREAD / 2`` of every ``xs``: the arithmetic of
    :func:`_block_narrow` over contiguous columns."""
    # the columns as views starting at 0: indexing xs[j0 + j] instead keeps LLVM from vectorising well (5x slower)
    y = xs[j0:]
    Qc = Q[j0:]
    Qic = Qinv[j0:]
    m = y.size
    pos = 0.0
    log_total = 0.0
    prod = 1.0
    count = 0
    for r in range(r0, r1):
        x = xs[r]
        P = Q[r]
        Pinv = Qinv[r]
        for k0 in range(0, m, _CHUNK):
            k1 = min(k0 + _CHUNK, m)
            rp = 1.0
            for j in range(k1 - k0):
                pos += max(y[k0 + j] - x, 0.0)
                rp *= 1.0 + min(P * Qic[k0 + j], Pinv * Qc[k0 + j])
            if count + (k1 - k0) > _CHUNK:  # flush before the running product could overflow
                log_total += math.log(prod)
                prod = 1.0
                count = 0
            prod *= rp
            count += k1 - k0
    return -(pos + log_total + math.log(prod))


_RANKED_RUN = 64  # positions per run of the wide path of ranked_loglik


@njit(cache=True, error_model="numpy")
def ranked_loglik(a: np.ndarray, gitems: np.ndarray, goff: np.ndarray, moff: np.ndarray, xs: np.ndarray,
                  Q: np.ndarray, Qinv: np.ndarray) -> float:
    """Paper Eq. 7 over every cross-group pair of a ranking (``Preferences.ranked``), without per-pair storage.

    With additive margins :math:`m_{k\\ell} = o_\\ell - o_k`, the pair of :math:`i \\in G_k` over :math:`j \\in G_\\ell`
    (:math:`k < \\ell`) is :math:`\\log\\sigma(x_i - x_j)` with :math:`x_i = a_i + o_k`. In group order the columns of
    every row of :math:`G_k` are one contiguous range (all worse groups), so the sum is a triangle of rows against
    suffixes: the separable product of the block kernel over contiguous memory, O(pairs) work vectorised and O(N)
    memory, whatever the number of groups. Returns spread over more than ``_SPREAD`` nats go run by run (whole
    groups, at least ``_RANKED_RUN`` positions) to :func:`_block_wide` against the rest of the ranking, and pair by
    pair within a run. ``xs``, ``Q``, ``Qinv``: scratch of length N.
    """
    K = goff.size - 1
    n = gitems.size
    lo = np.inf
    hi = -np.inf
    for k in range(K):
        for r in range(goff[k], goff[k + 1]):
            v = a[gitems[r]] + moff[k]
            xs[r] = v
            lo = min(lo, v)
            hi = max(hi, v)
    if n == 0:
        return 0.0
    if hi - lo != hi - lo:
        return np.nan
    total = 0.0
    if hi - lo <= _SPREAD:
        c = 0.5 * (lo + hi)
        for r in range(n):
            Q[r] = math.exp(xs[r] - c)
            Qinv[r] = 1.0 / Q[r]
        for k in range(K - 1):
            total += _ranked_rows(xs, Q, Qinv, goff[k], goff[k + 1], goff[k + 1])
        return total
    # Wide: cut the ranking at group boundaries into runs of >= _RANKED_RUN positions. Each run's rows against
    # everything after the run is one block for _block_wide (sorted columns, prefix sums, exact band); the pairs
    # between different groups inside a run go pair by pair. O((N / run) N log N + N run) instead of O(N^2).
    idx = np.arange(n)
    k = 0
    while k < K - 1:
        k1 = k + 1
        while k1 < K and goff[k1] - goff[k] < _RANKED_RUN:
            k1 += 1
        r0 = goff[k]
        r1 = goff[k1]
        if r1 < n:
            if hi - lo < np.inf:
                total += _block_wide(xs, idx[r0:r1], idx[r1:], 0.0)
            else:
                total += _block_softplus(xs, idx[r0:r1], idx[r1:], 0.0)
        for kk in range(k, k1 - 1):
            total += _block_softplus(xs, idx[goff[kk]:goff[kk + 1]], idx[goff[kk + 1]:r1], 0.0)
        k = k1
    return total


# ================================================================================== grouped Plackett-Luce
#
# Groups G_1 (best) ... G_K. With lambda_i = exp(a_i), the probability that every item of G_k ranks above every
# item of the lower groups R_k under a Plackett-Luce model (an exponential race: item i arrives at E_i ~ Exp(lambda_i),
# earlier is better) is P_k = int_0^inf e^{-t} prod_{i in G_k} (1 - exp(-t lambda_i / Lambda_k)) dt, and the
# ranking of the groups has probability prod_k P_k (memorylessness: the race among R_k restarts). Margins weight
# the lower items, Lambda_k = sum_{j in R_k} lambda_j exp(m_{k,l(j)}): two singleton groups give exactly the
# pairwise term log sigma(a_i - m - a_j) of Eq. 7.
#
# In s = log t, with x_i = a_i - log Lambda_k, v_i = e^{s + x_i} and L(u) = log(1 - exp(-e^u)):
#   direct form      g(s) = s - e^s + h(s),               h(s) = sum_i L(s + x_i),        P = int e^{g}
#   complement form  c(s) = s - e^s + log(1 - e^{h(s)}),                                   1 - P = int e^{c}
# g is concave (L'(u) = v / (e^v - 1) decreases), with its mode in (0, log(n + 1)]; c was unimodal on thousands
# of random and adversarial groups (the density form of 1 - P, which has a shorter tail, was not), with its
# mode in [min(-max x - 3, -1/2), 0]. The direct form gives log P to relative precision unless P is close to 1;
# the complement gives 1 - P to relative precision, hence log P = log1p(-(1 - P)) for near-certain orderings.
# A Laplace estimate at the direct mode picks the form. Each integral: safeguarded Newton for the mode, sigma
# from the curvature there, and the trapezoid rule in u with s = s0 + sigma m(u), where
# m(u) = (1 - beta) u + beta (1 - e^{-gamma u}) / gamma stretches the slowly decaying left tail (slope n + 1, or
# 1 for the complement) exponentially. Nodes go outwards until the integrand is e^{-_G_DROP} below the mode;
# the rule is compared with the one on every other node (twice the step) and halved until two levels agree to
# _G_ACCEPT: the rule converges geometrically, but the step it needs depends on how sharp the edges of the
# integrand are (an edge of many near-equal items is much sharper than the curvature at the mode says).
# Constants chosen by measurement: worst relative error of log P_k 7e-15 over 3,757 groups of 2 .. 10^4 items
# (returns spread 0.01 .. 1e6, clusters, near-certain to near-impossible orders) against the same integrals with
# 10x finer steps, and within 1e-10 of scipy's adaptive quadrature of the defining integral (the tests). Since
# 2026-12-05 (_G_ACCEPT 1e-8, the complement's stretch gamma 0.8: 1.3-1.4x fewer nodes on the shipped data),
# benchmarks/grouped_precision.py over 4,000 such groups: 99.9% within 2e-13 relative, worst 1.6e-11 relative
# (a near-certain order, log P_k = -4e-5: 6e-16 nats); worst absolute error 3e-8 nats at log P_k = -3e5 (rounding).
# The binned rule (dense bins and sparse items, 2026-12-06) on the 1,812 of them it takes: 99.9% within 6e-14
# relative, the same worst group, worst absolute error 1.4e-7 nats (|log P_k| ~ 1e6: rounding).
# Typical cost: 4-6 Newton steps and ~36 nodes, each one exp (or expm1) per item: O(n Q).

_LN2 = math.log(2.0)
_LOG_SQRT_2PI = 0.5 * math.log(2.0 * math.pi)
_G_TINY = -25.0  # u below: v < 1.4e-11 and L(u) = u - v/2 to 1e-22
_G_HUGE = 6.62  # u above: v > 750, exp(-v) underflows and the factor is exactly 1
_G_CLASS = 700.0  # |x_i + s0| above: the item is in one of those two regimes on the whole window
_G_WINDOW = 600.0  # no node lies further than this from the mode (the integrand is e^{-hundreds} there)
_G_DROP = 36.0  # nodes until the integrand is e^{-36} (1e-16) below its mode
_G_EDROP = math.exp(-_G_DROP)
_G_STEP = 0.45  # level-0 trapezoid step / sigma (checked against twice the step, halved until two agree)
_G_STEP_MAX = 0.35  # level-0 step cap in s: the integrand's complex singularities sit ~pi/2 off the real axis
_G_ACCEPT = 1e-8  # two levels agreeing to this leave an error far below it (measured: see above)
_G_MAX_LEVELS = 6
_G_MAP_DIRECT = (0.15, 0.3)  # (beta, gamma) of the tail stretch
_G_MAP_COMP = (0.1, 0.8)  # a stronger stretch of the slowly decaying left tail: ~25% fewer nodes (fetch_reach)
_G_SWITCH = math.log(0.7)  # Laplace estimate of log P above this: integrate the complement
_G_MAX_NODES = 5000  # per side, a guard only (typical: 30 .. 60 nodes in all)


@njit(cache=True, error_model="numpy")
def _pl_item(u: float) -> tuple[float, float, float]:
    """``(L, L', L'')`` at ``u``: :math:`L(u) = \\log(1 - e^{-e^u})`, :math:`L' = v/(e^v - 1)`, :math:`v = e^u`."""
    if u < _G_TINY:
        v = math.exp(u)
        return u - 0.5 * v, 1.0 - 0.5 * v, -0.5 * v
    if u > _G_HUGE:
        return 0.0, 0.0, 0.0
    v = math.exp(u)
    if v <= _LN2:
        om = -math.expm1(-v)  # 1 - e^{-v} without cancellation
        ev = 1.0 - om
        lg = math.log(om)
    else:
        ev = math.exp(-v)
        om = 1.0 - ev
        lg = math.log1p(-ev)
    phi = v * ev / om
    return lg, phi, phi * (1.0 - v / om)


@njit(cache=True, error_model="numpy")
def _pl_slopes(s: float, x: np.ndarray) -> tuple[float, float]:
    """:math:`h'(s)`, :math:`h''(s)` (no logarithms: what Newton needs for the direct form)."""
    h1 = 0.0
    h2 = 0.0
    for i in range(x.size):
        u = s + x[i]
        if u < _G_TINY:
            v = math.exp(u)
            h1 += 1.0 - 0.5 * v
            h2 -= 0.5 * v
        elif u <= _G_HUGE:
            v = math.exp(u)
            if v <= _LN2:
                om = -math.expm1(-v)
                ev = 1.0 - om
            else:
                ev = math.exp(-v)
                om = 1.0 - ev
            phi = v * ev / om
            h1 += phi
            h2 += phi * (1.0 - v / om)
    return h1, h2


@njit(cache=True, error_model="numpy")
def _pl_sums(s: float, x: np.ndarray) -> tuple[float, float, float]:
    """:math:`h(s)`, :math:`h'(s)`, :math:`h''(s)`."""
    h = 0.0
    h1 = 0.0
    h2 = 0.0
    for i in range(x.size):
        lg, p, q = _pl_item(s + x[i])
        h += lg
        h1 += p
        h2 += q
    return h, h1, h2


@njit(cache=True, error_model="numpy")
def _pl_comp_derivs(s: float, x: np.ndarray) -> tuple[float, float, float]:
    """``(c, c', c'')`` of the complement form at ``s`` (``c = -inf`` once :math:`h` rounds to 0)."""
    h, h1, h2 = _pl_sums(s, x)
    return _comp_from_h(s, h, h1, h2)


@njit(cache=True, error_model="numpy")
def _comp_from_h(s: float, h: float, h1: float, h2: float) -> tuple[float, float, float]:
    """``(c, c', c'')`` of the complement form at ``s`` from :math:`h, h', h''` there."""
    es = math.exp(s)
    if not h < 0.0:
        return -np.inf, -np.inf, -1.0
    w = -h
    E = math.expm1(w)  # e^{-h} - 1 > 0
    d1 = 1.0 - es - h1 / E
    # e^{w} / E^2 = 1 / (E (1 - e^{-w})): no overflow when w is large
    d2 = -es - h2 / E - h1 * h1 / (E * -math.expm1(-w))
    return s - es + math.log(-math.expm1(h)), d1, d2


@njit(cache=True, error_model="numpy", inline="always")
def _direct_slopes(s: float, h1: float, h2: float) -> tuple[float, float]:
    """``(f', f'')`` of the direct form :math:`f = s - e^s + h` at ``s`` from :math:`h', h''` there."""
    es = math.exp(s)
    return 1.0 - es + h1, -es + h2


@njit(cache=True, error_model="numpy")
def _newton_step(s: float, d1: float, d2: float, lo: float, hi: float) -> tuple[float, float, float, bool]:
    """One safeguarded Newton step for the mode: ``(next s, lo, hi, converged)``.

    The bracket keeps the side where the derivative ``d1`` is positive below ``s``; a step that leaves it (or a
    non-concave point) bisects instead. Converged: a Newton step below 1e-3 sigma (bisection steps never count:
    flat tails fool the scale), or a bracket at rounding level.
    """
    if d1 > 0.0:
        lo = s
    else:
        hi = s
    newton = d2 < 0.0 and d1 == d1
    sn = s - d1 / d2 if newton else 0.5 * (lo + hi)
    if not (lo < sn < hi):
        newton = False
        sn = 0.5 * (lo + hi)
    done = (newton and abs(sn - s) * math.sqrt(-d2) < 1e-3) or hi - lo <= 1e-12 * (1.0 + abs(s))
    return sn, lo, hi, done


@njit(cache=True, error_model="numpy")
def _pl_mode(comp: bool, x: np.ndarray) -> tuple[float, float, float]:
    """Mode ``s0`` of the direct (``comp`` False) or complement form, its value and second derivative.

    Newton on the derivative, safeguarded by bisection inside a bracket where the derivative changes sign:
    direct :math:`(-1, \\log(n+1) + 1)`, complement :math:`(\\min(-\\max x - 3, -1/2), 0)`.
    """
    n = x.size
    if comp:
        xmax = -np.inf
        xmin = np.inf
        for i in range(n):
            xmax = max(xmax, x[i])
            xmin = min(xmin, x[i])
        lo = min(-xmax - 3.0, -0.5)
        hi = 0.0
        s = min(max(-xmin, lo), hi)  # where the slowest item's race is decided
    else:
        lo = -1.0
        hi = math.log(n + 1.0) + 1.0
        s = 0.5 * math.log(n + 1.0)
    f = 0.0
    d2 = -1.0
    for _ in range(200):
        if comp:
            f, d1, d2 = _pl_comp_derivs(s, x)
        else:
            h1, h2 = _pl_slopes(s, x)
            d1, d2 = _direct_slopes(s, h1, h2)
        sn, lo, hi, done = _newton_step(s, d1, d2, lo, hi)
        if done:
            break
        s = sn
    if not comp:
        f = s - math.exp(s) + _pl_sums(s, x)[0]
    return s, f, d2


@njit(cache=True, error_model="numpy")
def _pl_prepare(x: np.ndarray, s0: float, u0: np.ndarray, b: np.ndarray) -> tuple[int, int, float]:
    """Split the items for node evaluations around ``s0``: ``(n_mid, n_low, sum_low)``.

    Items with :math:`x_i + s_0 < -\\_G\\_CLASS` have :math:`L = u` exactly on the whole window and are summed as
    ``n_low * delta + sum_low``; items above ``_G_CLASS`` have :math:`L = 0`. The others get
    ``u0 = x_i + s0`` and ``b = e^{u0}``, so that a node at ``s0 + delta`` needs :math:`v = b e^{\\delta}` (one
    multiply) instead of an exponential per item.
    """
    n_mid = 0
    n_low = 0
    sum_low = 0.0
    for i in range(x.size):
        u = x[i] + s0
        if u < -_G_CLASS:
            n_low += 1
            sum_low += u
        elif u <= _G_CLASS:
            u0[n_mid] = u
            b[n_mid] = math.exp(u)
            n_mid += 1
    return n_mid, n_low, sum_low


@njit(cache=True, error_model="numpy")
def _pl_h_at(delta: float, rho: float, u0: np.ndarray, b: np.ndarray, n_mid: int, n_low: int,
             sum_low: float) -> float:
    """:math:`h(s_0 + \\delta)` with ``rho = e^delta``: one ``exp``/``expm1`` per item, logs taken per product.

    Factors :math:`1 - e^{-v}` are multiplied (flushed to a log before underflow); those within 1e-3 of 1 are
    summed as a series of :math:`\\log(1 - e^{-v})` instead, so that a tiny :math:`h` (near-certain orderings)
    keeps its relative precision for the complement form.
    """
    h = n_low * delta + sum_low
    prod = 1.0
    lacc = 0.0
    ser = 0.0
    for k in range(n_mid):
        u = u0[k] + delta
        if u < _G_TINY:
            h += u - 0.5 * (b[k] * rho)
        elif u <= _G_HUGE:
            v = b[k] * rho
            if v <= _LN2:
                prod *= -math.expm1(-v)
            else:
                ev = math.exp(-v)
                if ev < 1e-3:
                    ser -= ev * (1.0 + ev * (0.5 + ev * (1.0 / 3.0 + ev * (0.25 + ev * 0.2))))
                else:
                    prod *= 1.0 - ev
            if prod < 1e-250:
                lacc += math.log(prod)
                prod = 1.0
    return h + ser + (lacc + math.log(prod))


def _h_at(s0: float, delta: float, hargs: tuple) -> float:
    r""":math:`h(s_0 + \delta)` of a group: per item (``hargs`` = the 5 arguments of :func:`_pl_h_at` after
    :math:`\rho`) or binned (the 6 arguments of :func:`_gb_h0` after ``s``, then those 5 for the items of the bins
    too sparse to bin). Compiled only."""
    raise NotImplementedError("compiled only")


@overload(_h_at, inline="always")
def _h_at_impl(s0, delta, hargs):  # Numba types, at compile time
    if len(hargs) == 5:
        def per_item(s0, delta, hargs):
            return _pl_h_at(delta, math.exp(delta), *hargs)
        return per_item

    def binned(s0, delta, hargs):
        return (_gb_h0(s0 + delta, hargs[0], hargs[1], hargs[2], hargs[3], hargs[4], hargs[5])
                + _pl_h_at(delta, math.exp(delta), hargs[6], hargs[7], hargs[8], hargs[9], hargs[10]))
    return binned


@njit(cache=True, error_model="numpy")
def _node(comp: bool, u: float, s0: float, sig: float, f0: float, beta: float, gamma: float, hargs: tuple) -> float:
    """Log of the mapped integrand at ``u`` relative to the mode ``f0`` (``-inf`` beyond the window or the last
    edge): the direct form, or the complement with ``comp``; :math:`h` from :func:`_h_at`."""
    eg = math.exp(-gamma * u)
    delta = sig * ((1.0 - beta) * u + beta * (1.0 - eg) / gamma)
    if abs(delta) > _G_WINDOW:
        return -np.inf
    hh = _h_at(s0, delta, hargs)
    s = s0 + delta
    if comp:
        if not hh < 0.0:
            return -np.inf  # 1 - e^h rounds to 0
        return s - math.exp(s) + math.log(-math.expm1(hh)) - f0 + math.log((1.0 - beta) + beta * eg)
    return s - math.exp(s) + hh - f0 + math.log((1.0 - beta) + beta * eg)


@njit(cache=True, error_model="numpy")
def _trapezoid(comp: bool, s0: float, sig: float, f0: float, beta: float, gamma: float, step: float,
               step_max: float, accept: float, hargs: tuple) -> float:
    """The integral of the direct (``comp`` False) or complement integrand over ``sig e^{f0}``: mapped
    trapezoid rule around the mode ``s0``, halving (:func:`_node`; per item or binned by ``hargs``).

    Level 0 walks outwards with step ``H`` until the integrand is ``_G_DROP`` below the mode and is checked
    against the rule with step ``2H`` on every other node; each further level adds the midpoints. The rule
    converges geometrically (the error roughly squares when the step halves), so once two levels agree to
    ``accept`` the finer one is accurate to about its square.
    """
    H = min(step, step_max / sig)  # level-0 step in u (units of sigma)
    acc = 1.0  # the node at the mode: e^{f0 - f0} m'(0), m'(0) = 1
    even = 1.0  # the nodes of the rule with step 2H
    kr = 0
    kl = 0
    for side in range(2):
        direction = 1.0 if side == 0 else -1.0
        k = 1
        while k <= _G_MAX_NODES:
            e = math.exp(_node(comp, direction * k * H, s0, sig, f0, beta, gamma, hargs))
            acc += e
            if k % 2 == 0:
                even += e
            if e < _G_EDROP:
                break
            k += 1
        if side == 0:
            kr = k
        else:
            kl = k
    prev = H * acc
    if abs(prev - 2.0 * H * even) <= accept * prev:
        return prev
    h = H
    n_new = kl + kr
    for _ in range(_G_MAX_LEVELS):
        h *= 0.5
        for i in range(n_new):
            acc += math.exp(_node(comp, -kl * H + (2 * i + 1) * h, s0, sig, f0, beta, gamma, hargs))
        cur = h * acc
        if abs(cur - prev) <= accept * cur:
            return cur
        prev = cur
        n_new *= 2
    return prev


@njit(cache=True, error_model="numpy")
def _pl_integral(comp: bool, x: np.ndarray, s0: float, sig: float, beta: float, gamma: float, step: float,
                 step_max: float, accept: float, u0: np.ndarray, b: np.ndarray) -> float:
    """Log of the direct (``comp`` False) or complement integral of a group's items ``x``: :func:`_trapezoid`."""
    n_mid, n_low, sum_low = _pl_prepare(x, s0, u0, b)
    h0 = _pl_h_at(0.0, 1.0, u0, b, n_mid, n_low, sum_low)
    if comp:
        if not h0 < 0.0:
            return -np.inf
        f0 = s0 - math.exp(s0) + math.log(-math.expm1(h0))
    else:
        f0 = s0 - math.exp(s0) + h0
    return f0 + math.log(sig * _trapezoid(comp, s0, sig, f0, beta, gamma, step, step_max, accept,
                                          (u0, b, n_mid, n_low, sum_low)))


@njit(cache=True, error_model="numpy")
def _group_term_finite(x: np.ndarray, buf: np.ndarray) -> float:
    """:func:`group_term` for finite ``x``."""
    n = x.size
    if n == 0:
        return 0.0
    if n == 1:  # closed form: log sigma(x), the Bradley-Terry pair
        z = -x[0]
        return -(max(z, 0.0) + math.log1p(math.exp(-abs(z))))
    u0 = buf[0]
    b = buf[1]
    s0, g0, g2 = _pl_mode(False, x)
    sig = 1.0 / math.sqrt(-g2)
    if g0 + math.log(sig) + _LOG_SQRT_2PI < _G_SWITCH:  # Laplace estimate: P not close to 1
        lp = _pl_integral(False, x, s0, sig, _G_MAP_DIRECT[0], _G_MAP_DIRECT[1], _G_STEP, _G_STEP_MAX,
                          _G_ACCEPT, u0, b)
        if lp <= math.log(0.9):
            return lp
    sc, c0, c2 = _pl_mode(True, x)
    if c0 == -np.inf:
        return 0.0  # 1 - P underflows: log P = -(1 - P) rounds to 0
    sigc = 1.0 / math.sqrt(-c2) if c2 < 0.0 else 1.0
    lq = _pl_integral(True, x, sc, sigc, _G_MAP_COMP[0], _G_MAP_COMP[1], _G_STEP, _G_STEP_MAX, _G_ACCEPT,
                      u0, b)
    if lq <= math.log(0.5):
        return math.log1p(-math.exp(lq))
    return _pl_integral(False, x, s0, sig, _G_MAP_DIRECT[0], _G_MAP_DIRECT[1], _G_STEP, _G_STEP_MAX,
                        _G_ACCEPT, u0, b)


@njit(cache=True, error_model="numpy")
def group_term(x: np.ndarray, buf: np.ndarray) -> float:
    """:math:`\\log P_k` for one group with :math:`x_i = a_i - \\log\\Lambda_k` (see the section comment).

    ``buf`` is scratch of shape (2, >= len(x)). Relative precision ~1e-13 (measured, see the section comment) for
    any finite ``x``, up to the conditioning of the inputs themselves (a relative change of :math:`\\log P_k` of about
    :math:`|x| \\epsilon` when :math:`P_k` is near 1); finite for finite input, ``-inf`` if an item has
    ``x = -inf``, NaN if any ``x`` is NaN.
    """
    n_inf = 0
    for i in range(x.size):
        if x[i] != x[i]:
            return np.nan
        if x[i] == -np.inf:
            return -np.inf
        if x[i] == np.inf:
            n_inf += 1
    if n_inf == 0:
        return _group_term_finite(x, buf)
    # an item infinitely far above the lower groups always ranks above them: drop it
    y = np.empty(x.size - n_inf)
    k = 0
    for i in range(x.size):
        if x[i] != np.inf:
            y[k] = x[i]
            k += 1
    return _group_term_finite(y, buf)


# ---------------------------------------------------------------------------------- large groups: binned moments
#
# For a group of n >= _GB_MIN items the O(n Q) node evaluations dominate (Q ~ 50 nodes and Newton steps, each an
# exp and a log per item). Bin the returns a_i of the group on a grid of width _GB_WIDTH, centres c_b, and keep per
# bin the moments M_bq = sum_{i in b} d_i^q / q!, d_i = a_i - c_b (|d_i| <= _GB_WIDTH / 2), q < _GB_ORDER: a counting
# sort of the d_i by bin, then vectorised power sums per bin, O(n _GB_ORDER) multiply-adds and no transcendental
# function per item. Then, with u_b = s - log Lambda + c_b,
#   h(s) = sum_i L(s + x_i) = sum_b sum_q L^(q)(u_b) M_bq,
# L's Taylor coefficients at u_b from power-series arithmetic (exp of a series, log of a series: O(Q^2) per bin and
# node, stable since e^{-v} v^q / q! <= 1), and likewise h', h''. L is analytic within pi/2 of the real axis, so the
# truncation error per item is about (_GB_WIDTH / 2 / 1.2)^_GB_ORDER |L| < 2e-14 |L|. Bins far below (u_b < _G_TINY)
# use L = u - v/2 in closed form (sum_i e^{d_i} = sum_q M_bq); bins far above contribute nothing. The same moments
# give the group's logsumexp for Lambda (sum_i e^{a_i} = sum_b e^{c_b} sum_q M_bq); the last group, which has no
# term of its own, gets its logsumexp without moments (_logsumexp_fast). A node then costs O(bins Q^2)
# instead of O(n): about 100 bins for returns spread over 10 nats. Used for the direct form (_gb_direct) and, when
# P_k is close to 1, the complement form (_gb_comp). A bin's Taylor series costs about as much as _GB_DENSE items of
# the per-item path, so a group may bin only its bins of at least _GB_DENSE items and sum the items of the sparser
# bins one by one beside them (since 2026-12-06: the shipped groups spread over ~27 nats had gone per item as a whole);
# _gb_moments picks that, every bin binned, or the per-item path by a cost rule. Groups spread over more than 8 n
# bins or with non-finite returns use the per-item path.
_GB_MIN = 64  # below this a bin rarely pays; _gb_moments decides by its own cost rule above it
_GB_BIN_COST = 10.0  # a bin's Taylor series at a node costs about as much as this many items of the per-item path
_GB_DENSE = 10  # items in a bin from which its Taylor series is cheaper than the items one by one
_GB_WIDTH = 0.1
_GB_ORDER = 10  # 12 until 2026-12-05: 1.15x slower nodes and binning for a truncation error below 1e-17
# (_gb_power_sums writes exactly these ten orders)
_GB_T = _GB_ORDER + 2  # Taylor coefficients needed for h'' (orders 0 .. _GB_ORDER + 1)
_INV_FACT = np.array([1.0 / math.factorial(q) for q in range(_GB_T + 1)])
_FACT = np.array([float(math.factorial(q)) for q in range(_GB_T + 1)])
_INV_INT = np.array([0.0] + [1.0 / q for q in range(1, _GB_T + 1)])


@njit(cache=True, error_model="numpy", fastmath=_FM)
def _gb_power_sums(d: np.ndarray, i0: int, i1: int, out: np.ndarray) -> None:
    """``out[q] = sum_i d_i^q / q!`` for ``q < _GB_ORDER`` over ``d[i0:i1]`` (reassociated: vectorised)."""
    s1 = 0.0
    s2 = 0.0
    s3 = 0.0
    s4 = 0.0
    s5 = 0.0
    s6 = 0.0
    s7 = 0.0
    s8 = 0.0
    s9 = 0.0
    for i in range(i0, i1):
        x = d[i]
        x2 = x * x
        x4 = x2 * x2
        x8 = x4 * x4
        s1 += x
        s2 += x2
        s3 += x2 * x
        s4 += x4
        s5 += x4 * x
        s6 += x4 * x2
        s7 += x4 * x2 * x
        s8 += x8
        s9 += x8 * x
    out[0] = i1 - i0
    out[1] = s1
    out[2] = s2 * _INV_FACT[2]
    out[3] = s3 * _INV_FACT[3]
    out[4] = s4 * _INV_FACT[4]
    out[5] = s5 * _INV_FACT[5]
    out[6] = s6 * _INV_FACT[6]
    out[7] = s7 * _INV_FACT[7]
    out[8] = s8 * _INV_FACT[8]
    out[9] = s9 * _INV_FACT[9]


@njit(cache=True, error_model="numpy")
def _gb_moments(a: np.ndarray, items: np.ndarray, buf: np.ndarray) -> tuple[np.ndarray, np.ndarray, int,
                                                                              np.ndarray]:
    """``(centres, moments, n_bins, sparse)`` of one group's returns: every bin carries its items' moments, or (when
    the cost rule prefers it) only the bins of at least ``_GB_DENSE`` items, and the returns of the other items are
    ``sparse``; ``n_bins = 0`` when binning does not pay (the cost rule, returns spread over more than 8 n bins,
    non-finite returns): the caller then uses the per-item path. ``buf``: scratch of shape (>= 2, >= n).

    ``moments`` has ``_GB_ORDER + 3`` columns: the moments, then the exclusive prefix sums over the bins below of
    :math:`M_0`, :math:`M_0 c_b + M_1` and (as a logarithm) :math:`e^{c_b} \\sum_q M_{bq}`: the closed form of the
    bins below ``_G_TINY`` at any node in O(1) (:func:`_gb_h`)."""
    n = items.size
    v_ = buf[0]  # the returns gathered once, then read in order by every later pass
    lo = np.inf
    hi = -np.inf
    for r in range(n):
        v = a[items[r]]
        v_[r] = v
        lo = min(lo, v)
        hi = max(hi, v)
    none = (np.zeros(0), np.zeros((0, _GB_ORDER + 3)), 0, np.zeros(0))
    if not (hi - lo < np.inf):
        return none
    nb = int((hi - lo) / _GB_WIDTH) + 1
    if nb > 8 * n:
        return none
    cen = np.empty(nb)
    for b in range(nb):
        cen[b] = lo + (b + 0.5) * _GB_WIDTH
    mom = np.zeros((nb, _GB_ORDER + 3))
    inv_w = 1.0 / _GB_WIDTH
    # a counting sort of the offsets d_i by bin, then each bin's power sums over contiguous memory (vectorised):
    # 1.3x the direct accumulation of ten moments per item into its bin's row (ten loads and stores per item)
    start = np.zeros(nb + 1, np.int64)
    for r in range(n):
        start[min(int((v_[r] - lo) * inv_w), nb - 1) + 1] += 1
    for b in range(nb):
        start[b + 1] += start[b]
    pos = start[:nb].copy()
    d_ = buf[1]
    for r in range(n):
        v = v_[r]
        b = min(int((v - lo) * inv_w), nb - 1)
        d_[pos[b]] = v - cen[b]
        pos[b] += 1
    for b in range(nb):
        if start[b + 1] > start[b]:
            _gb_power_sums(d_, start[b], start[b + 1], mom[b])
    n_full = 0
    n_dense = 0
    n_sparse = 0
    for b in range(nb):
        if mom[b, 0] >= _GB_DENSE:
            n_dense += 1
        elif mom[b, 0] > 0.0:
            n_full += 1
            n_sparse += int(mom[b, 0])
    n_full += n_dense
    # cost per node in item evaluations: every bin binned (only those within a node's window of _G_TINY .. _G_HUGE
    # cost), the dense ones binned and the rest per item, or all per item
    window = (_G_HUGE - _G_TINY) / _GB_WIDTH + 2.0
    all_bins = _GB_BIN_COST * min(n_full, window)
    hybrid = _GB_BIN_COST * min(n_dense, window) + n_sparse
    if min(all_bins, hybrid) >= n:
        return none
    # taking the sparse items out is one more pass over the group: worth it from ~100 nodes x the saving per node
    if all_bins - hybrid <= n / 400.0:
        n_sparse = 0
    sparse = np.empty(n_sparse)
    if n_sparse > 0:  # the sparse bins' items go one by one: out of the moments
        k = 0
        for r in range(n):
            v = v_[r]
            b = min(int((v - lo) * inv_w), nb - 1)
            if mom[b, 0] < _GB_DENSE:
                sparse[k] = v
                k += 1
        for b in range(nb):
            if mom[b, 0] < _GB_DENSE:
                mom[b, :_GB_ORDER] = 0.0
    p0 = 0.0
    p1 = 0.0
    lpe = -np.inf
    for b in range(nb):
        mom[b, _GB_ORDER] = p0
        mom[b, _GB_ORDER + 1] = p1
        mom[b, _GB_ORDER + 2] = lpe
        if mom[b, 0] > 0.0:
            se = 0.0
            for q in range(_GB_ORDER - 1, -1, -1):
                se += mom[b, q]
            p0 += mom[b, 0]
            p1 += mom[b, 0] * cen[b] + mom[b, 1]
            v = cen[b] + math.log(se)
            hi_ = max(lpe, v)
            lpe = hi_ + math.log1p(math.exp(min(lpe, v) - hi_))
    return cen, mom, nb, sparse


@njit(cache=True, error_model="numpy")
def _gb_logsumexp(cen: np.ndarray, mom: np.ndarray, nb: int, sparse: np.ndarray) -> float:
    """:math:`\\log\\sum_i e^{a_i}` of a binned group: :math:`\\sum_i e^{d_i} = \\sum_q M_{bq}` per dense bin, the
    sparse items one by one."""
    m = -np.inf
    for b in range(nb):
        if mom[b, 0] > 0.0:
            m = max(m, cen[b])
    for i in range(sparse.size):
        m = max(m, sparse[i])
    acc = 0.0
    for b in range(nb):
        if mom[b, 0] > 0.0:
            se = 0.0
            for q in range(_GB_ORDER - 1, -1, -1):
                se += mom[b, q]
            acc += math.exp(cen[b] - m) * se
    for i in range(sparse.size):
        acc += math.exp(sparse[i] - m)
    return m + math.log(acc)


@njit(cache=True, error_model="numpy", fastmath=_FM)  # reassociated sums: 1.3x, h within 6e-14 relative
def _pl_taylor(u: float, T: np.ndarray, f: np.ndarray, M: int) -> None:
    """``T[q] = L^(q)(u) / q!`` for ``q < M``, :math:`L(u) = \\log(1 - e^{-e^u})`, by series arithmetic:
    :math:`e^{-v e^d} = e^{-v} \\exp(g(d))` with :math:`g = -v (e^d - 1)`, then the logarithm of
    :math:`1 - e^{-v e^d}`. ``T`` and ``f`` are scratch of length >= ``M``; the orders below ``M`` do not depend on
    ``M``."""
    v = math.exp(u)
    for k in range(1, M):  # T holds k g_k = -v / (k-1)! until the log series overwrites it from below
        T[k] = -(v * _INV_FACT[k - 1])
    f[0] = 1.0
    for n in range(1, M):  # f = exp(g): f_n = (1/n) sum_k k g_k f_{n-k}
        acc = 0.0
        for k in range(1, n + 1):
            acc += T[k] * f[n - k]
        f[n] = acc * _INV_INT[n]
    ev = math.exp(-v)
    if v <= _LN2:
        D0 = -math.expm1(-v)
        T[0] = math.log(D0)
    else:
        D0 = 1.0 - ev
        T[0] = math.log1p(-ev)
    iD0 = 1.0 / D0
    for n in range(1, M):
        f[n] = -ev * f[n]  # D_n, the series of 1 - e^{-v e^d} above order 0
    for n in range(1, M):  # y = log(D): y_n = (D_n - (1/n) sum_{k<n} k y_k D_{n-k}) / D_0
        acc = 0.0
        for k in range(1, n):
            acc += k * T[k] * f[n - k]
        T[n] = (f[n] - acc * _INV_INT[n]) * iD0


@njit(cache=True, error_model="numpy", inline="always")
def _gb_below(z: float, cen: np.ndarray, mom: np.ndarray, nb: int) -> tuple[int, int, float, float, float]:
    """``(bl, bh, n0, s1, hv)`` at ``z = s + shift``: bins ``[0, bl)`` lie below ``_G_TINY`` (closed form
    :math:`L = u - v/2` from the prefix sums: ``n0`` items, ``s1`` their summed centres, ``hv`` the summed
    :math:`v/2`), bins ``[bh, nb)`` above ``_G_HUGE`` (:math:`L = 0`)."""
    half = 0.5 * _GB_WIDTH
    bl = min(max(int(math.ceil((_G_TINY - half - z - cen[0]) / _GB_WIDTH)), 0), nb)
    bh = min(max(int(math.floor((_G_HUGE + half - z - cen[0]) / _GB_WIDTH)) + 1, bl), nb)
    if bl < nb:
        n0, s1, lse_ = mom[bl, _GB_ORDER], mom[bl, _GB_ORDER + 1], mom[bl, _GB_ORDER + 2]
    else:  # every bin below: the prefix sums through the last one
        last = nb - 1
        n0 = mom[last, _GB_ORDER] + mom[last, 0]
        s1 = mom[last, _GB_ORDER + 1] + mom[last, 0] * cen[last] + mom[last, 1]
        se = 0.0
        for q in range(_GB_ORDER - 1, -1, -1):
            se += mom[last, q]
        v = cen[last] + math.log(se) if se > 0.0 else -np.inf
        lp = mom[last, _GB_ORDER + 2]
        hi_ = max(lp, v)
        lse_ = hi_ + math.log1p(math.exp(min(lp, v) - hi_)) if hi_ > -np.inf else -np.inf
    return bl, bh, n0, s1, 0.5 * math.exp(z + lse_)


@njit(cache=True, error_model="numpy")
def _gb_h0(s: float, shift: float, cen: np.ndarray, mom: np.ndarray, nb: int, T: np.ndarray,
           f: np.ndarray) -> float:
    """:math:`h(s)` alone (a quadrature node): :func:`_gb_h`'s first value (bit for bit) with Taylor series two
    orders shorter, as no :math:`h', h''` are needed."""
    z = s + shift
    bl, bh, n0, s1, hv = _gb_below(z, cen, mom, nb)
    h = n0 * z + s1 - hv
    for b in range(bl, bh):
        if mom[b, 0] == 0.0:
            continue
        _pl_taylor(z + cen[b], T, f, _GB_ORDER)
        for q in range(_GB_ORDER - 1, -1, -1):
            h += T[q] * (mom[b, q] * _FACT[q])
    return h


@njit(cache=True, error_model="numpy")
def _gb_h(s: float, shift: float, cen: np.ndarray, mom: np.ndarray, nb: int, T: np.ndarray,
          f: np.ndarray) -> tuple[float, float, float]:
    """:math:`h(s), h'(s), h''(s)` of a binned group, :math:`u_b = s + \\text{shift} + c_b`."""
    z = s + shift
    bl, bh, n0, s1, hv = _gb_below(z, cen, mom, nb)
    h = n0 * z + s1 - hv
    h1 = n0 - hv
    h2 = -hv
    for b in range(bl, bh):
        if mom[b, 0] == 0.0:
            continue
        _pl_taylor(z + cen[b], T, f, _GB_T)  # between _G_TINY and _G_HUGE: L's Taylor series about the bin centre
        for q in range(_GB_ORDER - 1, -1, -1):
            mq = mom[b, q] * _FACT[q]  # sum_i d_i^q
            h += T[q] * mq
            h1 += (q + 1) * T[q + 1] * mq
            h2 += (q + 1) * (q + 2) * T[q + 2] * mq
    return h, h1, h2


@njit(cache=True, error_model="numpy")
def _gb_sums(s: float, shift: float, cen: np.ndarray, mom: np.ndarray, nb: int, T: np.ndarray, f: np.ndarray,
             xs: np.ndarray) -> tuple[float, float, float]:
    """:math:`h, h', h''` at ``s`` of a binned group: :func:`_gb_h` plus the sparse items ``xs`` (shifted)."""
    h, h1, h2 = _gb_h(s, shift, cen, mom, nb, T, f)
    if xs.size > 0:
        hs, hs1, hs2 = _pl_sums(s, xs)
        h += hs
        h1 += hs1
        h2 += hs2
    return h, h1, h2


@njit(cache=True, error_model="numpy")
def _gb_integral(comp: bool, s0: float, sig: float, shift: float, cen: np.ndarray, mom: np.ndarray, nb: int,
                 xs: np.ndarray, buf: np.ndarray, T: np.ndarray, f: np.ndarray) -> float:
    """Log of the direct (``comp`` False) or complement integral of a binned group about its mode ``s0``:
    :func:`_pl_integral` with :math:`h` from the dense bins' moments and the sparse items ``xs``."""
    n_mid, n_low, sum_low = _pl_prepare(xs, s0, buf[0], buf[1])
    h0 = _gb_h0(s0, shift, cen, mom, nb, T, f) + _pl_h_at(0.0, 1.0, buf[0], buf[1], n_mid, n_low, sum_low)
    if comp:
        if not h0 < 0.0:
            return -np.inf
        f0 = s0 - math.exp(s0) + math.log(-math.expm1(h0))
        beta, gamma = _G_MAP_COMP
    else:
        f0 = s0 - math.exp(s0) + h0
        beta, gamma = _G_MAP_DIRECT
    return f0 + math.log(sig * _trapezoid(comp, s0, sig, f0, beta, gamma, _G_STEP, _G_STEP_MAX, _G_ACCEPT,
                                          (shift, cen, mom, nb, T, f, buf[0], buf[1], n_mid, n_low, sum_low)))


@njit(cache=True, error_model="numpy")
def _gb_direct(n: int, shift: float, cen: np.ndarray, mom: np.ndarray, nb: int, sparse: np.ndarray,
               buf: np.ndarray) -> float:
    """:math:`\\log P_k` by the direct form on binned moments (:func:`_pl_mode` and :func:`_pl_integral` with
    :math:`h` from :func:`_gb_h` and the sparse items), or NaN when the direct form is not the right one (``P_k``
    close to 1). ``buf``: scratch of shape (3, >= len(sparse))."""
    T = np.empty(_GB_T)
    f = np.empty(_GB_T)
    xs = buf[2, :sparse.size]
    for i in range(sparse.size):
        xs[i] = sparse[i] + shift
    lo = -1.0
    hi = math.log(n + 1.0) + 1.0
    s = 0.5 * math.log(n + 1.0)
    d2 = -1.0
    for _ in range(200):
        h, h1, h2 = _gb_sums(s, shift, cen, mom, nb, T, f, xs)
        d1, d2 = _direct_slopes(s, h1, h2)
        sn, lo, hi, done = _newton_step(s, d1, d2, lo, hi)
        if done:
            break
        s = sn
    s0 = s
    sig = 1.0 / math.sqrt(-d2)
    f0 = s0 - math.exp(s0) + h
    if not (f0 + math.log(sig) + _LOG_SQRT_2PI < _G_SWITCH):
        return np.nan
    lp = _gb_integral(False, s0, sig, shift, cen, mom, nb, xs, buf, T, f)
    return lp if lp <= math.log(0.9) else np.nan


@njit(cache=True, error_model="numpy")
def _gb_comp(shift: float, cen: np.ndarray, mom: np.ndarray, nb: int, sparse: np.ndarray, buf: np.ndarray) -> float:
    """:math:`\\log P_k` by the complement form on binned moments, for a group that :func:`_gb_direct` sent on
    (``P_k`` close to 1); NaN when the complement is not the right form either (the caller goes per item).

    The same steps as the per-item path (:func:`_pl_mode` with ``comp``, :func:`_pl_integral`), with
    :math:`h, h', h''` from :func:`_gb_h` and the sparse items. Near the complement's mode the items'
    :math:`v = e^{u}` are moderate, where the bins' Taylor series converge fast; the far nodes (large :math:`v`,
    slower series) carry less than :math:`e^{-30}` of the integral. Checked against the per-item path to 1e-12
    relative (the tests).
    """
    T = np.empty(_GB_T)
    f = np.empty(_GB_T)
    half = 0.5 * _GB_WIDTH
    xmin = np.inf
    xmax = -np.inf
    for b in range(nb):
        if mom[b, 0] > 0.0:
            xmax = cen[b] + half + shift
            xmin = min(xmin, cen[b] - half + shift)
    xs = buf[2, :sparse.size]
    for i in range(sparse.size):
        xs[i] = sparse[i] + shift
        xmin = min(xmin, xs[i])
        xmax = max(xmax, xs[i])
    if not xmin < np.inf:
        return np.nan
    lo = min(-xmax - 3.0, -0.5)
    hi = 0.0
    s = min(max(-xmin, lo), hi)
    c0 = -np.inf
    d2 = -1.0
    for _ in range(200):
        h, h1, h2 = _gb_sums(s, shift, cen, mom, nb, T, f, xs)
        c0, d1, d2 = _comp_from_h(s, h, h1, h2)
        sn, lo, hi, done = _newton_step(s, d1, d2, lo, hi)
        if done:
            break
        s = sn
    if c0 == -np.inf:
        return 0.0  # 1 - P underflows: log P = -(1 - P) rounds to 0
    sig = 1.0 / math.sqrt(-d2) if d2 < 0.0 else 1.0
    lq = _gb_integral(True, s, sig, shift, cen, mom, nb, xs, buf, T, f)
    if lq == -np.inf:
        return 0.0
    return math.log1p(-math.exp(lq)) if lq <= math.log(0.5) else np.nan


@njit(cache=True, error_model="numpy")
def _gb_term(n: int, shift: float, cen: np.ndarray, mom: np.ndarray, nb: int, sparse: np.ndarray,
             buf: np.ndarray) -> float:
    """:math:`\\log P_k` of a binned group: the direct form, else the complement; NaN: use the per-item path."""
    term = _gb_direct(n, shift, cen, mom, nb, sparse, buf)
    if term != term:
        term = _gb_comp(shift, cen, mom, nb, sparse, buf)
    return term


@njit(cache=True, error_model="numpy")
def _logsumexp_at(a: np.ndarray, idx: np.ndarray) -> float:
    m = -np.inf
    for i in range(idx.size):
        m = max(m, a[idx[i]])
    if m == -np.inf or m == np.inf:
        return m
    acc = 0.0
    for i in range(idx.size):
        acc += math.exp(a[idx[i]] - m)
    return m + math.log(acc)


@njit(cache=True, error_model="numpy")
def _logsumexp_fast(a: np.ndarray, idx: np.ndarray) -> float:
    """:func:`_logsumexp_at` without an ``exp`` per item for groups of >= ``_GB_MIN`` returns within ``n``
    bins: :math:`e^{a_i - \\max} = e^{c_b - \\max} e^{d_i}` with one ``exp`` per bin and :math:`e^{d_i}`,
    :math:`|d_i| \\le` ``_GB_WIDTH`` / 2, a degree-9 polynomial (truncation below 3e-20 relative): 4x faster."""
    lo, hi = _extend_range(a, idx, np.inf, -np.inf)
    n = idx.size
    if n < _GB_MIN or not (hi - lo < n * _GB_WIDTH):  # also inf, NaN: the exact path's conventions
        return _logsumexp_at(a, idx)
    nb = int((hi - lo) / _GB_WIDTH) + 1
    tab = np.empty(nb)
    for b in range(nb):
        tab[b] = math.exp(lo + (b + 0.5) * _GB_WIDTH - hi)
    return hi + math.log(_exp_sum_binned(a, idx, lo, tab))


@njit(cache=True, error_model="numpy", fastmath=_FM)
def _exp_sum_binned(a: np.ndarray, idx: np.ndarray, lo: float, tab: np.ndarray) -> float:
    """:math:`\\sum_i e^{a_i - \\max}` given ``tab[b]`` :math:`= e^{c_b - \\max}` (:func:`_logsumexp_fast`)."""
    inv_w = 1.0 / _GB_WIDTH
    nb = tab.size
    acc = 0.0
    for r in range(idx.size):
        v = a[idx[r]]
        b = min(int((v - lo) * inv_w), nb - 1)
        d = v - (lo + (b + 0.5) * _GB_WIDTH)
        e = 1.0 + d * (1.0 + d * (0.5 + d * (_INV_FACT[3] + d * (_INV_FACT[4] + d * (_INV_FACT[5] + d * (
            _INV_FACT[6] + d * (_INV_FACT[7] + d * (_INV_FACT[8] + d * _INV_FACT[9]))))))))
        acc += e * tab[b]
    return acc


@njit(cache=True, error_model="numpy")
def grouped_loglik(a: np.ndarray, gitems: np.ndarray, goff: np.ndarray, gmarg: np.ndarray, gbuf: np.ndarray,
                   moff: np.ndarray) -> float:
    """Grouped Plackett-Luce log-likelihood :math:`\\sum_{k<K} \\log P_k` for scaled returns ``a``
    (:func:`_grouped`)."""
    return _grouped(a, gitems, goff, gmarg, gbuf, moff, False)


@njit(cache=True, error_model="numpy")
def grouped_loglik_bound(a: np.ndarray, gitems: np.ndarray, goff: np.ndarray, gmarg: np.ndarray, gbuf: np.ndarray,
                         moff: np.ndarray) -> float:
    """An upper bound on :func:`grouped_loglik` that needs no quadrature, rounding included (``inf``: none).

    :math:`h` is concave, so below its tangent at any :math:`s_0`; integrating
    :math:`e^{s - e^s + h(s_0) + h'(s_0)(s - s_0)}` gives
    :math:`\\log P_k \\le h(s_0) - h'(s_0)\\,s_0 + \\log\\Gamma(1 + h'(s_0))` (and :math:`\\le 0`), taken at two
    points near the direct form's mode. Two evaluations of :math:`h, h'` per group instead of a quadrature: what
    the sampler uses to reject a death proposal without the exact likelihood when even the bound fails the test.
    """
    return _grouped(a, gitems, goff, gmarg, gbuf, moff, True)


@njit(cache=True, error_model="numpy")
def _group_bound(a: np.ndarray, items: np.ndarray, log_lam: float, binned: bool, cen: np.ndarray, mom: np.ndarray,
                 sp: np.ndarray, gbuf: np.ndarray) -> float:
    """:func:`grouped_loglik_bound`'s term of one group (``inf``: none)."""
    if not (log_lam == log_lam and abs(log_lam) < np.inf):
        return np.inf
    n = items.size
    s_a = 0.5 * math.log(n + 1.0)
    if binned:
        T = np.empty(_GB_T)
        f = np.empty(_GB_T)
        xs = gbuf[2, :sp.size]
        for i in range(sp.size):
            xs[i] = sp[i] - log_lam
        h, h1, _ = _gb_sums(s_a, -log_lam, cen, mom, cen.size, T, f, xs)
        b = _tangent(h, h1, s_a)
        s_b = math.log(h1 + 0.5)  # about the direct form's mode (e^s = 1 + h')
        h, h1, _ = _gb_sums(s_b, -log_lam, cen, mom, cen.size, T, f, xs)
    else:
        x = gbuf[2, :n]
        for i in range(n):
            x[i] = a[items[i]] - log_lam
        h, h1, _ = _pl_sums(s_a, x)
        b = _tangent(h, h1, s_a)
        s_b = math.log(h1 + 0.5)
        h, h1, _ = _pl_sums(s_b, x)
    b = min(b, _tangent(h, h1, s_b))
    if b != b:
        return np.inf
    return min(b, 0.0)


@njit(cache=True, error_model="numpy")
def _tangent(h: float, h1: float, s0: float) -> float:
    """:math:`h(s_0) - h'(s_0) s_0 + \\log\\Gamma(1 + h'(s_0))` plus a slack for rounding (1e-9 of its terms)."""
    lg = math.lgamma(1.0 + h1)
    return h - h1 * s0 + lg + 1e-9 * (abs(h) + abs(h1 * s0) + abs(lg) + 1.0)


@njit(cache=True, error_model="numpy")
def _grouped(a: np.ndarray, gitems: np.ndarray, goff: np.ndarray, gmarg: np.ndarray, gbuf: np.ndarray,
             moff: np.ndarray, bound: bool) -> float:
    """Grouped Plackett-Luce log-likelihood :math:`\\sum_{k<K} \\log P_k` for scaled returns ``a``.

    ``gitems[goff[k]:goff[k+1]]`` are the trajectories of group ``k`` (best first), ``gmarg`` the K x K margins
    :math:`m_{k\\ell}` (upper triangle) or, when empty, ``moff`` the offsets of additive margins
    (:math:`m_{k\\ell} = o_\\ell - o_k`), ``gbuf`` scratch of shape (4, >= max(largest group, K)).
    :math:`\\log\\Lambda_k = \\mathrm{logsumexp}_{\\ell > k}(m_{k\\ell} + \\mathrm{logsumexp}_{j \\in G_\\ell} a_j)`:
    O(N + K^2) for all terms with a matrix, O(N + K) with offsets (a running logsumexp over the worse groups,
    :math:`\\log\\Lambda_k = -o_k + \\mathrm{logsumexp}_{\\ell > k}(o_\\ell + \\ldots)`), then O(n_k Q) per group.
    """
    K = goff.size - 1
    lse = gbuf[3]
    # large groups: binned moments (see above), computed once and used for Lambda and for the group's own term
    slot = np.full(K, -1, np.int64)
    cens = [np.zeros(0)]
    moms = [np.zeros((0, _GB_ORDER + 3))]
    sps = [np.zeros(0)]
    for k in range(K - 1):  # the last group has no term: only its logsumexp is needed, without moments
        if goff[k + 1] - goff[k] >= _GB_MIN:
            cen, mom, nb, sp = _gb_moments(a, gitems[goff[k]:goff[k + 1]], gbuf)
            if nb > 0:
                slot[k] = len(cens)
                cens.append(cen)
                moms.append(mom)
                sps.append(sp)
    for l in range(1, K):
        if slot[l] >= 0:
            lse[l] = _gb_logsumexp(cens[slot[l]], moms[slot[l]], cens[slot[l]].size, sps[slot[l]])
        else:
            lse[l] = _logsumexp_fast(a, gitems[goff[l]:goff[l + 1]])
    additive = gmarg.shape[0] == 0
    if additive:  # lse[l] becomes logsumexp over l' >= l of (o_l' + lse_l')
        run = -np.inf
        for l in range(K - 1, 0, -1):
            v = moff[l] + lse[l]
            if v != v or run != run:
                run = np.nan
            elif run == -np.inf or v == np.inf:
                run = v
            elif v > -np.inf and run < np.inf:
                hi = max(run, v)
                run = hi + math.log1p(math.exp(min(run, v) - hi))
            lse[l] = run
    total = 0.0
    x = gbuf[2]
    for k in range(K - 1):
        if additive:
            log_lam = lse[k + 1] - moff[k]
        else:
            m = -np.inf
            for l in range(k + 1, K):
                m = max(m, lse[l] + gmarg[k, l])
            if m == -np.inf or m == np.inf or m != m:
                log_lam = m if m == m else np.nan
            else:
                acc = 0.0
                for l in range(k + 1, K):
                    acc += math.exp(lse[l] + gmarg[k, l] - m)
                log_lam = m + math.log(acc)
        n = goff[k + 1] - goff[k]
        if bound:
            b = _group_bound(a, gitems[goff[k]:goff[k + 1]], log_lam, slot[k] >= 0, cens[slot[k]], moms[slot[k]],
                             sps[slot[k]], gbuf)
            if not b < np.inf:  # NaN or no bound: no screening
                return np.inf
            total += b
            continue
        if slot[k] >= 0 and log_lam == log_lam and abs(log_lam) < np.inf:
            term = _gb_term(n, -log_lam, cens[slot[k]], moms[slot[k]], cens[slot[k]].size, sps[slot[k]], gbuf)
            if term == term:
                total += term
                continue
        for i in range(n):
            x[i] = a[gitems[goff[k] + i]] - log_lam
        total += group_term(x[:n], gbuf)
    return total


class LikelihoodArrays(NamedTuple):
    """The arguments of :func:`loglik` after the returns, by name (``PreferenceLikelihood.kernel_bundle()``).

    ``kind`` (``LIK_*`` of :mod:`pbicrl.inference.codes`); blocks of pairs (rows, row offsets, columns, column
    offsets, margins); explicit pairs (i, j, margins); scratch ``b, Q, Qinv`` (block width or N) and ``E, Einv``
    (N); the ranking (group members, group offsets, margin matrix, grouped scratch, margin offsets).
    """

    kind: int
    brows: np.ndarray
    broff: np.ndarray
    bcols: np.ndarray
    bcoff: np.ndarray
    bm: np.ndarray
    pi: np.ndarray
    pj: np.ndarray
    pm: np.ndarray
    b: np.ndarray
    Q: np.ndarray
    Qinv: np.ndarray
    E: np.ndarray
    Einv: np.ndarray
    gitems: np.ndarray
    goff: np.ndarray
    gmarg: np.ndarray
    gbuf: np.ndarray
    moff: np.ndarray


@njit(cache=True, error_model="numpy", inline="always")  # no call: its ~20 arrays would each cost a refcount
def loglik(a: np.ndarray, lik: LikelihoodArrays) -> float:
    """The log-likelihood of any kind: ``loglik(a, PreferenceLikelihood.kernel_bundle())``.

    ``lik.kind`` is ``LIK_PAIRWISE`` (:func:`total_loglik`, unchanged), ``LIK_GROUPED`` (:func:`grouped_loglik`) or
    ``LIK_RANKED`` (:func:`ranked_loglik`, with ``b``, ``Q``, ``Qinv`` of length N as its scratch).
    """
    if lik.kind == LIK_GROUPED:
        return grouped_loglik(a, lik.gitems, lik.goff, lik.gmarg, lik.gbuf, lik.moff)
    if lik.kind == LIK_RANKED:
        return ranked_loglik(a, lik.gitems, lik.goff, lik.moff, lik.b, lik.Q, lik.Qinv)
    return total_loglik(a, lik.brows, lik.broff, lik.bcols, lik.bcoff, lik.bm, lik.pi, lik.pj, lik.pm, lik.b, lik.Q,
                        lik.Qinv, lik.E, lik.Einv)
