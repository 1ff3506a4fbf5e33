"""Import grouped demonstrations from a table: CSV (standard library) or Parquet (pyarrow, extra ``io``).

One row per state. Columns:

* a trajectory id (any value; trajectories keep the order in which their ids first appear);
* the trajectory's group (positive integer, 1 = best; the same on every row of a trajectory);
* one column per feature (numeric);
* optionally state columns and action columns (numeric), and a step column that orders the rows of each
  trajectory (otherwise file order is kept).

Problems are reported with the column, the row (1-based data row; for CSV also the file line) and the value:
missing columns, a trajectory with rows in more than one group, non-numeric or empty values.
"""

from __future__ import annotations

import csv as _csv
import math
import os
import tempfile
from pathlib import Path
from typing import Any, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from pbicrl.data import Dataset, DatasetError, _umask

__all__ = ["TableError", "read_csv", "read_parquet", "read_table", "columns_to_dataset", "write_csv"]

_IO_HINT = 'pip install "pbicrl[io]"'


class TableError(DatasetError):
    """A table that cannot become a dataset; the message names the column and row."""


def _split(cols: str | Sequence[str] | None) -> list[str] | None:
    if cols is None:
        return None
    if isinstance(cols, str):
        return [c.strip() for c in cols.split(",") if c.strip()]
    return [str(c) for c in cols]


def columns_to_dataset(
    columns: dict[str, Sequence[Any]],
    *,
    id_col: str = "trajectory",
    group_col: str = "group",
    feature_cols: str | Sequence[str] | None = None,
    state_cols: str | Sequence[str] | None = None,
    action_cols: str | Sequence[str] | None = None,
    step_col: str | None = None,
    nominal_weights: ArrayLike | None = None,
    source: str = "table",
    lines: Sequence[int] | None = None,
) -> Dataset:
    """Build a :class:`Dataset` from named columns (each a sequence with one entry per row).

    Parameters
    ----------
    columns : dict of str -> sequence
    id_col, group_col : str
        Trajectory id and group label columns.
    feature_cols : comma-separated str or sequence of str, optional
        Default: every column not used as id, group, step, state or action.
    state_cols, action_cols : comma-separated str or sequence of str, optional
    step_col : str, optional
        Orders the rows within each trajectory.
    nominal_weights : array-like (d,), optional
    source : str
        File name for messages.
    lines : sequence of int, optional
        File line of each row, for messages (CSV).

    Raises
    ------
    TableError
    """
    names = list(columns)
    if not names:
        raise TableError(f"{source}: no columns")
    n_rows = len(columns[names[0]])
    if n_rows == 0:
        raise TableError(f"{source}: no data rows")
    feats = _split(feature_cols)
    states = _split(state_cols) or []
    actions = _split(action_cols) or []
    used = [id_col, group_col] + ([step_col] if step_col else []) + states + actions
    if feats is None:
        feats = [c for c in names if c not in used]
        if not feats:
            raise TableError(f"{source}: no feature columns left after id/group/state/action columns; "
                             f"columns are {names}")
    for role, want in (("--id-col", [id_col]), ("--group-col", [group_col]), ("--feature-cols", feats),
                       ("--state-cols", states), ("--action-cols", actions), ("--step-col", [step_col] if step_col else [])):
        missing = [c for c in want if c not in columns]
        if missing:
            raise TableError(f"{source}: {role}: column(s) {missing} not found; columns are {names}")
    clash = sorted(set(feats) & set([id_col, group_col] + states + actions + ([step_col] if step_col else [])))
    if clash:
        raise TableError(f"{source}: --feature-cols: {clash} also used as id/group/state/action/step column")
    if len(set(feats)) != len(feats):
        raise TableError(f"{source}: --feature-cols: repeated column names {feats}")

    def where(r: int) -> str:
        return f"row {r + 1}" + (f" (line {lines[r]})" if lines is not None else "")

    def numeric(col: str) -> NDArray[np.float64]:
        vals = columns[col]
        try:
            arr = np.asarray(vals, dtype=np.float64)
        except (TypeError, ValueError):
            arr = None
        if arr is None or arr.shape != (n_rows,):
            out = np.empty(n_rows)
            for r, v in enumerate(vals):
                try:
                    out[r] = float(v)
                except (TypeError, ValueError):
                    shown = "an empty value" if v is None or (isinstance(v, str) and not v.strip()) else repr(v)
                    raise TableError(f"{source}: column '{col}', {where(r)}: {shown} is not a number") from None
            arr = out
        bad = np.flatnonzero(~np.isfinite(arr))
        if bad.size:
            r = int(bad[0])
            raw = vals[r]
            shown = "an empty value" if raw is None or (isinstance(raw, str) and not raw.strip()) or \
                (isinstance(raw, float) and math.isnan(raw)) else repr(raw)
            raise TableError(f"{source}: column '{col}', {where(r)}: {shown} is not a finite number")
        return arr

    ids = [("" if v is None else str(v)).strip() for v in columns[id_col]]
    empty = [r for r, v in enumerate(ids) if not v]
    if empty:
        raise TableError(f"{source}: column '{id_col}', {where(empty[0])}: empty trajectory id")
    group = numeric(group_col)
    bad = np.flatnonzero((group != np.round(group)) | (group < 1))
    if bad.size:
        r = int(bad[0])
        raise TableError(f"{source}: column '{group_col}', {where(r)}: group labels must be positive integers "
                         f"(1 = best), got {columns[group_col][r]!r}")
    F = np.column_stack([numeric(c) for c in feats])
    S = np.column_stack([numeric(c) for c in states]) if states else None
    A = np.column_stack([numeric(c) for c in actions]) if actions else None
    step = numeric(step_col) if step_col else None

    order: dict[str, list[int]] = {}
    for r, t in enumerate(ids):
        order.setdefault(t, []).append(r)
    traj_rows, traj_group = [], []
    for t, rows in order.items():
        g = np.unique(group[rows])
        if g.size > 1:
            first = {int(x): rows[int(np.argmax(group[rows] == x))] for x in g}
            detail = ", ".join(f"{k} ({where(r)})" for k, r in sorted(first.items()))
            raise TableError(f"{source}: trajectory '{t}' has rows in more than one group: {detail}; "
                             f"every row of a trajectory must carry the same '{group_col}'")
        rows_arr = np.asarray(rows)
        if step is not None:
            s = step[rows_arr]
            rows_arr = rows_arr[np.argsort(s, kind="stable")]
            dup = np.flatnonzero(np.diff(np.sort(s)) == 0)
            if dup.size:
                raise TableError(f"{source}: trajectory '{t}': repeated value {np.sort(s)[dup[0]]:g} in step column "
                                 f"'{step_col}'")
        traj_rows.append(rows_arr)
        traj_group.append(int(g[0]))
    if len(set(traj_group)) < 2:
        raise TableError(f"{source}: column '{group_col}': need at least two groups to rank, all trajectories are "
                         f"in group {traj_group[0]}")
    return Dataset.from_trajectories(
        [F[r] for r in traj_rows], np.asarray(traj_group),
        states=None if S is None else [S[r] for r in traj_rows],
        actions=None if A is None else [A[r] for r in traj_rows],
        feature_names=feats, nominal_weights=nominal_weights)


def read_csv(path: str | os.PathLike[str], *, delimiter: str = ",", **kwargs: Any) -> Dataset:
    """Read a CSV file with a header row (see the module docstring; keyword arguments as
    :func:`columns_to_dataset`)."""
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"data: {p}: no such file")
    with open(p, newline="", encoding="utf-8-sig") as fh:
        reader = _csv.reader(fh, delimiter=delimiter)
        try:
            header = next(reader)
        except StopIteration:
            raise TableError(f"{p}: empty file (expected a header row)") from None
        header = [h.strip() for h in header]
        if len(set(header)) != len(header):
            dup = sorted({h for h in header if header.count(h) > 1})
            raise TableError(f"{p}: repeated column names {dup} in the header")
        cols: dict[str, list[str]] = {h: [] for h in header}
        lines: list[int] = []
        for row in reader:
            if not row or all(not x.strip() for x in row):
                continue
            if len(row) != len(header):
                raise TableError(f"{p}: line {reader.line_num}: {len(row)} values, the header has {len(header)} columns")
            lines.append(reader.line_num)
            for h, v in zip(header, row):
                cols[h].append(v)
    return columns_to_dataset(cols, source=str(p), lines=lines, **kwargs)


def read_parquet(path: str | os.PathLike[str], **kwargs: Any) -> Dataset:
    """Read a Parquet file (needs pyarrow: ``pip install "pbicrl[io]"``); keyword arguments as
    :func:`columns_to_dataset`."""
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"data: {p}: no such file")
    try:
        import pyarrow.parquet as pq
    except ImportError as exc:
        raise ImportError(f"reading Parquet needs pyarrow ({exc}): {_IO_HINT}") from exc
    try:
        table = pq.read_table(p)
    except Exception as exc:  # pyarrow raises its own error types for corrupt files
        raise TableError(f"{p}: not a readable Parquet file ({exc})") from None
    cols = {name: table.column(name).to_pylist() for name in table.column_names}
    return columns_to_dataset(cols, source=str(p), **kwargs)


def read_table(path: str | os.PathLike[str], *, format: str | None = None, **kwargs: Any) -> Dataset:
    """CSV or Parquet by ``format`` (``"csv"``, ``"tsv"``, ``"parquet"``) or the file extension."""
    p = Path(path)
    fmt = (format or p.suffix.lstrip(".")).lower()
    if fmt in ("csv", "txt"):
        return read_csv(p, **kwargs)
    if fmt == "tsv":
        return read_csv(p, delimiter="\t", **kwargs)
    if fmt in ("parquet", "pq"):
        return read_parquet(p, **kwargs)
    raise TableError(f"{p}: unknown table format {fmt!r}; use .csv, .tsv or .parquet (or pass format=)")


def write_csv(dataset: Dataset, path: str | os.PathLike[str], *, id_col: str = "trajectory",
              group_col: str = "group") -> Path:
    """Write a dataset as a table :func:`read_csv` reads back (states as ``state0..``, actions as
    ``action0..``), atomically."""
    p = Path(path)
    names = list(dataset.feature_names)
    k = 0 if dataset.states is None else dataset.states.shape[1]
    a = 0 if dataset.actions is None else dataset.actions.shape[1]
    header = [id_col, group_col] + names + [f"state{j}" for j in range(k)] + [f"action{j}" for j in range(a)]
    clash = set(header[:2]) & set(header[2:])
    if clash or len(set(header)) != len(header):
        raise TableError(f"{p}: column names clash: {sorted(clash) or header}")
    p.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=".tmp", dir=p.parent)
    try:
        with os.fdopen(fd, "w", newline="") as fh:
            w = _csv.writer(fh)
            w.writerow(header)
            for i in range(dataset.n_trajectories):
                lo, hi = dataset.offsets[i], dataset.offsets[i + 1]
                for r in range(lo, hi):
                    row = [i, int(dataset.group[i])] + [repr(float(x)) for x in dataset.features[r]]
                    if k:
                        row += [repr(float(x)) for x in dataset.states[r]]
                    if a:
                        row += [repr(float(x)) for x in dataset.actions[r]]
                    w.writerow(row)
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp creates 0600
        os.replace(tmp, p)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return p
