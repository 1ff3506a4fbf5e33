"""Import grouped demonstrations from a table: CSV (standard library) or Parquet (pyarrow, extra ``io``).

One row per state. Columns:

* a trajectory id (any value; trajectories keep the order in which their ids first appear);
* the trajectory's group (the same on every row of a trajectory): a positive integer, 1 = best, or a name
  ("good", "bad", "very bad") when the order of the names is given best first (``group_order``,
  ``--group-order 'good,bad,very bad'``); the names are kept as the dataset's ``group_names``;
* one column per feature (numeric);
* optionally state columns and action columns (numeric), and a step column that orders the rows of each
  trajectory (otherwise file order is kept).

Problems are reported with the column, the row (1-based data row; for CSV also the file line) and the value:
missing columns, a trajectory with rows in more than one group, non-numeric or empty values, a group name
missing from the given order, a delimiter that is not one character, a field longer than the CSV module's
limit (131,072 characters: usually a wrong delimiter or an unclosed quote), text that is not UTF-8.
"""

from __future__ import annotations

import csv as _csv
import math
import os
from pathlib import Path
from typing import Any, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from pbicrl._atomic import atomic_path, clean_stale_temporaries
from pbicrl.inference.data import Dataset, DatasetError, file_kind

__all__ = ["TableError", "read_csv", "read_parquet", "read_table", "columns_to_dataset", "write_csv", "check_delimiter"]

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
    group_order: str | Sequence[Any] | None = None,
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
    group_order : comma-separated str or sequence, optional
        The group names of ``group_col`` in preference order, best first (``["good", "bad", "very bad"]``):
        the ``k``-th name becomes group label ``k``, and the names of the groups present are stored as the
        dataset's ``group_names``. Without it the group column must hold positive integers (1 = best).
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
    ranked = _split(group_order)
    if ranked is not None:
        group = _ranked_groups(columns[group_col], ranked, group_col, source, where)
    else:
        try:
            group = numeric(group_col)
        except TableError as exc:
            seen = list(dict.fromkeys(("" if v is None else str(v)).strip() for v in columns[group_col]))
            shown = ",".join(v for v in seen[:5] if v) + (",..." if len(seen) > 5 else "")
            raise TableError(f"{exc}; group labels are positive integers (1 = best), or names whose order you give, "
                             f"best first, with --group-order (group_order=); the names found are "
                             f"--group-order '{shown}' in order of appearance") from None
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
        only = traj_group[0] if ranked is None else repr(ranked[traj_group[0] - 1])
        raise TableError(f"{source}: column '{group_col}': need at least two groups to rank, all trajectories are "
                         f"in group {only}")
    names = None if ranked is None else [ranked[k - 1] for k in sorted(set(traj_group))]
    return Dataset.from_trajectories(
        [F[r] for r in traj_rows], np.asarray(traj_group),
        states=None if S is None else [S[r] for r in traj_rows],
        actions=None if A is None else [A[r] for r in traj_rows],
        feature_names=feats, nominal_weights=nominal_weights, group_names=names)


def _ranked_groups(values: Sequence[Any], order: list[str], group_col: str, source: str,
                   where: Any) -> NDArray[np.float64]:
    """Group labels 1..K from group names and their order (best first)."""
    if len(order) < 2:
        raise TableError(f"{source}: --group-order: need at least two group names, best first, got {order}")
    dup = sorted({g for g in order if order.count(g) > 1})
    if dup:
        raise TableError(f"{source}: --group-order: repeated group name(s) {dup}")
    rank = {name: k + 1 for k, name in enumerate(order)}
    out = np.empty(len(values))
    for r, v in enumerate(values):
        key = "" if v is None else str(v).strip()
        if key not in rank:
            shown = "an empty value" if not key else repr(key)
            raise TableError(f"{source}: column '{group_col}', {where(r)}: group {shown} is not one of --group-order "
                             f"{', '.join(repr(g) for g in order)}")
        out[r] = rank[key]
    return out


def check_delimiter(delimiter: str) -> str:
    """A CSV field separator: one character (``"tab"`` or ``"\\t"`` for a tab); anything else is an error."""
    if not isinstance(delimiter, str):
        raise TableError(f"--delimiter: expected one character, got {delimiter!r}")
    named = {"tab": "\t", "\\t": "\t", "space": " ", "comma": ",", "semicolon": ";"}
    d = named.get(delimiter.lower() if len(delimiter) > 1 else delimiter, delimiter)
    if len(d) != 1:
        raise TableError(f"--delimiter: expected one character (e.g. ';' or 'tab'), got {delimiter!r} "
                         f"({len(delimiter)} characters)")
    if d in "\r\n\"" or d.isalnum():
        raise TableError(f"--delimiter: {delimiter!r} cannot separate fields (letters, digits, quotes and line breaks "
                         "are not allowed)")
    return d


def _check_input(p: Path, what: str) -> None:
    """A readable regular file, or an error that says what it is instead."""
    try:
        st = p.stat()
    except FileNotFoundError:
        raise FileNotFoundError(f"data: {p}: no such file") from None
    except OSError as exc:
        raise TableError(f"{p}: cannot be read ({exc.strerror or exc})") from None
    kind = file_kind(st.st_mode)
    if kind is not None:
        raise TableError(f"{p}: is a {kind}, not a {what} file")


def read_csv(path: str | os.PathLike[str], *, delimiter: str = ",", **kwargs: Any) -> Dataset:
    """Read a CSV file with a header row (see the module docstring; keyword arguments as
    :func:`columns_to_dataset`)."""
    p = Path(path)
    _check_input(p, "CSV")
    delimiter = check_delimiter(delimiter)
    reader: Any = None
    try:
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
    except _csv.Error as exc:
        line = reader.line_num if reader is not None else 1  # lines read so far, the bad one included
        if "field larger than field limit" in str(exc):
            raise TableError(f"{p}: line {line}: a field is longer than {_csv.field_size_limit():,} characters; "
                             f"is the delimiter right ({delimiter!r}; --delimiter) and every quote closed?") from None
        raise TableError(f"{p}: line {line}: not valid CSV ({exc})") from None
    except UnicodeDecodeError as exc:
        raise TableError(f"{p}: not UTF-8 text (byte {exc.start}: {exc.object[exc.start:exc.start + 1]!r}); "
                         "save the table as UTF-8 CSV") from None
    return columns_to_dataset(cols, source=str(p), lines=lines, **kwargs)


def read_parquet(path: str | os.PathLike[str], **kwargs: Any) -> Dataset:
    """Read a Parquet file (needs pyarrow: ``pip install "pbicrl[io]"``); keyword arguments as
    :func:`columns_to_dataset`."""
    p = Path(path)
    _check_input(p, "Parquet")
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
    clean_stale_temporaries(p)
    with atomic_path(p) as tmp:
        with open(tmp, "w", newline="", encoding="utf-8") as fh:  # newline="": the csv module ends the rows
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
    return p
