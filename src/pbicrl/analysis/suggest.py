r"""Active query selection: which unlabelled demonstrations to rank next.

A posterior over constraint indicators :math:`c` and penalties :math:`w_p` (draws :math:`\theta^{(s)}`,
:math:`s = 1..S`) and a labelled, grouped dataset :math:`\mathcal{G}_1 \succ \dots \succ \mathcal{G}_K` are given.
For an unlabelled candidate :math:`\tau_x` let :math:`Y \in \{1..K\}` be the group the user will put it in.
pbicrl ranks candidates by the mutual information between :math:`Y` and the indicators,

.. math::
    I(Y; c) = H\Big(\frac{1}{S}\sum_s p_s\Big) - \sum_z \frac{S_z}{S}\, H\Big(\frac{1}{S_z}\sum_{s: c^{(s)} = z} p_s\Big),

where :math:`p_s(k) = P(Y = k \mid \theta^{(s)}, \mathcal{D})` and :math:`z` runs over the distinct indicator
vectors among the draws (:math:`S_z` draws each). It is zero when the candidate's group is certain, and when
it does not depend on :math:`c`; it is the expected reduction of the entropy of :math:`c` from learning
:math:`Y` (plug-in estimate over the draws; with :math:`S` draws and few distinct sets it is close to exact).
``target="selected"`` ranks by :math:`\sum_j I(Y; c_j)` instead, the information about each marginal
:math:`P(c_j = 1)`, which decides the selected set (:math:`P(c_j = 1) > 0.5`).

**Group probabilities** :math:`p_s(k)`. Under the grouped Plackett-Luce likelihood (:mod:`pbicrl.inference.likelihood`)
with :math:`\lambda_i = e^{a_i}`, :math:`a_i = \beta\bar\phi_i^\top w^{(s)}`, the probability of the ranking is
:math:`\prod_{\ell<K} P_\ell` with :math:`P_\ell(\Lambda_\ell) = \int_0^\infty e^{-t}\prod_{i\in\mathcal{G}_\ell}
(1 - e^{-t\lambda_i/\Lambda_\ell})\,dt` and :math:`\Lambda_\ell = \sum_{j \in \mathcal{G}_{>\ell}} \lambda_j e^{m_{\ell, g(j)}}`.
We take :math:`p_s(k) \propto L_k`, the likelihood of the ranking with :math:`\tau_x` added to group :math:`k` and
every labelled trajectory where it is: the posterior predictive of the candidate's group under a uniform prior
over the :math:`K` groups (the grouped likelihood conditions on the group sizes, so it is not itself a
distribution over assignments; this normalisation over :math:`k` is the modelling choice). Adding
:math:`\tau_x` to group :math:`k` changes only

* the terms :math:`\ell < k`: :math:`\Lambda_\ell \to \Lambda_\ell + \lambda_x e^{m_{\ell k}}`;
* the term :math:`k` (if :math:`k < K`): with :math:`F_k(\Lambda) = P_k(\Lambda)/\Lambda` (a Laplace transform),
  :math:`P_k \to \Lambda_k\,[F_k(\Lambda_k) - F_k(\Lambda_k + \lambda_x)]`.

So, with :math:`z = \log(\lambda_x e^{m}) - \log\Lambda_\ell` and
:math:`\chi_\ell(z) = \log P_\ell(\Lambda_\ell(1 + e^z)) - \log P_\ell(\Lambda_\ell)`,

.. math::
    \log L_k - \log L = \sum_{\ell < k} \chi_\ell(a_x + m_{\ell k} - \log\Lambda_\ell)
      + [k < K]\,\psi_k(a_x - \log\Lambda_k), \qquad \psi(z) = \log\big(1 - e^{\chi(z) - \log(1 + e^z)}\big).

This is exact. The one approximation is numerical: per draw and group, :math:`\chi_\ell` and :math:`\psi_\ell` are
tabulated on a grid of :math:`z` (step :data:`Z_STEP`, over the range the candidates need within
[:data:`Z_LOW`, :data:`Z_HIGH`]) with the compiled :func:`pbicrl.inference.likelihood_kernels.group_term` and read by cubic
interpolation; outside the grid the exact asymptotes are used (:math:`\chi \propto e^z` and
:math:`\psi = z + \text{const}` as :math:`z \to -\infty`; linear :math:`\chi`, :math:`\psi \to 0` as
:math:`z \to \infty`). The cost per draw is O(grid x N) for the tables and O(M K^2) for M candidates, instead of
O(M K N) integrals. Parametric constraints (over states) are not supported.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from typing import Any, Literal, Sequence

import numpy as np
from numba import njit
from numpy.typing import ArrayLike, NDArray

from pbicrl.inference.likelihood_kernels import group_term
from pbicrl.inference.data import Dataset, DatasetError

__all__ = ["Suggestion", "Suggestions", "already_labelled", "group_probabilities", "information_gain", "suggest",
           "suggest_run",
           "TARGETS", "Z_LOW", "Z_HIGH", "Z_STEP"]

TARGETS = ("indicators", "selected")
Z_LOW = -12.0
"""Lower end of the tabulation grid of :math:`z` (below it the asymptote :math:`\\psi = z + \\text{const}`)."""
Z_HIGH = 30.0
"""Upper end of the tabulation grid of :math:`z` (above it :math:`\\chi` is extended linearly)."""
Z_STEP = 0.25
"""Grid step of the tabulated :math:`\\chi_\\ell, \\psi_\\ell` (cubic interpolation: error O(step^4))."""


# ---------------------------------------------------------------------------------------------- compiled core
@njit(cache=True, error_model="numpy")
def _softplus(z: float) -> float:
    return max(z, 0.0) + math.log1p(math.exp(-abs(z)))


@njit(cache=True, error_model="numpy")
def _cubic(t: np.ndarray, z0: float, h: float, z: float) -> float:
    """Cubic (4-point Lagrange) interpolation of table ``t`` on the grid ``z0 + h j`` at ``z`` inside it."""
    G = t.size
    u = (z - z0) / h
    j = int(math.floor(u))
    if j < 0:
        j = 0
    if j > G - 2:
        j = G - 2
    f = u - j
    if G < 4:
        return t[j] + f * (t[j + 1] - t[j])
    i0 = min(max(j - 1, 0), G - 4)  # four nodes around z, shifted inwards at the edges
    x = u - i0
    p0, p1, p2, p3 = t[i0], t[i0 + 1], t[i0 + 2], t[i0 + 3]
    return (-p0 * (x - 1.0) * (x - 2.0) * (x - 3.0) / 6.0 + p1 * x * (x - 2.0) * (x - 3.0) / 2.0
            - p2 * x * (x - 1.0) * (x - 3.0) / 2.0 + p3 * x * (x - 1.0) * (x - 2.0) / 6.0)


@njit(cache=True, error_model="numpy")
def _chi_at(chi: np.ndarray, z0: float, h: float, z: float) -> float:
    G = chi.size
    zmax = z0 + h * (G - 1)
    if z < z0:  # chi(z) ~ C e^z as z -> -inf
        return chi[0] * math.exp(z - z0)
    if z > zmax:  # asymptotically linear (slope -n)
        slope = (chi[G - 1] - chi[G - 2]) / h if G > 1 else 0.0
        return chi[G - 1] + slope * (z - zmax)
    return _cubic(chi, z0, h, z)


@njit(cache=True, error_model="numpy")
def _psi_at(psi: np.ndarray, z0: float, h: float, z: float) -> float:
    G = psi.size
    zmax = z0 + h * (G - 1)
    if z < z0:  # psi(z) = z + const + O(e^z)
        return psi[0] + (z - z0)
    if z > zmax:  # the candidate beats the lower groups for sure: psi -> 0
        return min(psi[G - 1], 0.0)
    return min(_cubic(psi, z0, h, z), 0.0)


@njit(cache=True, error_model="numpy")
def _margin(gmat: np.ndarray, goffs: np.ndarray, l: int, r: int) -> float:
    """:math:`m_{lr}`: from the K x K matrix when one is given (shape (K, K)), else additive, ``o_r - o_l``
    (the same floating-point value :attr:`Margins.matrix` would hold)."""
    if gmat.shape[0] == 0:
        return goffs[r] - goffs[l]
    return gmat[l, r]


@njit(cache=True, error_model="numpy")
def _slot_logits(a: np.ndarray, gitems: np.ndarray, goff: np.ndarray, gmat: np.ndarray, goffs: np.ndarray,
                 a_cand: np.ndarray, z_low: float, z_high: float, h: float, out: np.ndarray) -> None:
    """``out[m, k] = log L_k - log L`` for candidate ``m`` (scaled return ``a_cand[m]``) in group ``k``; margins
    as in :func:`_margin`."""
    K = goff.size - 1
    M = a_cand.size
    nmax = 1
    for k in range(K):
        nmax = max(nmax, goff[k + 1] - goff[k])
    buf = np.empty((2, nmax))
    x = np.empty(nmax)
    y = np.empty(nmax)
    lse = np.empty(K)
    for k in range(K):
        m = -np.inf
        for i in range(goff[k], goff[k + 1]):
            m = max(m, a[gitems[i]])
        acc = 0.0
        for i in range(goff[k], goff[k + 1]):
            acc += math.exp(a[gitems[i]] - m)
        lse[k] = m + math.log(acc)
    amin = np.inf
    amax = -np.inf
    for i in range(M):
        amin = min(amin, a_cand[i])
        amax = max(amax, a_cand[i])
    # per group l < K - 1: log Lambda_l, then chi_l and psi_l on the part of the grid the candidates need
    loglam = np.zeros(K)
    z0s = np.zeros(K)
    sizes = np.zeros(K, np.int64)
    G_max = int(math.ceil((z_high - z_low) / h)) + 1
    chi = np.zeros((K, G_max))
    psi = np.zeros((K, G_max))
    for l in range(K - 1):
        m = -np.inf
        for r in range(l + 1, K):
            m = max(m, lse[r] + _margin(gmat, goffs, l, r))
        acc = 0.0
        for r in range(l + 1, K):
            acc += math.exp(lse[r] + _margin(gmat, goffs, l, r) - m)
        loglam[l] = m + math.log(acc)
        mlo = 0.0
        mhi = 0.0
        for r in range(l + 1, K):
            mlo = min(mlo, _margin(gmat, goffs, l, r))
            mhi = max(mhi, _margin(gmat, goffs, l, r))
        lo = max(z_low, amin + mlo - loglam[l] - 2.0 * h)
        hi = min(z_high, amax + mhi - loglam[l] + 2.0 * h)
        j0 = int(math.floor((lo - z_low) / h))
        j1 = int(math.ceil((hi - z_low) / h))
        if j1 - j0 < 3:  # at least four nodes for the cubic rule
            j1 = min(j0 + 3, G_max - 1)
            j0 = max(j1 - 3, 0)
        z0s[l] = z_low + h * j0
        G = j1 - j0 + 1
        sizes[l] = G
        n = goff[l + 1] - goff[l]
        for i in range(n):
            x[i] = a[gitems[goff[l] + i]] - loglam[l]
        base = group_term(x[:n], buf)
        for j in range(G):
            z = z0s[l] + h * j
            sp = _softplus(z)
            for i in range(n):
                y[i] = x[i] - sp
            v = group_term(y[:n], buf) - base
            v = min(v, 0.0)  # P_l decreases as Lambda_l grows; rounding may give +1e-16
            chi[l, j] = v
            psi[l, j] = math.log(-math.expm1(v - sp))
    for c in range(M):
        ax = a_cand[c]
        for k in range(K):
            tot = 0.0
            for l in range(k):
                tot += _chi_at(chi[l, :sizes[l]], z0s[l], h, ax + _margin(gmat, goffs, l, k) - loglam[l])
            if k < K - 1:
                tot += _psi_at(psi[k, :sizes[k]], z0s[k], h, ax - loglam[k])
            out[c, k] = tot


# ---------------------------------------------------------------------------------------------- probabilities
def _group_arrays(labelled: Dataset) -> tuple[NDArray[np.int64], NDArray[np.int64], tuple[int, ...]]:
    labels = tuple(int(k) for k in labelled.group_labels)
    items = [np.flatnonzero(labelled.group == k) for k in labels]
    offsets = np.concatenate([[0], np.cumsum([len(i) for i in items])]).astype(np.int64)
    return np.concatenate(items).astype(np.int64), offsets, labels


def _margin_arrays(margins: Any, K: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``(matrix, offsets)`` for :func:`_slot_logits`: additive margins (zeros, gaps) as their K offsets with an
    empty matrix (O(K), nothing K x K); a general matrix as given."""
    from pbicrl.inference.preferences import Margins

    m = Margins.parse(margins, K)
    if m.offsets is not None:
        return np.zeros((0, 0)), np.ascontiguousarray(m.offsets, dtype=np.float64)
    return np.ascontiguousarray(m.matrix, dtype=np.float64), np.zeros(0)


def group_probabilities(
    weights: ArrayLike,
    labelled: Dataset,
    candidates: ArrayLike,
    *,
    margins: Any = None,
    beta: float = 1.0,
) -> NDArray[np.float64]:
    r"""Model-implied probability that each candidate belongs to each group, per draw (module docstring).

    Parameters
    ----------
    weights : array-like, (S, d)
        Total reward weights :math:`w^{(s)} = w_n + c^{(s)} \circ w_p^{(s)}` of each draw.
    labelled : Dataset
        The ranked demonstrations (at least two non-empty groups; unlabelled ones are ignored).
    candidates : array-like, (M, d)
        Mean feature vectors :math:`\bar\phi_x` of the candidates.
    margins : Margins, K-1 gaps or K x K matrix, optional
        :math:`m_{k\ell}` (default 0).
    beta : float
        Inverse temperature :math:`\beta`.

    Returns
    -------
    ndarray, (S, M, K)
        :math:`p_s(k)` for the non-empty groups of ``labelled``, best first; rows sum to 1.
    """
    W = np.atleast_2d(np.asarray(weights, dtype=np.float64))
    Xc = np.atleast_2d(np.asarray(candidates, dtype=np.float64))
    data = labelled.labelled() if labelled.n_unlabelled else labelled
    d = data.n_features
    if W.shape[1] != d:
        raise ValueError(f"weights: expected {d} columns (one per feature), got shape {W.shape}")
    if Xc.shape[1] != d:
        raise ValueError(f"candidates: expected {d} columns (one per feature), got shape {Xc.shape}")
    if not (np.all(np.isfinite(W)) and np.all(np.isfinite(Xc))):
        raise ValueError("weights/candidates: contain NaN or inf")
    if not (math.isfinite(beta) and beta > 0):
        raise ValueError(f"beta: expected a positive number, got {beta}")
    gitems, goff, labels = _group_arrays(data)
    K = len(labels)
    gmat, goffs = _margin_arrays(margins, K)
    F = data.mean_features
    out = np.empty((W.shape[0], Xc.shape[0], K))
    scratch = np.empty((Xc.shape[0], K))
    for s in range(W.shape[0]):
        a = np.ascontiguousarray(beta * (F @ W[s]))
        ac = np.ascontiguousarray(beta * (Xc @ W[s]))
        _slot_logits(a, gitems, goff, gmat, goffs, ac, Z_LOW, Z_HIGH, Z_STEP, scratch)
        z = scratch - scratch.max(axis=1, keepdims=True)
        p = np.exp(z)
        out[s] = p / p.sum(axis=1, keepdims=True)
    return out


def _entropy(p: NDArray[np.float64]) -> NDArray[np.float64]:
    """Entropy in nats along the last axis (0 log 0 = 0)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(p > 0, p * np.log(np.where(p > 0, p, 1.0)), 0.0)
    return -t.sum(axis=-1)


def information_gain(probabilities: ArrayLike, indicators: ArrayLike, *,
                     target: Literal["indicators", "selected"] = "indicators") -> NDArray[np.float64]:
    r"""Mutual information (nats) between each candidate's group and the indicators, from draws.

    Parameters
    ----------
    probabilities : array-like, (S, M, K)
        :math:`p_s(k)` per draw and candidate (:func:`group_probabilities`).
    indicators : array-like, (S, d)
        :math:`c^{(s)}` of the same draws.
    target : {"indicators", "selected"}
        ``indicators``: :math:`I(Y; c)` about the whole indicator vector. ``selected``:
        :math:`\sum_j I(Y; c_j)`, about each marginal (which decides the selected set).

    Returns
    -------
    ndarray, (M,)
        Non-negative (up to rounding, clipped at 0).
    """
    P = np.asarray(probabilities, dtype=np.float64)
    if P.ndim != 3:
        raise ValueError(f"probabilities: expected shape (draws, candidates, groups), got {P.shape}")
    C = np.asarray(indicators)
    if C.ndim != 2 or C.shape[0] != P.shape[0]:
        raise ValueError(f"indicators: expected one row per draw, shape ({P.shape[0]}, d), got {C.shape}")
    if target not in TARGETS:
        raise ValueError(f"target: expected one of {', '.join(TARGETS)}, got {target!r}")
    S = P.shape[0]
    h_marg = _entropy(P.mean(axis=0))

    def conditional(codes: NDArray[np.int64]) -> NDArray[np.float64]:
        h = np.zeros(P.shape[1])
        for z in np.unique(codes):
            sel = codes == z
            h += sel.sum() / S * _entropy(P[sel].mean(axis=0))
        return h

    if target == "indicators":
        _, codes = np.unique(C.astype(np.int8), axis=0, return_inverse=True)
        gain = h_marg - conditional(codes.reshape(-1))
    else:
        gain = np.zeros(P.shape[1])
        for j in range(C.shape[1]):
            gain += h_marg - conditional(C[:, j].astype(np.int64))
    return np.maximum(gain, 0.0)


# ---------------------------------------------------------------------------------------------- ranking
@dataclass(frozen=True)
class Suggestion:
    """One ranked candidate.

    Attributes
    ----------
    index : int
        Trajectory index in the pool.
    information_gain : float
        Nats (see :func:`information_gain`).
    group_probabilities : tuple of float
        Posterior predictive probability of each group (best first), averaged over the draws.
    """

    index: int
    information_gain: float
    group_probabilities: tuple[float, ...]


@dataclass(frozen=True)
class Suggestions:
    """Result of :func:`suggest`: the ``n`` most informative candidates, best first.

    Attributes
    ----------
    ranking : tuple of Suggestion
    target : str
    groups : tuple of str
        Names of the labelled groups, best first.
    n_candidates : int
        Candidates scored.
    n_draws : int
        Posterior draws used.
    already_labelled : tuple of int
        Pool indices left out because the same demonstration (same features, state by state) is already in the
        labelled data: ranking it again would tell nothing new.
    """

    ranking: tuple[Suggestion, ...]
    target: str
    groups: tuple[str, ...]
    n_candidates: int
    n_draws: int
    already_labelled: tuple[int, ...] = ()

    @property
    def indices(self) -> list[int]:
        """Pool indices of the suggestions, most informative first."""
        return [s.index for s in self.ranking]

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: ``target``, ``groups``, ``n_candidates``, ``n_draws``, ``unit``, ``already_labelled`` and
        ``suggestions``."""
        return {"target": self.target, "groups": list(self.groups), "n_candidates": self.n_candidates,
                "n_draws": self.n_draws, "unit": "nats", "already_labelled": list(self.already_labelled),
                "suggestions": [{"index": s.index, "information_gain": s.information_gain,
                                 "group_probabilities": dict(zip(self.groups, s.group_probabilities))}
                                for s in self.ranking]}

    def table(self) -> str:
        """Plain-text table, one row per suggestion."""
        head = f"{'rank':>4}  {'index':>6}  {'gain (nats)':>11}  " + "  ".join(f"{g[:10]:>10}" for g in self.groups)
        rows = [head, "-" * len(head)]
        for r, s in enumerate(self.ranking, 1):
            rows.append(f"{r:>4}  {s.index:>6}  {s.information_gain:>11.4f}  "
                        + "  ".join(f"{p:>10.3f}" for p in s.group_probabilities))
        rows.append(f"{self.n_candidates} candidates scored with {self.n_draws} posterior draws "
                    f"(target: {self.target}); columns: predicted P(group)")
        if self.already_labelled:
            shown = ", ".join(str(i) for i in self.already_labelled[:10]) + (", ..." if len(self.already_labelled) > 10
                                                                               else "")
            rows.append(f"left out {len(self.already_labelled)} pool trajectories already in the labelled data "
                        f"(by content): {shown}")
        return "\n".join(rows)


def _trajectory_keys(ds: Dataset, which: NDArray[np.int64]) -> list[bytes]:
    """A key per trajectory from its per-state features (length and values), to find the same demonstration in two
    datasets whatever its index."""
    import hashlib

    out = []
    for i in which.tolist():
        f = np.ascontiguousarray(ds.features[ds.offsets[i]:ds.offsets[i + 1]], dtype=np.float64)
        out.append(hashlib.sha1(f.tobytes() + f.shape[0].to_bytes(8, "little")).digest())
    return out


def already_labelled(pool: Dataset, candidates: ArrayLike, labelled: Dataset) -> NDArray[np.bool_]:
    """For each pool index in ``candidates``: whether the same demonstration (identical per-state features) is a
    labelled trajectory (group >= 1) of ``labelled``."""
    idx = np.asarray(candidates, dtype=np.int64).reshape(-1)
    lab = np.flatnonzero(np.asarray(labelled.group) >= 1)
    known = set(_trajectory_keys(labelled, lab))
    return np.array([k in known for k in _trajectory_keys(pool, idx)], dtype=bool)


def _pick_draws(n_total: int, max_draws: int) -> NDArray[np.int64]:
    """Evenly spaced draw indices (deterministic: no random choice of draws)."""
    if n_total <= max_draws:
        return np.arange(n_total)
    return np.unique(np.linspace(0, n_total - 1, max_draws).round().astype(np.int64))


def suggest(
    posterior: Any,
    labelled: Dataset,
    pool: Dataset,
    n: int = 5,
    *,
    candidates: Sequence[int] | None = None,
    target: Literal["indicators", "selected"] = "indicators",
    max_draws: int = 200,
    margins: Any = None,
    beta: float | None = None,
    nominal_weights: ArrayLike | None = None,
) -> Suggestions:
    """Rank pool trajectories by the information their group would give about the constraints.

    Parameters
    ----------
    posterior : Posterior or RunRecord
        Draws of a run on ``labelled`` (``pbicrl.infer`` or :func:`pbicrl.io.runs.read_run`).
    labelled : Dataset
        The grouped data the posterior was inferred from (unlabelled trajectories in it are ignored).
    pool : Dataset
        Where the candidates come from (same features).
    n : int
        How many to return.
    candidates : sequence of int, optional
        Pool indices to score; default: the pool's unlabelled (group 0), not skipped trajectories. Either way a
        candidate that is already a labelled trajectory of ``labelled`` (matched by content, not index) is left
        out and listed in :attr:`Suggestions.already_labelled`.
    target : {"indicators", "selected"}
        See :func:`information_gain`.
    max_draws : int
        Posterior draws used (evenly spaced over all chains).
    margins, beta, nominal_weights : optional
        Default: the run's (``extra.margins``, ``settings.beta``, ``settings.nominal_weights``), else the
        dataset's nominal weights, zero margins and :math:`\\beta = 1`.

    Returns
    -------
    Suggestions
        Ties in the gain go to the lower pool index.
    """
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise ValueError(f"n: expected a positive integer, got {n!r}")
    if isinstance(max_draws, bool) or not isinstance(max_draws, (int, np.integer)) or max_draws < 1:
        raise ValueError(f"max_draws: expected a positive integer, got {max_draws!r}")
    if tuple(getattr(posterior, "parameter_names", ()) or ()):
        raise ValueError("suggest: runs with parametric constraints (over states) are not supported; the "
                         "candidates' features would depend on each draw's parameters")
    data = labelled.labelled() if labelled.n_unlabelled else labelled
    names = tuple(posterior.feature_names)
    if names != tuple(data.feature_names):
        raise DatasetError(f"feature_names: the run has features {list(names)}, the labelled data "
                           f"{list(data.feature_names)}; pass the dataset the run was made with")
    if tuple(pool.feature_names) != tuple(data.feature_names):
        raise DatasetError(f"feature_names: the pool has features {list(pool.feature_names)}, the labelled data "
                           f"{list(data.feature_names)}")
    if candidates is None:
        idx = np.flatnonzero((pool.group == 0) & ~pool.skipped)
        if idx.size == 0:
            raise DatasetError("group: the pool has no unlabelled trajectories (group 0, not skipped) to suggest")
    else:
        idx = np.asarray(candidates, dtype=np.int64).reshape(-1)
        if idx.size == 0:
            raise ValueError("candidates: empty")
        if idx.min() < 0 or idx.max() >= pool.n_trajectories:
            raise ValueError(f"candidates: indices must lie in [0, {pool.n_trajectories})")
    # the pool may hold demonstrations the run was inferred from (a pool drawn from the same data): never suggest them
    known = already_labelled(pool, idx, labelled)
    left_out = tuple(int(i) for i in idx[known])
    idx = idx[~known]
    if idx.size == 0:
        raise DatasetError(f"group: all {len(left_out)} candidate pool trajectories are already labelled in the run's "
                           "data (the same features, state by state); there is nothing new to suggest")
    settings = dict(getattr(posterior, "settings", None) or {})
    if beta is None:
        beta = float(settings.get("beta", 1.0) or 1.0)
    d = data.n_features
    if nominal_weights is None:
        nominal_weights = settings.get("nominal_weights")
    if nominal_weights is None:
        nominal_weights = data.nominal_weights if data.nominal_weights is not None else np.zeros(d)
    wn = np.asarray(nominal_weights, dtype=np.float64).reshape(-1)
    if wn.shape != (d,):
        raise ValueError(f"nominal_weights: expected {d} values, got {wn.size}")
    K = data.n_groups
    if margins is None:  # the run's, as K offsets when additive (nothing K x K)
        from pbicrl.analysis.export import run_margins

        margins = run_margins(getattr(posterior, "extra", None) or {}, K, what="margins")
    C = np.asarray(posterior.indicators).reshape(-1, d)
    Wp = np.asarray(posterior.penalty_weights, dtype=np.float64).reshape(-1, d)
    if C.shape[0] == 0:
        raise ValueError("posterior: no draws")
    pick = _pick_draws(C.shape[0], int(max_draws))
    C, Wp = C[pick], Wp[pick]
    W = wn[None, :] + C * np.nan_to_num(Wp)
    P = group_probabilities(W, data, pool.mean_features[idx], margins=margins, beta=beta)
    gain = information_gain(P, C, target=target)
    order = np.lexsort((idx, -gain))[: int(n)]
    pbar = P.mean(axis=0)
    ranking = tuple(Suggestion(int(idx[o]), float(gain[o]), tuple(float(p) for p in pbar[o])) for o in order)
    groups = tuple(data.group_name(k) for k in data.group_labels.tolist())
    return Suggestions(ranking, str(target), groups, int(idx.size), int(pick.size), left_out)


def suggest_run(
    run_dir: str | os.PathLike[str],
    pool: str | os.PathLike[str] | Dataset,
    n: int = 5,
    *,
    data: str | os.PathLike[str] | Dataset | None = None,
    allow_unconverged: bool = False,
    **kwargs: Any,
) -> Suggestions:
    """:func:`suggest` for a run directory (``pbicrl infer --out``) and a pool file.

    Parameters
    ----------
    run_dir : path
    pool : path or Dataset
        Loaded with ``allow_unlabelled=True``.
    n : int
    data : path or Dataset, optional
        The labelled data of the run; default: the file the run records (``extra.data.path``).
    allow_unconverged : bool
        Rank from a run until converged that did not converge (refused by default: its draws are not yet the
        posterior, so neither is the information a label would bring).
    **kwargs
        Passed to :func:`suggest`.
    """
    from pbicrl.inference.data import load_dataset
    from pbicrl.io.runs import read_run

    run = read_run(run_dir)
    conv = (run.summary.get("extra") or {}).get("convergence") if isinstance(run.summary, dict) else None
    if isinstance(conv, dict) and conv.get("converged") is False and not allow_unconverged:
        failing = conv.get("failing") or {}
        raise ValueError(f"run: {run_dir} did NOT CONVERGE ({len(failing)} reported quantities fall short, e.g. "
                         f"{next(iter(failing.items()), ('', ''))[0]}: {next(iter(failing.values()), '')}); suggestions "
                         "from it would rank by draws that are not yet the posterior. Rerun the inference with a larger "
                         "--max-time, or pass --allow-unconverged")
    if data is None:
        data = run.data_path
        if data is None:
            raise FileNotFoundError(f"data: the run {run_dir} does not record its dataset; pass --data")
        if not data.is_file():
            raise FileNotFoundError(f"data: the run's dataset {data} is gone; pass --data with the labelled data")
    labelled = data if isinstance(data, Dataset) else load_dataset(data, allow_unlabelled=True)
    pool_ds = pool if isinstance(pool, Dataset) else load_dataset(pool, allow_unlabelled=True)
    return suggest(run, labelled, pool_ds, n, **kwargs)
