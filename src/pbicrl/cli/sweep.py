"""``pbicrl sweep CONFIG.toml``: the command line of :mod:`pbicrl.experiments.sweep`."""

from __future__ import annotations

import argparse
import os
import signal
import sys
from pathlib import Path
from typing import Any

from pbicrl.cli.argtypes import positive_int as _positive_int
from pbicrl.experiments.sweep import MANIFEST, fmt_value, load_sweep, plan_sweep, run_tasks

__all__ = ["add_subcommands"]


def add_subcommands(sub: Any) -> None:
    """``pbicrl sweep`` (hooked into :mod:`pbicrl.cli`)."""
    p = sub.add_parser("sweep", help="run a grid of experiments (local process pool, or Ray); resumable",
                       description="Expand a sweep file's [grid] over [base] and run every combination as an "
                                   "independent task. Finished runs are recognised by their config hash and "
                                   "skipped, so rerunning the same command resumes a killed sweep.")
    p.add_argument("config", type=Path, help="sweep file (TOML with [base], [grid], optional [sweep] and [[runs]])")
    p.add_argument("--executor", choices=["local", "ray", "serial"],
                   help="local process pool (default), ray (default when RAY_ADDRESS is set), serial (in-process)")
    p.add_argument("--workers", type=_positive_int,
                   help="worker processes (local; default: one per core) or CPUs of a local Ray instance")
    p.add_argument("--address", help="Ray cluster address (default: RAY_ADDRESS, else a local instance)")
    p.add_argument("--out", type=Path, help="results root (default: [sweep] out, else runs/<config stem>)")
    p.add_argument("--force", action="store_true", help="run finished runs again and replace their results")
    p.add_argument("--dry-run", action="store_true", help="list the runs and whether they are finished; run nothing")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=_cmd_sweep)


def _cmd_sweep(args: argparse.Namespace) -> int:
    from pbicrl.experiments.executors import make_executor

    spec = load_sweep(args.config, out=args.out)
    if args.dry_run:
        plan = plan_sweep(spec, force=args.force)
        print(plan.table())
        n_done = plan.counts()["cached"]
        print(f"{len(plan.records)} runs in {spec.out}: {n_done} finished, {len(plan.records) - n_done} to run")
        return 0
    executor = make_executor(args.executor, args.workers, address=args.address)
    print(f"sweep {args.config}: {len(spec.tasks)} runs -> {spec.out} on {executor.describe()}", file=sys.stderr)
    # SIGTERM (a scheduler's or `kill`'s) stops the sweep as Ctrl-C does: workers stopped, sweep.json written.
    previous = _on_sigterm(_raise_interrupt)
    try:
        result = run_tasks(spec.tasks, spec.out, executor, settings=spec.settings, force=args.force,
                           progress=not args.no_progress)
    except KeyboardInterrupt:
        print(f"pbicrl: interrupted; finished runs are kept in {spec.out}; run the same command to resume",
              file=sys.stderr)
        return 130
    finally:
        _on_sigterm(previous)
    print(result.table())
    c = result.counts()
    print(f"{c['total']} runs: {c['ran']} ran, {c['cached']} already finished, {c['failed']} failed; "
          f"{result.wall_s:.1f} s on {result.executor}; details in {spec.out / MANIFEST}")
    if result.failed:
        print("failures:", file=sys.stderr)
        for r in result.failed:
            print(f"  {r.task.dir_name} ({', '.join(f'{k}={fmt_value(v)}' for k, v in r.settings.items())}): {r.error}",
                  file=sys.stderr)
            if os.environ.get("PBICRL_DEBUG") and r.traceback:
                print(r.traceback, file=sys.stderr)
        print(f"(tracebacks in {spec.out / MANIFEST}; fix the cause and run the same command: only the failed and "
              "missing runs run again)", file=sys.stderr)
        return 1
    return 0


def _raise_interrupt(signum: int, frame: Any) -> None:
    raise KeyboardInterrupt(f"signal {signum}")


def _on_sigterm(handler: Any) -> Any:
    """Install ``handler`` for SIGTERM (main thread only); returns the previous one (None if unchanged)."""
    if handler is None:
        return None
    try:
        return signal.signal(signal.SIGTERM, handler)
    except (ValueError, OSError):  # not the main thread: leave the default
        return None
