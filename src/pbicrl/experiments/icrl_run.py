"""The whole ICRL benchmark in one call: infer each task's wall, train every run, write the report.

:func:`run_benchmark` (command line ``pbicrl benchmark icrl run``) does what the chain scripts in
``training/icrl/queue`` do by hand:

1. for every task with the ``ppo_lag_inferred`` method, infer the wall from the task's shipped ranked
   demonstrations (``icrl_<task>``) with ``pbicrl infer`` (a parametric half-space on the post-step position,
   the side of the task's true wall; :func:`wall_config_text`), or reuse the run directory already there;
2. train every (task, method, seed) of :func:`plan_jobs` at the documented budget (:data:`BUDGETS`) with
   :func:`pbicrl.experiments.icrl_benchmark.train_policy`, one run per worker: serially, on a local process pool,
   or on Ray. Each run is resumable (finished runs are skipped, a stopped one continues from its checkpoint) and
   locked (a run another process is training is reported ``busy`` and left to it);
3. write ``report.md``, ``results.json`` and the figures (:func:`pbicrl.experiments.icrl_report.build_report`).

Jobs are ordered seed-major (seed 0 of every row, then seed 1, ...) so that a benchmark stopped early has
every row with as many seeds as possible.
"""

from __future__ import annotations

import os
import sys
import time
import traceback
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

__all__ = ["BUDGETS", "Job", "infer_wall", "plan_jobs", "run_benchmark", "wall_config_text"]

BUDGETS: dict[str, dict[str, int]] = {
    "halfcheetah": {"ppo": 1_000_000, "ppo_lag_true": 3_000_000, "ppo_lag_inferred": 3_000_000, "icl": 4_500_000},
    "ant": {"ppo": 3_000_000, "ppo_lag_true": 3_000_000, "ppo_lag_inferred": 3_000_000, "icl": 2_500_000},
    "pendulum": {"ppo": 3_000_000, "ppo_lag_true": 2_000_000, "ppo_lag_inferred": 2_000_000, "icl": 2_000_000},
    "walker": {"ppo": 3_000_000, "ppo_lag_true": 3_000_000, "ppo_lag_inferred": 3_000_000, "icl": 2_500_000},
    "swimmer": {"ppo": 3_000_000, "ppo_lag_true": 2_000_000, "ppo_lag_inferred": 2_000_000, "icl": 2_000_000},
}
"""Environment steps per task and method: the budgets of ``docs/benchmarks/icrl/report.md`` (ICL: the total PPO
steps of its default preset; the pendulum and the swimmer, which have no preset of their own, Ant's 6 rounds scaled to
their PPO-Lagrangian budget of 2 M steps)."""

EXECUTORS: tuple[str, ...] = ("local", "serial", "ray")


@dataclass(frozen=True)
class Job:
    """One training run, ``<out>/<task>/<method>/seed<seed>``, to ``steps`` environment steps.

    Attributes
    ----------
    task : str
        A task name of :data:`pbicrl.envs.icrl_benchmark.ICRL_TASKS` (``halfcheetah``, ...).
    method : str
        ``ppo``, ``ppo_lag_true``, ``ppo_lag_inferred`` or ``icl``.
    seed : int
        >= 0.
    steps : int
        >= 1.
    """

    task: str
    method: str
    seed: int
    steps: int

    def __post_init__(self) -> None:
        from pbicrl.experiments.icrl_benchmark import METHODS

        if self.task not in BUDGETS:
            raise ValueError(f"task: unknown {self.task!r}; expected one of {list(BUDGETS)}")
        if self.method not in METHODS:
            raise ValueError(f"method: unknown {self.method!r}; expected one of {list(METHODS)}")
        if int(self.seed) != self.seed or self.seed < 0:
            raise ValueError(f"seed: must be an integer >= 0, got {self.seed!r}")
        if int(self.steps) != self.steps or self.steps < 1:
            raise ValueError(f"steps: must be an integer >= 1, got {self.steps!r}")

    @property
    def name(self) -> str:
        """``task:method:seed:steps``, as ``pbicrl benchmark icrl train --run`` spells a run."""
        return f"{self.task}:{self.method}:{self.seed}:{self.steps}"


def plan_jobs(tasks: Sequence[str] | None = None, seeds: int = 5, methods: Sequence[str] | None = None, *,
              budgets: dict[str, dict[str, int]] | None = None) -> tuple[list[Job], list[str]]:
    """The runs of a benchmark, seed-major, and the (task, method) pairs left out with why.

    Parameters
    ----------
    tasks : sequence of str, optional
        Task names or ``pbicrl/...`` ids (default all five; not empty, none twice).
    seeds : int
        Seeds ``0 .. seeds-1`` per row.
    methods : sequence of str, optional
        Default all four (``ppo``, ``ppo_lag_true``, ``ppo_lag_inferred``, ``icl``); not empty, none twice.
    budgets : dict, optional
        Steps per task and method replacing :data:`BUDGETS` where given (e.g. short runs for a test).

    Returns
    -------
    (list of Job, list of str)
    """
    from pbicrl.envs.icrl_benchmark import ICRL_TASKS, icrl_task
    from pbicrl.experiments.icrl_benchmark import ICL_TASKS, METHODS, selection

    names = selection("tasks", tasks, list(ICRL_TASKS), canonical=lambda t: icrl_task(t).name)
    ms = selection("methods", methods, METHODS)
    if int(seeds) != seeds or seeds < 1:
        raise ValueError(f"seeds: must be an integer >= 1, got {seeds!r}")
    skipped = [f"{t}/icl: no ICL environment for this task (ICL runs on {', '.join(ICL_TASKS)})"
               for t in names if "icl" in ms and t not in ICL_TASKS]
    jobs = []
    for s in range(int(seeds)):
        for t in names:
            for m in ms:
                if m == "icl" and t not in ICL_TASKS:
                    continue
                steps = (budgets or {}).get(t, {}).get(m, BUDGETS[t].get(m))
                if steps is None:
                    raise ValueError(f"budgets: no steps for {t}/{m}")
                jobs.append(Job(t, m, s, int(steps)))
    if not jobs:
        raise ValueError(f"nothing to run: {'; '.join(skipped)}")
    return jobs, skipped


def wall_config_text(task: str) -> str:
    """The ``pbicrl infer`` TOML of a task's wall: a half-space with unknown threshold on the dataset's state
    column 0 (the post-step x), on the side of the true wall (``docs/benchmarks/icrl/wall_behind.toml`` and
    ``wall_infront.toml``)."""
    from pbicrl.envs.icrl_benchmark import icrl_task

    spec = icrl_task(task)
    behind = spec.side == "behind"
    direction = "<=" if behind else ">="
    return (f"# {spec.name}: a step violates iff x {'<' if behind else '>'} {spec.wall:g} (x the post-step position);\n"
            f"# phi_wall(s) = 1[x {direction} theta] with theta unknown\n"
            f'[[constraints]]\nfamily = "axis_halfspace"\ndims = [0]\ndirection = "{direction}"\nname = "wall"\n')


def infer_wall(task: str, infer_dir: str | os.PathLike[str], *, seed: int = 0, chains: int = 2,
               jobs: int | None = None, max_time: float = 1500.0, progress: bool = False) -> Path:
    """The ``pbicrl infer`` run of a task's wall from its shipped demonstrations: ``<infer_dir>/<task>_wall``,
    reused when its ``summary.json`` exists, else inferred now (``iterations = "auto"``: until every reported
    quantity converged, or ``max_time`` seconds; the TOML is kept beside it as ``<task>_wall.toml``). The same
    run as ``pbicrl infer icrl_<task> --config <task>_wall.toml --out <infer_dir>/<task>_wall --chains 2``.

    Raises
    ------
    RuntimeError
        If the inference (new or reused) did not converge: a cost from it would not mean what it says.
    ValueError
        If a new inference's draws hold NaN or infinite values (:meth:`Posterior.require_usable_draws`; nothing
        written).
    """
    import json

    from pbicrl.api import infer_from_config
    from pbicrl.config import load_config
    from pbicrl.envs.icrl_benchmark import icrl_task
    from pbicrl.inference.data import load_dataset, resolve_dataset_path

    name = icrl_task(task).name
    root = Path(infer_dir)
    run = root / f"{name}_wall"
    if (run / "summary.json").is_file():
        if json.loads((run / "summary.json").read_text(encoding="utf-8")).get("converged") is False:
            raise RuntimeError(f"infer: {run} did not converge; remove it, or rerun it with a larger max_time")
        return run
    from pbicrl._atomic import write_text

    root.mkdir(parents=True, exist_ok=True)
    toml = root / f"{name}_wall.toml"
    write_text(toml, wall_config_text(name))
    data = resolve_dataset_path(f"icrl_{name}")
    cfg = load_config(toml).updated(chains=int(chains), seed=int(seed), jobs=jobs, max_time=float(max_time))
    post = infer_from_config(load_dataset(data), cfg, progress=progress)
    if post.converged is False:
        raise RuntimeError(f"infer: the wall of {name} did not converge in {max_time:g} s (nothing written); "
                           "rerun with a larger max_time")
    post.require_usable_draws()
    post.extra["data"]["path"] = str(data)
    post.save(run, inputs=[data, toml])
    return run


def _train_job(job: Job, out: str, inferred_run: str | None, kwargs: dict[str, Any]) -> dict[str, Any]:
    """Train one job; never raises (the outcome says what happened), so one failed run does not stop the others."""
    from pbicrl.experiments.icrl_benchmark import RunBusyError, train_policy

    t0 = time.monotonic()
    quiet = kwargs.pop("quiet", False)

    def log(s: str) -> None:
        print(time.strftime("%H:%M:%S"), s, flush=True)

    try:
        d = train_policy(job.task, job.method, job.seed, out, job.steps, inferred_run=inferred_run,
                         log=None if quiet else log, **kwargs)
        status, error, run_dir = "done", None, str(d)
    except RunBusyError as exc:
        status, error, run_dir = "busy", str(exc), None
    except RuntimeError as exc:
        status, error, run_dir = "failed", str(exc), None
    except Exception as exc:  # noqa: BLE001 - reported per job, with its traceback
        status, error, run_dir = "failed", f"{type(exc).__name__}: {exc}\n{traceback.format_exc()}", None
    return {"job": job.name, "status": status, "error": error, "run_dir": run_dir,
            "seconds": time.monotonic() - t0}


def _init_worker(parent: int) -> None:
    import signal

    from pbicrl.inference.samplers.driver import die_with_parent

    die_with_parent(parent)  # a run whose driver is gone stops (its last checkpoint is its resume point)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C: the driver stops the pool
    os.environ.setdefault("OMP_NUM_THREADS", "1")


def run_benchmark(out: str | os.PathLike[str], *, tasks: Sequence[str] | None = None, seeds: int = 5,
                  methods: Sequence[str] | None = None, executor: str = "local", workers: int | None = None,
                  infer_dir: str | os.PathLike[str] | None = None, report_dir: str | os.PathLike[str] | None = None,
                  budgets: dict[str, dict[str, int]] | None = None, eval_every: int = 10,
                  config_overrides: dict[str, Any] | None = None, infer_max_time: float = 1500.0,
                  log: Callable[[str], None] | None = print) -> dict[str, Any]:
    """Infer the walls, train every run of :func:`plan_jobs`, write the report (module docstring).

    Parameters
    ----------
    out : path
        Root of the training runs (``<out>/<task>/<method>/seed<k>``).
    tasks, seeds, methods, budgets
        The plan (:func:`plan_jobs`).
    executor : {"local", "serial", "ray"}
        ``local``: a process pool of ``workers`` processes (default: the CPU count), which die with this one;
        ``serial``: one run after the other in this process; ``ray``: one Ray task per run (``num_cpus=1``; the
        optional extra ``pip install "pbicrl[ray]"``): ``out`` and ``infer_dir`` must be on a disk every Ray worker
        sees.
    workers : int, optional
        Runs at once (``local``; default ``os.cpu_count()``).
    infer_dir : path, optional
        Where the walls' ``pbicrl infer`` runs are (or go): default ``<out>/infer``.
    report_dir : path, optional
        Where ``report.md`` goes (default: no report).
    eval_every, config_overrides
        Passed to :func:`~pbicrl.experiments.icrl_benchmark.train_policy` (overrides: short runs for tests; part of
        a run's identity).
    infer_max_time : float
        Seconds a wall inference may sample before it stops unconverged.
    log : callable or None
        The driver's progress lines (the runs print their own unless ``log`` is None).

    Returns
    -------
    dict
        ``jobs`` (per job: ``job``, ``status`` in ``done`` / ``busy`` / ``failed``, ``error``, ``run_dir``,
        ``seconds``), ``skipped`` and ``walls`` (task -> inference run), and ``report`` (the path, or None).
    """
    if executor not in EXECUTORS:
        raise ValueError(f"executor: unknown {executor!r}; expected one of {list(EXECUTORS)}")
    if workers is not None and (int(workers) != workers or workers < 1):
        raise ValueError(f"workers: must be an integer >= 1, got {workers!r}")
    jobs, skipped = plan_jobs(tasks, seeds, methods, budgets=budgets)
    say = log or (lambda s: None)
    root = Path(out)
    root.mkdir(parents=True, exist_ok=True)
    idir = Path(infer_dir) if infer_dir is not None else root / "infer"
    walls: dict[str, Path] = {}
    for t in dict.fromkeys(j.task for j in jobs if j.method == "ppo_lag_inferred"):
        had = (idir / f"{t}_wall" / "summary.json").is_file()
        say(f"[{t}] wall: {'reusing' if had else 'inferring'} {idir / f'{t}_wall'}")
        walls[t] = infer_wall(t, idir, max_time=infer_max_time)
    for s in skipped:
        say(f"left out: {s}")
    kwargs = {"eval_every": int(eval_every), "config_overrides": config_overrides, "quiet": log is None}
    args = [(j, str(root), str(walls[j.task]) if j.method == "ppo_lag_inferred" else None) for j in jobs]
    say(f"{len(jobs)} runs on {executor}" + (f" ({workers or os.cpu_count()} at once)" if executor == "local" else ""))
    outcomes: list[dict[str, Any]] = []

    def record(o: dict[str, Any]) -> None:
        outcomes.append(o)
        say(f"[{len(outcomes)}/{len(jobs)}] {o['job']}: {o['status']}"
            + (f" ({o['error'].splitlines()[0]})" if o["error"] else "") + f", {o['seconds'] / 3600:.2f} h")

    if executor == "serial":
        for a in args:
            record(_train_job(*a, dict(kwargs)))
    elif executor == "local":
        _run_local(args, kwargs, int(workers or os.cpu_count() or 1), record)
    else:
        _run_ray(args, kwargs, record)
    report = None
    if report_dir is not None:
        from pbicrl.experiments.icrl_report import build_report

        build_report(root, report_dir, tasks=list(dict.fromkeys(j.task for j in jobs)), seeds_planned=int(seeds))
        report = str(Path(report_dir) / "report.md")
        say(f"wrote {report}")
    order = {j.name: k for k, j in enumerate(jobs)}
    return {"jobs": sorted(outcomes, key=lambda o: order[o["job"]]), "skipped": skipped,
            "walls": {t: str(p) for t, p in walls.items()}, "report": report}


def _run_local(args: list[tuple[Job, str, str | None]], kwargs: dict[str, Any], workers: int,
               record: Callable[[dict[str, Any]], None]) -> None:
    import multiprocessing as mp
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait

    from pbicrl.inference.samplers.driver import stop_pool

    ctx = mp.get_context("fork" if sys.platform.startswith("linux") else "spawn")
    pool = ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=_init_worker,
                               initargs=(os.getpid(),))
    try:
        pending = {pool.submit(_train_job, *a, dict(kwargs)) for a in args}
        while pending:
            done, pending = wait(pending, return_when=FIRST_COMPLETED)
            for f in done:
                record(f.result())
    except BaseException:  # Ctrl-C, SIGTERM turned into an exception, a broken pool: stop every run now
        stop_pool(pool, grace=10.0)  # a run stopped mid-update resumes from its last checkpoint
        raise
    pool.shutdown(wait=True)


def _run_ray(args: list[tuple[Job, str, str | None]], kwargs: dict[str, Any],
             record: Callable[[dict[str, Any]], None]) -> None:
    from pbicrl.experiments.executors import import_ray

    ray = import_ray()
    started = not ray.is_initialized()
    if started:
        ray.init(address=os.environ.get("RAY_ADDRESS"), include_dashboard=False, log_to_driver=True)
    try:
        remote = ray.remote(num_cpus=1, max_retries=1)(_train_job)
        refs = {remote.remote(*a, dict(kwargs)): a[0] for a in args}
        while refs:
            done, _ = ray.wait(list(refs), num_returns=1)
            for r in done:
                refs.pop(r)
                record(ray.get(r))
    finally:
        if started:
            ray.shutdown()
