"""Likelihoods of ranked preferences: the margin-respecting Bradley-Terry model (paper Eq. 7) and an exact
grouped Plackett-Luce model.

For reward :math:`r_\\theta(s) = (w_n + c \\circ w_p)^\\top \\phi(s)` the scaled length-normalised return of
trajectory :math:`\\tau_i` is :math:`a_i = \\frac{\\beta}{T_i}\\sum_{s\\in\\tau_i} r_\\theta(s) = \\beta\\,\\bar\\phi_i^\\top w`
with :math:`\\bar\\phi_i` the mean feature vector.

``kind="pairwise"`` (default, the paper's Eq. 7) sums every cross-group pair as independent evidence:

.. math::
    \\mathcal{L}(w_p, c) = \\sum_{\\tau_i \\in \\mathcal{G}_k,\\ \\tau_j \\in \\mathcal{G}_\\ell,\\ k<\\ell}
        \\log \\frac{e^{a_i - m_{k\\ell}}}{e^{a_i - m_{k\\ell}} + e^{a_j}}.

``kind="grouped"`` is the exact probability of the grouped ranking under a Plackett-Luce model with weights
:math:`\\lambda_i = e^{a_i}`: :math:`\\mathcal{L} = \\sum_{k=1}^{K-1} \\log P_k`, with :math:`P_k` the probability
that every trajectory of :math:`\\mathcal{G}_k` ranks above every trajectory of the lower groups
:math:`\\mathcal{R}_k = \\bigcup_{\\ell > k} \\mathcal{G}_\\ell`,

.. math::
    P_k = \\int_0^\\infty e^{-t} \\prod_{i \\in \\mathcal{G}_k} \\left(1 - e^{-t \\lambda_i / \\Lambda_k}\\right) dt,
    \\qquad \\Lambda_k = \\sum_{\\ell > k} \\sum_{j \\in \\mathcal{G}_\\ell} \\lambda_j\\, e^{m_{k\\ell}}.

Margins, in the same scaled units as Eq. 7, weight the lower side: in term :math:`k` every trajectory of group
:math:`\\ell` counts as if its return were :math:`a_j + m_{k\\ell}`, so a positive margin asks group :math:`k` to
beat group :math:`\\ell` by about :math:`m_{k\\ell}` nats; with two groups of one trajectory each the
term is exactly Eq. 7's :math:`\\log\\sigma(a_i - m_{12} - a_j)` (with more groups, a single trajectory of group
:math:`k` is compared with all lower ones at once, :math:`\\log\\sigma(a_i - \\log\\Lambda_k)`, not pair by pair). It is the probability of the observed ranking itself, so each
trajectory's evidence counts once, where the pairwise sum counts it in each of its :math:`(K-1)n` pairs as if
independent; no tempering is needed (``power`` does not apply). Cost: O(N) per evaluation (a one-dimensional
integral per group, :func:`pbicrl.inference.likelihood_kernels.grouped_loglik`) instead of O(pairs); groups of thousands of
trajectories are binned (moments per bin, no transcendental function per trajectory and node), and many groups
with additive margins cost O(K), not O(K^2).

Returns are linear in the weights, so :class:`PreferenceLikelihood` precomputes :math:`\\beta\\bar\\Phi` once; the
compiled kernels (:mod:`pbicrl.inference.likelihood_kernels`) evaluate either likelihood exactly and fast.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from pbicrl.inference import likelihood_kernels as _kernels
from pbicrl.inference.codes import LIKELIHOODS as LIKELIHOOD_CODES
from pbicrl.inference.data import Dataset
from pbicrl.inference.preferences import RANKED_MIN_GROUPS, Margins, PreferenceError, Preferences

__all__ = ["PreferenceLikelihood", "log_likelihood", "log_likelihood_numpy", "scaled_returns", "pairwise_power",
           "LIKELIHOODS", "BETA_RANGE", "check_beta"]

LIKELIHOODS = ("pairwise", "grouped")

BETA_RANGE = (1e-6, 1e6)
"""Inverse temperatures accepted. The likelihood and the identification bounds scale returns by beta (and the
admissible penalties by 1/beta): within this range they stay finite for any finite features and prior; at
1e308 the returns overflow and every draw is NaN."""


def check_beta(beta: float, field: str = "beta") -> float:
    """``beta`` as a float, or a ValueError naming ``field`` and :data:`BETA_RANGE`."""
    try:
        b = float(beta)
    except (TypeError, ValueError):
        raise ValueError(f"{field}: the inverse temperature must be a number, got {beta!r}") from None
    if not (BETA_RANGE[0] <= b <= BETA_RANGE[1]):  # NaN fails too
        raise ValueError(f"{field}: the inverse temperature must lie in [{BETA_RANGE[0]:g}, {BETA_RANGE[1]:g}] to "
                         f"keep the likelihood finite, got {beta!r}")
    return b


def scaled_returns(mean_features: NDArray[np.float64], weights: ArrayLike, beta: float = 1.0) -> NDArray[np.float64]:
    """:math:`a = \\beta \\bar\\Phi w`, shape (N,)."""
    return beta * (np.asarray(mean_features, dtype=np.float64) @ np.asarray(weights, dtype=np.float64))


@dataclass(frozen=True, eq=False)
class PreferenceLikelihood:
    """Likelihood of ranked preferences for known features.

    Parameters
    ----------
    mean_features : ndarray, shape (N, d)
        Length-normalised feature sums :math:`\\bar\\phi_i`.
    preferences : Preferences
        Pairs and margins (``kind="grouped"``: built from ranked groups, every pair, see
        :meth:`Preferences.from_groups`).
    nominal_weights : ndarray, shape (d,)
        Known :math:`w_n`.
    beta : float
        Inverse temperature :math:`\\beta > 0`.
    power : float
        Likelihood power :math:`\\gamma \\in (0, 1]`: the log-likelihood is multiplied by it (1 = the paper).
        The all-pairs likelihood counts each of the :math:`(K-1)n` pairs a trajectory enters as independent
        evidence, which makes its posterior overconfident (see ``benchmarks/reports``); a power below 1
        tempers it. :func:`pairwise_power` gives the ratio of trajectories to pairs as a starting point.
        ``kind="pairwise"`` only.
    kind : {"pairwise", "grouped"}
        ``"pairwise"``: paper Eq. 7 over the preferences' pairs. ``"grouped"``: the exact grouped Plackett-Luce
        probability of the ranking (module docstring), O(N) per evaluation instead of O(pairs).
    """

    mean_features: NDArray[np.float64]
    preferences: Preferences
    nominal_weights: NDArray[np.float64]
    beta: float = 1.0
    power: float = 1.0
    kind: Literal["pairwise", "grouped"] = "pairwise"

    def __post_init__(self) -> None:
        F = np.ascontiguousarray(self.mean_features, dtype=np.float64)
        if F.ndim != 2:
            raise ValueError(f"mean_features: expected shape (N, d), got {F.shape}")
        wn = np.asarray(self.nominal_weights, dtype=np.float64).reshape(-1)
        if wn.shape != (F.shape[1],):
            raise ValueError(f"nominal_weights: expected {F.shape[1]} values (one per feature), got {wn.size}")
        if not np.all(np.isfinite(wn)):
            raise ValueError("nominal_weights: contains NaN or inf")
        beta = check_beta(self.beta)
        power = float(self.power)
        if not (np.isfinite(power) and 0.0 < power <= 1.0):
            raise ValueError(f"power: the likelihood power must lie in (0, 1], got {self.power}")
        object.__setattr__(self, "power", power)
        if self.preferences.n_trajectories != F.shape[0]:
            raise ValueError(f"preferences: built for {self.preferences.n_trajectories} trajectories, data have {F.shape[0]}")
        if self.kind not in LIKELIHOODS:
            raise ValueError(f"likelihood: unknown kind {self.kind!r}; choose one of {', '.join(LIKELIHOODS)}")
        if self.kind == "grouped":
            p = self.preferences
            if power != 1.0:
                raise ValueError(f"power: a likelihood power applies to likelihood='pairwise' only (got {power}); "
                                 "the grouped likelihood counts each trajectory once and needs no tempering")
            if p.n_groups < 2:
                raise PreferenceError("likelihood='grouped' needs preferences built from ranked groups "
                                      "(Preferences.from_groups), not explicit pairs")
            if p.protocol != "all":
                raise PreferenceError(f"pairs: sampled pairs ({p.protocol}) apply to likelihood='pairwise' only; "
                                      "the grouped likelihood uses the whole ranking")
        object.__setattr__(self, "mean_features", F)
        object.__setattr__(self, "nominal_weights", wn)
        object.__setattr__(self, "beta", beta)

    @classmethod
    def from_dataset(
        cls,
        dataset: Dataset,
        *,
        margins: Margins | ArrayLike | None = None,
        protocol: str | int = "all",
        seed: int | np.random.Generator | None = 0,
        nominal_weights: ArrayLike | None = None,
        beta: float = 1.0,
        preferences: Preferences | None = None,
        power: float | str = 1.0,
        likelihood: Literal["pairwise", "grouped"] = "pairwise",
        distinct_pairs: bool = False,
    ) -> "PreferenceLikelihood":
        """Likelihood of a grouped dataset; nominal weights default to the dataset's (else zeros).

        ``likelihood="grouped"`` uses the whole ranking: ``protocol`` (sampled pairs) and ``power`` apply to
        ``"pairwise"`` only and are errors otherwise. ``distinct_pairs``: sampled pairs without replacement
        (:meth:`Preferences.from_groups`, the authors' code).
        """
        if likelihood not in LIKELIHOODS:
            raise ValueError(f"likelihood: unknown kind {likelihood!r}; choose one of {', '.join(LIKELIHOODS)}")
        if likelihood == "grouped":
            if not (isinstance(protocol, str) and protocol == "all"):
                raise PreferenceError(f"pairs: sampling {protocol!r} pairs per group pair applies to "
                                      "likelihood='pairwise' only; the grouped likelihood uses the whole ranking")
            if isinstance(power, str) or float(power) != 1.0:
                raise ValueError(f"power: a likelihood power ({power!r}) applies to likelihood='pairwise' only; "
                                 "the grouped likelihood counts each trajectory once and needs no tempering")
        if preferences is None:
            preferences = Preferences.from_groups(dataset.group, margins, protocol=protocol, seed=seed,
                                                  distinct=distinct_pairs)
        if nominal_weights is None:
            nominal_weights = dataset.nominal_weights if dataset.nominal_weights is not None else np.zeros(dataset.n_features)
        if power == "pairs":
            power = pairwise_power(preferences)
        elif isinstance(power, str):
            raise ValueError(f"power: expected a number in (0, 1] or 'pairs', got {power!r}")
        return cls(dataset.mean_features, preferences, np.asarray(nominal_weights, dtype=np.float64), beta, float(power),
                   likelihood)

    @property
    def n_features(self) -> int:
        return int(self.mean_features.shape[1])

    @cached_property
    def scaled_features_T(self) -> NDArray[np.float64]:
        """:math:`(\\beta \\bar\\Phi)^\\top`, shape (d, N), contiguous per feature (for O(N) coordinate updates)."""
        return np.ascontiguousarray((self.beta * self.mean_features).T)

    @cached_property
    def _scratch_size(self) -> int:
        p = self.preferences
        if p.ranked and self.kind == "pairwise":
            return max(1, p.n_trajectories)  # ranked_loglik: the returns in group order and their exponentials
        return max(1, int(np.max(np.diff(p.block_col_offsets), initial=1)))

    @cached_property
    def _group_arrays(self) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.float64], int,
                                     NDArray[np.float64]]:
        """Group members (best group first), offsets, margin matrix, the grouped kernel's scratch width, and the
        offsets of additive margins. The grouped kernel uses the matrix below ``RANKED_MIN_GROUPS`` groups or when
        the margins are not additive, else the offsets (O(K) instead of O(K^2) per evaluation)."""
        p = self.preferences
        if self.kind == "pairwise" and p.ranked:
            return p.group_items, p.group_offsets, np.zeros((0, 0)), 1, p.margin_offsets
        if self.kind != "grouped":  # placeholders with the same types: one compiled loop serves every kind
            return np.zeros(0, np.int64), np.zeros(1, np.int64), np.zeros((0, 0)), 1, np.zeros(0)
        width = max(int(np.max(np.diff(p.group_offsets))), p.n_groups)
        if p.n_groups >= RANKED_MIN_GROUPS and p.margin_offsets.size == p.n_groups:
            return p.group_items, p.group_offsets, np.zeros((0, 0)), width, p.margin_offsets  # O(K), not O(K^2)
        return p.group_items, p.group_offsets, p.group_margins, width, p.margin_offsets

    def kernel_args(self) -> tuple:
        """The fields of :class:`pbicrl.inference.likelihood_kernels.LikelihoodArrays` in order (:meth:`kernel_bundle`).

        ``(kind code, the pairwise arrays, five pairwise scratch buffers, group members, group offsets, margin
        matrix, grouped scratch, margin offsets)``. A ranked layout (``Preferences.ranked``) gets the kind code of :func:`pbicrl.inference.likelihood_kernels.ranked_loglik`.
        """
        p = self.preferences
        n = self._scratch_size
        N = self.mean_features.shape[0]
        gitems, goff, gmarg, width, moff = self._group_arrays
        code = LIKELIHOOD_CODES["ranked" if (self.kind == "pairwise" and p.ranked) else self.kind]
        return (code, p.block_rows, p.block_row_offsets, p.block_cols, p.block_col_offsets,
                p.block_margins, p.pair_i, p.pair_j, p.pair_margins, _aligned(n), _aligned(n), _aligned(n),
                _aligned(N), _aligned(N), gitems, goff, gmarg, np.empty((4, width)), moff)

    def kernel_bundle(self) -> _kernels.LikelihoodArrays:
        """:meth:`kernel_args` by name (fresh scratch buffers), for the compiled sampler."""
        return _kernels.LikelihoodArrays(*self.kernel_args())

    def weights(self, penalty_weights: ArrayLike, indicators: ArrayLike | None = None) -> NDArray[np.float64]:
        """Total weights :math:`w_n + c \\circ w_p`."""
        wp = np.asarray(penalty_weights, dtype=np.float64)
        c = np.ones_like(wp) if indicators is None else np.asarray(indicators, dtype=np.float64)
        return self.nominal_weights + c * wp

    def returns(self, penalty_weights: ArrayLike, indicators: ArrayLike | None = None) -> NDArray[np.float64]:
        """Length-normalised returns :math:`\\bar r(\\tau_i)` (without :math:`\\beta`), shape (N,)."""
        return self.mean_features @ self.weights(penalty_weights, indicators)

    def __call__(self, penalty_weights: ArrayLike, indicators: ArrayLike | None = None) -> float:
        """:math:`\\mathcal{L}(w_p, c)`; ``indicators`` default to all ones (BPL)."""
        w = self.weights(penalty_weights, indicators)
        a = np.zeros(self.mean_features.shape[0])
        for j in range(w.size):  # fixed summation order (no BLAS), see samplers.kernels._returns
            a += w[j] * self.scaled_features_T[j]
        return self.power * float(_kernels.loglik(a, self.kernel_bundle()))

    def from_scaled_returns(self, a: ArrayLike) -> float:
        """Log-likelihood for given scaled returns :math:`a` (N,)."""
        return self.power * float(_kernels.loglik(np.ascontiguousarray(a, dtype=np.float64), self.kernel_bundle()))


def _aligned(n: int, align: int = 64) -> NDArray[np.float64]:
    """Empty float64 buffer starting on an ``align``-byte boundary.

    The compiled reductions are vectorised with re-association; LLVM peels loop iterations to reach an
    aligned address, so the summation order, and the last bit of the result, would otherwise depend on
    where the allocator put the buffer (seen as 1-ulp differences between processes).
    """
    raw = np.empty(n + align // 8, dtype=np.float64)
    start = (-raw.ctypes.data % align) // 8
    return raw[start:start + n]


def pairwise_power(preferences: Preferences) -> float:
    """Trajectories that take part in a pair divided by the number of pairs (at most 1).

    With all cross-group pairs of ``K`` groups of ``n`` this is :math:`2 / ((K-1) n)`: the log-likelihood is
    scaled as if each trajectory contributed one comparison's worth of evidence.
    """
    p = preferences
    ranked = p.group_items if p.ranked else np.zeros(0, np.int64)
    used = np.unique(np.concatenate([p.block_rows, p.block_cols, p.pair_i, p.pair_j, ranked]))
    return float(min(1.0, used.size / max(p.n_pairs, 1)))


def log_likelihood(dataset: Dataset, penalty_weights: ArrayLike, indicators: ArrayLike | None = None, *,
                   margins: Margins | ArrayLike | None = None, beta: float = 1.0,
                   nominal_weights: ArrayLike | None = None,
                   likelihood: Literal["pairwise", "grouped"] = "pairwise") -> float:
    """Convenience: :math:`\\mathcal{L}(w_p, c)` of a grouped dataset (all cross-group pairs, or grouped)."""
    lik = PreferenceLikelihood.from_dataset(dataset, margins=margins, nominal_weights=nominal_weights, beta=beta,
                                            likelihood=likelihood)
    return lik(penalty_weights, indicators)


def log_likelihood_numpy(a: NDArray[np.float64], preferences: Preferences) -> float:
    """Vectorised NumPy evaluation (a straightforward per-call broadcast over pairs; the benchmark's baseline)."""
    total = 0.0
    p = preferences
    for k in range(p.n_blocks):
        ai = a[p.block_rows[p.block_row_offsets[k]:p.block_row_offsets[k + 1]]] - p.block_margins[k]
        aj = a[p.block_cols[p.block_col_offsets[k]:p.block_col_offsets[k + 1]]]
        total -= np.logaddexp(0.0, aj[None, :] - ai[:, None]).sum()
    if p.ranked:
        for rows, cols, m in p.iter_blocks():
            total -= np.logaddexp(0.0, (a[cols] + m)[None, :] - a[rows][:, None]).sum()
    if p.pair_i.size:
        total -= np.logaddexp(0.0, a[p.pair_j] + p.pair_margins - a[p.pair_i]).sum()
    return float(total)
