"""``pbicrl train-safe``: the command line of :func:`pbicrl.experiments.safe_rl.train_safe` (imports nothing optional until it
runs)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from pbicrl.experiments.safe_rl import COSTS, DEFAULT_COST_LIMIT, ENVS, train_safe

__all__ = ["add_subcommands"]


def _cmd_train_safe(args: argparse.Namespace) -> int:
    constraints = [c.strip() for c in args.constraints.split(",") if c.strip()] if args.constraints else None
    ppo = {k: v for k, v in (("lr", args.lr), ("lagrange_lr", args.lagrange_lr)) if v is not None}
    try:
        s = train_safe(args.out, args.env, args.steps, args.cost_limit, run=args.run, cost=args.cost, mode=args.mode,
                       quantile=args.quantile, constraints=constraints, seed=args.seed, eval_episodes=args.eval_episodes,
                       warmup_steps=args.warmup_steps, ppo=ppo or None,
                       progress=not args.quiet)
    except KeyboardInterrupt:
        print(f"pbicrl: interrupted; checkpoint in {args.out}, rerun the same command to resume", file=sys.stderr)
        return 130
    print(json.dumps({k: s.get(k) for k in ("env", "cost", "cost_limit", "steps", "lambda", "last_10_updates",
                                            "evaluation", "cost_limit_met", "cost_limit_check", "runtime_s")}, indent=2))
    chk = s.get("cost_limit_check")
    if s.get("cost_limit_met") is False and chk:
        print(f"pbicrl: warning: the final policy did not meet --cost-limit {chk['cost_limit']:g}: evaluation cost "
              f"{chk['evaluation_cost']:.3g} per episode, violating episodes {chk['violating_episodes']:.0%}; train "
              "longer (--steps), raise --lagrange-lr or lower --lr", file=sys.stderr)
    return 0


def add_subcommands(sub: Any) -> None:
    """Register ``pbicrl train-safe`` (imports nothing optional until it runs)."""
    from pbicrl.cli.argtypes import nonneg_float, nonneg_int, open_unit, positive_float, positive_int

    p = sub.add_parser("train-safe", help="train a policy under an inferred constraint (PPO-Lagrangian; extras rl, envs)",
                       description="Constrained RL on the cost of an inferred constraint: maximise the nominal return "
                                   "subject to expected cost per episode <= --cost-limit. Resumable: rerun the same "
                                   "command to continue.")
    p.add_argument("run", nargs="?", type=Path, help="run directory of pbicrl infer (needed for --cost inferred)")
    p.add_argument("--env", required=True, choices=ENVS, help="environment (its nominal reward is the objective)")
    p.add_argument("--steps", required=True, type=positive_int, help="total environment steps")
    p.add_argument("--cost-limit", type=nonneg_float, default=DEFAULT_COST_LIMIT,
                   help=f"budget D on the expected cost per episode (default {DEFAULT_COST_LIMIT:g})")
    p.add_argument("--out", required=True, type=Path, help="run directory (checkpoint, progress.log, budget.json, ...)")
    p.add_argument("--seed", type=nonneg_int, default=0, help="random seed (default 0)")
    p.add_argument("--mode", choices=["conservative", "indicator", "probability", "sample", "penalty"], default=None,
                   help="how the posterior becomes a cost (default: conservative for parametric constraints - the "
                        "boundary at the edge of the identified region nearest the safe demonstrations -, else "
                        "indicator: 1 per step in a selected constraint)")
    p.add_argument("--quantile", type=open_unit, default=0.5, help="penalty mode: quantile of w_p | c=1 (default 0.5)")
    p.add_argument("--constraints", help="comma-separated constraints to cost (default: the selected set, or every "
                                         "feature with P(c=1) > 0 for probability/sample)")
    p.add_argument("--cost", choices=COSTS, default="inferred",
                   help="inferred (default): the run's constraint; true: the environment's true constraint "
                        "(reference); none: nominal only")
    p.add_argument("--warmup-steps", type=nonneg_int, default=0,
                   help="steps of nominal training (zero cost) before the cost is on (default 0)")
    p.add_argument("--eval-episodes", type=nonneg_int, default=20,
                   help="episodes of the final policy to evaluate into summary.json (default 20)")
    p.add_argument("--lr", type=positive_float, default=None,
                   help="PPO learning rate (default: the environment's, see pbicrl.experiments.safe_rl.ppo_config)")
    p.add_argument("--lagrange-lr", type=positive_float, default=None,
                   help="step of the Lagrange multiplier per unit of excess episode cost (default 0.05)")
    p.add_argument("--quiet", action="store_true", help="no progress lines on stderr (progress.log still has them)")
    p.set_defaults(func=_cmd_train_safe)
