"""``python -m pbicrl.cli.icrl_benchmark``: train the ICRL benchmark's reference policies one after another
(:func:`pbicrl.experiments.icrl_benchmark.train_policy`)."""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence

__all__ = ["main"]


def _parse_job(text: str) -> tuple[str, str, int, int]:
    parts = text.split(":")
    if len(parts) != 4:
        raise ValueError(f"--run: expected TASK:METHOD:SEED:STEPS, got {text!r}")
    task, method, seed, steps = parts
    try:
        return task, method, int(seed), int(float(steps))
    except ValueError:
        raise ValueError(f"--run: SEED and STEPS must be integers in {text!r}") from None


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m pbicrl.cli.icrl_benchmark --out DIR --run TASK:METHOD:SEED:STEPS [--run ...]``: train
    the listed runs one after another (each resumable; finished ones are skipped)."""
    from pbicrl.experiments.icrl_benchmark import expert_config, train_policy

    p = argparse.ArgumentParser(prog="python -m pbicrl.cli.icrl_benchmark", description=main.__doc__)
    p.add_argument("--out", required=True, help="root directory of the runs")
    p.add_argument("--run", action="append", required=True, metavar="TASK:METHOD:SEED:STEPS",
                   help="a run to train (repeatable; trained in order), e.g. halfcheetah:ppo_lag_true:0:3000000")
    p.add_argument("--checkpoint-every", type=int, default=2, help="updates between checkpoints (default 2)")
    p.add_argument("--eval-every", type=int, default=10, help="updates between evaluations (default 10)")
    args = p.parse_args(argv)
    try:
        jobs = [_parse_job(j) for j in args.run]
        for task, method, seed, steps in jobs:
            expert_config(task, method)  # fail on a bad task or method before hours of training
        for task, method, seed, steps in jobs:
            train_policy(task, method, seed, args.out, steps, checkpoint_every=args.checkpoint_every,
                         eval_every=args.eval_every, log=lambda s: print(time.strftime("%H:%M:%S"), s, flush=True))
    except (ValueError, RuntimeError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
