"""``pbicrl reproduce``: the command line of :func:`pbicrl.experiments.reproduce.reproduce`."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from pbicrl.experiments.reproduce import EXPERIMENTS, reproduce

__all__ = ["add_subcommands"]


def add_subcommands(sub: Any) -> None:
    from pbicrl.cli.argtypes import DeprecatedFlag
    from pbicrl.cli.argtypes import positive_int as _positive_int

    p = sub.add_parser("reproduce", help="reproduce the paper's experiments on the shipped demonstrations",
                       description="Run the paper's experiments; writes <out>/<experiment>/report.md, results.json and PNGs.")
    p.add_argument("experiment", choices=[*EXPERIMENTS, "all"])
    p.add_argument("--out", type=Path, default=Path("results"), help="results root (default results/)")
    p.add_argument("--quick", action="store_true", help="40,000 iterations instead of 400,000 (smoke runs)")
    p.add_argument("--pairs", choices=["all", "sampled"], default="all",
                   help="all cross-group pairs (paper Eq. 7, default) or N random pairs per group pair (authors' code)")
    p.add_argument("--protocol", dest="pairs", choices=["all", "sampled"], action=DeprecatedFlag, new="--pairs")
    p.add_argument("--seeds", type=_positive_int, default=5)
    p.add_argument("--iterations", type=_positive_int, help="iterations per chain (default: the paper's 400,000)")
    p.add_argument("--data", action="append", default=[], metavar="NAME=PATH",
                   help="use PATH instead of the shipped dataset NAME (point_mass, fetch_reach, halfcheetah, ant)")
    p.add_argument("--executor", choices=["local", "serial", "ray"], default="local")
    p.add_argument("--workers", type=_positive_int)
    p.add_argument("--no-progress", action="store_true")
    p.set_defaults(func=_cmd)


def _cmd(args: argparse.Namespace) -> int:
    data = {}
    for item in args.data:
        if "=" not in item:
            raise ValueError(f"--data: expected NAME=PATH, got {item!r}")
        k, v = item.split("=", 1)
        if not Path(v).exists():
            raise FileNotFoundError(f"--data: {v}: no such file")
        data[k] = v
    reproduce(args.experiment, out=args.out, quick=args.quick, pairs=args.pairs, seeds=args.seeds,
              executor=args.executor, workers=args.workers, progress=not args.no_progress,
              iterations=args.iterations, data=data)
    return 0
