"""One run of an experiment as a task: a JSON config in, a results directory out.

A :class:`Task` is a task *kind* (a registered name such as ``"infer"``, or an importable
``"package.module:function"``) plus a JSON-serialisable config. Its :attr:`Task.config_hash` (SHA-256 of the
canonical JSON of the format version, :data:`CACHE_VERSION`, the kind and its version, and the config entries
that are hashed: not the ``unhashed`` keys, not those equal to their default) identifies the run: the
results live in ``<root>/<name>-<hash[:12]>/`` with a ``result.json`` that records the full hash, the cache
version and the full config, so a sweep restarted with the same settings recognises finished runs and skips
them.

A finished run is reused only if it was made under the same defaults: its stored cache version must be
:data:`CACHE_VERSION` (bumped by hand when a default changes the numbers of every kind, or when settings are
renamed), and every setting it recorded must equal the current task's (so a run made under an old default of
a key it did not set, e.g. the prior, is run again rather than silently reused; settings added since keep
their default). Runs of an older cache version whose bump only renamed settings are *adopted* by
:func:`adopt_older_runs` (renamed, re-hashed, their headline numbers recomputed from their files); the others
are kept on disk, reported, and not reused.

A kind's function has the signature ``run(config: dict, out_dir: Path) -> dict``: it writes whatever files it
likes into ``out_dir`` (an empty directory that only becomes visible under its final name, together with
``result.json``, once the function has returned) and returns a small JSON-serialisable dict of headline
numbers. Functions are named by import path, so workers on other processes or machines import them without
needing the registry. Registering a new kind::

    from pbicrl.experiments.tasks import register_task

    def run_my_study(config: dict, out_dir: Path) -> dict:   # top level, importable
        ...
        return {"score": 0.93}

    register_task("my-study", run_my_study, columns=("score",))

This module is the engine (the task, its hash, results on disk, running one task, adopting older runs); the
registry of kinds and the worker's environment are in :mod:`pbicrl.experiments.registry`, the built-in kinds
(``infer``, ``reproduce-icl``, ``selftest``) in :mod:`pbicrl.experiments.kinds`. Their public names are
re-exported here, where they were before the split.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import shutil
import socket
import tempfile
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping

from pbicrl._atomic import apply_mode, fsync_tree, pid_alive, write_json
from pbicrl.experiments.kinds import (INFER_EXTRA, file_sha256, infer_config_of_reproduce_run, infer_result,
                                      prepare_data, prepare_infer, rename_v2, run_infer, run_selftest,
                                      summarize_infer)
from pbicrl.experiments.registry import (TaskError, TaskKind, get_task_kind, import_target, in_task_worker,
                                         register_task, task_jobs, task_kinds, task_worker)

__all__ = [
    "TASK_FORMAT", "CACHE_VERSION", "RESULT_FILE", "Task", "TaskKind", "TaskError", "register_task", "get_task_kind",
    "task_kinds", "canonical_json", "in_task_worker", "task_jobs", "task_worker", "execute_task", "finalize_task",
    "write_shipped", "find_done", "stale_reason", "read_result", "load_result", "clean_stale_temp_dirs", "started_hashes",
    "adopt_older_runs", "OlderRuns", "result_record", "error_text", "import_target",
    # the built-in kinds (pbicrl.experiments.kinds), re-exported where they were before the split
    "file_sha256", "prepare_data", "run_infer", "prepare_infer", "summarize_infer", "infer_result",
    "infer_config_of_reproduce_run", "rename_v2", "INFER_EXTRA", "run_selftest",
]

TASK_FORMAT = 1
"""Version of the hashed task description; bump when the meaning of a config changes for every kind."""

CACHE_VERSION = 3
"""Version of the numbers finished runs hold; part of every task hash and stored in each ``result.json``.

Bump it when a change of defaults (the prior, the likelihood, a sampler setting) or of the code makes
earlier results different from what the same config gives now: finished runs of older versions are then
run again instead of being reused. A bump that only renames settings registers a migration
(:data:`_RENAMES`) instead, so that :func:`adopt_older_runs` takes the finished runs over.
Version 2: runs cached before defaults were recorded with each run. Version 3: one settings vocabulary
(:class:`pbicrl.config.InferConfig`'s names; the reproduction's ``reproduce-run`` kind became ``infer``,
``dataset`` became ``data``, ``n_per_group`` ``demos_per_group``, ``sample_seed`` ``demos_seed``) and the
``infer`` kind's headline numbers include the reproduction's; version-2 runs are adopted.
"""

RESULT_FILE = "result.json"
_TMP_PREFIX = ".tmp-"

# --------------------------------------------------------------------------------------------- the task
def _plain(value: Any, where: str) -> Any:
    """JSON-ready copy: numpy scalars/arrays -> Python, tuples -> lists, paths -> str; anything else is an error."""
    if value is None or isinstance(value, (bool, str)):
        return value
    if isinstance(value, int):
        return int(value)
    if isinstance(value, float):
        if not math.isfinite(value):
            raise TaskError(f"{where}: {value} is not a finite number")
        return float(value)
    if isinstance(value, os.PathLike):
        return os.fspath(value)
    if isinstance(value, Mapping):
        out = {}
        for k, v in value.items():
            if not isinstance(k, str):
                raise TaskError(f"{where}: keys must be strings, got {k!r}")
            out[k] = _plain(v, f"{where}.{k}" if where else k)
        return out
    if isinstance(value, (list, tuple)):
        return [_plain(v, f"{where}[{i}]") for i, v in enumerate(value)]
    if hasattr(value, "tolist") and hasattr(value, "dtype"):  # numpy scalar or array, without importing numpy
        return _plain(value.tolist(), where)
    raise TaskError(f"{where or 'config'}: {type(value).__name__} is not JSON-serialisable")


def _integral(value: Any) -> Any:
    if isinstance(value, float) and value.is_integer() and abs(value) < 2**53:
        return int(value)
    if isinstance(value, dict):
        return {k: _integral(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_integral(v) for v in value]
    return value


def canonical_json(value: Any) -> str:
    """Canonical JSON (sorted keys, no spaces, ASCII) of a JSON-ready value; the input of the task hash.

    Whole floats are written as integers, so ``margins = [0, 1]`` and ``[0.0, 1.0]`` are the same run.
    """
    return json.dumps(_integral(_plain(value, "")), sort_keys=True, separators=(",", ":"), ensure_ascii=True,
                      allow_nan=False)


def _safe_name(name: str) -> str:
    out = "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in name).strip("._") or "task"
    return out[:80]


@dataclass(frozen=True, eq=False)
class Task:
    """One run: a task kind and its config.

    The config is validated and normalised by the kind's ``prepare`` when the task is created, so
    ``Task("infer", {"data": "example"})`` and a config that spells out every default are the same run.

    Parameters
    ----------
    kind : str
        Registered kind (:func:`task_kinds`) or ``"package.module:function"``.
    config : dict
        JSON-serialisable settings.
    name : str, optional
        Readable prefix of the output directory (default: the kind); not part of the hash.
    """

    kind: str
    config: dict = field(default_factory=dict)
    name: str | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.kind, str) or not self.kind:
            raise TaskError(f"kind: expected a task kind name, got {self.kind!r}")
        if not isinstance(self.config, Mapping):
            raise TaskError(f"config: expected a table of settings, got {type(self.config).__name__}")
        if self.name is not None and not isinstance(self.name, str):
            raise TaskError(f"name: expected a string, got {self.name!r}")
        spec = get_task_kind(self.kind)
        config = _plain(dict(self.config), "")
        if spec.prepare is not None:
            config = _plain(spec.prepare(config), "")
        object.__setattr__(self, "config", config)
        # Computed here and carried along (pickled with the task): workers need neither the registry nor `prepare`.
        unhashed = set(spec.unhashed)
        defaults = _plain(spec.defaults(), "defaults") if spec.defaults is not None else {}
        hashed = {k: v for k, v in config.items()
                  if k not in unhashed and not (k in defaults and canonical_json(v) == canonical_json(defaults[k]))}
        text = canonical_json({"format": TASK_FORMAT, "cache": CACHE_VERSION, "kind": self.kind,
                               "version": spec.version, "config": hashed})
        object.__setattr__(self, "_hash", hashlib.sha256(text.encode()).hexdigest())
        object.__setattr__(self, "_target", spec.target)
        object.__setattr__(self, "_compare", {k: v for k, v in config.items() if k not in unhashed})
        object.__setattr__(self, "_defaults", {k: v for k, v in defaults.items() if k not in unhashed})

    @property
    def spec(self) -> TaskKind:
        """The :class:`TaskKind` (looked up in the registry of this process)."""
        return get_task_kind(self.kind)

    @property
    def target(self) -> str:
        """``"module:function"`` that runs the task."""
        return self._target  # type: ignore[attr-defined]

    @property
    def config_hash(self) -> str:
        """SHA-256 (hex) of the canonical JSON of format, cache and kind versions, kind, and the hashed config
        entries."""
        return self._hash  # type: ignore[attr-defined]

    @property
    def dir_name(self) -> str:
        """``<name or kind>-<hash[:12]>``."""
        return f"{_safe_name(self.name or self.kind.rsplit(':', 1)[-1])}-{self.config_hash[:12]}"

    def out_dir(self, root: str | os.PathLike[str]) -> Path:
        """The results directory of this task under ``root``."""
        return Path(root) / self.dir_name

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Task) and other.config_hash == self.config_hash

    def __hash__(self) -> int:
        return hash(self.config_hash)

    def __repr__(self) -> str:
        return f"Task({self.kind!r}, {self.dir_name})"


# --------------------------------------------------------------------------------------------- results on disk
def read_result(directory: str | os.PathLike[str]) -> dict | None:
    """The ``result.json`` record in ``directory``, or None when it is missing or unreadable."""
    directory = Path(directory)
    try:
        return json.loads((directory / RESULT_FILE).read_text())
    except (OSError, ValueError):
        return None


def stale_reason(task: Task, record: Mapping[str, Any] | None) -> str | None:
    """Why a ``result.json`` record cannot stand for ``task`` (None if it can).

    Not the same full hash; another :data:`CACHE_VERSION`; or a setting recorded with another value than
    the task's (typically a default that changed since: the hash leaves out values equal to the default).
    A setting the record lacks is fine if the task has it at its default (the kind gained a setting).
    """
    if record is None:
        return "no readable result.json"
    if record.get("config_hash") != task.config_hash:
        return "another configuration (config hash differs)"
    version = record.get("cache_version", 1)
    if version != CACHE_VERSION:
        return f"made by cache version {version}, this pbicrl is at {CACHE_VERSION}"
    stored = record.get("config")
    if not isinstance(stored, Mapping):
        return "result.json records no config"
    current: dict[str, Any] = task._compare  # type: ignore[attr-defined]
    defaults: dict[str, Any] = task._defaults  # type: ignore[attr-defined]
    for key, value in current.items():
        if key in stored:
            if canonical_json(stored[key]) != canonical_json(value):
                return f"made with {key}={canonical_json(stored[key])}, now {key}={canonical_json(value)}"
        elif key in defaults and canonical_json(value) != canonical_json(defaults[key]):
            return f"made before setting {key!r} existed, now {key}={canonical_json(value)}"
    return None


def find_done(task: Task, root: str | os.PathLike[str]) -> Path | None:
    """The finished results directory of ``task`` under ``root`` (any name ending in its hash), or None.

    A run is finished iff its directory holds a ``result.json`` that records the same full config hash and
    for which :func:`stale_reason` finds nothing (same cache version, same settings).
    """
    root = Path(root)
    first = task.out_dir(root)
    candidates = [first] + sorted(p for p in root.glob(f"*-{task.config_hash[:12]}") if p != first) if root.is_dir() else []
    for d in candidates:
        if d.name.startswith(".") or not d.is_dir():
            continue
        if stale_reason(task, read_result(d)) is None:
            return d
    return None


def load_result(task: Task, root: str | os.PathLike[str]) -> dict | None:
    """The ``result.json`` record of a finished task (``record["result"]`` is what its function returned)."""
    d = find_done(task, root)
    return None if d is None else read_result(d)


def _host() -> str:
    return _safe_name(socket.gethostname()).replace(".", "_")[:40]


def _make_temp_dir(root: Path, task: Task) -> Path:
    """A private directory ``.tmp-<hash12>.<host>.<pid>.<random>`` in ``root`` (so stale ones can be recognised)."""
    root.mkdir(parents=True, exist_ok=True)
    return Path(tempfile.mkdtemp(prefix=f"{_TMP_PREFIX}{task.config_hash[:12]}.{_host()}.{os.getpid()}.", dir=root))


def started_hashes(root: str | os.PathLike[str]) -> set[str]:
    """The 12-character hash prefixes of the tasks that have a temporary directory under ``root`` (started,
    not finished, or killed)."""
    return {p.name[len(_TMP_PREFIX):].split(".")[0] for p in Path(root).glob(f"{_TMP_PREFIX}*")}


def clean_stale_temp_dirs(root: str | os.PathLike[str]) -> list[Path]:
    """Remove temporary run directories left in ``root`` by killed processes of this host; returns them.

    Directories of processes that are still alive (a concurrent sweep) and of other hosts are kept.
    """
    root = Path(root)
    removed: list[Path] = []
    if not root.is_dir():
        return removed
    host = _host()
    for p in root.glob(f"{_TMP_PREFIX}*"):
        parts = p.name[len(_TMP_PREFIX):].split(".")
        if len(parts) < 4 or parts[1] != host or not parts[2].isdigit():
            continue
        if not pid_alive(int(parts[2])):
            shutil.rmtree(p, ignore_errors=True)
            removed.append(p)
    return removed


def finalize_task(task: Task, root: Path, work: Path, result: Any, *, runtime_s: float, force: bool = False) -> Path:
    """Write ``result.json`` into ``work/run`` and rename it to the task's directory (the atomic step).

    If a finished directory with the same hash appeared meanwhile (a concurrent or orphaned worker) it is
    kept and this copy discarded, unless ``force``.
    """
    run_dir = work / "run"
    (run_dir / RESULT_FILE).write_text(json.dumps(result_record(task, result, runtime_s), indent=2) + "\n")
    fsync_tree(run_dir)
    apply_mode(run_dir, directory=True)  # mkdtemp makes 0700; the results should be as readable as any new directory
    final = task.out_dir(root)
    if final.exists():
        if stale_reason(task, read_result(final)) is None and not force:
            shutil.rmtree(work, ignore_errors=True)
            return final
        os.replace(final, work / "old")  # stale or forced: move aside first, then the new one takes its place
    try:
        os.replace(run_dir, final)
    except OSError:
        # Another process finished the same run between the check above and the rename: keep its copy.
        if stale_reason(task, read_result(final)) is not None:
            raise
    shutil.rmtree(work, ignore_errors=True)
    return final


def result_record(task: Task, result: Any, runtime_s: float, **more: Any) -> dict[str, Any]:
    """The ``result.json`` record of a finished run of ``task``."""
    return {
        "format": TASK_FORMAT, "cache_version": CACHE_VERSION, "kind": task.kind, "target": task.target,
        "name": task.name, "config_hash": task.config_hash, "config": task.config, "result": _plain(result, "result"),
        "runtime_s": float(runtime_s), "finished_at": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "host": socket.gethostname(),
    } | more



def _outcome(task: Task, status: str, *, out_dir: Path | None = None, result: Any = None, error: str | None = None,
             tb: str | None = None, runtime_s: float = 0.0) -> dict[str, Any]:
    return {"config_hash": task.config_hash, "status": status, "out_dir": None if out_dir is None else str(out_dir),
            "result": result, "error": error, "traceback": tb, "runtime_s": runtime_s}


def error_text(exc: BaseException) -> str:
    """``"ExceptionType: first line of the message"`` (what a failed run's outcome and reports show)."""
    msg = str(exc).strip()
    return f"{type(exc).__name__}: {msg.splitlines()[0]}" if msg else type(exc).__name__


def execute_task(task: Task, root: str | os.PathLike[str] | None, *, force: bool = False, jobs: int = 1
                 ) -> dict[str, Any]:
    """Run one task in this process, as a worker with ``jobs`` cores; never raises for a failing task.

    With ``root`` the results directory is created under it atomically; with ``root=None`` the task runs in a
    local temporary directory and the outcome carries its files as ``outcome["files"]`` (relative path ->
    bytes) for the caller to write with :func:`write_shipped` (executors whose workers cannot see ``root``).

    Returns
    -------
    dict
        ``status`` ("ran" or "failed"), ``result``, ``error`` and ``traceback``, ``runtime_s``, ``out_dir``.
    """
    t0 = time.perf_counter()
    ship = root is None
    work = Path(tempfile.mkdtemp(prefix="pbicrl-task-")) if ship else _make_temp_dir(Path(root), task)  # type: ignore[arg-type]
    try:
        (work / "run").mkdir()
        with task_worker(jobs):
            fn = import_target(task.target)
            result = fn(dict(task.config), work / "run")
        result = _plain(result if result is not None else {}, "result")
        runtime = time.perf_counter() - t0
        if ship:
            files = {str(p.relative_to(work / "run")): p.read_bytes()
                     for p in sorted((work / "run").rglob("*")) if p.is_file()}
            out = _outcome(task, "ran", result=result, runtime_s=runtime)
            out["files"] = files
            return out
        final = finalize_task(task, Path(root), work, result, runtime_s=runtime, force=force)  # type: ignore[arg-type]
        return _outcome(task, "ran", out_dir=final, result=result, runtime_s=runtime)
    except Exception as exc:  # a failing run is reported, not raised: the sweep goes on
        return _outcome(task, "failed", error=error_text(exc), tb=traceback.format_exc(),
                        runtime_s=time.perf_counter() - t0)
    finally:
        if work.exists():
            shutil.rmtree(work, ignore_errors=True)


def write_shipped(task: Task, root: str | os.PathLike[str], outcome: dict[str, Any], *, force: bool = False) -> dict[str, Any]:
    """Write the files a shipped outcome carries (see :func:`execute_task`) under ``root``, atomically."""
    files = outcome.pop("files", {})
    if outcome["status"] != "ran":
        return outcome
    work = _make_temp_dir(Path(root), task)
    try:
        run_dir = work / "run"
        for rel, data in files.items():
            path = run_dir / rel
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_bytes(data)
        run_dir.mkdir(exist_ok=True)
        outcome["out_dir"] = str(finalize_task(task, Path(root), work, outcome["result"],
                                               runtime_s=outcome["runtime_s"], force=force))
    finally:
        if work.exists():
            shutil.rmtree(work, ignore_errors=True)
    return outcome


_RENAMES: dict[int, Callable[[str, Mapping[str, Any]], tuple[str, dict[str, Any]]]] = {2: rename_v2}
"""Cache versions whose successor only renamed settings: version -> (kind, config) in the next version's names."""


@dataclass
class OlderRuns:
    """What :func:`adopt_older_runs` did: runs adopted (their new directories) and runs kept but not reused."""

    adopted: list[Path] = field(default_factory=list)
    not_reused: list[tuple[Path, str]] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        return {"adopted": [p.name for p in self.adopted],
                "not_reused": [{"dir": p.name, "reason": why} for p, why in self.not_reused]}


def _migrate(record: Mapping[str, Any]) -> Task:
    """The current task an older run's record stands for; TaskError saying why when there is none."""
    version = record.get("cache_version", 1)
    kind, config = record.get("kind"), record.get("config")
    if not isinstance(kind, str) or not isinstance(config, Mapping):
        raise TaskError("its result.json records no kind or config")
    while version < CACHE_VERSION:
        step = _RENAMES.get(version)
        if step is None:
            raise TaskError(f"made by cache version {version}, whose numbers may differ from this pbicrl's "
                            f"(version {CACHE_VERSION})")
        try:
            kind, config = step(kind, config)
        except (KeyError, TypeError, ValueError) as exc:
            raise TaskError(f"its version-{version} config cannot be renamed ({type(exc).__name__}: {exc})") from None
        version += 1
    import warnings

    from pbicrl.errors import PbicrlWarning

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", PbicrlWarning)
        task = Task(kind, config, name=record.get("name"))
    for key, value in config.items():  # e.g. data_sha256: the dataset must still be the one it was made from
        if key in task.config and canonical_json(task.config[key]) != canonical_json(value):
            raise TaskError(f"its setting {key} is {canonical_json(value)} but would now be "
                            f"{canonical_json(task.config[key])} (a changed or moved dataset?)")
    return task


def adopt_older_runs(root: str | os.PathLike[str], *, dry_run: bool = False) -> OlderRuns:
    """Take over the finished runs under ``root`` that an older cache version made, where that is exact.

    A run of an older :data:`CACHE_VERSION` whose later versions only renamed settings (:data:`_RENAMES`) is
    the run of the task its renamed config describes: its directory is renamed to that task's and its
    ``result.json`` rewritten (current version, config and hash; headline numbers computed again from its
    files by the kind's ``summarize``; ``adopted_from`` records the old version and hash). Other older runs
    (numbers that may differ, a dataset that changed, a kind that is gone, a current run of the same task)
    are left where they are and listed with the reason, never reused. With ``dry_run`` nothing is changed:
    ``adopted`` lists the directories the adoptable runs would get.
    """
    root = Path(root)
    out = OlderRuns()
    if not root.is_dir():
        return out
    for d in sorted(root.iterdir()):
        if d.name.startswith(".") or not d.is_dir():
            continue
        record = read_result(d)
        if record is None or record.get("cache_version", 1) >= CACHE_VERSION:
            continue
        try:
            task = _migrate(record)
            done = find_done(task, root)
            if done is not None:
                raise TaskError(f"{done.name} holds a current run of the same settings")
            summarize = task.spec.summarize
            if dry_run:
                out.adopted.append(task.out_dir(root))
                continue
            result = summarize(dict(task.config), d) if summarize is not None else record.get("result")
        except Exception as exc:  # TaskError or unreadable files: keep it, say why
            out.not_reused.append((d, str(exc) if isinstance(exc, TaskError) else error_text(exc)))
            continue
        target = task.out_dir(root)
        if target != d:
            try:
                os.rename(d, target)  # first the name, then the record: a crash between is finished next time
            except OSError as exc:
                out.not_reused.append((d, f"cannot be renamed to {target.name} ({exc.strerror or exc})"))
                continue
        write_json(target / RESULT_FILE, result_record(task, result, float(record.get("runtime_s") or 0.0),
                                                 finished_at=record.get("finished_at"), host=record.get("host"),
                                                 adopted_from={"cache_version": record.get("cache_version", 1),
                                                               "kind": record.get("kind"),
                                                               "config_hash": record.get("config_hash")}))
        out.adopted.append(target)
    return out


