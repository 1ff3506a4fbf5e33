"""Sweeps: many independent runs from one grid, on any executor, resumable; ``pbicrl sweep CONFIG.toml``.

A sweep file (TOML)::

    [sweep]                       # optional
    name = "margins"              # prefix of the run directories (default: the task kind)
    out = "runs/margins"          # results root, relative to this file (default: runs/<file stem>; --out wins)

    [base]                        # the task kind and the settings every run shares
    kind = "infer"
    data = "example"              # a path relative to this file, or a shipped dataset
    iterations = 20000
    chains = 4

    [grid]                        # every combination of these values (Cartesian product)
    seed = [0, 1, 2]
    margins = [[0.0, 1.0], [0.0, 2.9]]

    [[runs]]                      # optional: variants merged over [base], each crossed with the grid;
    data = "wall.npz"             # a [runs.grid] table adds or replaces grid keys for that variant
    [runs.grid]
    margins = [[0.0, 6.0]]

Each run is a :class:`~pbicrl.experiments.tasks.Task`; its results go to ``<out>/<name>-<hash12>/``. Runs whose
results already exist (same config hash, same :data:`~pbicrl.experiments.tasks.CACHE_VERSION`, same settings
including defaults) are skipped, so a killed sweep restarted with the same command loses at most the runs that
were in flight; a run cached under other defaults is run again, with a note saying why. ``<out>/sweep.json``
lists every run with its settings, status, headline numbers and error. SIGTERM stops a sweep like Ctrl-C:
running tasks are stopped, finished runs kept, ``sweep.json`` written.
"""

from __future__ import annotations

import inspect
import itertools
import json
import math
import os
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pbicrl._atomic import read_toml, write_json
from pbicrl._moved import moved_to_cli
from pbicrl.experiments.tasks import (
    RESULT_FILE,
    OlderRuns,
    Task,
    TaskError,
    adopt_older_runs,
    canonical_json,
    clean_stale_temp_dirs,
    find_done,
    get_task_kind,
    read_result,
    stale_reason,
)

__all__ = ["RunRecord", "SweepResult", "SweepSpec", "expand_grid", "fmt_value", "load_sweep", "plan_sweep", "MAX_RUNS",
           "run_tasks", "MANIFEST"]

MANIFEST = "sweep.json"
"""Name of the file, in the results root, that lists every run of a sweep."""


# --------------------------------------------------------------------------------------------- records
@dataclass
class RunRecord:
    """One run of a sweep and what became of it.

    ``status`` is ``"cached"`` (finished before, skipped), ``"ran"``, ``"failed"`` or ``"pending"``.
    """

    task: Task
    settings: dict[str, Any] = field(default_factory=dict)
    status: str = "pending"
    out_dir: str | None = None
    result: Any = None
    error: str | None = None
    traceback: str | None = None
    runtime_s: float | None = None

    @property
    def ok(self) -> bool:
        return self.status in ("cached", "ran")

    def to_dict(self) -> dict[str, Any]:
        return {"dir": None if self.out_dir is None else Path(self.out_dir).name, "kind": self.task.kind,
                "config_hash": self.task.config_hash, "settings": self.settings, "status": self.status,
                "runtime_s": self.runtime_s, "error": self.error, "result": self.result} | (
                    {"traceback": self.traceback} if self.traceback else {})


@dataclass
class SweepResult:
    """All runs of a sweep, in the order given, with the executor and wall time."""

    root: Path
    records: list[RunRecord]
    executor: str = ""
    wall_s: float = 0.0
    interrupted: bool = False
    older: OlderRuns = field(default_factory=OlderRuns)

    @property
    def failed(self) -> list[RunRecord]:
        return [r for r in self.records if r.status == "failed"]

    @property
    def ok(self) -> bool:
        """Every run finished (now or before)."""
        return all(r.ok for r in self.records)

    def counts(self) -> dict[str, int]:
        out = {"total": len(self.records)}
        for status in ("ran", "cached", "failed", "pending"):
            out[status] = sum(r.status == status for r in self.records)
        return out

    def to_dict(self) -> dict[str, Any]:
        return {"format": 1, "root": str(self.root), "executor": self.executor, "wall_s": self.wall_s,
                "interrupted": self.interrupted, "counts": self.counts(),
                "runs": [r.to_dict() for r in self.records], "older_cache_versions": self.older.to_dict()}

    def save(self, path: str | os.PathLike[str] | None = None) -> Path:
        """Write ``sweep.json`` (default: in the results root) atomically."""
        path = Path(path) if path is not None else self.root / MANIFEST
        return write_json(path, self.to_dict(), default=str)

    def table(self, columns: Sequence[str] | None = None) -> str:
        """One row per run: the settings that vary, status, time and headline numbers."""
        return _table(self.records, columns)


# --------------------------------------------------------------------------------------------- formatting
def fmt_value(value: Any) -> str:
    """A setting or headline number as a table cell (short; ``-`` for None)."""
    if value is None:
        return "-"
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return f"{value:.4g}" if math.isfinite(value) else str(value)
    if isinstance(value, (list, tuple)):
        if all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value):
            return "/".join(f"{v:.3g}" if isinstance(v, float) else str(v) for v in value)
        return "[" + ", ".join(fmt_value(v) for v in value) + "]"
    if isinstance(value, Mapping):
        return "{" + ", ".join(f"{k}={fmt_value(v)}" for k, v in value.items()) + "}"
    text = str(value)
    return text if len(text) <= 40 else "..." + text[-37:]


def _varying_keys(records: Sequence[RunRecord]) -> list[str]:
    """Settings keys whose values differ between runs (or all settings keys for a single run)."""
    keys: list[str] = []
    for r in records:
        for k in r.settings:
            if k not in keys:
                keys.append(k)
    if len(records) <= 1:
        return keys
    return [k for k in keys if len({canonical_json(r.settings.get(k)) for r in records}) > 1]


def _headline_columns(records: Sequence[RunRecord]) -> list[str]:
    cols: list[str] = []
    for r in records:
        try:
            declared = r.task.spec.columns
        except TaskError:
            declared = ()
        if declared:
            keys = list(declared)
        elif isinstance(r.result, Mapping):
            keys = [k for k, v in r.result.items() if v is None or isinstance(v, (int, float, str, bool))]
        else:
            keys = []
        for k in keys:
            if k not in cols:
                cols.append(k)
    return cols


def _table(records: Sequence[RunRecord], columns: Sequence[str] | None = None) -> str:
    settings = _varying_keys(records)
    cols = list(columns) if columns is not None else [c for c in _headline_columns(records) if c not in settings]
    head = ["#", *settings, "status", "time_s", *cols]
    rows = []
    for i, r in enumerate(records):
        res = r.result if isinstance(r.result, Mapping) else {}
        rows.append([str(i), *(fmt_value(r.settings.get(k)) for k in settings), r.status,
                     "-" if r.runtime_s is None else f"{r.runtime_s:.1f}", *(fmt_value(res.get(c)) for c in cols)])
    widths = [max(len(head[j]), *(len(row[j]) for row in rows)) if rows else len(head[j]) for j in range(len(head))]
    lines = ["  ".join(h.ljust(w) for h, w in zip(head, widths)).rstrip(), "  ".join("-" * w for w in widths)]
    lines += ["  ".join(c.ljust(w) for c, w in zip(row, widths)).rstrip() for row in rows]
    return "\n".join(lines)


# --------------------------------------------------------------------------------------------- running
def run_tasks(
    tasks: Sequence[Task],
    root: str | os.PathLike[str],
    executor: Any = "local",
    *,
    workers: int | None = None,
    settings: Sequence[Mapping[str, Any]] | None = None,
    force: bool = False,
    progress: bool = True,
    manifest: bool | str | os.PathLike[str] = True,
    on_outcome: Callable[[RunRecord], None] | None = None,
) -> SweepResult:
    """Run tasks, skipping those already finished under ``root``; the entry point of sweeps and reproductions.

    Parameters
    ----------
    tasks : sequence of Task
        Identical tasks (same hash) run once.
    root : path
        Results root; each task writes ``root/<name>-<hash12>/``.
    executor : Executor or {"local", "serial", "ray"}
        See :func:`pbicrl.experiments.executors.make_executor`.
    workers : int, optional
        Worker count when ``executor`` is a name.
    settings : sequence of dict, optional
        What distinguishes each run, for the table and ``sweep.json`` (default: the config keys that vary).
    force : bool
        Run everything again, replacing finished results.
    progress : bool
        One progress bar for the sweep (stderr); failures are printed as they happen. With the serial and local
        executors the bar also shows the sampler iterations of the runs in progress (done / planned, or done
        so far in runs until converged), updated twice a second, and says when a run compiles the sampler.
    manifest : bool or path
        Write ``sweep.json`` (to ``root`` or this path), updated as runs finish.
    on_outcome : callable, optional
        Called with each :class:`RunRecord` once it is finished, cached or failed.

    Returns
    -------
    SweepResult
        Also when interrupted (``KeyboardInterrupt`` is re-raised after ``sweep.json`` is written).
    """
    from pbicrl.experiments.executors import Executor, make_executor

    if not isinstance(executor, Executor):
        executor = make_executor(executor, workers)
    root = Path(root).absolute()
    tasks = list(tasks)
    if settings is not None and len(settings) != len(tasks):
        raise ValueError(f"settings: expected one entry per task ({len(tasks)}), got {len(settings)}")
    if settings is None:
        settings = _auto_settings(tasks)
    records = [RunRecord(t, dict(s)) for t, s in zip(tasks, settings)]
    result = SweepResult(root, records, executor.describe())
    manifest_path = None if manifest is False else (root / MANIFEST if manifest is True else Path(manifest))

    root.mkdir(parents=True, exist_ok=True)
    clean_stale_temp_dirs(root)
    result.older = adopt_older_runs(root)
    _note_older(result.older, root, progress)
    by_hash: dict[str, list[RunRecord]] = {}
    for r in records:
        by_hash.setdefault(r.task.config_hash, []).append(r)
    todo: list[Task] = []
    for group in by_hash.values():
        done = None if force else find_done(group[0].task, root)
        if done is not None:
            rec = json.loads((done / RESULT_FILE).read_text())
            for r in group:
                r.status, r.out_dir, r.result, r.runtime_s = "cached", str(done), rec.get("result"), rec.get("runtime_s")
                if on_outcome is not None:
                    on_outcome(r)
        else:
            todo.append(group[0].task)
            if not force:
                _note_stale(group[0].task, root, progress)

    bar = _bar(len(by_hash), len(by_hash) - len(todo), progress)
    status = None if bar is None else _BarStatus(bar)
    counter = None
    if status is not None and todo:  # nothing finishes while the workers compile the samplers: say so
        from pbicrl.analysis.margins import COMPILING_NOTE
        from pbicrl.inference.samplers.driver import RunsCounter

        bar.set_description(f"sweep ({COMPILING_NOTE})")
        counter = RunsCounter(status.update)
    t0 = time.perf_counter()
    last_save = 0.0
    n_failed = 0
    if counter is not None and "counter" not in inspect.signature(executor.run).parameters:
        counter = None  # an executor of the user's, written before executors counted iterations
    outcomes = executor.run(todo, root, force=force, **({} if counter is None else {"counter": counter}))
    try:
        if manifest_path is not None:
            result.save(manifest_path)
        for task, outcome in outcomes:
            n_failed += outcome["status"] == "failed"
            for r in by_hash[task.config_hash]:
                r.status, r.out_dir, r.result = outcome["status"], outcome.get("out_dir"), outcome.get("result")
                r.error, r.traceback, r.runtime_s = outcome.get("error"), outcome.get("traceback"), outcome.get("runtime_s")
                if on_outcome is not None:
                    on_outcome(r)
            if outcome["status"] == "failed":
                msg = f"failed: {task.dir_name}: {outcome.get('error')}"
                if bar is not None:
                    bar.write(msg, file=sys.stderr)
                else:
                    print(msg, file=sys.stderr)
            if status is not None:
                status.started()
                status.failed = n_failed
                bar.update(1)
                status.show()
                if counter is not None:
                    counter.tick(force=True)  # the finished run's share is out
            result.wall_s = time.perf_counter() - t0
            if manifest_path is not None and time.monotonic() - last_save > 2.0:
                result.save(manifest_path)
                last_save = time.monotonic()
    except KeyboardInterrupt:
        result.interrupted = True
        raise
    finally:
        outcomes.close()  # stops the workers now if we leave early (an interrupt or an error here)
        if bar is not None:
            bar.close()
        clean_stale_temp_dirs(root)  # also those of processes killed just before this sweep started
        result.wall_s = time.perf_counter() - t0
        if manifest_path is not None:
            result.save(manifest_path)
    return result


def _note_older(older: OlderRuns, root: Path, progress: bool) -> None:
    """Say which runs of older cache versions were adopted and which are kept but not reused (and why)."""
    if not progress:
        return  # sweep.json lists them under older_cache_versions
    if older.adopted:
        print(f"note: {len(older.adopted)} finished run(s) in {root} made by an older pbicrl are taken over "
              "(settings renamed, numbers unchanged)", file=sys.stderr)
    for d, why in older.not_reused:
        print(f"note: {d.name}: made by an older pbicrl, not reused ({why}); kept - delete it if you no longer "
              "need it", file=sys.stderr)


def _note_stale(task: Task, root: Path, progress: bool) -> None:
    """Say why a finished run of the same hash is not reused (made under other defaults or cache version)."""
    d = task.out_dir(root)
    if not d.is_dir():
        return
    rec = read_result(d)
    reason = stale_reason(task, rec) if rec is not None else None
    if reason is not None and progress:
        print(f"note: {d.name}: cached result not reused ({reason}); running it again", file=sys.stderr)


def _auto_settings(tasks: Sequence[Task]) -> list[dict[str, Any]]:
    """Per task, the config entries (and kind) that are not the same for every task."""
    kinds = {t.kind for t in tasks}
    vary: dict[str, list[str]] = {}
    for kind in kinds:
        same = [t for t in tasks if t.kind == kind]
        keys: list[str] = []
        for t in same:
            keys += [k for k in t.config if k not in keys and not k.endswith("_sha256")]  # derived from a path
        vary[kind] = [k for k in keys if len({canonical_json(t.config.get(k)) for t in same}) > 1]
    return [({"kind": t.kind} if len(kinds) > 1 else {}) | {k: t.config.get(k) for k in vary[t.kind]} for t in tasks]


class _BarStatus:
    """The sweep bar's description and postfix: failures so far and the progress inside the runs in progress
    (a :class:`~pbicrl.inference.samplers.driver.RunsCounter`'s ``on_change``)."""

    def __init__(self, bar: Any) -> None:
        self.bar = bar
        self.failed = 0
        self.runs: Any = None  # the last RunsSnapshot
        self._text: str | None = None
        self._started = False
        self._noted = False

    def update(self, runs: Any) -> None:
        self.runs = runs
        if runs.done or runs.done_until_converged:
            self.started()  # a run samples: the compiling note of the description is no longer needed
        self.show()

    def started(self) -> None:
        if not self._started:
            self.bar.set_description("sweep", refresh=False)
            self._started = True

    def show(self) -> None:
        from tqdm import tqdm

        def size(n: int) -> str:
            return tqdm.format_sizeof(n) if n else "0"

        parts = []
        r = self.runs
        if r is not None:
            if r.compiling:
                if not self._noted:  # once: the compile takes ~15 s, minutes on a loaded machine
                    from pbicrl.inference.samplers.driver import COMPILE_NOTE

                    self.bar.write(COMPILE_NOTE, file=sys.stderr)
                    self._noted = True
                parts.append(f"compiling the sampler ({r.compiling} run{'s' if r.compiling != 1 else ''})")
            if r.planned > 0:
                parts.append(f"in runs {size(r.done)}/{size(r.planned)} it "
                             f"({100 * r.done / r.planned:.0f}%)")
            if r.done_until_converged > 0:
                parts.append(f"{size(r.done_until_converged)} it in runs until converged")
        if self.failed:
            parts.append(f"failed={self.failed}")
        text = ", ".join(parts)
        if text != self._text:
            self._text = text
            self.bar.set_postfix_str(text, refresh=True)


def _bar(total: int, initial: int, enabled: bool) -> Any:
    if not enabled:
        return None
    from tqdm.auto import tqdm

    class _Bar(tqdm):  # type: ignore[misc, valid-type]
        monitor_interval = 0  # no monitor thread: the local pool forks while the bar is open

    return _Bar(total=total, initial=initial, desc="sweep", unit="run", file=sys.stderr, dynamic_ncols=True)


# --------------------------------------------------------------------------------------------- sweep files
@dataclass(frozen=True)
class SweepSpec:
    """An expanded sweep file: the tasks, what varies between them, and where results go."""

    tasks: list[Task]
    settings: list[dict[str, Any]]
    out: Path
    name: str
    source: Path | None = None


MAX_RUNS = 100_000
"""Most runs one sweep file may expand to (each is a process's worth of work and a directory)."""


def expand_grid(base: Mapping[str, Any], grid: Mapping[str, Sequence[Any]] | None = None,
                runs: Sequence[Mapping[str, Any]] | None = None) -> list[tuple[dict[str, Any], dict[str, Any]]]:
    """Every combination of ``grid`` values over ``base`` (crossed with each ``runs`` variant).

    Returns
    -------
    list of (config, settings)
        ``config`` is the merged table (including ``kind``); ``settings`` holds the grid values and the
        variant's keys of that combination.
    """
    out = []
    variants = list(runs) if runs else [{}]
    grids = []
    for i, variant in enumerate(variants):
        where = f"runs[{i}]" if runs else "grid"
        variant = dict(variant)
        vgrid = dict(grid or {})
        extra = variant.pop("grid", None)
        if extra is not None:
            if not isinstance(extra, Mapping):
                raise TaskError(f"{where}.grid: expected a table of lists")
            vgrid.update(extra)
        for key, values in vgrid.items():
            if not isinstance(values, list) or not values:
                raise TaskError(f"grid.{key}: expected a non-empty list of values, got {values!r}")
        grids.append((variant, vgrid))
    # the size is a product of list lengths: counted before anything is built (60**8 runs would fill the memory)
    total = sum(math.prod(len(v) for v in vgrid.values()) for _, vgrid in grids)
    if total > MAX_RUNS:
        sizes = " x ".join(str(len(v)) for v in grids[0][1].values()) if len(grids) == 1 else f"{len(grids)} variants"
        raise TaskError(f"grid: {total:,} runs ({sizes}), more than {MAX_RUNS:,}; split the sweep or shorten the "
                        "lists")
    for variant, vgrid in grids:
        keys = list(vgrid)
        for combo in itertools.product(*(vgrid[k] for k in keys)):
            point = dict(zip(keys, combo))
            out.append((dict(base) | variant | point, variant | point))
    return out


def load_sweep(path: str | os.PathLike[str], *, out: str | os.PathLike[str] | None = None) -> SweepSpec:
    """Read and expand a sweep file (see the module docstring); errors name the key."""
    path = Path(path)
    raw = read_toml(path, "sweep config", error=TaskError)
    unknown = set(raw) - {"sweep", "base", "grid", "runs"}
    if unknown:
        raise TaskError(f"sweep config: unknown table(s) {', '.join(sorted(unknown))}; expected [sweep], [base], [grid], [[runs]]")
    meta, base, grid, runs = raw.get("sweep", {}), raw.get("base", {}), raw.get("grid", {}), raw.get("runs")
    for name, table in (("sweep", meta), ("base", base), ("grid", grid)):
        if not isinstance(table, dict):
            raise TaskError(f"sweep config: [{name}] must be a table")
    if runs is not None and (not isinstance(runs, list) or not all(isinstance(r, dict) for r in runs)):
        raise TaskError("sweep config: runs must be an array of tables ([[runs]])")
    bad = set(meta) - {"name", "out"}
    if bad:
        raise TaskError(f"sweep config: [sweep] key '{min(bad)}': unknown; known keys are name, out")
    here = path.parent
    tasks: list[Task] = []
    settings: list[dict[str, Any]] = []
    seen: dict[str, int] = {}
    name = meta.get("name")
    if name is not None and not isinstance(name, str):
        raise TaskError(f"sweep.name: expected a string, got {name!r}")
    for i, (config, point) in enumerate(expand_grid(base, grid, runs)):
        kind = config.pop("kind", None)
        if kind is None:
            raise TaskError("base.kind: missing; name the task kind, e.g. kind = \"infer\"")
        if not isinstance(kind, str):
            raise TaskError(f"base.kind: expected a string, got {kind!r}")
        spec = get_task_kind(kind)
        for key in spec.path_keys:  # relative paths are relative to the sweep file when they exist there
            value = config.get(key)
            if isinstance(value, str) and not os.path.isabs(value) and (here / value).exists():
                config[key] = str((here / value).resolve())
        try:
            task = Task(kind, config, name=name)
        except TaskError as exc:
            where = ", ".join(f"{k}={fmt_value(v)}" for k, v in point.items())
            raise TaskError(f"{exc} (run {i}{': ' + where if where else ''})") from None
        if task.config_hash in seen:
            continue  # the same run reached twice (e.g. only an unhashed key varies): once is enough
        seen[task.config_hash] = len(tasks)
        tasks.append(task)
        settings.append(point)
    if not tasks:
        raise TaskError("sweep config: no runs (is a [grid] list empty?)")
    if out is not None:
        root = Path(out)
    elif "out" in meta:
        if not isinstance(meta["out"], str):
            raise TaskError(f"sweep.out: expected a directory path, got {meta['out']!r}")
        root = here / meta["out"]
    else:
        root = Path("runs") / path.stem
    return SweepSpec(tasks, settings, root, name or tasks[0].kind, path)


def plan_sweep(spec: SweepSpec, *, force: bool = False, progress: bool = True) -> SweepResult:
    """What running ``spec`` would do, doing nothing: every run ``"cached"`` (finished, or an older cache
    version's run that would be taken over) or ``"pending"``; ``progress`` prints the notes on older runs."""
    older = adopt_older_runs(spec.out, dry_run=True)  # what a real run would take over; nothing moves
    _note_older(older, spec.out, progress)
    records = []
    for task, point in zip(spec.tasks, spec.settings):
        done = None if force else find_done(task, spec.out)
        taken_over = not force and task.out_dir(spec.out) in older.adopted
        rec = RunRecord(task, point, "cached" if done is not None or taken_over else "pending")
        if done is not None:
            saved = json.loads((done / RESULT_FILE).read_text())
            rec.result, rec.runtime_s, rec.out_dir = saved.get("result"), saved.get("runtime_s"), str(done)
        records.append(rec)
    return SweepResult(spec.out, records, executor="dry run", older=older)


__getattr__ = moved_to_cli(__name__, {"add_subcommands": "pbicrl.cli.sweep"})  # the command line moved
