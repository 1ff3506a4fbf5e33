"""Export a posterior to ArviZ (InferenceData with arviz 0.x, DataTree with arviz 1.x) and NetCDF.

Needs ``pip install "pbicrl[diag]"`` (ArviZ and h5netcdf), imported lazily.

Layout (dimension ``feature`` has the dataset's feature names as coordinates, in the posterior group only those
whose draws vary; ``param`` the parameter names of parametric constraints, ``trajectory`` the trajectory
indices ``0..N-1``):

================ ============================== ===========================================================
group            variable                       meaning
================ ============================== ===========================================================
posterior        ``indicator``                  :math:`c_j \\in \\{0, 1\\}`, over dimension ``indicator_feature``: the
                 (indicator_feature)            features whose indicator changes between draws
posterior        ``penalty`` (feature)          effective penalty :math:`c_j w_{p,j}`, the features whose penalty
                                                changes between draws
posterior        ``penalty_weight`` (feature)   latent :math:`w_{p,j}` while :math:`c_j = 0`: only when it
                                                differs from ``penalty`` (the ``paper`` sampler keeps it;
                                                ``pbicrl`` and ``bpl`` do not, so it would repeat ``penalty``)
posterior        ``parameter`` (param)          constraint parameters, when the run has them (NaN while
                                                their constraint is inactive)
log_likelihood   ``preferences`` (trajectory)   each trajectory's share of the log-likelihood (see below), on
                                                at most ``pointwise_draws`` evenly spaced draws per chain
                                                (coordinate ``draw`` = the kept-draw index); only when the
                                                likelihood is known (the run's dataset, or ``likelihood=``)
sample_stats     ``total_log_likelihood``       total log-likelihood of all preferences, every draw (named
                                                so that ArviZ never takes it for the pointwise one)
sample_stats     ``lp``, ``log_prior``          log posterior (up to a constant), log prior
sample_stats     ``move``, ``accepted``,        per-draw move type (1 flip, 2 weight, 3 parameter), whether it
                 ``acceptance_rate``            was accepted, and the fraction of iterations accepted since the
                                                previous kept draw, when the chains record them (attributes
                                                ``move``, ``accepted``, ``acceptance_fraction`` (chains, draws))
constant_data    ``map_indicator``,             the MAP state and the nominal weights; ``group`` (trajectory)
                 ``map_penalty``,               when the dataset is known
                 ``nominal_weight`` (feature)
constant_data    ``indicator_constant``,        the value of an indicator / penalty that is the same in every
                 ``penalty_constant`` (feature) draw (e.g. a constraint on in every draw, or a feature that is not
                                                a candidate), NaN where it varies. Such a quantity is left out of
                                                the posterior group: R-hat and ESS are not applicable to it
                                                (``summary.json`` gives ``null``), and ``az.summary`` would report
                                                NaN with a RuntimeWarning
================ ============================== ===========================================================

**Pointwise log-likelihood.** ``az.loo`` needs one log-likelihood term per observation. The pairwise
likelihood's terms are comparisons (one per pair: 270,000 for 3 groups of 300, and they are not
exchangeable observations either), so the unit here is the trajectory, and each term is split between the
trajectories it involves so that the shares of one draw sum to its total log-likelihood
(:func:`pointwise_loglik`):

* ``pairwise`` (paper Eq. 7): each pair's term :math:`\\log\\sigma(a_i - m - a_j)` is split in half between its
  two trajectories (times the likelihood power).
* ``grouped`` (Plackett-Luce): the term :math:`\\log P_k` of group :math:`\\mathcal{G}_k` against the lower groups
  :math:`\\mathcal{R}_k` is split in half between the two sides, as a pair's is. The upper half goes to the
  members :math:`i \\in \\mathcal{G}_k` in proportion to their own winner terms
  :math:`\\ell_i = \\log\\sigma(a_i - \\log\\Lambda_k)` (the log-probability that :math:`i` alone beats every lower
  trajectory, :func:`pbicrl.inference.likelihood_kernels.group_term` of one item): a member that barely beats the lower groups
  carries more of the term. The lower half goes to the members :math:`j \\in \\mathcal{R}_k` in proportion to
  their weight :math:`e^{a_j + m_{k\\ell(j)}} / \\Lambda_k` in :math:`\\Lambda_k`: a lower trajectory that
  nearly reaches group :math:`k` carries more. Every share has the sign of its term, each term's shares add
  up to it, so the shares sum to :math:`\\sum_k \\log P_k`; with two groups of one trajectory each they are exactly
  the pairwise split of :math:`\\log\\sigma(a_i - m - a_j)` (with more groups a term compares one trajectory
  with all lower ones at once).
"""

from __future__ import annotations

import json
import os
import re
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Mapping

import numpy as np
from numpy.typing import ArrayLike, NDArray

from pbicrl._atomic import OutputExistsError, atomic_path
from pbicrl.analysis.diagnostics import INSTALL_HINT, arviz_major, require_arviz
from pbicrl.inference.codes import MOVES
from pbicrl.inference.constraints import constraint_set_of
from pbicrl.inference.draws import parameter_draws

if TYPE_CHECKING:
    from pbicrl.inference.constraints import ConstraintSet
    from pbicrl.inference.preferences import Margins
    from pbicrl.inference.data import Dataset
    from pbicrl.inference.likelihood import PreferenceLikelihood

__all__ = ["to_arviz", "to_netcdf", "pointwise_loglik", "pointwise_log_likelihood", "run_likelihood",
           "run_margins", "POINTWISE_DRAWS", "TOTAL_LOG_LIKELIHOOD"]

TOTAL_LOG_LIKELIHOOD = "total_log_likelihood"
"""Name of the total log-likelihood in ``sample_stats`` (``log_likelihood`` there would be read by ArviZ as the
pointwise log-likelihood of one observation; exports written before pbicrl 0.2 used that name)."""

POINTWISE_DRAWS = 500
"""Default number of draws per chain for the pointwise log-likelihood (it costs one pass over all pairs each)."""

_ROW_CHUNK = 256  # rows of a dense block evaluated at once: bounds the temporary to 256 x (group size) floats
_CHECK_RTOL = 1e-6  # rebuilt vs recorded total log-likelihood: agreement expected to ~1e-12, this is generous
_AS_DICT_ALL_PAIRS = 64  # Margins.as_dict lists every m_kl up to this many groups, else consecutive gaps only


# --------------------------------------------------------------------------------------- pointwise shares
def _pointwise_pairwise(lik: "PreferenceLikelihood", a: NDArray[np.float64]) -> NDArray[np.float64]:
    """Half of every pair's :math:`\\log\\sigma(a_i - m - a_j)` to ``i`` and half to ``j``."""
    p = lik.preferences
    N = a.size
    out = np.zeros(N)
    # dense blocks, or a ranked layout's rows against every worse group (per-column margins): never K x K
    for rows, cols, margin in p.iter_blocks():
        if rows.size == 0 or cols.size == 0:
            continue
        ac = a[cols] + margin
        col_sum = np.zeros(cols.size)
        for r0 in range(0, rows.size, _ROW_CHUNK):
            r = rows[r0:r0 + _ROW_CHUNK]
            # log sigma(a_i - m - a_j) = -softplus(a_j + m - a_i); logaddexp is exact for any spread
            t = -np.logaddexp(0.0, ac[None, :] - a[r][:, None])
            # bincount, not fancy-index +=, so a trajectory listed twice in a block keeps both shares
            out += np.bincount(r, weights=0.5 * t.sum(axis=1), minlength=N)
            col_sum += t.sum(axis=0)
        out += np.bincount(cols, weights=0.5 * col_sum, minlength=N)
    if p.pair_i.size:
        t = -np.logaddexp(0.0, a[p.pair_j] + p.pair_margins - a[p.pair_i])
        out += np.bincount(p.pair_i, weights=0.5 * t, minlength=N)
        out += np.bincount(p.pair_j, weights=0.5 * t, minlength=N)
    return out


def _logsumexp(x: NDArray[np.float64]) -> float:
    m = float(np.max(x)) if x.size else -np.inf
    if not np.isfinite(m):
        return m
    return m + float(np.log(np.sum(np.exp(x - m))))


def _split(total: float, weights: NDArray[np.float64]) -> NDArray[np.float64]:
    """``total`` shared in proportion to non-negative ``weights`` (equally if they sum to 0)."""
    ws = float(weights.sum())
    if not np.isfinite(total):
        # an impossible ordering (-inf) or NaN: every member gets it, the sum stays -inf / NaN
        return np.full(weights.size, total)
    if ws > 0 and np.isfinite(ws):
        return total * (weights / ws)
    return np.full(weights.size, total / weights.size)


def _pointwise_grouped(lik: "PreferenceLikelihood", a: NDArray[np.float64]) -> NDArray[np.float64]:
    r"""Half of each :math:`\log P_k` to the members of :math:`\mathcal{G}_k` by their winner terms, half to the lower
    trajectories by their weight in :math:`\Lambda_k` (module docstring).

    Additive margins (offsets :math:`o`, :math:`m_{k\ell} = o_\ell - o_k`) and finite returns take
    :func:`_pointwise_grouped_additive`, O(N + K); otherwise every group's term is split one by one, O(N K)."""
    p = lik.preferences
    o = p.margin_offsets
    if o.size and np.all(np.isfinite(a)):
        return _pointwise_grouped_additive(lik, a)
    M = p.group_margins
    return _pointwise_grouped_loop(lik, a, (lambda k: M[k]) if M.size else (lambda k: o - o[k]))


def _group_terms(a: NDArray[np.float64], items: NDArray[np.int64], off: NDArray[np.int64],
                 log_lam: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    r"""Every :math:`\log P_k` (k < K-1) and every upper member's winner term :math:`\log\sigma(x_i)` (ranked order)."""
    from pbicrl.inference import likelihood_kernels as _kernels

    K = off.size - 1
    sizes = np.diff(off)[:K - 1]
    x = a[items[:off[K - 1]]] - np.repeat(log_lam, sizes)
    own = -np.logaddexp(0.0, -x)  # log sigma(x_i): member i alone against every lower trajectory
    terms = np.empty(K - 1)
    one = sizes == 1
    terms[one] = own[off[:K - 1][one]]  # one item: P_k = sigma(x) exactly
    buf = np.empty((2, max(1, int(sizes.max()))))
    for k in np.flatnonzero(~one):
        terms[k] = float(_kernels.group_term(np.ascontiguousarray(x[off[k]:off[k + 1]]), buf))
    return terms, own


def _pointwise_grouped_additive(lik: "PreferenceLikelihood", a: NDArray[np.float64]) -> NDArray[np.float64]:
    r"""The split of :func:`_pointwise_grouped_loop` in O(N + K) for additive margins and finite returns.

    With :math:`B_\ell = \log\sum_{j\in\mathcal{G}_\ell} e^{a_j} + o_\ell`, :math:`\log\Lambda_k = \operatorname{logsumexp}_{\ell>k}
    B_\ell - o_k` (a suffix accumulation), and a lower trajectory :math:`j \in \mathcal{G}_\ell` gets
    :math:`\sum_{k<\ell} 	frac12 \log P_k\, e^{a_j + o_\ell - o_k - \log\Lambda_k} = e^{a_j + o_\ell} S_\ell`, a prefix sum
    :math:`S_\ell` over the groups above (its weights in each :math:`\Lambda_k` sum to one exactly, so no
    normalisation per group is needed)."""
    p = lik.preferences
    items, off, o = p.group_items, p.group_offsets, p.margin_offsets
    K = off.size - 1
    N = a.size
    ar = a[items]  # ranked order
    starts = off[:-1]
    mx = np.maximum.reduceat(ar, starts)
    lse = mx + np.log(np.add.reduceat(np.exp(ar - np.repeat(mx, np.diff(off))), starts))
    suffix = np.logaddexp.accumulate((lse + o)[::-1])[::-1]       # logsumexp_{l >= k} B_l
    log_lam = suffix[1:] - o[:-1]                                 # k = 0 .. K-2
    terms, own = _group_terms(a, items, off, log_lam)
    shares = np.zeros(N)                                          # ranked order
    # upper half: in proportion to -own within each group (equally where those sum to 0)
    up = off[K - 1]
    gid = np.repeat(np.arange(K - 1), np.diff(off)[:K - 1])
    ws = np.add.reduceat(-own, starts[:K - 1])
    half = 0.5 * terms
    ok = (ws > 0) & np.isfinite(ws)
    frac = np.where(ok[gid], -own / np.where(ok, ws, 1.0)[gid], 1.0 / np.diff(off)[:K - 1][gid])
    shares[:up] += half[gid] * frac
    # lower half: e^{a_j + o_l} * S_l, S_l = sum_{k<l} half_k e^{-o_k - log Lambda_k}, signs kept apart (log P_k <= 0
    # up to rounding)
    base = -o[:-1] - log_lam
    with np.errstate(divide="ignore"):
        neg = np.logaddexp.accumulate(np.log(np.maximum(-half, 0.0)) + base)
        pos = np.logaddexp.accumulate(np.log(np.maximum(half, 0.0)) + base)
    lo = off[1]
    gl = np.repeat(np.arange(1, K), np.diff(off)[1:])             # group of each lower position
    e = ar[lo:] + o[gl]
    shares[lo:] += np.exp(e + pos[gl - 1]) - np.exp(e + neg[gl - 1])
    out = np.zeros(N)
    out[items] = shares
    return out


def _pointwise_grouped_loop(lik: "PreferenceLikelihood", a: NDArray[np.float64],
                            margin_row: Callable[[int], NDArray[np.float64]]) -> NDArray[np.float64]:
    r"""Every group's term split one by one (any margins, any returns): ``margin_row(k)`` is :math:`m_{k\cdot}`, (K,)."""
    from pbicrl.inference import likelihood_kernels as _kernels
    p = lik.preferences
    items, off = p.group_items, p.group_offsets
    K = off.size - 1
    out = np.zeros(a.size)
    lse = np.array([_logsumexp(a[items[off[l]:off[l + 1]]]) for l in range(K)])
    buf = np.empty((2, max(1, int(np.max(np.diff(off))))))
    for k in range(K - 1):
        lower = np.arange(k + 1, K)
        row = margin_row(k)
        log_lam = _logsumexp(lse[lower] + row[lower])
        upper = items[off[k]:off[k + 1]]
        x = np.ascontiguousarray(a[upper] - log_lam)
        term = float(_kernels.group_term(x, buf))  # log P_k, as grouped_loglik computes it
        own = -np.logaddexp(0.0, -x)  # log sigma(x_i): member i alone against every lower trajectory
        out[upper] += _split(0.5 * term, -own)
        low = items[off[k + 1]:off[K]]
        group_of = np.repeat(lower, np.diff(off)[k + 1:])
        out[low] += _split(0.5 * term, np.exp(a[low] + row[group_of] - log_lam))
    return out


# One entry per likelihood kind; a kind's function returns (N,) shares that sum to the unpowered total.
_POINTWISE: dict[str, Callable[["PreferenceLikelihood", NDArray[np.float64]], NDArray[np.float64]]] = {
    "pairwise": _pointwise_pairwise,
    "grouped": _pointwise_grouped,
}


def pointwise_loglik(lik: "PreferenceLikelihood", a: ArrayLike) -> NDArray[np.float64]:
    """Each trajectory's share of the log-likelihood at scaled returns ``a``.

    Parameters
    ----------
    lik : PreferenceLikelihood
        Its ``preferences`` (dense blocks and explicit pairs), ``power`` and ``kind`` (``"pairwise"``, the
        default when the attribute is absent) define the terms.
    a : array-like, (N,)
        Scaled length-normalised returns :math:`a_i = \\beta \\bar\\phi_i^\\top w` (see
        :func:`pbicrl.inference.likelihood.scaled_returns`).

    Returns
    -------
    ndarray, (N,)
        For the pairwise likelihood, trajectory :math:`i` gets half of the term
        :math:`\\log\\sigma(a_i - m - a_j)` of every pair it takes part in, times the likelihood power; for the
        grouped likelihood, its shares of the group terms :math:`\\log P_k` (module docstring). The shares sum to
        ``lik.from_scaled_returns(a)`` (up to rounding); a trajectory in no term gets 0.

    Raises
    ------
    ValueError
        For an unknown kind or an ``a`` of the wrong length.
    """
    kind = str(getattr(lik, "kind", "pairwise"))
    fn = _POINTWISE.get(kind)
    if fn is None:
        raise ValueError(f"pointwise_loglik: unknown likelihood kind {kind!r}; known: {', '.join(_POINTWISE)}")
    a = np.asarray(a, dtype=np.float64).reshape(-1)
    N = int(lik.preferences.n_trajectories)
    if a.size != N:
        raise ValueError(f"pointwise_loglik: expected {N} scaled returns (one per trajectory), got {a.size}")
    return float(getattr(lik, "power", 1.0)) * fn(lik, a)


# --------------------------------------------------------------------------------------- per-draw returns
def _scaled_returns(lik: "PreferenceLikelihood", cset: "ConstraintSet | None", c: NDArray, wp: NDArray,
                    theta: NDArray | None) -> NDArray[np.float64]:
    """:math:`a` of one draw: known features at :math:`w_n + c\\circ w_p`, constraint features at their
    parameters (nominal weight 0, skipped while inactive, where the sampler stores NaN parameters)."""
    dk = lik.n_features
    eff = np.asarray(c, dtype=np.float64) * np.asarray(wp, dtype=np.float64)
    a = lik.beta * (lik.mean_features @ (lik.nominal_weights + eff[:dk]))
    if cset is not None:
        for m in range(cset.n_constraints):
            w = eff[dk + m]
            if w != 0.0:
                a = a + lik.beta * w * cset.mean_feature(m, cset.theta_of(np.asarray(theta), m))
    return a


def _draw_index(n_draws: int, max_draws: int | None) -> NDArray[np.int64]:
    if max_draws is not None and max_draws < 1:
        raise ValueError(f"pointwise_draws: expected a positive number of draws per chain, got {max_draws}")
    if max_draws is None or max_draws >= n_draws:
        return np.arange(n_draws)
    return np.unique(np.round(np.linspace(0, n_draws - 1, int(max_draws))).astype(np.int64))


def pointwise_log_likelihood(post: Any, lik: "PreferenceLikelihood", *, constraints: "ConstraintSet | None" = None,
                             draws: ArrayLike | None = None) -> NDArray[np.float64]:
    """Per-trajectory log-likelihood shares (:func:`pointwise_loglik`) of the posterior's draws.

    Parameters
    ----------
    post : Posterior or RunRecord
    lik : PreferenceLikelihood
        The likelihood the run sampled (known features only).
    constraints : ConstraintSet, optional
        The run's parametric constraints, bound to the dataset (their features follow each draw's parameters).
    draws : array-like of int, optional
        Kept-draw indices to evaluate (default all).

    Returns
    -------
    ndarray, (chains, len(draws), N)
    """
    c = np.asarray(post.indicators)
    wp = np.asarray(post.penalty_weights, dtype=np.float64)
    C, D, d = c.shape
    dk = lik.n_features
    n_con = 0 if constraints is None else constraints.n_constraints
    if d != dk + n_con:
        raise ValueError(f"export: the posterior has {d} features, the likelihood {dk} and the constraints {n_con}")
    theta = getattr(post, "parameters", None)
    theta = None if theta is None or not np.size(theta) else np.asarray(theta, dtype=np.float64)
    if theta is not None and theta.ndim == 2:
        theta = theta[:, :, None]
    idx = np.arange(D) if draws is None else np.asarray(draws, dtype=np.int64).reshape(-1)
    out = np.empty((C, idx.size, lik.preferences.n_trajectories))
    for ch in range(C):
        for k, t in enumerate(idx):
            a = _scaled_returns(lik, constraints, c[ch, t], wp[ch, t], None if theta is None else theta[ch, t])
            out[ch, k] = pointwise_loglik(lik, a)
    return out


# --------------------------------------------------------------------------------------- rebuilding a run's likelihood
def run_margins(extra: Mapping[str, Any], n_groups: int, *, what: str = "export") -> "Margins":
    """The margins a run recorded, ``extra["margins"]`` (``{"m12": ..}``, ``{"m1_2": ..}`` for 10+ groups; beyond
    64 groups :meth:`Margins.as_dict` lists only the consecutive gaps of additive margins, read back as gaps: no
    K x K). None recorded: zero margins.

    Parameters
    ----------
    extra : mapping
        The run's ``extra`` (``Posterior.extra``).
    n_groups : int
        :math:`K`, the number of groups of the dataset the run was made with.
    what : str
        Names the caller in error messages.

    Raises
    ------
    ValueError
        A key that is not a margin ``m<k>_<l>``, or one that does not fit ``n_groups``.
    """
    from pbicrl.inference.preferences import Margins

    vals: dict[tuple[int, int], float] = {}
    for key, v in dict(extra.get("margins") or {}).items():
        hit = re.fullmatch(r"m(\d+)_(\d+)", key) or (re.fullmatch(r"m(\d)(\d)", key) if n_groups < 10 else None)
        if hit is None:
            raise ValueError(f"{what}: cannot read margin {key!r} of the run")
        k, l = int(hit.group(1)), int(hit.group(2))
        if not 1 <= k < l <= n_groups:
            raise ValueError(f"{what}: margin {key!r} does not fit the dataset's {n_groups} groups")
        vals[(k, l)] = float(v)
    consecutive = len(vals) == n_groups - 1 and all(l == k + 1 for k, l in vals)
    if not vals or (consecutive and n_groups > _AS_DICT_ALL_PAIRS):
        return Margins.from_gaps([vals.get((k, k + 1), 0.0) for k in range(1, n_groups)])
    return Margins.from_dict(vals, n_groups)


def run_likelihood(post: Any, dataset: "Dataset") -> tuple["PreferenceLikelihood", "ConstraintSet | None"]:
    """Rebuild the likelihood a run sampled from its recorded settings and its dataset, and check it.

    Uses ``settings`` (``beta``, ``nominal_weights``, ``protocol``; ``power`` and ``pairs_seed`` from
    ``settings`` or ``extra`` where recorded, else 1 and 0) and ``extra["margins"]``, and recomputes the total
    log-likelihood of a few draws.

    Raises
    ------
    ValueError
        If the run used an unknown likelihood kind, if the dataset does not match the run, the preferences cannot be rebuilt (explicit comparisons), or
        the rebuilt likelihood does not reproduce the recorded log-likelihood (e.g. a run sampled with a
        likelihood power or pair seed its ``summary.json`` does not record): the message says which.
    """
    from pbicrl.inference.likelihood import PreferenceLikelihood

    settings = dict(getattr(post, "settings", {}) or {})
    extra = dict(getattr(post, "extra", {}) or {})
    kind = str(extra.get("likelihood") or settings.get("likelihood") or "pairwise")
    if kind not in _POINTWISE:
        raise ValueError(f"export: the run used the {kind!r} likelihood, which this pbicrl does not know; "
                         "export without the pointwise log-likelihood (pointwise=False)")
    names = [str(n) for n in post.feature_names]
    dk = dataset.n_features
    if list(dataset.feature_names) != names[:dk]:
        raise ValueError(f"export: the dataset's features {list(dataset.feature_names)} do not match the run's "
                         f"{names[:dk]}; pass the dataset the run was inferred from")
    protocol = str(settings.get("protocol", "all"))
    hit = re.fullmatch(r"(\d+) per group pair( \(distinct\))?", protocol)
    if protocol != "all" and hit is None:
        raise ValueError(f"export: the run's preferences ({protocol!r}) cannot be rebuilt from the dataset; "
                         "pass likelihood=")
    def recorded(key: str, default: float) -> float:  # settings (sampler record) first, then extra (infer's)
        v = settings.get(key, extra.get(key))
        return default if v is None else float(v)

    wn = settings.get("nominal_weights")
    lik = PreferenceLikelihood.from_dataset(
        dataset, margins=run_margins(extra, dataset.n_groups),
        protocol="all" if hit is None else int(hit.group(1)), seed=int(recorded("pairs_seed", 0)),
        distinct_pairs=hit is not None and hit.group(2) is not None,
        nominal_weights=None if wn is None else np.asarray(wn, dtype=np.float64),
        beta=recorded("beta", 1.0), power=recorded("power", 1.0), likelihood=kind)  # type: ignore[arg-type]
    cset = constraint_set_of(post, dataset)
    _check_likelihood(post, lik, cset)
    return lik, cset


def _check_likelihood(post: Any, lik: "PreferenceLikelihood", cset: "ConstraintSet | None") -> None:
    """Raise if ``lik`` does not reproduce the recorded total log-likelihood at three draws."""
    ll = np.asarray(post.log_likelihood, dtype=np.float64)
    C, D = ll.shape
    if D == 0:
        return
    theta = getattr(post, "parameters", None)
    theta = None if theta is None or not np.size(theta) else np.asarray(theta, dtype=np.float64)
    if theta is not None and theta.ndim == 2:
        theta = theta[:, :, None]
    for ch, t in {(0, 0), (C - 1, D // 2), (C // 2, D - 1)}:
        a = _scaled_returns(lik, cset, post.indicators[ch, t], post.penalty_weights[ch, t],
                            None if theta is None else theta[ch, t])
        got, want = lik.from_scaled_returns(a), float(ll[ch, t])
        if not np.isclose(got, want, rtol=_CHECK_RTOL, atol=_CHECK_RTOL):
            raise ValueError(
                f"export: the likelihood rebuilt from the run's settings gives {got:.10g} at chain {ch}, draw {t}, "
                f"the run recorded {want:.10g}: this is not the run's likelihood (the dataset changed since the run, "
                "or a likelihood power or pair seed that summary.json does not record). Pass the run's dataset= or "
                "likelihood= (and constraints=).")


# --------------------------------------------------------------------------------------- assembling the groups
def _json_default(o: Any) -> Any:
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, np.generic):
        return o.item()
    return str(o)


def _sample_stats(post: Any) -> dict[str, tuple[NDArray, dict[str, Any]]]:
    """Per-draw statistics: totals always; move type and acceptance when the chains carry them."""
    ll = np.asarray(post.log_likelihood, dtype=np.float64)
    lp = np.asarray(getattr(post, "log_prior", None) if getattr(post, "log_prior", None) is not None
                    else np.zeros_like(ll), dtype=np.float64)
    stats: dict[str, tuple[NDArray, dict[str, Any]]] = {
        # not "log_likelihood": ArviZ takes a sample_stats variable of that name for the pointwise one
        TOTAL_LOG_LIKELIHOOD: (ll, {"long_name": "total log-likelihood of all preferences (not pointwise: the "
                                                 "log_likelihood group holds each trajectory's share)"}),
        "lp": (ll + lp, {"long_name": "log posterior (up to a constant)"}),
        "log_prior": (lp, {"long_name": "log prior"}),
    }
    move = getattr(post, "move", None)
    if move is not None and np.shape(move) == ll.shape:
        stats["move"] = (np.asarray(move, dtype=np.int8),
                         {"flag_values": list(MOVES), "flag_meanings": " ".join(MOVES.values())})
    acc = getattr(post, "accepted", None)
    if acc is not None and np.shape(acc) == ll.shape:
        stats["accepted"] = (np.asarray(acc, dtype=bool), {"long_name": "the move that produced the draw was accepted"})
    # named apart from Posterior.acceptance_rate(), the rates per move type over the whole run
    rate = getattr(post, "acceptance_fraction", None)
    if rate is not None and np.shape(rate) == ll.shape:
        stats["acceptance_rate"] = (np.asarray(rate, dtype=np.float64),
                                    {"long_name": "fraction of iterations accepted since the previous kept draw"})
    return stats


def _varying(x: NDArray) -> NDArray[np.bool_]:
    """(chains, draws, d) -> (d,): True where some draw differs from the first one."""
    flat = x.reshape(-1, x.shape[-1])
    if flat.shape[0] == 0:
        return np.zeros(x.shape[-1], dtype=bool)
    return ~np.all(flat == flat[:1], axis=0)


def _find_dataset(post: Any, dataset: Any) -> "Dataset | None":
    """The run's dataset: ``dataset`` if given, else the one the posterior kept (:func:`pbicrl.infer`), else the
    file the run recorded (``extra.data.path``, or the copy ``extra.data.file`` in the run directory); None when
    none of these exists. A dataset whose content hash differs from the recorded ``extra.data.sha256`` is an error."""
    from pbicrl.inference.data import Dataset, load_dataset
    from pbicrl.io.runs import recorded_dataset

    where = "dataset"
    if dataset is None:
        kept = getattr(post, "dataset", None)
        if isinstance(kept, Dataset):
            return kept
        dp = recorded_dataset(post)
        if dp is None or not dp.is_file():
            return None
        dataset, where = dp, f"the run's recorded dataset {dp}"
    if isinstance(dataset, (str, os.PathLike)):
        where = where if where != "dataset" else f"dataset {os.fspath(dataset)}"
        dataset = load_dataset(dataset)
    if not isinstance(dataset, Dataset):
        raise TypeError(f"dataset: expected a Dataset or a path, got {type(dataset).__name__}")
    want = (dict(getattr(post, "extra", {}) or {}).get("data") or {}).get("sha256")
    if isinstance(want, str) and dataset.content_hash() != want:
        raise ValueError(f"export: {where} is not the data this run was inferred from (content hash "
                         f"{dataset.content_hash()[:12]}..., the run recorded {want[:12]}...); pass the run's "
                         "dataset (dataset=, --data)")
    return dataset


def _no_dataset_message(post: Any) -> str:
    """Why the pointwise log-likelihood cannot be built, and what to do."""
    from pbicrl.io.runs import recorded_dataset

    data = dict(getattr(post, "extra", {}) or {}).get("data") or {}
    dp = recorded_dataset(post)
    sha = data.get("sha256")
    what = (f"the dataset the run recorded, {dp}, does not exist any more" if dp is not None else
            "the run records no dataset file" + (f" (only its content hash sha256 {sha[:12]}...)"
                                                 if isinstance(sha, str) else ""))
    return (f"export: no pointwise log-likelihood (the log_likelihood group az.loo and az.waic need): {what}; "
            "pass the run's dataset (dataset= in Python, --data on the command line), or export without it "
            "(pointwise=False, --no-pointwise)")


def _datasets(post: Any, *, dataset: Any, likelihood: Any, constraints: Any, pointwise: bool | str,
              pointwise_draws: int | None) -> tuple[dict[str, Any], dict[str, Any]]:
    """xarray Datasets per group, and the root attributes."""
    import xarray as xr

    names = [str(n) for n in post.feature_names]
    c = np.asarray(post.indicators).astype(np.int8)
    wp = np.asarray(post.penalty_weights, dtype=np.float64)
    C, D, d = c.shape
    chain, draw = np.arange(C), np.arange(D)
    base = {"chain": chain, "draw": draw}

    eff = c * wp
    # A quantity with the same value in every draw has no R-hat or ESS (summary.json says null): it goes to
    # constant_data, so that az.summary never reports NaN R-hat (with a RuntimeWarning) for it.
    latent = not np.array_equal(wp, eff)  # the paper sampler keeps a latent w_p while c = 0; others store 0
    vc = _varying(c)
    vp = _varying(eff) | (_varying(wp) if latent else False)
    names_arr = np.array(names, dtype=object)
    note = ("only the features whose {} changes between draws; the others are constant_data.{}_constant "
            "(R-hat and ESS are not applicable to a constant)")
    post_vars: dict[str, Any] = {}
    coords: dict[str, Any] = dict(base)
    if vc.any():
        post_vars["indicator"] = (("chain", "draw", "indicator_feature"), c[:, :, vc],
                                  {"long_name": "constraint indicator c", "note": note.format("indicator", "indicator")})
        coords["indicator_feature"] = [str(n) for n in names_arr[vc]]
    if vp.any():
        post_vars["penalty"] = (("chain", "draw", "feature"), eff[:, :, vp],
                                {"long_name": "effective penalty c * w_p", "note": note.format("penalty", "penalty")})
        if latent:
            post_vars["penalty_weight"] = (("chain", "draw", "feature"), wp[:, :, vp],
                                           {"long_name": "penalty weight w_p (latent while c = 0)"})
        coords["feature"] = [str(n) for n in names_arr[vp]]
    params, pnames = parameter_draws(post)
    if params is not None:
        post_vars["parameter"] = (("chain", "draw", "param"), params,
                                  {"long_name": "constraint parameters (NaN while the constraint is inactive)"})
        coords["param"] = pnames
    groups: dict[str, Any] = {"posterior": xr.Dataset(post_vars, coords=coords)}
    groups["sample_stats"] = xr.Dataset({k: (("chain", "draw"), v, a) for k, (v, a) in _sample_stats(post).items()},
                                        coords=base)

    settings = dict(getattr(post, "settings", {}) or {})
    wn = settings.get("nominal_weights")
    nominal = np.zeros(d) if wn is None else np.asarray(wn, dtype=np.float64).reshape(-1)
    const: dict[str, Any] = {
        "map_indicator": (("feature",), np.asarray(post.map_indicators).astype(np.int8)),
        "map_penalty": (("feature",),
                        np.asarray(post.map_indicators) * np.asarray(post.map_penalty_weights, dtype=np.float64)),
        # the nominal weights of the known features; parametric constraints have none (NaN if unknown)
        "nominal_weight": (("feature",), np.concatenate([nominal, np.zeros(d - nominal.size)])
                           if nominal.size <= d and nominal.size else np.full(d, np.nan)),
    }
    fixed = "the value in every draw where it never changes (not in the posterior group: R-hat and ESS are not " \
            "applicable), NaN where it varies"
    const["indicator_constant"] = (("feature",), np.where(vc, np.nan, c[0, 0] if D else np.nan),
                                   {"long_name": f"indicator c: {fixed}"})
    const["penalty_constant"] = (("feature",), np.where(vp, np.nan, eff[0, 0] if D else np.nan),
                                 {"long_name": f"effective penalty c * w_p: {fixed}"})
    const_coords: dict[str, Any] = {"feature": names}
    map_params = getattr(post, "map_parameters", None)
    if params is not None and map_params is not None and np.size(map_params) == len(pnames):
        const["map_parameter"] = (("param",), np.asarray(map_params, dtype=np.float64).reshape(-1))
        const_coords["param"] = pnames

    if pointwise not in (True, False, "auto"):
        raise ValueError(f"pointwise: expected True, False or 'auto', got {pointwise!r}")
    idx = _draw_index(D, pointwise_draws)  # a bad argument is an error in every mode
    # a dataset passed in must load; the run's recorded one may have moved or changed (then "auto" warns)
    ds = _find_dataset(post, dataset) if dataset is not None else None
    if pointwise is not False:
        try:
            if ds is None:
                ds = _find_dataset(post, None)
            if likelihood is None:
                if ds is None:
                    raise ValueError(_no_dataset_message(post))
                likelihood, constraints = run_likelihood(post, ds)
            elif constraints is None and ds is not None:
                constraints = constraint_set_of(post, ds)
            pw = pointwise_log_likelihood(post, likelihood, constraints=constraints, draws=idx)
        except (ValueError, NotImplementedError) as exc:
            if pointwise is True:
                raise
            from pbicrl.errors import warn

            warn(f"{exc}; the export has no log_likelihood group (az.loo needs it)", stacklevel=4)
        else:
            N = pw.shape[2]
            share = {"pairwise": "half of each pair's log sigma(a_i - m - a_j) to each of its two trajectories",
                     "grouped": "half of each group term log P_k to the group's members (by their own winner terms), "
                                "half to the lower trajectories (by their weight in Lambda_k)"}
            kind = str(getattr(likelihood, "kind", "pairwise"))
            groups["log_likelihood"] = xr.Dataset(
                {"preferences": (("chain", "draw", "trajectory"), pw,
                                 {"long_name": "log-likelihood share of each trajectory",
                                  "share": share.get(kind, kind), "likelihood_kind": kind,
                                  "power": float(getattr(likelihood, "power", 1.0)),
                                  "draws_per_chain": f"{idx.size} of {D} (evenly spaced; coordinate "
                                                     "draw = kept draw)"})},
                coords={"chain": chain, "draw": idx, "trajectory": np.arange(N)})
            if ds is not None and ds.n_trajectories == N:
                const["group"] = (("trajectory",), np.asarray(ds.group, dtype=np.int64))
                const_coords["trajectory"] = np.arange(N)
    groups["constant_data"] = xr.Dataset(const, coords=const_coords)

    attrs = {"inference_library": "pbicrl", "sampler": str(getattr(post, "sampler", "")),
             "seed": int(getattr(post, "seed", 0)), "settings_json": json.dumps(settings, default=_json_default)}
    try:
        from pbicrl._version import __version__

        attrs["inference_library_version"] = __version__
    except ImportError:  # pragma: no cover
        pass
    return groups, attrs


def to_arviz(post: Any, *, dataset: "Dataset | str | os.PathLike[str] | None" = None,
             likelihood: "PreferenceLikelihood | None" = None, constraints: "ConstraintSet | None" = None,
             pointwise: bool | str = True, pointwise_draws: int | None = POINTWISE_DRAWS) -> Any:
    """ArviZ object of a posterior (see the module docstring for its variables).

    Parameters
    ----------
    post : Posterior or RunRecord
    dataset : Dataset or path, optional
        For the pointwise log-likelihood; default: the dataset :func:`pbicrl.infer` kept with the posterior, else
        the file the run recorded (``extra.data.path``, or the copy ``extra.data.file`` that
        :meth:`~pbicrl.inference.posterior.Posterior.save` stores for an in-memory dataset). Checked against the
        recorded content hash (``extra.data.sha256``) when there is one.
    likelihood : PreferenceLikelihood, optional
        The likelihood the run sampled; default: rebuilt from the run's settings and ``dataset`` and
        checked against the recorded log-likelihood (:func:`run_likelihood`).
    constraints : ConstraintSet, optional
        With ``likelihood``, the run's parametric constraints (default: rebuilt from the settings).
    pointwise : True, False or "auto"
        Whether to store the pointwise log-likelihood. True (default): always, and a :class:`ValueError` naming
        what is missing when the dataset cannot be found (never an export that ``az.loo`` would misread);
        ``"auto"`` stores it when the likelihood is known and otherwise warns
        (:class:`~pbicrl.errors.PbicrlWarning`) and leaves out the ``log_likelihood`` group.
    pointwise_draws : int or None
        At most this many evenly spaced draws per chain for it (None: all).

    Returns
    -------
    arviz.InferenceData (arviz < 1) or xarray.DataTree (arviz >= 1)

    Notes
    -----
    ``az.loo`` estimates the relative efficiency from the posterior group's ESS divided by the number of
    pointwise draws; with thinned pointwise draws pass ``reff=`` if the chains mix much better than that.

    A trajectory that every better one beats by far has a share of about 0 (e.g. -1e-19) in every draw. ArviZ
    0.x's Pareto smoothing divides by zero on such a numerically constant column and reports NaN for its
    ``loo_i`` (and so for ``elpd_loo``), although its leave-one-out term is 0; the shares are stored as
    computed, ``az.loo(data, pointwise=True).loo_i`` shows which trajectories these are.
    """
    az = require_arviz()
    groups, attrs = _datasets(post, dataset=dataset, likelihood=likelihood, constraints=constraints,
                              pointwise=pointwise, pointwise_draws=pointwise_draws)
    for g in groups.values():
        g.attrs.update(attrs)
    if arviz_major(az) >= 1:
        import xarray as xr

        tree = xr.DataTree.from_dict(groups)
        tree.attrs.update(attrs)
        return tree
    # InferenceData takes the groups as they are, so log_likelihood may keep its own (thinned) draw coordinate
    return az.InferenceData(**groups)


def to_netcdf(post: Any, path: str | os.PathLike[str], *, overwrite: bool = False, **kwargs: Any) -> Path:
    """Write :func:`to_arviz` of ``post`` to a NetCDF file atomically (temp file, then rename).

    Keyword arguments go to :func:`to_arviz` (``dataset``, ``likelihood``, ``pointwise``, ...).

    Raises
    ------
    pbicrl.io.runs.OutputExistsError
        If ``path`` exists and ``overwrite`` is false (a :class:`FileExistsError`).
    ImportError
        If ArviZ or a NetCDF engine (h5netcdf) is missing; the message names the pip command.
    """
    out = Path(path)
    if out.exists() and not overwrite:
        raise OutputExistsError("path", out, kind="file")
    try:
        import h5netcdf  # noqa: F401
        import h5py  # noqa: F401  (h5netcdf's backend, not always pulled in by it)
    except ImportError as exc:
        raise ImportError(f"NetCDF export needs h5netcdf ({exc}): {INSTALL_HINT}") from exc
    data = to_arviz(post, **kwargs)
    with atomic_path(out, overwrite=overwrite) as tmp:
        data.to_netcdf(tmp, engine="h5netcdf")
    return out
