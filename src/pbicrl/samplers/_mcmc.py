"""Compiled Metropolis-Hastings loop shared by the PBICRL, paper (Algorithm 1) and BPL samplers.

All randomness arrives as pre-drawn arrays (one row of uniforms/normals per iteration), so a chain is a
pure function of its inputs and identical whatever the chunking. State lives in small arrays mutated in
place; :mod:`pbicrl.samplers.kernels` wraps them in NamedTuples.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from pbicrl._kernels import total_loglik

MODE_PBICRL = 0  # flip-and-draw moves (reversible jump), valid for the stated prior
MODE_PAPER = 1  # the paper's Algorithm 1 verbatim
MODE_BPL = 2  # Algorithm 3: weights only, every feature on

# counters layout
C_FLIP_PROP, C_FLIP_ACC, C_W_PROP, C_W_ACC, C_EVALS = 0, 1, 2, 3, 4

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


@njit(cache=True, error_model="numpy")
def run_chunk(mode, n, it0, burn_in, thin, adapt_every,
              c, w, a, scal, FbT, brows, broff, bcols, bcoff, bm, pi_, pj, pm, sb, sQ, sQi, sE, sEi,
              u_j, u_mv, z, u_acc,
              cand, p_flip, f_s, log_odds, pkind, prm,
              sigma, q_mu, q_s, ad_n, ad_sum, ad_sq, ad_prop, ad_acc,
              out_c, out_w, out_ll, out_lp, n_out,
              map_c, map_w, map_scal, counts, a_new, memo_valid, memo_ll):
    """Advance one chain by ``n`` iterations (global iteration numbers ``it0 .. it0+n-1``, 0-based).

    ``scal`` = [log-likelihood, log-prior]; ``map_scal`` = [best log-posterior, its log-likelihood];
    ``n_out`` = [number of stored draws]. Draws are stored after ``burn_in`` every ``thin`` iterations.
    """
    d = w.size
    N = a.size
    nc = cand.size
    ll = scal[0]
    lp = scal[1]
    for t in range(n):
        it = it0 + t
        do_flip = False
        j = -1
        if mode == MODE_PAPER:
            j = cand[min(int(u_j[t] * nc), nc - 1)]
            do_flip = ((it + 1) % f_s) != 0  # paper counts iterations from 1
        elif mode == MODE_BPL:
            j = cand[min(int(u_j[t] * nc), nc - 1)]
        else:
            do_flip = u_mv[t] < p_flip
            if do_flip:
                j = cand[min(int(u_j[t] * nc), nc - 1)]
            else:
                n_on = 0
                for k in range(nc):
                    n_on += c[cand[k]]
                if n_on == 0:
                    j = -1  # identity move: no weight to step
                else:
                    pick = min(int(u_j[t] * n_on), n_on - 1)
                    for k in range(nc):
                        if c[cand[k]] == 1:
                            if pick == 0:
                                j = cand[k]
                                break
                            pick -= 1
        accepted = False
        if j >= 0:
            if do_flip:
                counts[C_FLIP_PROP] += 1
                if mode == MODE_PAPER:
                    # flip c_j, keep the latent w_j; likelihood ratio only (Algorithm 1, lines 6, 11-15)
                    delta = w[j] if c[j] == 0 else -w[j]
                    if memo_valid[j]:  # same state, same proposal: reuse its likelihood
                        ll_new = memo_ll[j]
                    else:
                        for i in range(N):
                            a_new[i] = a[i] + delta * FbT[j, i]
                        ll_new = total_loglik(a_new, brows, broff, bcols, bcoff, bm, pi_, pj, pm, sb, sQ, sQi, sE, sEi)
                        counts[C_EVALS] += 1
                        memo_valid[j] = True
                        memo_ll[j] = ll_new
                    log_r = ll_new - ll
                    if log_r >= 0.0 or math.log(u_acc[t]) < log_r:
                        for i in range(N):
                            a[i] += delta * FbT[j, i]
                        c[j] = 1 - c[j]
                        ll = ll_new
                        accepted = True
                else:
                    # reversible-jump flip: switching on draws w_j ~ q_j; switching off drops it
                    if c[j] == 0:
                        w_new = q_mu[j] + q_s[j] * z[t]
                        lpw = _logprior_w(pkind[j], prm, j, w_new)
                        if lpw > -np.inf:
                            for i in range(N):
                                a_new[i] = a[i] + w_new * FbT[j, i]
                            ll_new = total_loglik(a_new, brows, broff, bcols, bcoff, bm, pi_, pj, pm, sb, sQ, sQi, sE, sEi)
                            counts[C_EVALS] += 1
                            log_r = ll_new - ll + log_odds + lpw - _lognormal(w_new, q_mu[j], q_s[j])
                            if math.log(u_acc[t]) < log_r:
                                for i in range(N):
                                    a[i] = a_new[i]
                                c[j] = 1
                                w[j] = w_new
                                ll = ll_new
                                lp += log_odds + lpw
                                accepted = True
                    else:
                        lpw = _logprior_w(pkind[j], prm, j, w[j])
                        for i in range(N):
                            a_new[i] = a[i] - w[j] * FbT[j, i]
                        ll_new = total_loglik(a_new, brows, broff, bcols, bcoff, bm, pi_, pj, pm, sb, sQ, sQi, sE, sEi)
                        counts[C_EVALS] += 1
                        log_r = ll_new - ll - log_odds - lpw + _lognormal(w[j], q_mu[j], q_s[j])
                        if math.log(u_acc[t]) < log_r:
                            for i in range(N):
                                a[i] = a_new[i]
                            c[j] = 0
                            w[j] = 0.0
                            ll = ll_new
                            lp -= log_odds + lpw
                            accepted = True
                if accepted:
                    counts[C_FLIP_ACC] += 1
            else:
                counts[C_W_PROP] += 1
                ad_prop[j] += 1
                step = sigma[j] * z[t]
                w_new = w[j] + step
                lp_old = _logprior_w(pkind[j], prm, j, w[j]) if mode != MODE_PAPER else 0.0
                lp_newj = _logprior_w(pkind[j], prm, j, w_new) if mode != MODE_PAPER else 0.0
                if lp_newj > -np.inf:
                    if c[j] == 0:
                        # paper mode only: an inactive weight leaves the likelihood unchanged, always accepted
                        w[j] = w_new
                        accepted = True
                    else:
                        for i in range(N):
                            a_new[i] = a[i] + step * FbT[j, i]
                        ll_new = total_loglik(a_new, brows, broff, bcols, bcoff, bm, pi_, pj, pm, sb, sQ, sQi, sE, sEi)
                        counts[C_EVALS] += 1
                        log_r = ll_new - ll + lp_newj - lp_old
                        if log_r >= 0.0 or math.log(u_acc[t]) < log_r:
                            for i in range(N):
                                a[i] = a_new[i]
                            w[j] = w_new
                            ll = ll_new
                            lp += lp_newj - lp_old
                            accepted = True
                if accepted:
                    counts[C_W_ACC] += 1
                    ad_acc[j] += 1
            if accepted:
                for k in range(d):
                    memo_valid[k] = False
        # MAP over every visited state
        if ll + lp > map_scal[0]:
            map_scal[0] = ll + lp
            map_scal[1] = ll
            for k in range(d):
                map_c[k] = c[k]
                map_w[k] = w[k]
        if it < burn_in:
            if mode == MODE_PBICRL:
                for k in range(d):
                    if c[k] == 1:
                        ad_n[k] += 1
                        ad_sum[k] += w[k]
                        ad_sq[k] += w[k] * w[k]
            if adapt_every > 0 and (it + 1) % adapt_every == 0:
                for k in range(d):
                    if ad_prop[k] >= 10:
                        rate = ad_acc[k] / ad_prop[k]
                        sigma[k] *= math.exp(rate - 0.3)  # Robbins-Monro towards ~30% acceptance
                    ad_prop[k] = 0
                    ad_acc[k] = 0
                    if mode == MODE_PBICRL and ad_n[k] >= 20:
                        mean = ad_sum[k] / ad_n[k]
                        var = max(ad_sq[k] / ad_n[k] - mean * mean, 0.0)
                        q_mu[k] = mean
                        q_s[k] = max(2.0 * math.sqrt(var), sigma[k])  # wide: the window is autocorrelated
                        ad_n[k] = 0
                        ad_sum[k] = 0.0
                        ad_sq[k] = 0.0
        elif (it - burn_in) % thin == 0:
            r = n_out[0]
            if r < out_ll.size:
                for k in range(d):
                    out_c[r, k] = c[k]
                    out_w[r, k] = w[k]
                out_ll[r] = ll
                out_lp[r] = lp
                n_out[0] = r + 1
    scal[0] = ll
    scal[1] = lp
