"""Compiled mean features of parametric constraints: fraction of each trajectory's states in the region."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from pbicrl.inference.codes import FAM_AXIS, FAM_BALL, FAM_BOX, FAM_HALFSPACE

__all__ = ["param_column", "FAM_AXIS", "FAM_HALFSPACE", "FAM_BOX", "FAM_BALL"]


@njit(cache=True)
def _count_ge(seg_sorted: np.ndarray, lo: int, hi: int, t: float) -> int:
    """Number of values >= t in the sorted slice [lo, hi) (binary search for the first value >= t)."""
    a, b = lo, hi
    while a < b:
        mid = (a + b) >> 1
        if seg_sorted[mid] < t:
            a = mid + 1
        else:
            b = mid
    return hi - a


@njit(cache=True)
def _count_le(seg_sorted: np.ndarray, lo: int, hi: int, t: float) -> int:
    """Number of values <= t in the sorted slice [lo, hi) (binary search for the first value > t)."""
    a, b = lo, hi
    while a < b:
        mid = (a + b) >> 1
        if seg_sorted[mid] <= t:
            a = mid + 1
        else:
            b = mid
    return a - lo


@njit(cache=True, error_model="numpy")
def param_column(m, theta, scale, fam, sign, poff, dims_off, dims, sorted_vals, states, offsets, inv_len, out, naive):
    """out[i] = scale * (fraction of trajectory i's states inside constraint m's region at ``theta``).

    ``naive=True`` recounts every state even for axis halfspaces (the benchmark's O(N T) comparison).
    """
    N = offsets.size - 1
    p0 = poff[m]
    d0 = dims_off[m]
    D = dims_off[m + 1] - d0
    f = fam[m]
    if f == FAM_AXIS and not naive:
        t = theta[p0]
        for i in range(N):
            if sign[m] > 0:
                cnt = _count_ge(sorted_vals[m], offsets[i], offsets[i + 1], t)
            else:
                cnt = _count_le(sorted_vals[m], offsets[i], offsets[i + 1], t)
            out[i] = scale * cnt * inv_len[i]
        return
    if f == FAM_HALFSPACE:
        nvec = np.empty(D)
        s = 1.0
        for k in range(D - 1):
            nvec[k] = s * math.cos(theta[p0 + k])
            s *= math.sin(theta[p0 + k])
        nvec[D - 1] = s
        b = theta[p0 + D - 1]
    for i in range(N):
        cnt = 0
        for r in range(offsets[i], offsets[i + 1]):
            if f == FAM_AXIS:
                x = states[r, dims[d0]]
                ins = x >= theta[p0] if sign[m] > 0 else x <= theta[p0]
            elif f == FAM_BOX:
                ins = True
                for k in range(D):
                    x = states[r, dims[d0 + k]]
                    if x < theta[p0 + k] or x > theta[p0 + D + k]:
                        ins = False
                        break
            elif f == FAM_BALL:
                d2 = 0.0
                for k in range(D):
                    diff = states[r, dims[d0 + k]] - theta[p0 + k]
                    d2 += diff * diff
                rad = theta[p0 + D]
                ins = d2 < rad * rad
            else:
                proj = 0.0
                for k in range(D):
                    proj += nvec[k] * states[r, dims[d0 + k]]
                ins = proj >= b
            if ins:
                cnt += 1
        out[i] = scale * cnt * inv_len[i]
