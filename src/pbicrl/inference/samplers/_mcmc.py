"""Compiled Metropolis-Hastings loop shared by the PBICRL, paper (Algorithms 1/2) and BPL samplers.

All randomness arrives as pre-drawn arrays (one row of uniforms/normals per iteration), so a chain is a
pure function of its inputs. :func:`advance` takes typed bundles (:mod:`pbicrl.inference.samplers.bundles`) whose
arrays it mutates in place; :mod:`pbicrl.inference.samplers.kernels` copies the state first. Integer codes
(modes, moves, counters) are the named constants of :mod:`pbicrl.inference.codes`.

The loop is built from small functions that Numba inlines into it (no call, no reference counting of the
bundles' arrays): :func:`choose` picks an iteration's move, :func:`flip`, :func:`weight`, :func:`parameter` and
:func:`joint` propose it, :func:`mh_accept` is the one Metropolis-Hastings test they share, :func:`adapt` tunes
the proposals during warm-up. The moves take one :class:`~pbicrl.inference.samplers.bundles.Context` (the call's
bundles and settings), read its fields by name and pass the log-likelihood and log-prior on as two numbers.

Features ``0..d_known-1`` are known features; features ``d_known..`` are parametric constraints whose
(scaled) mean-feature rows of ``Position.features_T`` are recomputed from :math:`\\vartheta` by
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
                                    LIK_GROUPED, LIK_PAIRWISE, MODE_AUTHORS, MODE_BPL, MODE_PAPER, MODE_PBICRL,
                                    MOVE_FLIP, MOVE_JOINT, MOVE_NONE, MOVE_PARAMETER, MOVE_WEIGHT)
from pbicrl.inference.likelihood_kernels import LikelihoodArrays, grouped_loglik_bound, loglik, pairs_loglik_bound
from pbicrl.inference.samplers import _parametric, _priorkern, bundles
from pbicrl.inference.samplers._cache import flush_stale
from pbicrl.inference.samplers._parametric import param_column
from pbicrl.inference.samplers._priorkern import logprior_w, lognormal
from pbicrl.inference.samplers.bundles import (Adaptation, ConstraintArrays, Context, Draws, MapTracker, Model,
                                               Moves, Position, Randoms, Schedule, Scratch)

__all__ = ["advance", "choose", "flip", "weight", "parameter", "joint", "adapt", "mh_accept"]

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
def _bound(power: float, a_new: np.ndarray, lik: LikelihoodArrays) -> float:
    """``power`` times an upper bound on the log-likelihood, rounding included (:func:`mh_accept`): the explicit
    pairs' or the grouped likelihood's (:func:`pbicrl.inference.likelihood_kernels.grouped_loglik_bound`)."""
    if lik.kind == LIK_GROUPED:
        return power * grouped_loglik_bound(a_new, lik.gitems, lik.goff, lik.gmarg, lik.gbuf, lik.moff)
    u, slack = pairs_loglik_bound(a_new, lik.pi, lik.pj, lik.pm)
    return power * (u + 2.0 * slack)


# Measured (benchmarks/reports/fast_default.md, session 13): the bound costs 12-17% of an exact evaluation on the
# shipped point mass and Fetch-Reach (1,100-1,700 trajectories) and screens ~17% of the evaluations away; on
# 3 x 100,000 trajectories it costs about half of one (the binning pass) and the runs were 12% slower.
_SCREEN_MAX_N = 50_000


@njit(cache=True, error_model="numpy", inline="always")
def _unscreened(ctx: Context) -> float:
    """The ``bound`` argument of :func:`mh_accept` for every move but a death: NaN (compute the bound) for explicit
    pairs, whose bound is cheap; ``inf`` (no screening) for the grouped likelihood, whose bound pays only where
    rejection is nearly certain, i.e. switching off a constraint the rankings need."""
    return np.nan if ctx.lik.kind == LIK_PAIRWISE else np.inf


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


@njit(cache=True, error_model="numpy", inline="always")
def _column(m: int, theta: np.ndarray, beta: float, cons: ConstraintArrays, out: np.ndarray, naive: bool) -> None:
    """:func:`pbicrl.inference.samplers._parametric.param_column` of constraint ``m`` at ``theta`` into ``out``."""
    param_column(m, theta, beta, cons.fam, cons.sign, cons.poff, cons.dims_off, cons.dims, cons.sorted_vals,
                 cons.states, cons.offsets, cons.inv_len, out, naive)


@njit(cache=True, error_model="numpy", inline="always")
def mh_accept(ctx: Context, t: int, ll: float, t1: float, t2: float, t3: float, memo: int,
              bound: float) -> tuple[bool, float]:
    r"""The Metropolis-Hastings test of the proposal of iteration row ``t``, whose returns are
    ``ctx.scratch.a_new``: accept when :math:`\log u < \gamma\mathcal{L}' - \gamma\mathcal{L} + t_1 + t_2 + t_3`
    (:math:`u` = ``ctx.rnd.u_acc[t]``); returns (accepted, :math:`\gamma\mathcal{L}'`).

    The terms are added in this order on purpose (floating-point addition is not associative, and the chain
    must not depend on how a move groups its prior and proposal terms); a term subtracted by the move is
    passed negated, which is the same operation. ``memo >= 0``: the likelihood of the proposal is
    ``scratch.memo_ll[memo]`` where ``scratch.memo_valid[memo]``, and is stored there once evaluated.

    With ``ctx.screen`` (explicit pairs; the grouped likelihood's death moves), a proposal is rejected from an upper
    bound on its log-likelihood (``bound``; NaN: compute it; ``inf``: none) when even the bound fails the test.
    Floating-point addition is monotone, so the exact log-ratio, computed by the same expression, would fail too:
    same decisions, same chain, fewer exact evaluations (``counts[C_EVALS]``).
    """
    scratch, power = ctx.scratch, ctx.model.power
    lu = math.log(ctx.rnd.u_acc[t])
    if memo >= 0 and scratch.memo_valid[memo]:
        ll_new = scratch.memo_ll[memo]
    else:
        if ctx.screen:
            if math.isnan(bound):
                bound = _bound(power, scratch.a_new, ctx.lik)
            if bound - ll + t1 + t2 + t3 < lu:
                return False, -np.inf
        ll_new = power * loglik(scratch.a_new, ctx.lik)
        ctx.counts[C_EVALS] += 1
        if memo >= 0:
            scratch.memo_valid[memo] = True
            scratch.memo_ll[memo] = ll_new
    log_r = ll_new - ll + t1 + t2 + t3
    return log_r >= 0.0 or lu < log_r, ll_new


@njit(cache=True, error_model="numpy", inline="always")
def _pick(u: float, cand: np.ndarray) -> int:
    """The candidate feature that the uniform ``u`` picks."""
    nc = cand.size
    return cand[min(int(u * nc), nc - 1)]


@njit(cache=True, error_model="numpy", inline="always")
def choose(t: int, it: int, mode: int, joint_on: bool, c: np.ndarray, moves: Moves, rnd: Randoms) -> tuple[int, int]:
    """The move of iteration ``it`` (``MOVE_*``) and its feature (-1: none), from the ``t``-th random numbers."""
    u_mv = rnd.u_mv[t]
    cand = moves.cand
    if mode == MODE_PAPER or mode == MODE_AUTHORS:
        j = _pick(rnd.u_j[t], cand)
        # paper counts iterations from 1; the authors' code from 0 (its first iteration steps a weight)
        if ((it + (0 if mode == MODE_AUTHORS else 1)) % moves.f_s) != 0:
            return MOVE_FLIP, j
        if j >= moves.d_known and u_mv < moves.p_theta:
            return MOVE_PARAMETER, j
        return MOVE_WEIGHT, j
    if joint_on and u_mv >= 1.0 - moves.p_joint:
        return MOVE_JOINT, -1
    if mode == MODE_BPL:
        j = _pick(rnd.u_j[t], cand)
        return (MOVE_PARAMETER if (j >= moves.d_known and u_mv < moves.p_theta) else MOVE_WEIGHT), j
    if u_mv < moves.p_flip:
        return MOVE_FLIP, _pick(rnd.u_j[t], cand)
    # a step on an active feature (a parametric one for a parameter step)
    want_theta = u_mv < moves.p_flip + moves.p_theta
    nc = cand.size
    n_on = 0
    for k in range(nc):
        if c[cand[k]] == 1 and (not want_theta or cand[k] >= moves.d_known):
            n_on += 1
    if n_on == 0:
        return MOVE_NONE, -1
    pick = min(int(rnd.u_j[t] * n_on), n_on - 1)
    for k in range(nc):
        if c[cand[k]] == 1 and (not want_theta or cand[k] >= moves.d_known):
            if pick == 0:
                return (MOVE_PARAMETER if want_theta else MOVE_WEIGHT), cand[k]
            pick -= 1
    return MOVE_NONE, -1


@njit(cache=True, error_model="numpy", inline="always")
def _param_range(j: int, ctx: Context) -> tuple[int, int]:
    """The parameters ``p0 .. p1-1`` of parametric constraint ``j`` (a feature ``>= moves.d_known``)."""
    m = j - ctx.moves.d_known
    return ctx.cons.poff[m], ctx.cons.poff[m + 1]


@njit(cache=True, error_model="numpy", inline="always")
def _log_q_weight(w: float, j: int, ctx: Context) -> float:
    """Log density at ``w`` of feature ``j``'s flip-and-draw proposal :math:`q_j` (see :class:`Moves`)."""
    ad, moves = ctx.adaptation, ctx.moves
    if moves.log_sign[j] != 0:
        return _log_q_birth(abs(w), ad.q_mean[j], ad.q_scale[j], moves.birth_bound[j]) if w != 0.0 else -np.inf
    return lognormal(w, ad.q_mean[j], ad.q_scale[j])


@njit(cache=True, error_model="numpy", inline="always")
def _add_log_q_theta(lq: float, theta: np.ndarray, p0: int, p1: int, ad: Adaptation) -> float:
    r"""``lq`` plus the log density of the parameter proposal :math:`q_\vartheta` at ``theta[p0:p1]``, term by term."""
    for p in range(p0, p1):
        lq += lognormal(theta[p], ad.q_theta_mean[p], ad.q_theta_scale[p])
    return lq


@njit(cache=True, error_model="numpy", inline="always")
def _flip_latent(t: int, j: int, ctx: Context, bmemo: np.ndarray, ll: float) -> tuple[bool, float]:
    """Algorithm 1's flip: :math:`c_j` flips, the latent weight (and parameters) stay; likelihood ratio only.

    ``bmemo[j]``: the screening bound of flipping ``j`` in the current state (NaN: not computed yet); a flip
    proposed again before the state changes reuses it (same value, same decision)."""
    pos, scratch = ctx.pos, ctx.scratch
    a, FbT, c, w = pos.scaled_returns, pos.features_T, pos.indicators, pos.penalty_weights
    delta = w[j] if c[j] == 0 else -w[j]
    if not scratch.memo_valid[j]:
        for i in range(a.size):
            scratch.a_new[i] = a[i] + delta * FbT[j, i]
        if ctx.screen and math.isnan(bmemo[j]):
            bmemo[j] = _bound(ctx.model.power, scratch.a_new, ctx.lik)
    ok, ll_new = mh_accept(ctx, t, ll, 0.0, 0.0, 0.0, j, bmemo[j])
    if ok:
        for i in range(a.size):
            a[i] += delta * FbT[j, i]
        c[j] = 1 - c[j]
        if ctx.mode == MODE_AUTHORS and c[j] == 0:
            w[j] = 0.0  # the authors' code: a feature switched off loses its weight
        ll = ll_new
    return ok, ll


@njit(cache=True, error_model="numpy", inline="always")
def _birth(t: int, j: int, ctx: Context, ll: float, lp: float) -> tuple[bool, float, float]:
    r"""Reversible jump on: draw :math:`w_j \sim q_j` (and :math:`\vartheta_j \sim q_\vartheta` for a parametric
    constraint)."""
    pos, ad, moves, model, rnd, scratch = ctx.pos, ctx.adaptation, ctx.moves, ctx.model, ctx.rnd, ctx.scratch
    a, FbT, theta = pos.scaled_returns, pos.features_T, pos.parameters
    z = rnd.z[t]
    theta_new, col_new = scratch.theta_new, scratch.col_new
    if moves.log_sign[j] != 0:
        # mixture on the magnitude: u_mv / p_flip is a fresh uniform that picks the component
        if rnd.u_mv[t] < 0.5 * moves.p_flip:
            w_abs = math.exp(ad.q_mean[j] + ad.q_scale[j] * z)
        else:
            w_abs = moves.birth_bound[j] * 0.5 * math.erfc(-z / math.sqrt(2.0))  # Phi(z) b: uniform on (0, b)
        w_new = moves.log_sign[j] * w_abs
    else:
        w_new = ad.q_mean[j] + ad.q_scale[j] * z
    lq = _log_q_weight(w_new, j, ctx)
    lpw = logprior_w(model.prior_kind[j], model.prior_params, j, w_new)
    parametric = j >= moves.d_known
    p0 = p1 = 0
    if parametric:
        p0, p1 = _param_range(j, ctx)
        for p in range(theta.size):
            theta_new[p] = theta[p]
        for p in range(p0, p1):
            theta_new[p] = ad.q_theta_mean[p] + ad.q_theta_scale[p] * rnd.zt[t, p - p0]
        lq = _add_log_q_theta(lq, theta_new, p0, p1, ad)
        lpw += _logprior_theta(theta_new, p0, p1, ctx.cons.lo, ctx.cons.hi, True)
    if not lpw > -np.inf:
        return False, ll, lp
    if parametric:
        _column(j - moves.d_known, theta_new, model.beta, ctx.cons, col_new, moves.naive)
    else:
        for i in range(a.size):
            col_new[i] = FbT[j, i]
    for i in range(a.size):
        scratch.a_new[i] = a[i] + w_new * col_new[i]
    ok, ll_new = mh_accept(ctx, t, ll, model.log_odds, lpw, -lq, -1, _unscreened(ctx))
    if ok:
        scratch.memo_ll[j] = ll  # the off-state likelihood stays known
        for i in range(a.size):
            a[i] = scratch.a_new[i]
        if parametric:
            for p in range(p0, p1):
                theta[p] = theta_new[p]
            for i in range(a.size):
                FbT[j, i] = col_new[i]
        pos.indicators[j] = 1
        pos.penalty_weights[j] = w_new
        ll = ll_new
        lp += model.log_odds + lpw
    return ok, ll, lp


@njit(cache=True, error_model="numpy", inline="always")
def _death(t: int, j: int, ctx: Context, ll: float, lp: float) -> tuple[bool, float, float]:
    r"""Reversible jump off: drop :math:`w_j` (and :math:`\vartheta_j`); the reverse of :func:`_birth`."""
    pos, model, scratch = ctx.pos, ctx.model, ctx.scratch
    a, FbT, w = pos.scaled_returns, pos.features_T, pos.penalty_weights
    lpw = logprior_w(model.prior_kind[j], model.prior_params, j, w[j])
    lq = _log_q_weight(w[j], j, ctx)
    if j >= ctx.moves.d_known:
        p0, p1 = _param_range(j, ctx)
        lpw += _logprior_theta(pos.parameters, p0, p1, ctx.cons.lo, ctx.cons.hi, True)
        lq = _add_log_q_theta(lq, pos.parameters, p0, p1, ctx.adaptation)
    if not scratch.memo_valid[j]:
        for i in range(a.size):
            scratch.a_new[i] = a[i] - w[j] * FbT[j, i]
    ok, ll_new = mh_accept(ctx, t, ll, -model.log_odds, -lpw, lq, j, np.nan)
    if ok:
        for i in range(a.size):
            a[i] -= w[j] * FbT[j, i]
        pos.indicators[j] = 0
        w[j] = 0.0
        ll = ll_new
        lp -= model.log_odds + lpw
    return ok, ll, lp


@njit(cache=True, error_model="numpy", inline="always")
def flip(t: int, j: int, ctx: Context, bmemo: np.ndarray, ll: float, lp: float) -> tuple[bool, float, float]:
    """Flip :math:`c_j`: Algorithm 1's latent flip in ``paper``/``authors`` mode, else a reversible jump."""
    ctx.counts[C_FLIP_PROP] += 1
    if ctx.mode == MODE_PAPER or ctx.mode == MODE_AUTHORS:
        ok, ll = _flip_latent(t, j, ctx, bmemo, ll)
    elif ctx.pos.indicators[j] == 0:
        ok, ll, lp = _birth(t, j, ctx, ll, lp)
    else:
        ok, ll, lp = _death(t, j, ctx, ll, lp)
    if ok:
        ctx.counts[C_FLIP_ACC] += 1
    return ok, ll, lp


@njit(cache=True, error_model="numpy", inline="always")
def weight(t: int, j: int, ctx: Context, ll: float, lp: float) -> tuple[bool, float, float]:
    r"""Random walk on one weight :math:`w_j` (on :math:`\eta = \log|w_j|` where ``moves.log_sign[j] != 0``)."""
    pos, ad, model, scratch = ctx.pos, ctx.adaptation, ctx.model, ctx.scratch
    a, FbT, c, w = pos.scaled_returns, pos.features_T, pos.indicators, pos.penalty_weights
    sigma, lsg = ad.sigma, ctx.moves.log_sign
    ctx.counts[C_W_PROP] += 1
    ad.stats[3, j] += 1
    use_prior = ctx.mode == MODE_PBICRL or ctx.mode == MODE_BPL  # Algorithm 1 accepts on the likelihood ratio
    ok = False
    jac = 0.0
    if lsg[j] != 0 and w[j] != 0.0:
        # random walk on eta = log|w|; the Jacobian |dw'/deta'| / |dw/deta| = |w'| / |w| enters the ratio
        jac = sigma[j] * ctx.rnd.z[t]
        w_new = lsg[j] * math.exp(math.log(abs(w[j])) + jac)
        step = w_new - w[j]
    else:
        step = sigma[j] * ctx.rnd.z[t]
        w_new = w[j] + step
    lp_old = logprior_w(model.prior_kind[j], model.prior_params, j, w[j]) if use_prior else 0.0
    lp_new = logprior_w(model.prior_kind[j], model.prior_params, j, w_new) if use_prior else 0.0
    if lp_new > -np.inf:
        if c[j] == 0:
            # latent modes only: an inactive weight leaves the likelihood unchanged, always accepted; the
            # authors' code proposes from the effective weights, so an inactive one stays 0
            w[j] = 0.0 if ctx.mode == MODE_AUTHORS else w_new
            ok = True
        else:
            for i in range(a.size):
                scratch.a_new[i] = a[i] + step * FbT[j, i]
            ok, ll_new = mh_accept(ctx, t, ll, lp_new, -lp_old, jac, -1, _unscreened(ctx))
            if ok:
                for i in range(a.size):
                    a[i] = scratch.a_new[i]
                w[j] = w_new
                ll = ll_new
                lp += lp_new - lp_old
    if ok:
        ctx.counts[C_W_ACC] += 1
        ad.stats[4, j] += 1
    return ok, ll, lp


@njit(cache=True, error_model="numpy", inline="always")
def parameter(t: int, j: int, ctx: Context, ll: float, lp: float) -> tuple[bool, float, float]:
    r"""Random walk on the parameters :math:`\vartheta` of parametric constraint ``j``."""
    pos, ad, cons, scratch = ctx.pos, ctx.adaptation, ctx.cons, ctx.scratch
    a, FbT, theta = pos.scaled_returns, pos.features_T, pos.parameters
    theta_new, col_new, sigma_t = scratch.theta_new, scratch.col_new, ad.sigma_theta
    use_prior = ctx.mode == MODE_PBICRL or ctx.mode == MODE_BPL
    p0, p1 = _param_range(j, ctx)
    ctx.counts[C_T_PROP] += 1
    ad.theta_stats[3, p0] += 1
    ok = False
    for p in range(theta.size):
        theta_new[p] = theta[p]
    for p in range(p0, p1):
        theta_new[p] = theta[p] + sigma_t[p] * ctx.rnd.zt[t, p - p0]
    lpt_new = _logprior_theta(theta_new, p0, p1, cons.lo, cons.hi, use_prior)
    if lpt_new > -np.inf:
        lpt_old = _logprior_theta(theta, p0, p1, cons.lo, cons.hi, use_prior)
        _column(j - ctx.moves.d_known, theta_new, ctx.model.beta, cons, col_new, ctx.moves.naive)
        if pos.indicators[j] == 0:
            # paper mode only: a latent location leaves the likelihood unchanged
            ok = True
        else:
            for i in range(a.size):
                scratch.a_new[i] = a[i] + pos.penalty_weights[j] * (col_new[i] - FbT[j, i])
            ok, ll_new = mh_accept(ctx, t, ll, lpt_new, -lpt_old, 0.0, -1, _unscreened(ctx))
            if ok:
                for i in range(a.size):
                    a[i] = scratch.a_new[i]
                ll = ll_new
                lp += lpt_new - lpt_old
        if ok:
            for p in range(p0, p1):
                theta[p] = theta_new[p]
            for i in range(a.size):
                FbT[j, i] = col_new[i]
    if ok:
        ctx.counts[C_T_ACC] += 1
        ad.theta_stats[4, p0] += 1
    return ok, ll, lp


@njit(cache=True, error_model="numpy", inline="always")
def joint(t: int, ctx: Context, act: np.ndarray, dw: np.ndarray, Lc: np.ndarray, ll: float,
          lp: float) -> tuple[int, bool, float, float]:
    r"""All active weights together: :math:`w_A' = w_A + s\,(2.38/\sqrt{|A|})\,L z` (see :func:`advance`).
    Returns the move (``MOVE_NONE`` when no weight is active: nothing was proposed), accepted, log-densities."""
    pos, ad, model = ctx.pos, ctx.adaptation, ctx.model
    a, FbT, c, w = pos.scaled_returns, pos.features_T, pos.indicators, pos.penalty_weights
    cand, lsg, jsc = ctx.moves.cand, ctx.moves.log_sign, ad.joint_scale
    pkind, prm = model.prior_kind, model.prior_params
    m = 0
    for k in range(cand.size):
        if c[cand[k]] == 1:
            act[m] = cand[k]
            m += 1
    if m == 0:
        return MOVE_NONE, False, ll, lp
    ctx.counts[C_W_PROP] += 1
    jsc[1] += 1.0
    if not _cholesky_active(ad.joint_cov, act, m, Lc):
        for r in range(m):  # not positive definite: the single-site scales
            for q in range(m):
                Lc[r, q] = ad.sigma[act[r]] if r == q else 0.0
    sc = jsc[0] * 2.38 / math.sqrt(m)
    lp_old = 0.0
    lp_new = 0.0
    jac = 0.0
    for r in range(m):
        acc_ = 0.0
        for q in range(r + 1):
            acc_ += Lc[r, q] * ctx.rnd.zj[t, q]
        dw[r] = sc * acc_
        jj = act[r]
        if lsg[jj] != 0 and w[jj] != 0.0:  # a step on eta = log|w| (Jacobian |w'|/|w|)
            jac += dw[r]
            dw[r] = lsg[jj] * math.exp(math.log(abs(w[jj])) + dw[r]) - w[jj]
        lp_old += logprior_w(pkind[jj], prm, jj, w[jj])
        lp_new += logprior_w(pkind[jj], prm, jj, w[jj] + dw[r])
    ok = False
    if lp_new > -np.inf:
        a_new = ctx.scratch.a_new
        for i in range(a.size):
            a_new[i] = a[i]
        for r in range(m):
            jj = act[r]
            for i in range(a.size):
                a_new[i] += dw[r] * FbT[jj, i]
        ok, ll_new = mh_accept(ctx, t, ll, lp_new, -lp_old, jac, -1, _unscreened(ctx))
        if ok:
            for i in range(a.size):
                a[i] = a_new[i]
            for r in range(m):
                w[act[r]] += dw[r]
            ll = ll_new
            lp += lp_new - lp_old
    if ok:
        ctx.counts[C_W_ACC] += 1
        jsc[2] += 1.0
    return MOVE_JOINT, ok, ll, lp


@njit(cache=True, error_model="numpy", inline="always")
def _forget(move: int, j: int, latent: bool, c: np.ndarray, scratch: Scratch, bmemo: np.ndarray) -> None:
    """After an accepted move: invalidate the memoised likelihoods (and latent flip bounds) it changed."""
    memo_valid = scratch.memo_valid
    d = c.size
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
            memo_valid[j] = True  # memo_ll[j] holds the off-state likelihood (set by the move)


@njit(cache=True, error_model="numpy", inline="always")
def _track_best(pos: Position, best: MapTracker, ll: float, lp: float) -> None:
    """The MAP over every visited state."""
    if ll + lp > best.log_density[0]:
        best.log_density[0] = ll + lp
        best.log_density[1] = ll
        for k in range(pos.indicators.size):
            best.indicators[k] = pos.indicators[k]
            best.penalty_weights[k] = pos.penalty_weights[k]
        for p in range(pos.parameters.size):
            best.parameters[p] = pos.parameters[p]


@njit(cache=True, error_model="numpy", inline="always")
def _eta(w: float, log_sign: int) -> float:
    """The scale a weight moves on: :math:`\\log|w|` where ``log_sign != 0`` (and ``w != 0``), else ``w``."""
    return math.log(abs(w)) if log_sign != 0 and w != 0.0 else w


@njit(cache=True, error_model="numpy", inline="always")
def _accumulate(mode: int, joint_on: bool, it: int, burn_in: int, pos: Position, cons: ConstraintArrays,
                moves: Moves, adaptation: Adaptation) -> None:
    """Warm-up statistics of the current state: co-active weights for the joint move (second half of warm-up
    only: past the initial transient) and, in ``pbicrl`` mode, the active weights and parameters."""
    c, w, theta, lsg, cand = pos.indicators, pos.penalty_weights, pos.parameters, moves.log_sign, moves.cand
    if joint_on and 2 * it >= burn_in:
        jst = adaptation.joint_stats
        for k1 in range(cand.size):
            j1 = cand[k1]
            if c[j1] == 1:
                e1 = _eta(w[j1], lsg[j1])
                for k2 in range(cand.size):
                    j2 = cand[k2]
                    if c[j2] == 1:
                        e2 = _eta(w[j2], lsg[j2])
                        jst[0, j1, j2] += 1.0
                        jst[1, j1, j2] += e1
                        jst[2, j1, j2] += e1 * e2
    if mode == MODE_PBICRL:
        ad, adt, poff = adaptation.stats, adaptation.theta_stats, cons.poff
        for k in range(c.size):
            if c[k] == 1:
                wk = _eta(w[k], lsg[k])
                ad[0, k] += 1
                ad[1, k] += wk
                ad[2, k] += wk * wk
                if k >= moves.d_known:
                    for p in range(poff[k - moves.d_known], poff[k - moves.d_known + 1]):
                        adt[0, p] += 1
                        adt[1, p] += theta[p]
                        adt[2, p] += theta[p] * theta[p]


_TAN_TARGET = math.tan(0.15 * math.pi)  # acceptance 0.3 under the model of _scale_factor


@njit(cache=True, error_model="numpy")
def _scale_factor(accepted: float, proposed: float, solve: bool = True) -> float:
    """The factor for a weight's random-walk scale (``pbicrl`` sampler) after a warm-up window that accepted
    ``accepted`` of ``proposed`` steps: Robbins-Monro :math:`e^{\\alpha - 0.3}` (the ``bpl`` sampler's rule) from
    10% acceptance up; below, a step far wider than the posterior, the scale is solved for in one window (from 50
    steps in the window: fewer say too little, P(< 10% | 30%) = 7e-4 at 50, and a feature switched on for a few
    steps of a window must not collapse its scale).

    A Gaussian step of scale :math:`\\sigma` on a Gaussian of sd :math:`s` is accepted with probability
    :math:`(2/\\pi)\\arctan(2s/\\sigma)`; the factor that takes :math:`\\alpha` to 30% under that model is
    :math:`\\tan(\\pi\\alpha/2)/\\tan(0.15\\pi)` (at least 0.1). Robbins-Monro shrinks a scale by at most 0.74x per
    window: on 3 x 100,000 trajectories, whose posterior is ~100x narrower than the start's scale, the weight steps
    still accepted 2.8% after the four windows of warm-up, and the chains needed 6,130-12,918 iterations (seeds
    0-2) against 4,410-5,754 with this rule. Above 10% the rule is unchanged: the shipped point-mass (seeds 0-11) and
    Fetch-Reach (seeds 0-19) runs to convergence take the same iterations as before. ``solve`` False: Robbins-Monro
    throughout (the ``bpl`` sampler)."""
    if not solve or accepted >= 0.1 * proposed or proposed < 50.0:
        return math.exp(accepted / proposed - 0.3)
    rate = (accepted + 0.5) / (proposed + 1.0)
    return max(math.tan(0.5 * math.pi * rate) / _TAN_TARGET, 0.1)


@njit(cache=True, error_model="numpy", inline="always")
def adapt(mode: int, joint_on: bool, cons: ConstraintArrays, moves: Moves, adaptation: Adaptation) -> None:
    """One adaptation point of warm-up: Robbins-Monro scales towards ~30% acceptance; in ``pbicrl`` mode the
    flip-and-draw proposals from the window's active draws; the joint move's covariance and scale."""
    if joint_on:
        _adapt_joint(adaptation.joint_cov, adaptation.joint_stats, adaptation.joint_scale, adaptation.sigma, moves.cand)
    ad, sigma = adaptation.stats, adaptation.sigma
    for k in range(sigma.size):
        if ad[3, k] >= 10:
            sigma[k] *= _scale_factor(ad[4, k], ad[3, k], mode == MODE_PBICRL)  # towards ~30% acceptance
        ad[3, k] = 0
        ad[4, k] = 0
        if mode == MODE_PBICRL and ad[0, k] >= 20:  # on eta = log|w| where log_sign[k] != 0
            mean = ad[1, k] / ad[0, k]
            var = max(ad[2, k] / ad[0, k] - mean * mean, 0.0)
            adaptation.q_mean[k] = mean
            adaptation.q_scale[k] = max(2.0 * math.sqrt(var), sigma[k])  # wide: the window is autocorrelated
            ad[0, k] = 0
            ad[1, k] = 0.0
            ad[2, k] = 0.0
    adt, sigma_t, poff = adaptation.theta_stats, adaptation.sigma_theta, cons.poff
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
                adaptation.q_theta_mean[p] = mean
                adaptation.q_theta_scale[p] = max(2.0 * math.sqrt(var), sigma_t[p])
                adt[0, p] = 0
                adt[1, p] = 0.0
                adt[2, p] = 0.0


@njit(cache=True, error_model="numpy", inline="always")
def _store(mode: int, pos: Position, cons: ConstraintArrays, moves: Moves, draws: Draws, ll: float, lp: float) -> None:
    """Keep the current state as the next draw (parameters of an inactive constraint: NaN in ``pbicrl`` mode)."""
    r = draws.n[0]
    if r >= draws.log_likelihood.size:
        return
    c, poff = pos.indicators, cons.poff
    for k in range(c.size):
        draws.indicators[r, k] = c[k]
        draws.penalty_weights[r, k] = pos.penalty_weights[k]
    for mm in range(poff.size - 1):
        off = mode == MODE_PBICRL and c[moves.d_known + mm] == 0
        for p in range(poff[mm], poff[mm + 1]):
            draws.parameters[r, p] = np.nan if off else pos.parameters[p]
    draws.log_likelihood[r] = ll
    draws.log_prior[r] = lp
    draws.n[0] = r + 1


@njit(cache=True, error_model="numpy")
def advance(sched: Schedule, pos: Position, lik: LikelihoodArrays, cons: ConstraintArrays, moves: Moves,
            model: Model, rnd: Randoms, adaptation: Adaptation, draws: Draws, best: MapTracker, counts: np.ndarray,
            scratch: Scratch) -> None:
    """Advance one chain by ``sched.n`` iterations (global iteration numbers ``it0 .. it0+n-1``, 0-based).

    Every argument is a bundle of :mod:`pbicrl.inference.samplers.bundles` (``lik``:
    :class:`pbicrl.inference.likelihood_kernels.LikelihoodArrays`, passed on to
    :func:`pbicrl.inference.likelihood_kernels.loglik`); ``counts`` (``N_COUNTS``,) is indexed by ``C_*``. Each
    iteration :func:`choose` picks a move, which one of :func:`flip`, :func:`weight`, :func:`parameter` and
    :func:`joint` proposes and tests with :func:`mh_accept`; then the MAP is tracked, and during warm-up the
    proposals adapt (:func:`adapt`, every ``sched.adapt_every`` iterations), else every ``sched.thin``-th state is
    stored. The log-likelihood :math:`\\gamma\\mathcal{L}` (``model.power`` :math:`\\gamma`; 1 = the paper's model)
    and log-prior travel as two numbers and are written back to ``pos.log_density`` at the end.

    In ``pbicrl`` mode ``scratch.memo_ll[j]`` caches the likelihood with feature ``j`` switched off (valid while no
    other component changes); in ``paper`` mode it caches the likelihood of flipping ``j``.

    ``pbicrl`` and ``bpl``: with probability ``p_joint`` (``u_mv >= 1 - p_joint``) an iteration moves all active
    weights together, :math:`w_A' = w_A + s\\,(2.38/\\sqrt{|A|})\\,L z` with ``z = zj[t, :|A|]``, :math:`L L^\\top` the
    adapted covariance ``joint_cov`` restricted to the active set (diagonal ``sigma^2`` where it is not positive
    definite) and ``s = joint_scale[0]``. In the second half of warm-up ``joint_stats`` (3, d, d) accumulates
    co-active counts, sums and products of the weights, and ``joint_cov`` is re-estimated from it at each adaptation
    point; ``s`` adapts towards 25% acceptance throughout warm-up (``joint_scale[1:3]``: proposals, accepts in the
    window). Afterwards the kernel is fixed.

    ``scratch.last`` receives [move code, accepted] of the last iteration (``MOVE_*``; a joint move with no active
    weight counts as ``MOVE_NONE``).
    """
    mode = sched.mode
    d = pos.penalty_weights.size
    ll = pos.log_density[0]
    lp = pos.log_density[1]
    latent = mode == MODE_PAPER or mode == MODE_AUTHORS  # Algorithm 1's schedule, likelihood-ratio acceptance
    # explicit pairs only: the cheap bound of mh_accept
    # explicit pairs: every move; the grouped likelihood: death moves of the pbicrl sampler (see _unscreened), up to
    # _SCREEN_MAX_N trajectories: beyond, binning the returns (which the bound needs too) is most of an evaluation
    screen = ((lik.kind == LIK_PAIRWISE and lik.bm.size == 0 and lik.pi.size >= 16)
              or (lik.kind == LIK_GROUPED and mode == MODE_PBICRL and lik.gitems.size <= _SCREEN_MAX_N))
    joint_on = moves.p_joint > 0.0 and (mode == MODE_PBICRL or mode == MODE_BPL)
    ctx = Context(mode, screen, pos, lik, cons, moves, model, rnd, adaptation, counts, scratch)
    act = np.empty(d, np.int64)
    bmemo = np.full(d, np.nan)
    dw = np.empty(d)
    Lc = np.empty((d, d))
    move = MOVE_NONE
    accepted = False
    for t in range(sched.n):
        it = sched.it0 + t
        move, j = choose(t, it, mode, joint_on, pos.indicators, moves, rnd)
        accepted = False
        if move == MOVE_FLIP:
            accepted, ll, lp = flip(t, j, ctx, bmemo, ll, lp)
        elif move == MOVE_WEIGHT:
            accepted, ll, lp = weight(t, j, ctx, ll, lp)
        elif move == MOVE_PARAMETER:
            accepted, ll, lp = parameter(t, j, ctx, ll, lp)
        elif move == MOVE_JOINT:
            move, accepted, ll, lp = joint(t, ctx, act, dw, Lc, ll, lp)
        if accepted:
            _forget(move, j, latent, pos.indicators, scratch, bmemo)
        _track_best(pos, best, ll, lp)
        if it < sched.burn_in:
            _accumulate(mode, joint_on, it, sched.burn_in, pos, cons, moves, adaptation)
            if sched.adapt_every > 0 and (it + 1) % sched.adapt_every == 0:
                adapt(mode, joint_on, cons, moves, adaptation)
        elif (it - sched.burn_in) % sched.thin == 0:
            _store(mode, pos, cons, moves, draws, ll, lp)
    pos.log_density[0] = ll
    pos.log_density[1] = lp
    scratch.last[0] = move
    scratch.last[1] = accepted


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
