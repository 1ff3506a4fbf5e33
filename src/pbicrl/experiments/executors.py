"""Where tasks run: in this process, on a local process pool, or on Ray.

Every executor has one method, :meth:`Executor.run`, that yields ``(task, outcome)`` pairs as tasks finish.
The numbers a task produces depend only on its config (its seeds), never on the executor: a worker always
runs its task's MCMC chains in-process, each from its own child of the task's ``SeedSequence``.

* :class:`SerialExecutor` - one task after the other in this process (debugging, timing baselines).
* :class:`LocalExecutor` - a ``concurrent.futures`` process pool, one task per core.
* :class:`RayExecutor` - Ray's task API (``ray.remote``), on a local Ray instance or the cluster named by
  ``address`` / ``RAY_ADDRESS``; the optional extra ``pip install "pbicrl[ray]"``.

Progress inside the runs: given a :class:`~pbicrl.inference.samplers.driver.RunsCounter` (``counter``), the serial
and local executors count the sampler iterations of the tasks in progress there (a sweep's bar shows them); the
local pool passes it to its workers through the pool's initializer (``fork`` and ``spawn`` alike) and, while it
waits, calls its :meth:`~pbicrl.inference.samplers.driver.RunsCounter.tick` every ``counter.interval`` (0.5 s).
The Ray executor ignores it (its workers may be on other machines): a Ray sweep's bar moves when a run ends.

Local pool workers die with the process that started them (:func:`pbicrl.inference.samplers.driver.die_with_parent`):
a sweep killed with SIGTERM or SIGKILL leaves no task running, and none blocked forever on a pipe to a
parent that is gone; their temporary directories are removed by the next run.
"""

from __future__ import annotations

import logging
import multiprocessing as mp
import os
import signal
from abc import ABC, abstractmethod
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path
from typing import TYPE_CHECKING, Any, Generator, Iterator, Sequence

from pbicrl.experiments.tasks import Task, clean_stale_temp_dirs, execute_task, started_hashes, write_shipped

if TYPE_CHECKING:
    from pbicrl.inference.samplers.driver import RunsCounter

__all__ = ["Executor", "SerialExecutor", "LocalExecutor", "RayExecutor", "make_executor", "import_ray", "EXECUTORS"]

EXECUTORS = ("local", "serial", "ray")


def _failed(task: Task, error: str, tb: str | None = None) -> dict[str, Any]:
    return {"config_hash": task.config_hash, "status": "failed", "out_dir": None, "result": None,
            "error": error, "traceback": tb, "runtime_s": 0.0}


class Executor(ABC):
    """Runs tasks; see the module docstring."""

    name: str = "executor"

    @property
    @abstractmethod
    def workers(self) -> int:
        """How many tasks run at once."""

    @abstractmethod
    def run(self, tasks: Sequence[Task], root: str | os.PathLike[str], *, force: bool = False,
            counter: RunsCounter | None = None) -> Iterator[tuple[Task, dict[str, Any]]]:
        """Run ``tasks``, writing each results directory under ``root``; yield ``(task, outcome)`` as they finish.

        A failing task yields an outcome with ``status == "failed"`` and its ``error``; it never stops the
        others. ``force`` replaces finished results instead of keeping the first copy. ``counter`` counts the
        sampler iterations of the tasks in progress, where the executor supports it (see the module docstring).
        """

    def describe(self) -> str:
        return f"{self.name} ({self.workers} worker{'s' if self.workers != 1 else ''})"


class SerialExecutor(Executor):
    """One task at a time in this process (no pickling, plain tracebacks)."""

    name = "serial"

    @property
    def workers(self) -> int:
        return 1

    def run(self, tasks: Sequence[Task], root: str | os.PathLike[str], *, force: bool = False,
            counter: RunsCounter | None = None) -> Iterator[tuple[Task, dict[str, Any]]]:
        from pbicrl.inference.samplers.driver import set_runs_counter

        root = Path(root).absolute()
        for task in tasks:
            old = set_runs_counter(counter)
            try:
                outcome = execute_task(task, root, force=force)
            finally:
                set_runs_counter(old)
            yield task, outcome


def _init_pool_worker(parent: int | None = None, counter: RunsCounter | None = None) -> None:
    from pbicrl.inference.samplers.driver import die_with_parent, set_runs_counter

    # A worker whose parent is gone would finish its task, then wait forever for the next one on a pipe
    # that its siblings keep open: end it with the parent instead (the next run cleans its temporaries).
    die_with_parent(parent)
    # Ctrl-C goes to the whole process group; the parent decides what happens to running tasks.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    # The parent's SIGTERM handler (a sweep turns SIGTERM into an interrupt) is inherited through fork:
    # a worker must die on the parent's terminate(), as any process does by default.
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    set_runs_counter(counter)  # the sampler counts its iterations there, for the sweep's bar


class LocalExecutor(Executor):
    """A local process pool (``concurrent.futures.ProcessPoolExecutor``), one task per worker process.

    With fewer tasks than workers, each task gets ``max_workers // n_tasks`` cores for its chains
    (:func:`~pbicrl.experiments.tasks.task_jobs`).

    Parameters
    ----------
    max_workers : int, optional
        Worker processes (default: ``os.cpu_count()``).
    start_method : str, optional
        ``multiprocessing`` start method (default ``"fork"`` where available: workers start in milliseconds
        and inherit task kinds registered at run time).

    Notes
    -----
    If a worker process dies (killed for memory, a crash in compiled code) the pool breaks. The tasks that
    had not started are resubmitted to a new pool; those that were running are suspects and run again
    afterwards, each alone in its own process: one that dies alone is reported as failed, the others finish.
    """

    name = "local"

    def __init__(self, max_workers: int | None = None, *, start_method: str | None = None):
        n = (os.cpu_count() or 1) if max_workers is None else int(max_workers)
        if n < 1:
            raise ValueError(f"workers: expected a positive integer, got {max_workers}")
        self.max_workers = n
        if start_method is None:
            start_method = "fork" if "fork" in mp.get_all_start_methods() else None
        self.start_method = start_method

    @property
    def workers(self) -> int:
        return self.max_workers

    def run(self, tasks: Sequence[Task], root: str | os.PathLike[str], *, force: bool = False,
            counter: RunsCounter | None = None) -> Iterator[tuple[Task, dict[str, Any]]]:
        root = Path(root).absolute()
        pending, suspects = list(tasks), []
        while pending:
            started, queued, progressed = yield from self._round(pending, root, force, self.max_workers, counter)
            suspects += started
            if not started and not progressed:  # died before any task could start: no way to tell who
                suspects, queued = suspects + queued, []
            pending = queued
        for task in suspects:
            started, queued, _ = yield from self._round([task], root, force, 1, counter)
            if started or queued:
                yield task, _failed(task, "worker process died while running this task (killed for memory, "
                                          "or a crash in compiled code)")

    def _round(self, tasks: list[Task], root: Path, force: bool, workers: int, counter: RunsCounter | None
               ) -> Generator[tuple[Task, dict[str, Any]], None, tuple[list[Task], list[Task], bool]]:
        """Run ``tasks`` on one pool, yielding outcomes; returns the tasks a broken pool cut short
        (started, queued) and whether any task finished."""
        ctx = mp.get_context(self.start_method)
        if counter is not None:
            # no task in progress (a worker that died in the last round left its share); memory of this context
            counter.reset(ctx)
        pool = ProcessPoolExecutor(max_workers=min(workers, len(tasks)), mp_context=ctx, initializer=_init_pool_worker,
                                   initargs=(os.getpid(), counter))
        cut: list[Task] = []
        progressed = False
        try:
            # Fewer tasks than cores (a few long runs): each task may spread its chains over its share.
            jobs = max(1, self.max_workers // len(tasks))
            futures = {pool.submit(execute_task, t, root, force=force, jobs=jobs): t for t in tasks}
            not_done = set(futures)
            while not_done:
                done, not_done = wait(not_done, timeout=None if counter is None else max(counter.interval, 0.05),
                                      return_when=FIRST_COMPLETED)
                if counter is not None:
                    counter.tick()  # the sweep's bar: progress inside the running tasks
                for f in done:
                    task = futures[f]
                    try:
                        outcome = f.result()
                    except BrokenProcessPool:
                        cut.append(task)
                        continue
                    except Exception as exc:  # e.g. the task could not be pickled
                        outcome = _failed(task, f"{type(exc).__name__}: {exc}")
                    progressed = True
                    yield task, outcome
        except BaseException:
            _terminate(pool)
            clean_stale_temp_dirs(root)
            raise
        pool.shutdown(wait=True)
        if not cut:
            return [], [], progressed
        # A task has started iff its temporary directory exists (the first thing a worker creates).
        began = started_hashes(root)
        clean_stale_temp_dirs(root)
        started = [t for t in cut if t.config_hash[:12] in began]
        return started, [t for t in cut if t.config_hash[:12] not in began], progressed


def _terminate(pool: ProcessPoolExecutor) -> None:
    """Stop a pool now, running tasks included (their temporary directories are cleaned up afterwards):
    SIGTERM, then SIGKILL for a task that handles SIGTERM and does not stop within two seconds."""
    from pbicrl.inference.samplers.driver import stop_pool

    stop_pool(pool, grace=2.0)


def _ray_execute(task: Task, force: bool) -> dict[str, Any]:
    # Runs on a Ray worker, which may not see the driver's disk: the files come back with the outcome.
    return execute_task(task, None, force=force)


def import_ray() -> Any:
    """Ray, or an ImportError that names the extra to install."""
    try:
        import ray
    except ImportError:
        raise ImportError('the ray executor needs Ray: pip install "pbicrl[ray]"') from None
    return ray


class RayExecutor(Executor):
    """Ray tasks (``ray.remote(num_cpus=1)``), one per run.

    Uses an already initialised Ray, else connects to ``address`` (or the ``RAY_ADDRESS`` environment
    variable), else starts a local instance with ``num_cpus`` CPUs (shut down again afterwards). Workers
    send their files back to the driver, which writes them under ``root`` atomically: the results directory
    need not be shared with the cluster, but data files named by path must be readable on the workers.

    Parameters
    ----------
    address : str, optional
        Ray cluster address (``"auto"``, ``"ray://host:10001"``, ...).
    num_cpus : int, optional
        CPUs of a local instance started here (default: all).
    max_in_flight : int, optional
        Submit at most this many tasks at once (default: all; Ray schedules them over the cluster).
    max_retries : int
        Ray's retries of a task whose worker died.
    """

    name = "ray"

    def __init__(self, address: str | None = None, *, num_cpus: int | None = None, max_in_flight: int | None = None,
                 max_retries: int = 1):
        self.address = address
        self.num_cpus = num_cpus
        self.max_in_flight = max_in_flight
        self.max_retries = int(max_retries)

    @property
    def workers(self) -> int:
        if self.max_in_flight:
            return int(self.max_in_flight)
        try:
            ray = import_ray()
            if ray.is_initialized():
                return int(ray.cluster_resources().get("CPU", 1))
        except ImportError:
            pass
        return int(self.num_cpus or os.cpu_count() or 1)

    def describe(self) -> str:
        where = self.address or os.environ.get("RAY_ADDRESS") or "local instance"
        return f"ray ({where})"

    def run(self, tasks: Sequence[Task], root: str | os.PathLike[str], *, force: bool = False,
            counter: RunsCounter | None = None) -> Iterator[tuple[Task, dict[str, Any]]]:
        ray = import_ray()  # ``counter`` is not used: a Ray worker may be on another machine
        root = Path(root).absolute()
        started = False
        if not ray.is_initialized():
            opts: dict[str, Any] = {"include_dashboard": False, "log_to_driver": False,
                                    "logging_level": logging.WARNING}
            address = self.address or os.environ.get("RAY_ADDRESS")
            if address:
                ray.init(address=address, **opts)
            else:
                ray.init(num_cpus=self.num_cpus, **opts)
            started = True
        try:
            remote = ray.remote(num_cpus=1, max_retries=self.max_retries)(_ray_execute)
            queue = list(tasks)
            limit = self.max_in_flight or len(queue) or 1
            in_flight: dict[Any, Task] = {}
            try:
                while queue or in_flight:
                    while queue and len(in_flight) < limit:
                        task = queue.pop(0)
                        in_flight[remote.remote(task, force)] = task
                    done, _ = ray.wait(list(in_flight), num_returns=1)
                    for ref in done:
                        task = in_flight.pop(ref)
                        try:
                            outcome = ray.get(ref)
                        except Exception as exc:  # the worker died max_retries + 1 times, or Ray failed
                            outcome = _failed(task, f"ray: {type(exc).__name__}: {str(exc).strip().splitlines()[0] if str(exc).strip() else ''}")
                        else:
                            outcome = write_shipped(task, root, outcome, force=force)
                        yield task, outcome
            except BaseException:
                for ref in in_flight:
                    ray.cancel(ref, force=True)
                raise
        finally:
            if started:
                ray.shutdown()


def make_executor(kind: str | None = None, workers: int | None = None, *, address: str | None = None) -> Executor:
    """An executor by name: ``"local"`` (default; ``"ray"`` when ``RAY_ADDRESS`` is set), ``"serial"`` or ``"ray"``.

    ``workers`` is the pool size for ``local``, the CPUs of a local Ray instance (or the tasks in flight on a
    cluster) for ``ray``, and must be 1 or unset for ``serial``.
    """
    if kind is None:
        kind = "ray" if (address or os.environ.get("RAY_ADDRESS")) else "local"
    if workers is not None and int(workers) < 1:
        raise ValueError(f"workers: expected a positive integer, got {workers}")
    if kind == "local":
        return LocalExecutor(workers)
    if kind == "serial":
        if workers not in (None, 1):
            raise ValueError(f"workers: the serial executor runs one task at a time, got {workers}")
        return SerialExecutor()
    if kind == "ray":
        import_ray()
        remote = address or os.environ.get("RAY_ADDRESS")
        return RayExecutor(address, num_cpus=None if remote else workers, max_in_flight=workers if remote else None)
    raise ValueError(f"executor: expected one of {', '.join(EXECUTORS)}, got {kind!r}")
