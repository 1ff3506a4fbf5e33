"""The registry of task kinds and the worker's environment: what a task *is* before any run.

A task kind is a name bound to ``"module:function"`` (:class:`TaskKind`); :func:`register_task` adds one,
:func:`get_task_kind` looks one up (or builds an ad-hoc one for an importable ``"module:function"``). A worker
process marks itself with :class:`task_worker` so that the task's own parallel work uses no more than
:func:`task_jobs` cores. The engine that runs tasks and caches their results is :mod:`pbicrl.experiments.tasks`;
the built-in kinds are in :mod:`pbicrl.experiments.kinds`.

Standard library only, so that kinds can register themselves without importing the engine.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from importlib import import_module
from pathlib import Path
from typing import Any, Callable, Iterable

__all__ = ["TaskError", "TaskKind", "register_task", "get_task_kind", "task_kinds", "import_target",
           "in_task_worker", "task_jobs", "task_worker"]

_WORKER_ENV = "PBICRL_TASK_WORKER"
_JOBS_ENV = "PBICRL_TASK_JOBS"


class TaskError(ValueError):
    """Invalid task description (unknown kind, bad config); the message names the key."""


# --------------------------------------------------------------------------------------------- registry
@dataclass(frozen=True)
class TaskKind:
    """A registered kind of task.

    Attributes
    ----------
    name : str
        Name used in ``Task.kind`` and in sweep files (``kind = "infer"``).
    target : str
        ``"module:function"`` of ``run(config, out_dir) -> dict``; imported by the worker.
    prepare : callable, optional
        ``prepare(config) -> config``: validates the config (errors name the key) and may normalise it or
        fill in defaults; it runs when the :class:`Task` is created (in the parent, before anything is
        launched) and must be idempotent.
    unhashed : tuple of str
        Config keys that do not change the results (e.g. a data path whose content is hashed separately,
        or a number of worker processes); excluded from the hash.
    path_keys : tuple of str
        Config keys that hold file paths; a sweep file resolves them relative to its own directory.
    columns : tuple of str
        Keys of the returned dict to show in summary tables (default: every scalar value).
    defaults : callable, optional
        ``defaults() -> dict`` of the values a missing key stands for. Entries equal to their default are
        left out of the hash, so a kind can gain new settings (with defaults that keep the old behaviour)
        without invalidating finished runs.
    version : int
        Part of the hash: bump it when a change makes old results of this kind wrong (e.g. a new default).
    summarize : callable, optional
        ``summarize(config, out_dir) -> dict``: the headline numbers of a finished run computed again from its
        files; used when a run of an older cache version is adopted (:func:`adopt_older_runs`). Without it the
        stored numbers are kept.
    """

    name: str
    target: str
    prepare: Callable[[dict], dict] | None = None
    unhashed: tuple[str, ...] = ()
    path_keys: tuple[str, ...] = ()
    columns: tuple[str, ...] = ()
    defaults: Callable[[], dict] | None = None
    version: int = 1
    summarize: Callable[[dict, Path], dict] | None = None


_REGISTRY: dict[str, TaskKind] = {}


def _target_of(run: Callable[..., Any] | str) -> str:
    if isinstance(run, str):
        if ":" not in run:
            raise TaskError(f"task target {run!r}: expected 'package.module:function'")
        return run
    module, qualname = getattr(run, "__module__", None), getattr(run, "__qualname__", "")
    if not module or "<locals>" in qualname or "<lambda>" in qualname or module == "__main__":
        raise TaskError(f"task function {qualname or run!r}: must be a top-level function of an importable module "
                        "(workers import it by name)")
    return f"{module}:{qualname}"


def register_task(name: str, run: Callable[[dict, Path], dict] | str, *, prepare: Callable[[dict], dict] | None = None,
                  unhashed: Iterable[str] = (), path_keys: Iterable[str] = (), columns: Iterable[str] = (),
                  defaults: Callable[[], dict] | None = None, version: int = 1,
                  summarize: Callable[[dict, Path], dict] | None = None, replace: bool = False) -> TaskKind:
    """Register a task kind (see :class:`TaskKind`); returns it.

    Parameters
    ----------
    name : str
        Kind name; letters, digits, ``-``, ``_`` and ``.``.
    run : callable or str
        Top-level function ``run(config, out_dir) -> dict`` or its ``"module:function"`` path.
    prepare, unhashed, path_keys, columns, defaults, version, summarize
        See :class:`TaskKind`.
    replace : bool
        Allow re-registering an existing name with a different target.
    """
    if not name or not all(ch.isalnum() or ch in "-_." for ch in name):
        raise TaskError(f"task kind {name!r}: use letters, digits, '-', '_' and '.'")
    kind = TaskKind(name, _target_of(run), prepare, tuple(unhashed), tuple(path_keys), tuple(columns), defaults,
                    int(version), summarize)
    old = _REGISTRY.get(name)
    if old is not None and old.target != kind.target and not replace:
        raise TaskError(f"task kind {name!r} is already registered to {old.target}; pass replace=True")
    _REGISTRY[name] = kind
    return kind


# Kinds defined in modules that are imported only when such a task is requested (keeps `pbicrl` import light).
_LAZY_KINDS: dict[str, str] = {}


def get_task_kind(kind: str) -> TaskKind:
    """The registered :class:`TaskKind` of ``kind``, or an ad-hoc one for a ``"module:function"`` path."""
    if kind in _REGISTRY:
        return _REGISTRY[kind]
    if kind in _LAZY_KINDS:
        import_module(_LAZY_KINDS[kind])
        if kind in _REGISTRY:
            return _REGISTRY[kind]
    if ":" in kind:
        try:  # fail here, before anything is launched, rather than in every worker
            import_target(kind)
        except (ImportError, AttributeError, ValueError) as exc:
            raise TaskError(f"kind: cannot import {kind!r} ({type(exc).__name__}: {exc})") from None
        return TaskKind(kind, kind)
    known = ", ".join(sorted(set(_REGISTRY) | set(_LAZY_KINDS)))
    raise TaskError(f"kind: unknown task kind {kind!r}; known kinds are {known} "
                    "(or give an importable 'package.module:function')")


def task_kinds() -> list[str]:
    """Names of all registered task kinds."""
    return sorted(set(_REGISTRY) | set(_LAZY_KINDS))


def in_task_worker() -> bool:
    """True inside a task run by an executor: the executor owns the cores, so nested parallelism (MCMC
    chains, torch threads) must use no more than :func:`task_jobs` processes or threads."""
    return os.environ.get(_WORKER_ENV) == "1"


def task_jobs() -> int:
    """Processes (or threads) a task may use for its own parallel work: 1, unless the executor has more
    cores than tasks (then its share of them). Results must not depend on it."""
    try:
        return max(1, int(os.environ.get(_JOBS_ENV, "1")))
    except ValueError:
        return 1


class task_worker:
    """Context manager that marks the current process as a task worker with ``jobs`` cores (see
    :func:`in_task_worker`, :func:`task_jobs`)."""

    def __init__(self, jobs: int = 1) -> None:
        self.jobs = max(1, int(jobs))

    def __enter__(self) -> "task_worker":
        self._old = {k: os.environ.get(k) for k in (_WORKER_ENV, _JOBS_ENV)}
        os.environ[_WORKER_ENV] = "1"
        os.environ[_JOBS_ENV] = str(self.jobs)
        return self

    def __exit__(self, *exc: object) -> None:
        for k, v in self._old.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def import_target(target: str) -> Callable[[dict, Path], Any]:
    """The function a ``"module:function"`` target names (imported now)."""
    module, _, qualname = target.partition(":")
    obj: Any = import_module(module)
    for part in qualname.split("."):
        obj = getattr(obj, part)
    return obj
