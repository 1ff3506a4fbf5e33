"""The state of one labelling session: groups, assignments, skips and the gap relation, saved on every change.

:class:`LabelSession` owns the output file. Every change names the revision it was made on; a change on
an older revision (another tab made one in between) is a :class:`Conflict`, and so is an output file that
another program changed since this session last wrote it. The file is the documented dataset ``.npz``
(:mod:`pbicrl.inference.data`) with group 0 for unlabelled trajectories, written atomically (a temporary, then
``os.replace``) by :meth:`pbicrl.inference.data.Dataset.save`; an existing output resumes the session.
"""

from __future__ import annotations

import os
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np
from numpy.typing import NDArray

from pbicrl.inference.data import MAX_GROUPS, Dataset, DatasetError, list_shipped_datasets, load_dataset, resolve_dataset_path

__all__ = ["LabelSession", "SessionError", "Conflict", "DEFAULT_GROUPS", "MAX_NAME_LENGTH"]

DEFAULT_GROUPS = ("good", "bad", "very bad")
"""Groups a session starts with when the input defines none (best first)."""
MAX_NAME_LENGTH = 100


class SessionError(ValueError):
    """A change that cannot be applied (unknown trajectory id, bad group, bad gap relation, ...)."""


class Conflict(SessionError):
    """The change was made on an outdated revision, or the output file was changed by someone else."""


@dataclass(frozen=True)
class _Stamp:
    """Identity of the output file as this session last wrote (or found) it."""

    inode: int
    size: int
    mtime_ns: int

    @classmethod
    def of(cls, path: Path) -> "_Stamp | None":
        try:
            st = os.stat(path)
        except FileNotFoundError:
            return None
        return cls(st.st_ino, st.st_size, st.st_mtime_ns)


def _same_trajectories(a: Dataset, b: Dataset) -> str | None:
    """Why ``b`` does not hold the trajectories of ``a`` (None if it does)."""
    if a.n_trajectories != b.n_trajectories:
        return f"{b.n_trajectories} trajectories, the input has {a.n_trajectories}"
    if not np.array_equal(a.offsets, b.offsets):
        return "trajectories of other lengths"
    if a.feature_names != b.feature_names or not np.array_equal(a.features, b.features):
        return "other features"
    if (a.states is None) != (b.states is None) or (a.states is not None and not np.array_equal(a.states, b.states)):
        return "other states"
    return None


def _guess_env(path: Path) -> str | None:
    """The env id of a shipped dataset (``point_mass.npz`` shipped with pbicrl -> ``point_mass``)."""
    from pbicrl.inference.data import shipped_dir

    try:
        if path.resolve().parent == shipped_dir().resolve() and path.stem in list_shipped_datasets():
            return path.stem
    except OSError:
        return None
    return None


class LabelSession:
    """Labelling state of one dataset, saved to ``out`` on every change.

    Parameters
    ----------
    data : str or path
        The demonstrations (a pool, a partly labelled file or a grouped dataset; a shipped dataset's name
        works). They must have ``states``.
    out : path
        Where the labelled dataset goes (``.npz``). If it exists and holds the same trajectories, the session
        resumes from it.
    env_id : str, optional
        Overrides the dataset's ``env_id`` (for the pictures; saved with the labels).

    Raises
    ------
    pbicrl.inference.data.DatasetError
        Unreadable data, no states, an output that is not a dataset or holds other trajectories.
    """

    def __init__(self, data: str | os.PathLike[str], out: str | os.PathLike[str], *, env_id: str | None = None) -> None:
        src = resolve_dataset_path(data)
        out = Path(out)
        if out.suffix != ".npz":
            raise DatasetError(f"out: {out}: expected a file name ending in .npz")
        if out.is_dir():
            raise DatasetError(f"out: {out} is a directory; give a file name such as {out / 'labelled.npz'}")
        if out.exists() and src.resolve() == out.resolve():
            raise DatasetError(f"out: {out} is the input file; write the labels to another file (the input stays "
                               "unchanged)")
        base = load_dataset(src, allow_unlabelled=True)
        if base.states is None:
            raise DatasetError(f"states: {src} has no states; pbicrl label draws each demonstration from its "
                               "states (positions, or x for the wall tasks): add a 'states' array (S, k)")
        self.source = src
        self.out = out
        self._lock = threading.RLock()
        start = base
        self.resumed = False
        if out.exists():
            try:
                prev = load_dataset(out, allow_unlabelled=True)
            except DatasetError as exc:
                raise DatasetError(f"out: {out} exists but is not a dataset this session can resume ({exc}); "
                                   "choose another file") from None
            why = _same_trajectories(base, prev)
            if why is not None:
                raise DatasetError(f"out: {out} exists and holds {why}; it is not a labelling of {src}. Choose "
                                   "another --out (or move the old file away)")
            start, self.resumed = prev, True
        self.base = base
        self.env_id = env_id or start.env_id or base.env_id or _guess_env(src)
        names = [start.group_name(k) for k in start.defined_groups] if start.defined_groups else []
        if not names:
            names = list(DEFAULT_GROUPS)
        rank = {k: r + 1 for r, k in enumerate(start.defined_groups)}
        self._group = np.array([rank.get(int(g), 0) for g in start.group], dtype=np.int64)
        self._skipped = np.asarray(start.skipped, dtype=bool).copy()
        self._names = names
        self._gaps: list[float] | None = None if start.gap_relation is None else start.gap_relation.tolist()
        self.revision = 1
        self._stamp = _Stamp.of(out)
        self.saved_revision = self.revision if self.resumed else 0

    # ------------------------------------------------------------------ views
    @property
    def n(self) -> int:
        """Number of trajectories."""
        return self.base.n_trajectories

    @property
    def group_names(self) -> list[str]:
        """Names of the groups, best first (group ``k`` is ``group_names[k-1]``)."""
        return list(self._names)

    @property
    def group(self) -> NDArray[np.int64]:
        """Group per trajectory, 0 = unlabelled (a copy)."""
        return self._group.copy()

    @property
    def skipped(self) -> NDArray[np.bool_]:
        """Skip flag per trajectory (a copy)."""
        return self._skipped.copy()

    @property
    def gap_relation(self) -> list[float] | None:
        return None if self._gaps is None else list(self._gaps)

    def state(self) -> dict[str, Any]:
        """JSON-ready state: revision, groups, assignments, skips, gap relation, counts, file."""
        with self._lock:
            counts = [int(np.sum(self._group == k)) for k in range(1, len(self._names) + 1)]
            return {"revision": self.revision, "saved_revision": self.saved_revision, "out": str(self.out),
                    "source": str(self.source), "resumed": self.resumed, "n": self.n,
                    "groups": [{"label": k + 1, "name": nm, "count": counts[k]} for k, nm in enumerate(self._names)],
                    "group": self._group.tolist(), "skipped": self._skipped.tolist(),
                    "gap_relation": self.gap_relation, "n_unlabelled": int(np.sum((self._group == 0) & ~self._skipped)),
                    "n_skipped": int(self._skipped.sum()), "env_id": self.env_id,
                    "lengths": self.base.lengths.tolist(), "feature_names": list(self.base.feature_names)}

    def dataset(self) -> Dataset:
        """The labelling as a dataset (group 0 = unlabelled; ``allow_unlabelled``)."""
        with self._lock:
            b = self.base
            return Dataset(b.features, b.offsets, self._group.copy(), b.states, b.actions, b.feature_names,
                           b.nominal_weights, tuple(self._names),
                           None if self._gaps is None else np.array(self._gaps, dtype=np.float64),
                           self._skipped.copy(), self.env_id, allow_unlabelled=True)

    # ------------------------------------------------------------------ changes
    def _ids(self, ids: Any) -> NDArray[np.int64]:
        if not isinstance(ids, (list, tuple)) or not ids:
            raise SessionError("ids: expected a non-empty list of trajectory ids")
        out = []
        for i in ids:
            if isinstance(i, bool) or not isinstance(i, (int, np.integer)):
                raise SessionError(f"ids: {i!r} is not a trajectory id (an integer)")
            if not 0 <= int(i) < self.n:
                raise SessionError(f"ids: unknown trajectory {i}; ids are 0 to {self.n - 1}")
            out.append(int(i))
        return np.array(out, dtype=np.int64)

    def _check_revision(self, revision: Any) -> None:
        if isinstance(revision, bool) or not isinstance(revision, int):
            raise SessionError(f"revision: expected the integer revision the change was made on, got {revision!r}")
        if revision != self.revision:
            raise Conflict(f"revision: this labelling changed in another tab or window (now at revision "
                           f"{self.revision}, this page has {revision}); reload the page to continue from the "
                           "saved state")

    def _commit(self, apply: Any) -> dict[str, Any]:
        """Apply a change to copies, save, and keep it only if the save worked."""
        old = (self._group.copy(), self._skipped.copy(), list(self._names), self.gap_relation)
        try:
            apply()
            self._save()
        except BaseException:
            self._group, self._skipped, self._names, self._gaps = old
            raise
        self.revision += 1
        self.saved_revision = self.revision
        return self.state()

    def _save(self) -> None:
        now = _Stamp.of(self.out)
        if now != self._stamp:
            raise Conflict(f"out: {self.out} was changed by another program since this session "
                           f"{'wrote' if self.saved_revision else 'started'}; restart 'pbicrl label' to resume from "
                           "it, or choose another --out")
        self.dataset().save(self.out, compress=False)
        self._stamp = _Stamp.of(self.out)

    def assign(self, revision: int, ids: Sequence[int], group: int) -> dict[str, Any]:
        """Put trajectories ``ids`` into ``group`` (1 = best; 0 = back to unlabelled); clears their skip."""
        with self._lock:
            self._check_revision(revision)
            idx = self._ids(ids)
            if isinstance(group, bool) or not isinstance(group, int) or not 0 <= group <= len(self._names):
                raise SessionError(f"group: expected 0 (unlabelled) or a group 1 to {len(self._names)}, got {group!r}")

            def apply() -> None:
                self._group[idx] = group
                self._skipped[idx] = False
            return self._commit(apply)

    def skip(self, revision: int, ids: Sequence[int], skipped: bool = True) -> dict[str, Any]:
        """Mark trajectories ``ids`` skipped (they leave their group) or not skipped (unlabelled)."""
        with self._lock:
            self._check_revision(revision)
            idx = self._ids(ids)
            if not isinstance(skipped, bool):
                raise SessionError(f"skipped: expected true or false, got {skipped!r}")

            def apply() -> None:
                self._group[idx] = 0
                self._skipped[idx] = skipped
            return self._commit(apply)

    def set_groups(self, revision: int, names: Sequence[str], source: Sequence[int | None] | None = None
                   ) -> dict[str, Any]:
        """Create, rename, reorder or delete groups.

        Parameters
        ----------
        revision : int
        names : sequence of str
            The new groups, best first.
        source : sequence of (int or None), optional
            For each new group, the current group (label) it continues, or None for a new, empty group.
            Current groups that no entry names are deleted: their trajectories become unlabelled. Default:
            ``1, 2, ...`` (renaming, or adding groups at the end). The gap relation is kept when only names
            change, and cleared otherwise.
        """
        with self._lock:
            self._check_revision(revision)
            if not isinstance(names, (list, tuple)) or not names:
                raise SessionError("names: expected a non-empty list of group names, best first")
            clean = []
            for i, nm in enumerate(names):
                if not isinstance(nm, str) or not nm.strip():
                    raise SessionError(f"names: group {i + 1} needs a name (non-empty text), got {nm!r}")
                nm = nm.strip()
                if len(nm) > MAX_NAME_LENGTH or not nm.isprintable():
                    raise SessionError(f"names: group {i + 1}: at most {MAX_NAME_LENGTH} printable characters")
                clean.append(nm)
            if len(set(clean)) != len(clean):
                raise SessionError(f"names: group names must be unique, got {clean}")
            if len(clean) > MAX_GROUPS:
                raise SessionError(f"names: at most {MAX_GROUPS} groups")
            K = len(self._names)
            src = list(range(1, min(K, len(clean)) + 1)) + [None] * max(0, len(clean) - K) if source is None else source
            if not isinstance(src, (list, tuple)) or len(src) != len(clean):
                raise SessionError(f"source: expected one entry per group ({len(clean)}), got {src!r}")
            seen = set()
            for s in src:
                if s is None:
                    continue
                if isinstance(s, bool) or not isinstance(s, int) or not 1 <= s <= K:
                    raise SessionError(f"source: {s!r} is not a current group (1 to {K}) or null")
                if s in seen:
                    raise SessionError(f"source: group {s} is named twice")
                seen.add(s)
            rename_only = list(src) == list(range(1, K + 1))

            def apply() -> None:
                remap = np.zeros(K + 1, dtype=np.int64)
                for new, s in enumerate(src, start=1):
                    if s is not None:
                        remap[s] = new
                self._group = remap[self._group]
                self._names = clean
                if not rename_only:
                    self._gaps = None
            return self._commit(apply)

    def set_gap_relation(self, revision: int, values: Sequence[float] | None) -> dict[str, Any]:
        """State the relative sizes of the K-1 gaps between consecutive groups (None clears them)."""
        with self._lock:
            self._check_revision(revision)
            K = len(self._names)
            if values is not None:
                if not isinstance(values, (list, tuple)) or len(values) != K - 1:
                    raise SessionError(f"gap_relation: {K} groups need {K - 1} relative gap sizes, got {values!r}")
                vals = []
                for v in values:
                    if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v) or v <= 0:
                        raise SessionError(f"gap_relation: sizes must be positive numbers, got {v!r}")
                    vals.append(float(v))
                values = vals
                if K < 2:
                    raise SessionError("gap_relation: needs at least two groups")

            def apply() -> None:
                self._gaps = None if values is None else list(values)
            return self._commit(apply)
