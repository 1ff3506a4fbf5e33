"""Ranked demonstration datasets.

A :class:`Dataset` holds ``N`` ragged trajectories, each a sequence of per-state
feature vectors :math:`\\phi(s) \\in \\mathbb{R}^d`, and a group label per trajectory
(1 = most preferred group :math:`\\mathcal{G}_1`, larger labels are worse).

On disk a dataset is one ``.npz`` archive (always read with ``allow_pickle=False``):

=================== ============ ==========================================================
field               shape        meaning
=================== ============ ==========================================================
``features``        (S, d) float per-state features, all trajectories stacked
``offsets``         (N+1,) int   trajectory ``i`` is rows ``offsets[i]:offsets[i+1]``
``group``           (N,) int     group label, 1 = most preferred
``states``          (S, k) float optional per-state states (for parametric constraints)
``actions``         (S, a) float optional per-state actions
``feature_names``   (d,) str     optional feature names
``nominal_weights`` (d,) float   optional known nominal weights :math:`w_n`
=================== ============ ==========================================================
"""

from __future__ import annotations

import os
import tempfile
import zipfile
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["Dataset", "DatasetError", "load_dataset"]


class DatasetError(ValueError):
    """Invalid dataset content; the message names the offending field."""


def _as_float_2d(name: str, value: ArrayLike) -> NDArray[np.float64]:
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise DatasetError(f"{name}: values must be numeric ({exc})") from None
    if arr.ndim == 1:
        arr = arr[:, None]
    if arr.ndim != 2:
        raise DatasetError(f"{name}: expected a 2-D array (rows, columns), got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        bad = np.argwhere(~np.isfinite(arr))[0]
        raise DatasetError(f"{name}: contains NaN or inf (first at row {bad[0]}, column {bad[1]})")
    return np.ascontiguousarray(arr)


@dataclass(frozen=True, eq=False)
class Dataset:
    """Grouped demonstrations with per-state features.

    Parameters
    ----------
    features : ndarray, shape (S, d)
        Per-state features :math:`\\phi(s)` of all trajectories, stacked.
    offsets : ndarray, shape (N + 1,)
        Trajectory boundaries: trajectory ``i`` is ``features[offsets[i]:offsets[i+1]]``.
        Must start at 0, be strictly increasing (no empty trajectory) and end at ``S``.
    group : ndarray, shape (N,)
        Positive integer group labels; 1 is the most preferred group. Any labels
        ``K >= 2`` distinct values; ranking follows their numeric order.
    states : ndarray, shape (S, k), optional
        Per-state states (e.g. positions), needed by parametric constraints.
    actions : ndarray, shape (S, a), optional
        Per-state actions.
    feature_names : tuple of str, length d, optional
        Defaults to ``("f0", "f1", ...)``.
    nominal_weights : ndarray, shape (d,), optional
        Known nominal weights :math:`w_n`.

    Raises
    ------
    DatasetError
        With a message naming the field, for any inconsistent or non-finite input.
    """

    features: NDArray[np.float64]
    offsets: NDArray[np.int64]
    group: NDArray[np.int64]
    states: NDArray[np.float64] | None = None
    actions: NDArray[np.float64] | None = None
    feature_names: tuple[str, ...] = field(default=())
    nominal_weights: NDArray[np.float64] | None = None

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        feats = _as_float_2d("features", self.features)
        S, d = feats.shape
        if S == 0 or d == 0:
            raise DatasetError(f"features: must have at least one row and one column, got shape {feats.shape}")
        offsets = np.asarray(self.offsets)
        if offsets.ndim != 1 or offsets.size < 2:
            raise DatasetError(f"offsets: expected a 1-D array of length N+1 >= 2, got shape {offsets.shape}")
        if not np.issubdtype(offsets.dtype, np.integer):
            if not np.issubdtype(offsets.dtype, np.floating) or not np.all(offsets == np.round(offsets)):
                raise DatasetError(f"offsets: must be integers, got dtype {offsets.dtype}")
        offsets = offsets.astype(np.int64)
        if offsets[0] != 0:
            raise DatasetError(f"offsets: must start at 0, starts at {offsets[0]}")
        steps = np.diff(offsets)
        if np.any(steps <= 0):
            i = int(np.argmax(steps <= 0))
            kind = "empty" if steps[i] == 0 else "decreasing"
            raise DatasetError(f"offsets: must be strictly increasing; trajectory {i} is {kind} "
                               f"(offsets[{i}]={offsets[i]}, offsets[{i + 1}]={offsets[i + 1]})")
        if offsets[-1] != S:
            raise DatasetError(f"offsets: must end at the number of feature rows S={S}, ends at {offsets[-1]}")
        N = offsets.size - 1

        group = np.asarray(self.group)
        if group.shape != (N,):
            raise DatasetError(f"group: expected shape ({N},) (one label per trajectory), got {group.shape}")
        if not np.issubdtype(group.dtype, np.integer):
            if np.issubdtype(group.dtype, np.floating) and np.all(np.isfinite(group)) and np.all(group == np.round(group)):
                group = group.astype(np.int64)
            else:
                raise DatasetError(f"group: labels must be positive integers, got dtype {group.dtype}")
        group = group.astype(np.int64)
        if np.any(group < 1):
            raise DatasetError(f"group: labels must be positive integers (1 = most preferred), got {int(group.min())}")
        if np.unique(group).size < 2:
            raise DatasetError("group: need at least two non-empty groups to rank, found "
                               f"{np.unique(group).size} ({np.unique(group).tolist()})")

        states = None if self.states is None else _as_float_2d("states", self.states)
        if states is not None and states.shape[0] != S:
            raise DatasetError(f"states: expected {S} rows (one per feature row), got {states.shape[0]}")
        actions = None if self.actions is None else _as_float_2d("actions", self.actions)
        if actions is not None and actions.shape[0] != S:
            raise DatasetError(f"actions: expected {S} rows (one per feature row), got {actions.shape[0]}")

        names = tuple(str(n) for n in self.feature_names) if len(self.feature_names) else tuple(f"f{j}" for j in range(d))
        if len(names) != d:
            raise DatasetError(f"feature_names: expected {d} names (one per feature column), got {len(names)}")
        if len(set(names)) != d:
            raise DatasetError(f"feature_names: names must be unique, got {list(names)}")

        wn = None
        if self.nominal_weights is not None:
            try:
                wn = np.asarray(self.nominal_weights, dtype=np.float64).reshape(-1)
            except (TypeError, ValueError):
                raise DatasetError("nominal_weights: values must be numeric") from None
            if wn.shape != (d,):
                raise DatasetError(f"nominal_weights: expected {d} values (one per feature), got {wn.size}")
            if not np.all(np.isfinite(wn)):
                raise DatasetError("nominal_weights: contains NaN or inf")

        set_(self, "features", feats)
        set_(self, "offsets", offsets)
        set_(self, "group", group)
        set_(self, "states", states)
        set_(self, "actions", actions)
        set_(self, "feature_names", names)
        set_(self, "nominal_weights", wn)

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_trajectories(
        cls,
        features: Sequence[ArrayLike],
        group: ArrayLike,
        *,
        states: Sequence[ArrayLike] | None = None,
        actions: Sequence[ArrayLike] | None = None,
        feature_names: Sequence[str] | None = None,
        nominal_weights: ArrayLike | None = None,
    ) -> "Dataset":
        """Build from a list of per-trajectory arrays.

        Parameters
        ----------
        features : sequence of arrays, each (T_i, d)
        group : array-like, (N,)
        states, actions : sequence of arrays, each (T_i, k), optional
        feature_names : sequence of str, optional
        nominal_weights : array-like, (d,), optional
        """
        if len(features) == 0:
            raise DatasetError("features: no trajectories given")
        blocks = []
        for i, f in enumerate(features):
            try:
                a = np.asarray(f, dtype=np.float64)
            except (TypeError, ValueError) as exc:
                raise DatasetError(f"features: trajectory {i} is not numeric ({exc})") from None
            if a.ndim == 1:
                a = a[:, None]
            if a.ndim != 2:
                raise DatasetError(f"features: trajectory {i} must be 2-D (T_i, d), got shape {a.shape}")
            if a.shape[0] == 0:
                raise DatasetError(f"features: trajectory {i} is empty")
            if blocks and a.shape[1] != blocks[0].shape[1]:
                raise DatasetError(f"features: trajectory {i} has {a.shape[1]} features, trajectory 0 has {blocks[0].shape[1]}")
            blocks.append(a)
        lengths = np.array([b.shape[0] for b in blocks], dtype=np.int64)
        offsets = np.concatenate([[0], np.cumsum(lengths)])

        def stack(name: str, seq: Sequence[ArrayLike] | None) -> NDArray[np.float64] | None:
            if seq is None:
                return None
            if len(seq) != len(blocks):
                raise DatasetError(f"{name}: expected {len(blocks)} trajectories, got {len(seq)}")
            parts = []
            for i, s in enumerate(seq):
                a = np.asarray(s, dtype=np.float64)
                a = a[:, None] if a.ndim == 1 else a
                if a.ndim != 2 or a.shape[0] != lengths[i]:
                    raise DatasetError(f"{name}: trajectory {i} must have {lengths[i]} rows, got shape {a.shape}")
                parts.append(a)
            return np.concatenate(parts, axis=0)

        return cls(
            features=np.concatenate(blocks, axis=0),
            offsets=offsets,
            group=np.asarray(group),
            states=stack("states", states),
            actions=stack("actions", actions),
            feature_names=tuple(feature_names) if feature_names is not None else (),
            nominal_weights=nominal_weights,
        )

    # ------------------------------------------------------------------ properties
    @property
    def n_trajectories(self) -> int:
        """Number of trajectories ``N``."""
        return int(self.offsets.size - 1)

    @property
    def n_features(self) -> int:
        """Number of features ``d``."""
        return int(self.features.shape[1])

    @property
    def lengths(self) -> NDArray[np.int64]:
        """Trajectory lengths ``T_i``, shape (N,)."""
        return np.diff(self.offsets)

    @property
    def group_labels(self) -> NDArray[np.int64]:
        """Distinct group labels in preference order (best first), shape (K,)."""
        return np.unique(self.group)

    @property
    def n_groups(self) -> int:
        """Number of non-empty groups ``K``."""
        return int(self.group_labels.size)

    @cached_property
    def mean_features(self) -> NDArray[np.float64]:
        """Length-normalised feature sums :math:`\\frac{1}{T_i}\\sum_{s\\in\\tau_i}\\phi(s)`, shape (N, d)."""
        sums = np.add.reduceat(self.features, self.offsets[:-1], axis=0)
        return sums / self.lengths[:, None]

    def trajectory(self, i: int) -> NDArray[np.float64]:
        """Features of trajectory ``i``, shape (T_i, d)."""
        return self.features[self.offsets[i]:self.offsets[i + 1]]

    def trajectory_states(self, i: int) -> NDArray[np.float64]:
        """States of trajectory ``i``, shape (T_i, k)."""
        if self.states is None:
            raise DatasetError("states: this dataset has no states")
        return self.states[self.offsets[i]:self.offsets[i + 1]]

    def group_counts(self) -> dict[int, int]:
        """Number of trajectories per group label."""
        labels, counts = np.unique(self.group, return_counts=True)
        return {int(k): int(c) for k, c in zip(labels, counts)}

    # ------------------------------------------------------------------ selection
    def subset(self, indices: ArrayLike) -> "Dataset":
        """Dataset of the trajectories ``indices`` (in that order)."""
        idx = np.asarray(indices, dtype=np.int64).reshape(-1)
        if idx.size == 0:
            raise DatasetError("subset: no trajectories selected")
        if idx.min() < 0 or idx.max() >= self.n_trajectories:
            raise DatasetError(f"subset: indices must lie in [0, {self.n_trajectories})")
        rows = np.concatenate([np.arange(self.offsets[i], self.offsets[i + 1]) for i in idx])
        lengths = self.lengths[idx]
        return Dataset(
            features=self.features[rows],
            offsets=np.concatenate([[0], np.cumsum(lengths)]),
            group=self.group[idx],
            states=None if self.states is None else self.states[rows],
            actions=None if self.actions is None else self.actions[rows],
            feature_names=self.feature_names,
            nominal_weights=self.nominal_weights,
        )

    def sample_per_group(self, n: int, seed: int | np.random.Generator | None = 0) -> "Dataset":
        """Draw ``n`` trajectories from every group without replacement (all if a group has fewer)."""
        if n < 1:
            raise DatasetError(f"sample_per_group: n must be >= 1, got {n}")
        rng = np.random.default_rng(seed)
        picks = []
        for k in self.group_labels:
            members = np.flatnonzero(self.group == k)
            take = members if members.size <= n else np.sort(rng.choice(members, size=n, replace=False))
            picks.append(take)
        return self.subset(np.concatenate(picks))

    def with_nominal_weights(self, nominal_weights: ArrayLike) -> "Dataset":
        """Copy with other nominal weights :math:`w_n`."""
        return Dataset(self.features, self.offsets, self.group, self.states, self.actions,
                       self.feature_names, np.asarray(nominal_weights, dtype=np.float64))

    # ------------------------------------------------------------------ I/O
    def save(self, path: str | os.PathLike[str], *, compress: bool = True) -> Path:
        """Write the dataset to ``path`` (``.npz``) atomically: a crash never leaves a partial file."""
        path = Path(path)
        if path.suffix != ".npz":
            path = path.with_suffix(path.suffix + ".npz") if path.suffix else path.with_suffix(".npz")
        arrays: dict[str, NDArray] = {
            "features": self.features, "offsets": self.offsets, "group": self.group,
            "feature_names": np.array(self.feature_names, dtype=np.str_),
        }
        if self.states is not None:
            arrays["states"] = self.states
        if self.actions is not None:
            arrays["actions"] = self.actions
        if self.nominal_weights is not None:
            arrays["nominal_weights"] = self.nominal_weights
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=".tmp-", suffix=".npz", dir=path.parent)
        try:
            with os.fdopen(fd, "wb") as fh:
                (np.savez_compressed if compress else np.savez)(fh, **arrays)
            os.chmod(tmp, 0o666 & ~_umask())  # mkstemp creates 0600; give the file normal permissions
            os.replace(tmp, path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
        return path

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> "Dataset":
        """Read and validate a dataset written by :meth:`save` (or by hand, see module docs)."""
        path = Path(path)
        if not path.exists():
            raise DatasetError(f"{path}: no such file")
        if not zipfile.is_zipfile(path):
            raise DatasetError(f"{path}: not a readable .npz archive (not a zip file)")
        try:
            with np.load(path, allow_pickle=False) as z:
                content = {k: z[k] for k in z.files}
        except ValueError as exc:
            if "pickle" in str(exc).lower():
                raise DatasetError(f"{path}: contains Python objects (pickles), which are not read for "
                                   "safety; store feature_names as a string array") from None
            raise DatasetError(f"{path}: not a readable .npz archive ({exc})") from None
        except Exception as exc:  # zipfile / OSError: corrupt file
            raise DatasetError(f"{path}: not a readable .npz archive ({exc})") from None
        missing = [k for k in ("features", "offsets", "group") if k not in content]
        if missing:
            raise DatasetError(f"{path}: missing required field(s) {', '.join(missing)}")
        names = content.get("feature_names")
        return cls(
            features=content["features"],
            offsets=content["offsets"],
            group=content["group"],
            states=content.get("states"),
            actions=content.get("actions"),
            feature_names=tuple(str(n) for n in names.tolist()) if names is not None and names.size else (),
            nominal_weights=content.get("nominal_weights"),
        )

    def __repr__(self) -> str:
        counts = ", ".join(f"G{k}: {c}" for k, c in self.group_counts().items())
        return (f"Dataset(N={self.n_trajectories}, d={self.n_features}, states={self.lengths.sum()}, "
                f"groups={{{counts}}}, features={list(self.feature_names)})")


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def load_dataset(path: str | os.PathLike[str]) -> Dataset:
    """Read a ``.npz`` dataset; see :class:`Dataset`."""
    return Dataset.load(path)
