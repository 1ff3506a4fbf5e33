"""Preferences between trajectories, built from ranked groups, sampled pairs or explicit comparisons.

The likelihood sums :math:`\\log P(\\tau_i \\succ \\tau_j)` over a set of ordered pairs, each with a margin
:math:`m_{k\\ell}` that is subtracted from the preferred side (paper Eq. 7).  Two storage forms:

* **blocks** - every pair :math:`(\\tau_i \\in \\mathcal{G}_k, \\tau_j \\in \\mathcal{G}_\\ell)`, :math:`k < \\ell`,
  stored as one dense rows x cols block per group pair (the paper's equation; the fast kernel exploits it);
* **pairs** - an explicit list ``(i, j, m)`` meaning :math:`\\tau_i \\succ \\tau_j` with margin ``m``
  (the authors' sampled protocol: ``n`` random pairs per group pair; or user comparisons).

Preferences built from ranked groups also keep the ranking itself (**groups**: the members of each group, best
first, the K x K margin matrix and, for additive margins, K offsets), which the grouped Plackett-Luce likelihood
(:class:`pbicrl.inference.likelihood.PreferenceLikelihood` with ``kind="grouped"``) uses instead of the pairs. With many
groups (``RANKED_MIN_GROUPS``, e.g. a total ranking) and additive margins, all cross-group pairs are stored as the
ranking alone (**ranked**: no blocks, nothing of size K x K), since K(K-1)/2 blocks would not fit.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Iterator, Literal, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["Margins", "Preferences", "PreferenceError", "RANKED_MIN_GROUPS", "MARGIN_MAX"]

MARGIN_MAX = 1e9
"""Largest margin magnitude accepted. A margin enters the log-likelihood as it is (``log sigmoid(z - m)``): up to
1e9 every term, sum and the identification LP stay finite; beyond, a margin says no more (every ranking already
has probability 0 at 1e9) and 1e308 overflows to NaN draws reported as a normal posterior."""


class PreferenceError(ValueError):
    """Invalid preference or margin specification."""


_DICT_MAX_GROUPS = 64  # Margins.as_dict lists every m_kl up to this many groups
_MATRIX_MAX_GROUPS = 2048  # Preferences.group_margins keeps the K x K matrix up to this many groups (32 MiB)
RANKED_MIN_GROUPS = 9
"""From this many groups on, :meth:`Preferences.from_groups` stores all cross-group pairs as the ranking itself
(``ranked``) instead of one dense block per group pair (K(K-1)/2 of them), when the margins are additive."""


@dataclass(frozen=True, eq=False, init=False)
class Margins:
    """Margins :math:`m_{k\\ell}` between ranked groups.

    Parameters
    ----------
    matrix : ndarray, shape (K, K)
        Upper-triangular: ``matrix[k, l]`` (``k < l``, 0-based ranks) is the margin subtracted from the
        preferred side of every pair with the better trajectory in the ``k``-th group and the worse in the
        ``l``-th. Entries on and below the diagonal are ignored (stored as 0). The grouped likelihood uses the
        same numbers in the same scaled units: in the term of group ``k`` the trajectories of group ``l`` count as
        if their returns were raised by ``matrix[k, l]`` (:mod:`pbicrl.inference.likelihood`).

    Notes
    -----
    *Additive* margins, :math:`m_{k\\ell} = o_\\ell - o_k` for per-group offsets :math:`o` (all zero, or built from
    consecutive gaps), are stored as the K offsets alone (:meth:`from_offsets`, :attr:`offsets`): O(K) memory, and
    likelihoods over many groups need no K x K structure. :attr:`matrix` is then built on demand (O(K^2)).
    """

    _matrix: NDArray[np.float64] | None
    _offsets: NDArray[np.float64] | None

    def __init__(self, matrix: ArrayLike) -> None:
        m = np.asarray(matrix, dtype=np.float64)
        if m.ndim != 2 or m.shape[0] != m.shape[1] or m.shape[0] < 2:
            raise PreferenceError(f"margins: expected a K x K matrix with K >= 2, got shape {m.shape}")
        if not np.all(np.isfinite(m)):
            raise PreferenceError("margins: contains NaN or inf")
        if np.any(np.abs(m) > MARGIN_MAX):
            raise PreferenceError(f"margins: {np.abs(m).max():g} is out of range; margins must lie within "
                                  f"+-{MARGIN_MAX:g} to keep the likelihood finite")
        lower = np.tril(m, 0)
        if np.any(lower != 0):
            raise PreferenceError("margins: only the upper triangle (k < l) may be non-zero; "
                                  "m_kl is the margin of group k over a worse group l")
        m = np.triu(m, 1)
        # additive exactly as stored: o_l = m_0l, and every m_kl equals o_l - o_k in floating point
        o = m[0].copy()
        additive = bool(np.array_equal(m, np.triu(o[None, :] - o[:, None], 1)))
        object.__setattr__(self, "_matrix", m)
        object.__setattr__(self, "_offsets", o if additive else None)

    @classmethod
    def from_offsets(cls, offsets: ArrayLike) -> "Margins":
        """Additive margins :math:`m_{k\\ell} = o_\\ell - o_k` from K per-group offsets (no K x K matrix is stored)."""
        o = np.asarray(offsets, dtype=np.float64).reshape(-1)
        if o.size < 2:
            raise PreferenceError(f"margins: need offsets for K >= 2 groups, got {o.size}")
        if not np.all(np.isfinite(o)):
            raise PreferenceError("margins: contains NaN or inf")
        if np.any(np.abs(o - o[0]) > MARGIN_MAX):
            raise PreferenceError(f"margins: {np.abs(o - o[0]).max():g} is out of range; margins must lie within "
                                  f"+-{MARGIN_MAX:g} to keep the likelihood finite")
        out = cls.__new__(cls)
        object.__setattr__(out, "_matrix", None)
        object.__setattr__(out, "_offsets", o - o[0])
        return out

    @property
    def matrix(self) -> NDArray[np.float64]:
        """The K x K upper-triangular matrix (built from the offsets for additive margins: O(K^2) memory)."""
        if self._matrix is not None:
            return self._matrix
        o = self._offsets
        return np.triu(o[None, :] - o[:, None], 1)

    @property
    def offsets(self) -> NDArray[np.float64] | None:
        """Per-group offsets :math:`o` with :math:`m_{k\\ell} = o_\\ell - o_k` and :math:`o_0 = 0` for additive
        margins, else None."""
        return self._offsets

    @property
    def n_groups(self) -> int:
        return int(self._offsets.size if self._matrix is None else self._matrix.shape[0])

    @classmethod
    def zeros(cls, n_groups: int) -> "Margins":
        """All margins zero: the plain Bradley-Terry model."""
        return cls.from_offsets(np.zeros(int(n_groups)))

    @classmethod
    def from_gaps(cls, gaps: Sequence[float]) -> "Margins":
        """Margins from consecutive gaps ``g_k`` between groups ``k`` and ``k+1``: :math:`m_{k\\ell}=\\sum_{k\\le r<\\ell} g_r`."""
        g = np.asarray(gaps, dtype=np.float64).reshape(-1)
        if g.size < 1:
            raise PreferenceError("margins: need at least one gap (K-1 gaps for K groups)")
        return cls.from_offsets(np.concatenate([[0.0], np.cumsum(g)]))

    @classmethod
    def from_dict(cls, values: dict[tuple[int, int], float], n_groups: int) -> "Margins":
        """From ``{(k, l): m_kl}`` with 1-based group ranks, ``k < l``."""
        m = np.zeros((n_groups, n_groups))
        for (k, l), v in values.items():
            if not (1 <= k < l <= n_groups):
                raise PreferenceError(f"margins: pair ({k}, {l}) must satisfy 1 <= k < l <= {n_groups}")
            m[k - 1, l - 1] = float(v)
        return cls(m)

    @classmethod
    def parse(cls, value: "Margins | ArrayLike | None", n_groups: int) -> "Margins":
        """Accept ``None`` (zeros), a ``Margins``, a K x K matrix, or K-1 consecutive gaps."""
        if value is None:
            return cls.zeros(n_groups)
        if isinstance(value, Margins):
            out = value
        else:
            try:
                arr = np.asarray(value, dtype=np.float64)
            except (TypeError, ValueError):
                raise PreferenceError("margins: must be numbers (K-1 gaps or a K x K matrix)") from None
            if arr.ndim == 0:
                arr = arr.reshape(1)
            if arr.ndim == 1:
                if arr.size != n_groups - 1:
                    raise PreferenceError(f"margins: {n_groups} groups need {n_groups - 1} consecutive gaps, got {arr.size}")
                out = cls.from_gaps(arr)
            else:
                out = cls(arr)
        if out.n_groups != n_groups:
            raise PreferenceError(f"margins: matrix is {out.n_groups} x {out.n_groups} but the data have {n_groups} groups")
        return out

    def as_dict(self) -> dict[str, float]:
        """``{"m12": ..., "m13": ...}`` with 1-based ranks.

        Beyond ``_DICT_MAX_GROUPS`` groups, additive margins list only the consecutive ones (``m1_2``, ``m2_3``, ...;
        the others are their sums) instead of all K(K-1)/2.
        """
        K = self.n_groups
        o = self._offsets
        if K > _DICT_MAX_GROUPS and o is not None:
            return {f"m{k + 1}_{k + 2}": float(o[k + 1] - o[k]) for k in range(K - 1)}
        m = self.matrix
        return {f"m{k + 1}{l + 1}" if K < 10 else f"m{k + 1}_{l + 1}": float(m[k, l])
                for k in range(K) for l in range(k + 1, K)}


@dataclass(frozen=True, eq=False)
class Preferences:
    """A set of ordered preferences with margins over ``N`` trajectories.

    Parameters
    ----------
    n_trajectories : int
        ``N``; indices refer to trajectories ``0..N-1`` of a dataset.
    block_rows, block_row_offsets : ndarray, (R,), (B+1,)
        Preferred-side trajectory indices of each dense block ``b`` are
        ``block_rows[block_row_offsets[b]:block_row_offsets[b+1]]``.
    block_cols, block_col_offsets : ndarray, (C,), (B+1,)
        Dispreferred-side indices, likewise.
    block_margins : ndarray, (B,)
        Margin of each block.
    pair_i, pair_j : ndarray, (P,)
        Explicit pairs :math:`\\tau_{i_p} \\succ \\tau_{j_p}`.
    pair_margins : ndarray, (P,)
        Margin of each explicit pair.
    protocol : str
        How the preferences were built (for reports).
    group_items, group_offsets : ndarray, (G,), (K+1,)
        The ranked groups, when built from groups: trajectories of the ``k``-th best group (0-based) are
        ``group_items[group_offsets[k]:group_offsets[k+1]]``, in ascending index order. Empty (``K = 0``) otherwise.
    group_margins : ndarray, (K, K) or (0, 0)
        :math:`m_{k\\ell}` between the groups (upper triangle), as in :class:`Margins`; empty beyond
        ``_MATRIX_MAX_GROUPS`` groups with additive margins (then ``margin_offsets`` hold them).
    margin_offsets : ndarray, (K,) or (0,)
        For additive margins, offsets :math:`o` with :math:`m_{k\\ell} = o_\\ell - o_k` (:attr:`Margins.offsets`);
        empty otherwise.
    ranked : bool
        All cross-group pairs of the groups, stored as the ranking itself: no blocks, no explicit pairs, no K x K
        structure (:meth:`from_groups` with ``RANKED_MIN_GROUPS`` or more groups and additive margins). The pairwise
        likelihood then runs over each group's rows against the contiguous rest of the ranking
        (:func:`pbicrl.inference.likelihood_kernels.ranked_loglik`); :meth:`iter_blocks` and :meth:`to_pair_list` expand it.
    """

    n_trajectories: int
    block_rows: NDArray[np.int64]
    block_row_offsets: NDArray[np.int64]
    block_cols: NDArray[np.int64]
    block_col_offsets: NDArray[np.int64]
    block_margins: NDArray[np.float64]
    pair_i: NDArray[np.int64]
    pair_j: NDArray[np.int64]
    pair_margins: NDArray[np.float64]
    protocol: str = "custom"
    group_items: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    group_offsets: NDArray[np.int64] = field(default_factory=lambda: np.zeros(1, dtype=np.int64))
    group_margins: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 0)))
    margin_offsets: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))
    ranked: bool = False

    def __post_init__(self) -> None:
        N = int(self.n_trajectories)
        for name in ("block_rows", "block_row_offsets", "block_cols", "block_col_offsets", "pair_i", "pair_j",
                     "group_items", "group_offsets"):
            object.__setattr__(self, name, np.ascontiguousarray(getattr(self, name), dtype=np.int64))
        for name in ("block_margins", "pair_margins", "group_margins", "margin_offsets"):
            object.__setattr__(self, name, np.ascontiguousarray(getattr(self, name), dtype=np.float64))
        self._check_groups(N)
        B = self.block_margins.size
        if self.block_row_offsets.size != B + 1 or self.block_col_offsets.size != B + 1:
            raise PreferenceError("preferences: block offsets must have one more entry than block margins")
        if self.pair_i.shape != self.pair_j.shape or self.pair_i.shape != self.pair_margins.shape:
            raise PreferenceError("preferences: pair_i, pair_j and pair_margins must have the same length")
        for name in ("block_rows", "block_cols", "pair_i", "pair_j"):
            idx = getattr(self, name)
            if idx.size and (idx.min() < 0 or idx.max() >= N):
                raise PreferenceError(f"preferences: {name} has an index outside [0, {N})")
        if np.any(self.pair_i == self.pair_j):
            raise PreferenceError("preferences: a trajectory cannot be preferred to itself")
        if self.n_pairs == 0:
            raise PreferenceError("preferences: no pairs; need at least two ranked groups or one comparison")

    def _check_groups(self, N: int) -> None:
        off, items, M = self.group_offsets, self.group_items, self.group_margins
        K = off.size - 1
        if off.ndim != 1 or off.size < 1 or off[0] != 0 or off[-1] != items.size or np.any(np.diff(off) < 0):
            raise PreferenceError("preferences: group_offsets must rise from 0 to len(group_items)")
        if K and np.any(np.diff(off) == 0):
            raise PreferenceError("preferences: every ranked group needs at least one trajectory")
        if items.size and (items.min() < 0 or items.max() >= N or np.unique(items).size != items.size):
            raise PreferenceError(f"preferences: group_items must be distinct indices in [0, {N})")
        o = self.margin_offsets
        if o.ndim != 1 or o.size not in (0, K) or not np.all(np.isfinite(o)):
            raise PreferenceError(f"preferences: margin_offsets must be empty or {K} finite numbers")
        if not ((M.shape == (K, K) and np.all(np.isfinite(M))) or (M.size == 0 and o.size == K)):
            raise PreferenceError(f"preferences: group_margins must be a finite {K} x {K} matrix")
        object.__setattr__(self, "ranked", bool(self.ranked))
        if self.ranked and (K < 2 or o.size != K or self.block_margins.size or self.pair_i.size):
            raise PreferenceError("preferences: a ranked layout needs >= 2 groups, margin_offsets, and no blocks or "
                                  "explicit pairs")

    # ------------------------------------------------------------------ constructors
    @classmethod
    def from_groups(
        cls,
        group: ArrayLike,
        margins: Margins | ArrayLike | None = None,
        *,
        protocol: Literal["all"] | int = "all",
        seed: int | np.random.Generator | None = 0,
        distinct: bool = False,
    ) -> "Preferences":
        """Preferences implied by a ranking of groups.

        Parameters
        ----------
        group : array-like, (N,)
            Group label per trajectory; lower label = more preferred.
        margins : Margins, K x K matrix or K-1 gaps, optional
            Margins :math:`m_{k\\ell}`; zeros by default.
        protocol : "all" or int
            ``"all"``: every cross-group pair (paper Eq. 7). An integer ``n``: ``n`` pairs drawn uniformly
            at random (with replacement) for every group pair ``k < l`` (the authors' experiments).
        seed : int or Generator
            For the sampled protocol.
        distinct : bool
            Sampled protocol: draw the ``n`` pairs of a group pair without replacement from its
            :math:`|\\mathcal{G}_k||\\mathcal{G}_\\ell|` pairs, as the authors' code does (it shuffles every pair
            and keeps the first ``n``); default: each side drawn with replacement.
        """
        g = np.asarray(group)
        if g.ndim != 1 or g.size < 2:
            raise PreferenceError("group: need a 1-D array of at least two labels")
        labels = np.unique(g)
        if labels.size < 2:
            raise PreferenceError("group: need at least two non-empty groups")
        K = labels.size
        m = Margins.parse(margins, K)
        # one pass over the labels (not K passes): members of each group in ascending index order
        order = np.argsort(np.searchsorted(labels, g), kind="stable")
        sizes = np.unique(g, return_counts=True)[1]
        bounds = np.concatenate([[0], np.cumsum(sizes)])
        members = [order[bounds[k]:bounds[k + 1]] for k in range(K)]
        empty = np.zeros(0, dtype=np.int64)
        ranked = protocol == "all" and K >= RANKED_MIN_GROUPS and m.offsets is not None
        # the ranking itself, for the grouped likelihood (whatever the pair protocol)
        big = K > _MATRIX_MAX_GROUPS and m.offsets is not None
        groups = {"group_items": order.astype(np.int64), "group_offsets": bounds.astype(np.int64),
                  "group_margins": np.zeros((0, 0)) if big else m.matrix,
                  "margin_offsets": np.zeros(0) if m.offsets is None else m.offsets}
        if ranked:
            return cls(g.size, empty, np.zeros(1, dtype=np.int64), empty, np.zeros(1, dtype=np.int64), np.zeros(0),
                       empty, empty, np.zeros(0), protocol="all", ranked=True, **groups)
        if protocol == "all":
            rows, cols, roff, coff, bm = [], [], [0], [0], []
            for k in range(K):
                for l in range(k + 1, K):
                    rows.append(members[k]); cols.append(members[l])
                    roff.append(roff[-1] + members[k].size); coff.append(coff[-1] + members[l].size)
                    bm.append(m.matrix[k, l])
            return cls(g.size, np.concatenate(rows), np.array(roff), np.concatenate(cols), np.array(coff),
                       np.array(bm), empty, empty, np.zeros(0), protocol="all", **groups)
        if isinstance(protocol, (bool, np.bool_)) or not isinstance(protocol, (int, np.integer)) or protocol < 1:
            raise PreferenceError(f"protocol: expected 'all' or a positive number of pairs per group pair, got {protocol!r}")
        rng = np.random.default_rng(seed)
        pi, pj, pm = [], [], []
        for k in range(K):
            for l in range(k + 1, K):
                if distinct:
                    nk, nl = members[k].size, members[l].size
                    if int(protocol) > nk * nl:
                        raise PreferenceError(f"protocol: {int(protocol)} distinct pairs asked of groups {k + 1} and "
                                              f"{l + 1}, which have only {nk * nl}")
                    flat = rng.choice(nk * nl, size=int(protocol), replace=False)
                    pi.append(members[k][flat // nl])
                    pj.append(members[l][flat % nl])
                else:
                    pi.append(rng.choice(members[k], size=int(protocol)))
                    pj.append(rng.choice(members[l], size=int(protocol)))
                pm.append(np.full(int(protocol), m.matrix[k, l]))
        return cls(g.size, empty, np.zeros(1, dtype=np.int64), empty, np.zeros(1, dtype=np.int64), np.zeros(0),
                   np.concatenate(pi), np.concatenate(pj), np.concatenate(pm),
                   protocol=f"{int(protocol)} per group pair" + (" (distinct)" if distinct else ""), **groups)

    @classmethod
    def from_pairs(cls, pairs: ArrayLike, n_trajectories: int, margins: ArrayLike | float = 0.0) -> "Preferences":
        """Explicit comparisons: row ``(i, j)`` of ``pairs`` means trajectory ``i`` is preferred to ``j``."""
        p = np.asarray(pairs)
        if p.ndim != 2 or p.shape[1] != 2 or p.shape[0] == 0:
            raise PreferenceError(f"pairs: expected shape (P, 2) with P >= 1, got {p.shape}")
        if not np.issubdtype(p.dtype, np.integer):
            raise PreferenceError("pairs: trajectory indices must be integers")
        m = np.broadcast_to(np.asarray(margins, dtype=np.float64), (p.shape[0],)).copy()
        empty = np.zeros(0, dtype=np.int64)
        return cls(int(n_trajectories), empty, np.zeros(1, dtype=np.int64), empty, np.zeros(1, dtype=np.int64),
                   np.zeros(0), p[:, 0], p[:, 1], m, protocol="pairs")

    # ------------------------------------------------------------------ views
    def __repr__(self) -> str:
        # counts only: the index arrays hold one entry per trajectory or pair (thousands)
        groups = f", groups={self.n_groups}" if self.n_groups else ""
        explicit = f", explicit_pairs={self.pair_i.size}" if self.pair_i.size else ""
        return (f"Preferences(N={int(self.n_trajectories)}{groups}, pairs={self.n_pairs:,}, blocks={self.n_blocks}"
                f"{explicit}, protocol={self.protocol!r})")

    @property
    def n_blocks(self) -> int:
        return int(self.block_margins.size)

    @property
    def n_groups(self) -> int:
        """Number of ranked groups ``K`` kept for the grouped likelihood (0 when built from explicit pairs)."""
        return int(self.group_offsets.size - 1)

    @property
    def n_pairs(self) -> int:
        """Total number of ordered pairs (dense blocks plus explicit pairs, or those of a ranked layout)."""
        if self.ranked:
            sizes = np.diff(self.group_offsets)
            return int(np.sum(sizes * (self.group_items.size - self.group_offsets[1:])))
        nr = np.diff(self.block_row_offsets)
        nc = np.diff(self.block_col_offsets)
        return int(np.sum(nr * nc) + self.pair_i.size)

    def iter_blocks(self) -> Iterator[tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.float64]]]:
        """Every dense set of pairs as ``(rows, cols, margins)``: each row is preferred to each column, with margin
        ``margins[c]`` for column ``c``. Blocks give one per group pair (constant margins); a ranked layout gives one
        per group (its rows against all worse groups, K - 1 in all). Explicit pairs are not included."""
        if self.ranked:
            items, off, o = self.group_items, self.group_offsets, self.margin_offsets
            col_offset = np.repeat(o, np.diff(off))  # o of each position's group
            for k in range(self.n_groups - 1):
                yield items[off[k]:off[k + 1]], items[off[k + 1]:], col_offset[off[k + 1]:] - o[k]
            return
        for b in range(self.n_blocks):
            c = self.block_cols[self.block_col_offsets[b]:self.block_col_offsets[b + 1]]
            yield (self.block_rows[self.block_row_offsets[b]:self.block_row_offsets[b + 1]], c,
                   np.full(c.size, self.block_margins[b]))

    def to_pair_list(self) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.float64]]:
        """Every pair as ``(i, j, m)`` arrays (expands the blocks; for checks and small problems)."""
        I, J, M = [self.pair_i], [self.pair_j], [self.pair_margins]
        for r, c, m in self.iter_blocks():
            I.append(np.repeat(r, c.size)); J.append(np.tile(c, r.size)); M.append(np.tile(m, r.size))
        return np.concatenate(I), np.concatenate(J), np.concatenate(M)

    def with_margins(self, group: ArrayLike, margins: Margins | ArrayLike) -> "Preferences":
        """Same pairs, margins replaced by those of ``margins`` (looked up from the groups of each pair)."""
        g = np.asarray(group)
        labels = np.unique(g)
        m = Margins.parse(margins, labels.size)
        if self.ranked:  # all pairs of the ranking: the same pairs, laid out for the new margins
            return Preferences.from_groups(g, m)
        rank = np.searchsorted(labels, g)
        bm = np.array([m.matrix[rank[self.block_rows[self.block_row_offsets[b]]],
                                rank[self.block_cols[self.block_col_offsets[b]]]] for b in range(self.n_blocks)])
        pm = m.matrix[rank[self.pair_i], rank[self.pair_j]] if self.pair_i.size else np.zeros(0)
        same_groups = self.n_groups == labels.size
        gm = m.matrix if same_groups else self.group_margins
        mo = (np.zeros(0) if m.offsets is None else m.offsets) if same_groups else self.margin_offsets
        return Preferences(self.n_trajectories, self.block_rows, self.block_row_offsets, self.block_cols,
                           self.block_col_offsets, bm, self.pair_i, self.pair_j, pm, protocol=self.protocol,
                           group_items=self.group_items, group_offsets=self.group_offsets, group_margins=gm,
                           margin_offsets=mo)
