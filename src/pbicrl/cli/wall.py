"""Command-line entry for the demonstrators: ``python -m pbicrl.demonstrators``.

Subcommands (mountable into another CLI with :func:`add_subcommands`):

``train-wall``
    Train (or resume) the good/violating SAC demonstrator of HalfCheetah or Ant.
``demos-wall``
    Roll out both demonstrators and write a ranked dataset (``.npz``) + JSON report.
``plot-wall``
    Visitation-frequency PNG of x for good vs violating demonstrations.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from collections.abc import Sequence
from pathlib import Path

from pbicrl.cli.argtypes import finite_float_or_auto, nonneg_int
from pbicrl.cli.argtypes import positive_int as _positive_int

__all__ = ["add_subcommands", "build_parser", "main"]


def _utc_time(text: str) -> float:
    """Parse ``YYYY-MM-DDTHH:MM[:SS]Z`` (UTC) into a unix time."""
    from datetime import UTC, datetime

    try:
        dt = datetime.fromisoformat(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a UTC time like 2026-11-22T02:10:00Z, got {text!r}") from None
    if dt.tzinfo is None:
        dt = dt.replace(tzinfo=UTC)
    return dt.timestamp()


def _ent_coef(text: str) -> float | str:
    if text == "auto" or text.startswith("auto_"):
        try:
            if text != "auto":
                float(text[5:])
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected auto, auto_<number> or a number, got {text!r}") from None
        return text
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected auto, auto_<number> or a number, got {text!r}") from None
    if not value > 0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {text!r}")
    return value


def _cmd_train_wall(args: argparse.Namespace) -> int:
    from pbicrl.demonstrators.wall import train_wall_policy

    kwargs = {"seed": args.seed, "learning_rate": args.learning_rate, "batch_size": args.batch_size,
              "net_arch": tuple(args.net_arch), "buffer_size": args.buffer_size,
              "learning_starts": args.learning_starts, "checkpoint_every": args.checkpoint_every,
              "log_every": args.log_every, "torch_threads": args.torch_threads,
              "init_from": args.init_from, "progress": not args.quiet, "deadline": args.deadline,
              "ent_coef": args.ent_coef, "position_bonus": args.position_bonus,
              "terminate_when_flipped": args.terminate_when_flipped, "reach_bonus": args.reach_bonus,
              "start_spread": args.start_spread,
              "prefill_steps": args.prefill_steps, "target_entropy": args.target_entropy}
    try:
        path = train_wall_policy(args.env, args.mode, args.steps, args.out, **kwargs)
    except KeyboardInterrupt as exc:
        print(f"interrupted: {exc}", file=sys.stderr)
        return 130
    print(path)
    return 0


def _cmd_demos_wall(args: argparse.Namespace) -> int:
    from pbicrl.cli.navigation import npz_path, check_outputs
    from pbicrl.demonstrators.wall import generate_wall_demos

    inputs = [args.good_policy, args.violating_policy]
    check_outputs([npz_path(args.out)], args.overwrite, inputs)
    check_outputs([args.report], args.overwrite, [*inputs, npz_path(args.out)], field="--report")
    args.out = npz_path(args.out)
    _, report = generate_wall_demos(args.env, args.good_policy, args.violating_policy, args.n, args.out,
                                    seed=args.seed, n_steps=args.steps, deterministic=args.deterministic,
                                    quantize=not args.no_quantize, max_attempts_factor=args.max_attempts_factor)
    report["file"] = str(args.out)
    report["file_bytes"] = os.path.getsize(args.out)
    text = json.dumps(report, indent=2, sort_keys=True)
    if args.report:
        from pbicrl._atomic import write_text

        write_text(args.report, text + "\n")
    print(text)
    return 0


def _cmd_plot_wall(args: argparse.Namespace) -> int:
    from pbicrl.demonstrators.wall import plot_wall_visitation
    from pbicrl.envs.mujoco_wall import wall_spec

    from pbicrl.cli.navigation import check_outputs

    check_outputs([args.out], args.overwrite, [args.dataset])
    wall = args.wall_x if args.wall_x is not None else wall_spec(args.env).wall_x
    print(plot_wall_visitation(args.dataset, wall, args.out, title=args.title or args.env))
    return 0


def add_subcommands(subparsers: argparse._SubParsersAction) -> None:
    """Add ``train-wall``, ``demos-wall`` and ``plot-wall`` to an argparse subparsers object.

    Each subparser sets ``func`` (call ``args.func(args)``, returns an exit code).
    """
    p = subparsers.add_parser("train-wall", help="train/resume a SAC demonstrator for HalfCheetah/Ant with a wall")
    p.add_argument("--env", required=True, choices=["halfcheetah", "ant"])
    p.add_argument("--mode", required=True, choices=["good", "violating"],
                   help="good: constrained reward (wall penalty); violating: nominal reward")
    p.add_argument("--steps", required=True, type=_positive_int, help="total environment steps (across resumes)")
    p.add_argument("--out", required=True, type=Path, help="run directory (resumes if it has a checkpoint)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--learning-rate", type=float, default=3e-4)
    p.add_argument("--batch-size", type=_positive_int, default=128)
    p.add_argument("--net-arch", type=_positive_int, nargs="+", default=[256, 256])
    p.add_argument("--buffer-size", type=_positive_int, default=10_000)
    p.add_argument("--learning-starts", type=int, default=10_000, help="initial uniformly random steps")
    p.add_argument("--checkpoint-every", type=_positive_int, default=10_000)
    p.add_argument("--log-every", type=_positive_int, default=2_000)
    p.add_argument("--torch-threads", type=_positive_int, default=1)
    p.add_argument("--init-from", type=Path, default=None,
                   help="warm start from an SB3 model zip or a policy-only policy.zip")
    p.add_argument("--ent-coef", type=_ent_coef, default="auto",
                   help="SAC entropy coefficient: auto, auto_<initial> (e.g. auto_0.05) or a number")
    p.add_argument("--position-bonus", type=float, default=0.0,
                   help="training-only shaping of the good demonstrator: + B * min(x, wall) per step (0: paper)")
    p.add_argument("--target-entropy", type=finite_float_or_auto, default="auto",
                   help="entropy the SAC temperature aims at: auto (-dim(action)) or a number; lower: less noisy")
    p.add_argument("--reach-bonus", type=float, default=0.0,
                   help="training-only shaping of the good demonstrator: + B per step with x in [wall - 0.5, wall) "
                        "(0: paper)")
    p.add_argument("--start-spread", type=float, default=0.0,
                   help="training-only exploring starts of the good demonstrator: each episode starts up to this "
                        "far ahead of Gymnasium's start (uniform; 0: paper)")
    p.add_argument("--prefill-steps", type=nonneg_int, default=0,
                   help="warm start only: fill the fresh replay buffer with this many steps of the loaded policy "
                        "(sampled actions) before the first gradient step")
    p.add_argument("--terminate-when-flipped", action="store_true",
                   help="training-only (ant): end an episode when the torso turns upside down, as a fall does")
    p.add_argument("--deadline", type=_utc_time, default=None,
                   help="UTC time (e.g. 2026-11-22T02:10:00Z) at which to stop and finalise the policy early")
    p.add_argument("--quiet", action="store_true", help="do not echo progress to stderr")
    p.set_defaults(func=_cmd_train_wall)

    p = subparsers.add_parser("demos-wall", help="roll out good/violating demonstrators into a dataset")
    p.add_argument("--env", required=True, choices=["halfcheetah", "ant"])
    p.add_argument("--good-policy", required=True, type=Path)
    p.add_argument("--violating-policy", required=True, type=Path)
    p.add_argument("-n", type=_positive_int, default=200, help="trajectories per group")
    p.add_argument("--steps", type=_positive_int, default=500, help="trajectory length")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--deterministic", action="store_true", help="use the policy mean instead of sampling")
    p.add_argument("--max-attempts-factor", type=_positive_int, default=3,
                   help="give up after this many times n rollouts per group (rejections are reported)")
    p.add_argument("--no-quantize", action="store_true",
                   help="store full-precision x/actions (default: x on a 2**-16 m grid, actions on 2**-10)")
    p.add_argument("--out", required=True, type=Path, help="output .npz")
    p.add_argument("--report", type=Path, default=None, help="also write the JSON report here")
    p.add_argument("--overwrite", action="store_true", help="replace an existing --out/--report file (never an input)")
    p.set_defaults(func=_cmd_demos_wall)

    p = subparsers.add_parser("plot-wall", help="x visitation frequency of good vs violating demonstrations")
    p.add_argument("--env", required=True, choices=["halfcheetah", "ant"])
    p.add_argument("--dataset", required=True, type=Path)
    p.add_argument("--out", required=True, type=Path, help="output PNG")
    p.add_argument("--wall-x", type=float, default=None, help="defaults to the environment's wall")
    p.add_argument("--title", default=None)
    p.add_argument("--overwrite", action="store_true", help="replace an existing --out file")
    p.set_defaults(func=_cmd_plot_wall)


def build_parser() -> argparse.ArgumentParser:
    """Parser of ``python -m pbicrl.demonstrators``."""
    from pbicrl.cli.argtypes import standalone_parser

    return standalone_parser("python -m pbicrl.demonstrators", "SAC demonstrators for pbicrl", add_subcommands)


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return int(args.func(args))
