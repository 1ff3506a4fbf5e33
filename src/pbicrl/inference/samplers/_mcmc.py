"""Compiled Metropolis-Hastings loop shared by the PBICRL, paper (Algorithms 1/2) and BPL samplers.

All randomness arrives as pre-drawn arrays (one row of uniforms/normals per iteration), so a chain is a
pure function of its inputs. :func:`advance` takes typed bundles (:mod:`pbicrl.inference.samplers.bundles`) whose
arrays it mutates in place; :mod:`pbicrl.inference.samplers.kernels` copies the state first. Integer codes
(modes, moves, counters) are the named constants of :mod:`pbicrl.inference.codes`.

Features ``0..d_known-1`` are known features; features ``d_known..`` are parametric constraints whose
(scaled) mean-feature rows of ``FbT`` are recomputed from :math:`\\vartheta` by
:func:`pbicrl.inference.samplers._parametric.param_column`.
"""

from __future__ import annotations

import math
import sys
from types import ModuleType

import numpy as np
from numba import njit
from numba.core.dispatcher import Dispatcher

from pbicrl.inference import codes, likelihood_kernels
from pbicrl.inference.codes import (C_EVALS, C_FLIP_ACC, C_FLIP_PROP, C_T_ACC, C_T_PROP, C_W_ACC, C_W_PROP,
                                    LIK_PAIRWISE, MODE_AUTHORS, MODE_BPL, MODE_PAPER, MODE_PBICRL, MOVE_FLIP,
                                    MOVE_JOINT, MOVE_NONE, MOVE_PARAMETER, MOVE_WEIGHT, N_COUNTS)
from pbicrl.inference.likelihood_kernels import LikelihoodArrays, loglik, pairs_loglik_bound
from pbicrl.inference.samplers import _parametric, _priorkern, bundles
from pbicrl.inference.samplers._cache import flush_stale
from pbicrl.inference.samplers._parametric import param_column
from pbicrl.inference.samplers._priorkern import logprior_w, lognormal
from pbicrl.inference.samplers.bundles import (Adaptation, ConstraintArrays, Draws, MapTracker, Model, Moves,
                                               Position, Randoms, Schedule, Scratch)

__all__ = ["advance", "run_chunk", "MODE_PBICRL", "MODE_PAPER", "MODE_BPL", "MODE_AUTHORS", "C_FLIP_PROP",
           "C_FLIP_ACC", "C_W_PROP", "C_W_ACC", "C_EVALS", "C_T_PROP", "C_T_ACC", "N_COUNTS"]

@njit(cache=True)
def _logprior_theta(theta: np.ndarray, p0: int, p1: int, tlo: np.ndarray, thi: np.ndarray, use_prior: bool) -> float:
    """Uniform prior on the box [tlo, thi] for parameters p0..p1-1 (bounds always enforced)."""
    total = 0.0
    for p in range(p0, p1):
        if theta[p] < tlo[p] or theta[p] > thi[p] or theta[p] != theta[p]:
            return -np.inf
        if use_prior:
            total -= math.log(thi[p] - tlo[p])
    return total


@njit(cache=True, error_model="numpy")
def _log_q_birth(w_abs: float, mu_a: float, s_a: float, b: float) -> float:
    r"""Log density (of :math:`w`, on the prior's half-line) of the birth proposal: with probability 1/2
    :math:`\log|w| \sim \mathcal{N}(\mu_a, s_a^2)`, else :math:`|w| \sim U(0, b)` (the prior's shape near 0)."""
    eta = math.log(w_abs)
    la = lognormal(eta, mu_a, s_a) - eta
    lb = -math.log(b) if w_abs <= b else -np.inf
    hi = max(la, lb)
    if hi == -np.inf:
        return -np.inf
    return hi + math.log(0.5 * (math.exp(la - hi) + math.exp(lb - hi)))


@njit(cache=True, error_model="numpy", inline="always")
def _bound(power: float, a_new: np.ndarray, pi_: np.ndarray, pj: np.ndarray, pm: np.ndarray) -> float:
    """``power`` times an upper bound on the explicit pairs' log-likelihood, rounding included (see the caller)."""
    u, slack = pairs_loglik_bound(a_new, pi_, pj, pm)
    return power * (u + 2.0 * slack)


@njit(cache=True, error_model="numpy")
def _cholesky_active(cov: np.ndarray, act: np.ndarray, m: int, L: np.ndarray) -> bool:
    """Lower Cholesky factor of ``cov[act[:m], act[:m]]`` into ``L[:m, :m]``; False if not positive definite."""
    for r in range(m):
        for q in range(r + 1):
            acc = cov[act[r], act[q]]
            for k in range(q):
                acc -= L[r, k] * L[q, k]
            if r == q:
                if not acc > 0.0:
                    return False
                L[r, r] = math.sqrt(acc)
            else:
                L[r, q] = acc / L[q, q]
    return True


@njit(cache=True, error_model="numpy")
def _adapt_joint(jcov: np.ndarray, jst: np.ndarray, jsc: np.ndarray, sigma: np.ndarray, cand: np.ndarray) -> None:
    """Warm-up only: the joint move's covariance from the co-active draws so far (diagonal ``sigma^2`` until there
    are 20), its scale towards 25% acceptance."""
    if jsc[1] >= 5.0:
        jsc[0] *= math.exp(jsc[2] / jsc[1] - 0.25)
    jsc[1] = 0.0
    jsc[2] = 0.0
    for k1 in range(cand.size):
        j1 = cand[k1]
        for k2 in range(cand.size):
            j2 = cand[k2]
            cnt = jst[0, j1, j2]
            if cnt >= 20.0 and jst[0, j1, j1] >= 20.0 and jst[0, j2, j2] >= 20.0:
                cov = jst[2, j1, j2] / cnt - (jst[1, j1, j2] / cnt) * (jst[1, j2, j1] / cnt)
                jcov[j1, j2] = max(cov, 1e-300) if j1 == j2 else cov
            elif j1 == j2:
                jcov[j1, j1] = sigma[j1] * sigma[j1]
            else:
                jcov[j1, j2] = 0.0


@njit(cache=True, error_model="numpy")
def advance(sched: Schedule, pos: Position, lik: LikelihoodArrays, cons: ConstraintArrays, moves: Moves,
            model: Model, rnd: Randoms, adapt: Adaptation, draws: Draws, best: MapTracker, counts: np.ndarray,
            scratch: Scratch) -> None:
    """Advance one chain by ``sched.n`` iterations (global iteration numbers ``it0 .. it0+n-1``, 0-based).

    Every argument is a bundle of :mod:`pbicrl.inference.samplers.bundles` (``lik``:
    :class:`pbicrl.inference.likelihood_kernels.LikelihoodArrays`, passed on to
    :func:`pbicrl.inference.likelihood_kernels.loglik`); ``counts`` (``N_COUNTS``,) is indexed by ``C_*``. The body
    reads the fields into the short local names below (``scal`` = ``pos.log_density`` = [log-likelihood,
    log-prior]; ``map_scal`` = ``best.log_density`` = [best log-posterior, its log-likelihood];
    ``n_out`` = [number of stored draws]. ``power`` tempers the log-likelihood (1 = the paper's model). ``naive`` recounts every state for axis halfspaces (benchmark only). Draws are stored after ``burn_in`` every ``thin`` iterations.
    ``ad`` (5, d) and ``adt`` (5, P) are warm-up accumulators (count, sum, sum of squares; proposals, accepts).
    In ``pbicrl`` mode ``memo_ll[j]`` caches the likelihood with feature ``j`` switched off (valid while no
    other component changes); in ``paper`` mode it caches the likelihood of flipping ``j``.

    ``pbicrl`` and ``bpl``: with probability ``p_joint`` (``u_mv >= 1 - p_joint``) an iteration moves all active
    weights together, :math:`w_A' = w_A + s\\,(2.38/\\sqrt{|A|})\\,L z` with ``z = zj[t, :|A|]``, :math:`L L^\\top` the
    adapted covariance ``jcov`` restricted to the active set (diagonal ``sigma^2`` where it is not positive
    definite) and ``s = jsc[0]``. In the second half of warm-up ``jst`` (3, d, d) accumulates co-active counts, sums
    and products of the weights, and ``jcov`` is re-estimated from it at each adaptation point; ``s`` adapts towards
    25% acceptance throughout warm-up (``jsc[1:3]``: proposals, accepts in the window). Afterwards the kernel is
    fixed.

    ``scratch.last`` receives [move code, accepted] of the last iteration (``MOVE_*``; a joint move with no active
    weight counts as ``MOVE_NONE``).
    """
    # Local names for the fields: the arithmetic below reads exactly as it did with positional arguments.
    mode, n, it0, burn_in, thin, adapt_every = sched
    c, w, theta, a, FbT, scal = pos
    lkind, brows, broff, bcols, bcoff, bm, pi_, pj, pm = (lik.kind, lik.brows, lik.broff, lik.bcols, lik.bcoff,
                                                           lik.bm, lik.pi, lik.pj, lik.pm)
    sb, sQ, sQi, sE, sEi, gitems, goff, gmarg, gbuf, moff = (lik.b, lik.Q, lik.Qinv, lik.E, lik.Einv, lik.gitems,
                                                             lik.goff, lik.gmarg, lik.gbuf, lik.moff)
    fam, sign, poff, dims_off, dims, sorted_vals, states, offsets, inv_len, tlo, thi = cons
    d_known, naive, cand, p_flip, p_theta, f_s, p_joint, lsg, qb = moves
    beta, power, log_odds, pkind, prm = model
    u_j, u_mv, z, u_acc, zt, zj = rnd
    sigma, q_mu, q_s, sigma_t, qt_mu, qt_s, ad, adt, jcov, jst, jsc = adapt
    out_c, out_w, out_t, out_ll, out_lp, n_out = draws
    map_c, map_w, map_t, map_scal = best
    a_new, col_new, theta_new, memo_valid, memo_ll, last = scratch
    d = w.size
    N = a.size
    P = theta.size
    nc = cand.size
    ll = scal[0]
    lp = scal[1]
    latent = mode == MODE_PAPER or mode == MODE_AUTHORS  # Algorithm 1's schedule, likelihood-ratio acceptance
    use_prior = not latent
    # Explicit pairs only: reject a proposal from a cheap upper bound on its log-likelihood when even the bound fails
    # the acceptance test. Floating-point addition is monotone, so the exact log-ratio, computed by the same
    # expression, would fail too: same decisions, same chain, fewer exact evaluations (counts[C_EVALS]).
    screen = lkind == LIK_PAIRWISE and bm.size == 0 and pi_.size >= 16
    joint = p_joint > 0.0 and (mode == MODE_PBICRL or mode == MODE_BPL)
    act = np.empty(d, np.int64)
    # latent flips: the screening bound of flipping j in the current state (NaN: not computed); a flip proposed
    # again before the state changes reuses it (same value, same decision)
    bmemo = np.full(d, np.nan)
    dw = np.empty(d)
    Lc = np.empty((d, d))
    move = MOVE_NONE
    accepted = False
    for t in range(n):
        it = it0 + t
        move = MOVE_NONE
        j = -1
        if latent:
            j = cand[min(int(u_j[t] * nc), nc - 1)]
            # paper counts iterations from 1; the authors' code from 0 (its first iteration steps a weight)
            if ((it + (0 if mode == MODE_AUTHORS else 1)) % f_s) != 0:
                move = MOVE_FLIP
            elif j >= d_known and u_mv[t] < p_theta:
                move = MOVE_PARAMETER
            else:
                move = MOVE_WEIGHT
        elif joint and u_mv[t] >= 1.0 - p_joint:
            move = MOVE_JOINT
        elif mode == MODE_BPL:
            j = cand[min(int(u_j[t] * nc), nc - 1)]
            move = MOVE_PARAMETER if (j >= d_known and u_mv[t] < p_theta) else MOVE_WEIGHT
        else:
            if u_mv[t] < p_flip:
                j = cand[min(int(u_j[t] * nc), nc - 1)]
                move = MOVE_FLIP
            else:
                want_theta = u_mv[t] < p_flip + p_theta
                n_on = 0
                for k in range(nc):
                    if c[cand[k]] == 1 and (not want_theta or cand[k] >= d_known):
                        n_on += 1
                if n_on > 0:
                    pick = min(int(u_j[t] * n_on), n_on - 1)
                    for k in range(nc):
                        if c[cand[k]] == 1 and (not want_theta or cand[k] >= d_known):
                            if pick == 0:
                                j = cand[k]
                                break
                            pick -= 1
                    move = MOVE_PARAMETER if want_theta else MOVE_WEIGHT
        accepted = False
        if move == MOVE_FLIP:
            counts[C_FLIP_PROP] += 1
            if latent:
                # flip c_j, keep the latent weight (and parameters); likelihood ratio only
                delta = w[j] if c[j] == 0 else -w[j]
                lu = math.log(u_acc[t])
                screened = False
                if memo_valid[j]:
                    ll_new = memo_ll[j]
                else:
                    fresh = False
                    if screen:
                        if bmemo[j] != bmemo[j]:  # no bound for flipping j in this state yet
                            for i in range(N):
                                a_new[i] = a[i] + delta * FbT[j, i]
                            fresh = True
                            bmemo[j] = _bound(power, a_new, pi_, pj, pm)
                        screened = bmemo[j] - ll < lu
                    if screened:
                        ll_new = -np.inf
                    else:
                        if not fresh:
                            for i in range(N):
                                a_new[i] = a[i] + delta * FbT[j, i]
                        ll_new = power * loglik(a_new, lkind, brows, broff, bcols, bcoff, bm, pi_, pj, pm, sb, sQ,
                                                sQi, sE, sEi, gitems, goff, gmarg, gbuf, moff)
                        counts[C_EVALS] += 1
                        memo_valid[j] = True
                        memo_ll[j] = ll_new
                log_r = ll_new - ll
                if not screened and (log_r >= 0.0 or lu < log_r):
                    for i in range(N):
                        a[i] += delta * FbT[j, i]
                    c[j] = 1 - c[j]
                    if mode == MODE_AUTHORS and c[j] == 0:
                        w[j] = 0.0  # the authors' code: a feature switched off loses its weight
                    ll = ll_new
                    accepted = True
            elif c[j] == 0:
                # reversible jump on: draw w_j ~ q_j (and theta_j ~ q_theta for a parametric constraint)
                if lsg[j] != 0:
                    # mixture on the magnitude: u_mv / p_flip is a fresh uniform that picks the component
                    if u_mv[t] < 0.5 * p_flip:
                        w_abs = math.exp(q_mu[j] + q_s[j] * z[t])
                    else:
                        w_abs = qb[j] * 0.5 * math.erfc(-z[t] / math.sqrt(2.0))  # Phi(z) b: uniform on (0, b)
                    w_new = lsg[j] * w_abs
                    lq = _log_q_birth(w_abs, q_mu[j], q_s[j], qb[j]) if w_abs > 0.0 else -np.inf
                else:
                    w_new = q_mu[j] + q_s[j] * z[t]
                    lq = lognormal(w_new, q_mu[j], q_s[j])
                lpw = logprior_w(pkind[j], prm, j, w_new)
                if j >= d_known:
                    m = j - d_known
                    p0 = poff[m]
                    p1 = poff[m + 1]
                    for p in range(P):
                        theta_new[p] = theta[p]
                    for p in range(p0, p1):
                        theta_new[p] = qt_mu[p] + qt_s[p] * zt[t, p - p0]
                        lq += lognormal(theta_new[p], qt_mu[p], qt_s[p])
                    lpw += _logprior_theta(theta_new, p0, p1, tlo, thi, True)
                if lpw > -np.inf:
                    if j >= d_known:
                        param_column(j - d_known, theta_new, beta, fam, sign, poff, dims_off, dims, sorted_vals,
                                     states, offsets, inv_len, col_new, naive)
                    else:
                        for i in range(N):
                            col_new[i] = FbT[j, i]
                    for i in range(N):
                        a_new[i] = a[i] + w_new * col_new[i]
                    lu = math.log(u_acc[t])
                    screened = screen and _bound(power, a_new, pi_, pj, pm) - ll + log_odds + lpw - lq < lu
                    log_r = -np.inf
                    if not screened:
                        ll_new = power * loglik(a_new, lkind, brows, broff, bcols, bcoff, bm, pi_, pj, pm, sb, sQ, sQi,
                                                sE, sEi, gitems, goff, gmarg, gbuf, moff)
                        counts[C_EVALS] += 1
                        log_r = ll_new - ll + log_odds + lpw - lq
                    if not screened and lu < log_r:
                        memo_ll[j] = ll  # the off-state likelihood stays known
                        for i in range(N):
                            a[i] = a_new[i]
                        if j >= d_known:
                            m = j - d_known
                            for p in range(poff[m], poff[m + 1]):
                                theta[p] = theta_new[p]
                            for i in range(N):
                                FbT[j, i] = col_new[i]
                        c[j] = 1
                        w[j] = w_new
                        ll = ll_new
                        lp += log_odds + lpw
                        accepted = True
            else:
                # reversible jump off: drop w_j (and theta_j); the reverse of the move above
                lpw = logprior_w(pkind[j], prm, j, w[j])
                if lsg[j] != 0:
                    lq = _log_q_birth(abs(w[j]), q_mu[j], q_s[j], qb[j]) if w[j] != 0.0 else -np.inf
                else:
                    lq = lognormal(w[j], q_mu[j], q_s[j])
                if j >= d_known:
                    m = j - d_known
                    lpw += _logprior_theta(theta, poff[m], poff[m + 1], tlo, thi, True)
                    for p in range(poff[m], poff[m + 1]):
                        lq += lognormal(theta[p], qt_mu[p], qt_s[p])
                lu = math.log(u_acc[t])
                screened = False
                if memo_valid[j]:
                    ll_new = memo_ll[j]
                else:
                    for i in range(N):
                        a_new[i] = a[i] - w[j] * FbT[j, i]
                    if screen:
                        screened = _bound(power, a_new, pi_, pj, pm) - ll - log_odds - lpw + lq < lu
                    if screened:
                        ll_new = -np.inf
                    else:
                        ll_new = power * loglik(a_new, lkind, brows, broff, bcols, bcoff, bm, pi_, pj, pm, sb, sQ,
                                                sQi, sE, sEi, gitems, goff, gmarg, gbuf, moff)
                        counts[C_EVALS] += 1
                        memo_valid[j] = True
                        memo_ll[j] = ll_new
                log_r = ll_new - ll - log_odds - lpw + lq
                if not screened and lu < log_r:
                    for i in range(N):
                        a[i] -= w[j] * FbT[j, i]
                    c[j] = 0
                    w[j] = 0.0
                    ll = ll_new
                    lp -= log_odds + lpw
                    accepted = True
            if accepted:
                counts[C_FLIP_ACC] += 1
        elif move == MOVE_WEIGHT:
            counts[C_W_PROP] += 1
            ad[3, j] += 1
            jac = 0.0
            if lsg[j] != 0 and w[j] != 0.0:
                # random walk on eta = log|w|; the Jacobian |dw'/deta'| / |dw/deta| = |w'| / |w| enters the ratio
                jac = sigma[j] * z[t]
                w_new = lsg[j] * math.exp(math.log(abs(w[j])) + jac)
                step = w_new - w[j]
            else:
                step = sigma[j] * z[t]
                w_new = w[j] + step
            lp_old = logprior_w(pkind[j], prm, j, w[j]) if use_prior else 0.0
            lp_newj = logprior_w(pkind[j], prm, j, w_new) if use_prior else 0.0
            if lp_newj > -np.inf:
                if c[j] == 0:
                    # latent modes only: an inactive weight leaves the likelihood unchanged, always accepted; the
                    # authors' code proposes from the effective weights, so an inactive one stays 0
                    w[j] = 0.0 if mode == MODE_AUTHORS else w_new
                    accepted = True
                else:
                    for i in range(N):
                        a_new[i] = a[i] + step * FbT[j, i]
                    lu = math.log(u_acc[t])
                    screened = screen and _bound(power, a_new, pi_, pj, pm) - ll + lp_newj - lp_old + jac < lu
                    log_r = -np.inf
                    if not screened:
                        ll_new = power * loglik(a_new, lkind, brows, broff, bcols, bcoff, bm, pi_, pj, pm, sb, sQ, sQi,
                                                sE, sEi, gitems, goff, gmarg, gbuf, moff)
                        counts[C_EVALS] += 1
                        log_r = ll_new - ll + lp_newj - lp_old + jac
                    if not screened and (log_r >= 0.0 or lu < log_r):
                        for i in range(N):
                            a[i] = a_new[i]
                        w[j] = w_new
                        ll = ll_new
                        lp += lp_newj - lp_old
                        accepted = True
            if accepted:
                counts[C_W_ACC] += 1
                ad[4, j] += 1
        elif move == MOVE_PARAMETER:
            m = j - d_known
            p0 = poff[m]
            p1 = poff[m + 1]
            counts[C_T_PROP] += 1
            adt[3, p0] += 1
            for p in range(P):
                theta_new[p] = theta[p]
            for p in range(p0, p1):
                theta_new[p] = theta[p] + sigma_t[p] * zt[t, p - p0]
            lpt_new = _logprior_theta(theta_new, p0, p1, tlo, thi, use_prior)
            if lpt_new > -np.inf:
                lpt_old = _logprior_theta(theta, p0, p1, tlo, thi, use_prior)
                param_column(m, theta_new, beta, fam, sign, poff, dims_off, dims, sorted_vals, states, offsets,
                             inv_len, col_new, naive)
                if c[j] == 0:
                    # paper mode only: a latent location leaves the likelihood unchanged
                    accepted = True
                else:
                    for i in range(N):
                        a_new[i] = a[i] + w[j] * (col_new[i] - FbT[j, i])
                    lu = math.log(u_acc[t])
                    screened = screen and _bound(power, a_new, pi_, pj, pm) - ll + lpt_new - lpt_old < lu
                    log_r = -np.inf
                    if not screened:
                        ll_new = power * loglik(a_new, lkind, brows, broff, bcols, bcoff, bm, pi_, pj, pm, sb, sQ, sQi,
                                                sE, sEi, gitems, goff, gmarg, gbuf, moff)
                        counts[C_EVALS] += 1
                        log_r = ll_new - ll + lpt_new - lpt_old
                    if not screened and (log_r >= 0.0 or lu < log_r):
                        for i in range(N):
                            a[i] = a_new[i]
                        ll = ll_new
                        lp += lpt_new - lpt_old
                        accepted = True
                if accepted:
                    for p in range(p0, p1):
                        theta[p] = theta_new[p]
                    for i in range(N):
                        FbT[j, i] = col_new[i]
            if accepted:
                counts[C_T_ACC] += 1
                adt[4, p0] += 1
        elif move == MOVE_JOINT:
            m = 0
            for k in range(nc):
                if c[cand[k]] == 1:
                    act[m] = cand[k]
                    m += 1
            if m > 0:
                counts[C_W_PROP] += 1
                jsc[1] += 1.0
                if not _cholesky_active(jcov, act, m, Lc):
                    for r in range(m):  # not positive definite: the single-site scales
                        for q in range(m):
                            Lc[r, q] = sigma[act[r]] if r == q else 0.0
                sc = jsc[0] * 2.38 / math.sqrt(m)
                lp_old = 0.0
                lp_new = 0.0
                jac = 0.0
                for r in range(m):
                    acc_ = 0.0
                    for q in range(r + 1):
                        acc_ += Lc[r, q] * zj[t, q]
                    dw[r] = sc * acc_
                    jj = act[r]
                    if lsg[jj] != 0 and w[jj] != 0.0:  # a step on eta = log|w| (Jacobian |w'|/|w|)
                        jac += dw[r]
                        dw[r] = lsg[jj] * math.exp(math.log(abs(w[jj])) + dw[r]) - w[jj]
                    lp_old += logprior_w(pkind[jj], prm, jj, w[jj])
                    lp_new += logprior_w(pkind[jj], prm, jj, w[jj] + dw[r])
                if lp_new > -np.inf:
                    for i in range(N):
                        a_new[i] = a[i]
                    for r in range(m):
                        jj = act[r]
                        for i in range(N):
                            a_new[i] += dw[r] * FbT[jj, i]
                    lu = math.log(u_acc[t])
                    screened = screen and _bound(power, a_new, pi_, pj, pm) - ll + lp_new - lp_old + jac < lu
                    log_r = -np.inf
                    if not screened:
                        ll_new = power * loglik(a_new, lkind, brows, broff, bcols, bcoff, bm, pi_, pj, pm, sb, sQ, sQi,
                                                sE, sEi, gitems, goff, gmarg, gbuf, moff)
                        counts[C_EVALS] += 1
                        log_r = ll_new - ll + lp_new - lp_old + jac
                    if not screened and (log_r >= 0.0 or lu < log_r):
                        for i in range(N):
                            a[i] = a_new[i]
                        for r in range(m):
                            w[act[r]] += dw[r]
                        ll = ll_new
                        lp += lp_new - lp_old
                        accepted = True
            else:
                move = MOVE_NONE  # no active weight: nothing was proposed
            if accepted:
                counts[C_W_ACC] += 1
                jsc[2] += 1.0
        if accepted:
            if move == MOVE_JOINT:
                for k in range(d):
                    memo_valid[k] = False
            elif latent and move != MOVE_FLIP and c[j] == 0:
                # a latent weight or location moved: the returns did not change, so only flipping j changes
                memo_valid[j] = False
                bmemo[j] = np.nan
            elif latent:
                for k in range(d):
                    memo_valid[k] = False
                    bmemo[k] = np.nan
            else:
                for k in range(d):
                    if k != j:
                        memo_valid[k] = False
                if move == MOVE_FLIP:
                    memo_valid[j] = True  # memo_ll[j] holds the off-state likelihood (set above)
        # MAP over every visited state
        if ll + lp > map_scal[0]:
            map_scal[0] = ll + lp
            map_scal[1] = ll
            for k in range(d):
                map_c[k] = c[k]
                map_w[k] = w[k]
            for p in range(P):
                map_t[p] = theta[p]
        if it < burn_in:
            if joint and 2 * it >= burn_in:  # second half of warm-up only: past the initial transient
                for k1 in range(nc):
                    j1 = cand[k1]
                    if c[j1] == 1:
                        e1 = math.log(abs(w[j1])) if lsg[j1] != 0 and w[j1] != 0.0 else w[j1]
                        for k2 in range(nc):
                            j2 = cand[k2]
                            if c[j2] == 1:
                                e2 = math.log(abs(w[j2])) if lsg[j2] != 0 and w[j2] != 0.0 else w[j2]
                                jst[0, j1, j2] += 1.0
                                jst[1, j1, j2] += e1
                                jst[2, j1, j2] += e1 * e2
            if joint and adapt_every > 0 and (it + 1) % adapt_every == 0:
                _adapt_joint(jcov, jst, jsc, sigma, cand)
            if mode == MODE_PBICRL:
                for k in range(d):
                    if c[k] == 1:
                        wk = math.log(abs(w[k])) if lsg[k] != 0 and w[k] != 0.0 else w[k]
                        ad[0, k] += 1
                        ad[1, k] += wk
                        ad[2, k] += wk * wk
                        if k >= d_known:
                            for p in range(poff[k - d_known], poff[k - d_known + 1]):
                                adt[0, p] += 1
                                adt[1, p] += theta[p]
                                adt[2, p] += theta[p] * theta[p]
            if adapt_every > 0 and (it + 1) % adapt_every == 0:
                for k in range(d):
                    if ad[3, k] >= 10:
                        sigma[k] *= math.exp(ad[4, k] / ad[3, k] - 0.3)  # Robbins-Monro towards ~30% acceptance
                    ad[3, k] = 0
                    ad[4, k] = 0
                    if mode == MODE_PBICRL and ad[0, k] >= 20:  # on eta = log|w| where lsg[k] != 0
                        mean = ad[1, k] / ad[0, k]
                        var = max(ad[2, k] / ad[0, k] - mean * mean, 0.0)
                        q_mu[k] = mean
                        q_s[k] = max(2.0 * math.sqrt(var), sigma[k])  # wide: the window is autocorrelated
                        ad[0, k] = 0
                        ad[1, k] = 0.0
                        ad[2, k] = 0.0
                for mm in range(poff.size - 1):
                    p0 = poff[mm]
                    if adt[3, p0] >= 10:
                        f = math.exp(adt[4, p0] / adt[3, p0] - 0.3)
                        for p in range(p0, poff[mm + 1]):
                            sigma_t[p] *= f
                    adt[3, p0] = 0
                    adt[4, p0] = 0
                    for p in range(p0, poff[mm + 1]):
                        if mode == MODE_PBICRL and adt[0, p] >= 20:
                            mean = adt[1, p] / adt[0, p]
                            var = max(adt[2, p] / adt[0, p] - mean * mean, 0.0)
                            qt_mu[p] = mean
                            qt_s[p] = max(2.0 * math.sqrt(var), sigma_t[p])
                            adt[0, p] = 0
                            adt[1, p] = 0.0
                            adt[2, p] = 0.0
        elif (it - burn_in) % thin == 0:
            r = n_out[0]
            if r < out_ll.size:
                for k in range(d):
                    out_c[r, k] = c[k]
                    out_w[r, k] = w[k]
                for mm in range(poff.size - 1):
                    off = mode == MODE_PBICRL and c[d_known + mm] == 0
                    for p in range(poff[mm], poff[mm + 1]):
                        out_t[r, p] = np.nan if off else theta[p]
                out_ll[r] = ll
                out_lp[r] = lp
                n_out[0] = r + 1
    scal[0] = ll
    scal[1] = lp
    last[0] = move
    last[1] = accepted


def run_chunk(mode, n, it0, burn_in, thin, adapt_every, d_known, naive,
              c, w, theta, a, scal, FbT, beta, power,
              lkind, brows, broff, bcols, bcoff, bm, pi_, pj, pm, sb, sQ, sQi, sE, sEi, gitems, goff, gmarg, gbuf, moff,
              fam, sign, poff, dims_off, dims, sorted_vals, states, offsets, inv_len, tlo, thi,
              u_j, u_mv, z, u_acc, zt,
              cand, p_flip, p_theta, f_s, log_odds, pkind, prm,
              sigma, q_mu, q_s, sigma_t, qt_mu, qt_s, ad, adt,
              out_c, out_w, out_t, out_ll, out_lp, n_out,
              map_c, map_w, map_t, map_scal, counts,
              a_new, col_new, theta_new, memo_valid, memo_ll,
              p_joint, zj, jcov, jst, jsc) -> None:  # noqa: ANN001 - the recorded positional form, typed by advance
    """:func:`advance` with its bundles spread into the positional arguments it took before the bundles.

    Plain Python (it packs the same arrays, no copies, and calls :func:`advance`): the stored chain reference
    (``tests/data/chain_reference.npz``) records ``run_chunk``'s arguments in this order. New code calls
    :func:`advance`.
    """
    advance(Schedule(int(mode), int(n), int(it0), int(burn_in), int(thin), int(adapt_every)),
            Position(c, w, theta, a, FbT, scal),
            LikelihoodArrays(lkind, brows, broff, bcols, bcoff, bm, pi_, pj, pm, sb, sQ, sQi, sE, sEi, gitems, goff,
                             gmarg, gbuf, moff),
            ConstraintArrays(fam, sign, poff, dims_off, dims, sorted_vals, states, offsets, inv_len, tlo, thi),
            Moves(int(d_known), bool(naive), cand, float(p_flip), float(p_theta), int(f_s), float(p_joint),
                  np.zeros(c.size, np.int64), np.ones(c.size)),
            Model(float(beta), float(power), float(log_odds), pkind, prm),
            Randoms(u_j, u_mv, z, u_acc, zt, zj),
            Adaptation(sigma, q_mu, q_s, sigma_t, qt_mu, qt_s, ad, adt, jcov, jst, jsc),
            Draws(out_c, out_w, out_t, out_ll, out_lp, n_out),
            MapTracker(map_c, map_w, map_t, map_scal), counts,
            Scratch(a_new, col_new, theta_new, memo_valid, memo_ll, np.zeros(2, np.int64)))


# ------------------------------------------------------------------------------------------------ on-disk cache
def _cached_dispatchers(module: ModuleType) -> list[Dispatcher]:
    return [v for v in vars(module).values() if isinstance(v, Dispatcher) and v.py_func.__module__ == module.__name__]


def _flush_stale_caches() -> None:
    """Numba re-validates a cached function against its own file only (:mod:`pbicrl.inference.samplers._cache`):
    flush each module's cached functions when any file whose code or constants they compile in has changed.
    Runs at import, before any of them is called (``import pbicrl`` imports this module)."""
    here = sys.modules[__name__]
    deps = {
        codes: [codes],
        likelihood_kernels: [likelihood_kernels, codes],
        _parametric: [_parametric, codes],
        _priorkern: [_priorkern, codes],
        here: [here, codes, likelihood_kernels, _parametric, _priorkern, bundles],
    }
    for module, sources in deps.items():
        flush_stale(_cached_dispatchers(module), [m.__file__ for m in sources])


_flush_stale_caches()
