"""Command line for the grid / point-mass / Fetch-Reach demonstrations: ``python -m pbicrl.envs``.

Subcommands (mountable into another CLI with :func:`add_subcommands`, e.g. as ``pbicrl envs``):

``train``   train or resume a SAC demonstrator (good = true reward, violating = nominal reward)
``demos``   roll both demonstrators out into a ranked ``.npz`` dataset (+ JSON report, optional Minari);
            ``--paper-protocol``: the paper's design (one start distribution, a policy mix, groups
            from the worst region entered), how the shipped data are made
``plot``    PNG of a dataset's trajectories coloured by group
``grid``    write the 3x3-grid example dataset (paper Fig. 1)
``minari-to-npz``  convert a local Minari dataset written by ``demos --minari-id`` to ``.npz``

Regenerate everything shipped in ``pbicrl/data`` from scratch (``docs/envs.md`` lists the
exact budgets)::

    python -m pbicrl.envs grid --out src/pbicrl/data/grid.npz
    python -m pbicrl.envs train --env point_mass --reward nominal --steps 40000 --ship src/pbicrl/data/policies
    python -m pbicrl.envs train --env point_mass --reward true --steps 30000 --ship src/pbicrl/data/policies \
        --relabel-from runs/envs/point_mass_nominal
    python -m pbicrl.envs demos --env point_mass --paper-protocol --out src/pbicrl/data/point_mass.npz
    python -m pbicrl.envs plot --env point_mass --dataset src/pbicrl/data/point_mass.npz \
        --out docs/figures/point_mass_demos.png
    (the same for --env fetch_reach with --steps 12000 / 40000)

``demos --paper-protocol`` takes its defaults (mix probability ``--p-good``, stochastic actions,
start distribution ``--start``, seed) from :data:`pbicrl.demonstrators.navigation.PAPER_PROTOCOL`
and writes the full command into the JSON report.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path

from pbicrl.cli.argtypes import positive_int as _positive_int, probability
from pbicrl._atomic import copy_file

__all__ = ["DATA_DIR", "add_subcommands", "build_parser", "main", "shipped_policy"]

DATA_DIR = Path(__file__).resolve().parent.parent / "data"
_ROLE = {"true": "good", "nominal": "violating"}


def _start_names(env: str) -> tuple[str, ...]:
    """Start distributions a --paper-protocol run may use (PointMassEnv / FetchReachConstrainedEnv ``start``)."""
    if env == "point_mass":
        from pbicrl.envs.point_mass import START_STRIPS

        return tuple(START_STRIPS)
    from pbicrl.envs.fetch_reach import START_BOXES

    return tuple(START_BOXES)


def shipped_policy(env: str, role: str) -> Path:
    """Path of a shipped policy, ``pbicrl/inference/data/policies/<env>_<role>.zip`` (role: good | violating)."""
    if role not in ("good", "violating"):
        raise ValueError(f"role: expected 'good' or 'violating', got {role!r}")
    return DATA_DIR / "policies" / f"{env}_{role}.zip"


def npz_path(path: Path) -> Path:
    """The file ``Dataset.save`` writes for ``path`` (``.npz`` appended to another suffix)."""
    path = Path(path)
    return path if path.suffix == ".npz" else path.with_suffix(path.suffix + ".npz" if path.suffix else ".npz")


def check_outputs(outputs: Sequence[Path | None], overwrite: bool, inputs: Sequence[Path | None] = (),
                  field: str = "--out") -> None:
    """Before any work: an existing output file is replaced only with ``--overwrite``, an input never."""
    from pbicrl._atomic import check_file_output

    for out in outputs:
        if out is not None:
            check_file_output(out, overwrite=overwrite, inputs=[i for i in inputs if i is not None], field=field)


def _cmd_train(args: argparse.Namespace) -> int:
    from pbicrl.demonstrators.navigation import train_nav_policy

    out = args.out or Path("runs") / "envs" / f"{args.env}_{args.reward}"
    kwargs = dict(seed=args.seed, checkpoint_every=args.checkpoint_every, log_every=args.log_every,
                  torch_threads=args.torch_threads, progress=not args.quiet)
    kwargs.update({k: getattr(args, k) for k in ("learning_starts", "shaping_scale", "init_from")
                   if getattr(args, k) is not None})  # given: passed on; else the trainer's defaults
    if args.relabel_from is not None:
        from pbicrl.demonstrators.navigation import NAV_ENVS, relabelled_warm_start

        if (Path(out) / "checkpoint").exists():
            print(f"error: --relabel-from: {out} already holds a checkpoint (resume without the flag)", file=sys.stderr)
            return 2
        ent = NAV_ENVS[args.env].ent_coef
        relabelled_warm_start(args.relabel_from, args.env, args.reward, out, seed=args.seed, tau=args.tau,
                              ent_coef=ent if isinstance(ent, float) else 0.05, shaping_scale=args.shaping_scale)
        kwargs.setdefault("learning_starts", 0)
    try:
        policy = train_nav_policy(args.env, args.reward, out, args.steps, **kwargs)
    except KeyboardInterrupt as exc:
        print(f"interrupted: {exc}", file=sys.stderr)
        return 130
    if args.ship is not None:
        stem = f"{args.env}_{_ROLE[args.reward]}"
        copy_file(policy, Path(args.ship) / f"{stem}.zip")
        copy_file(Path(out) / "budget.json", Path(args.ship) / f"{stem}.budget.json")
    print(policy)
    return 0


def _paper_protocol_command(args: argparse.Namespace, p_good: float, deterministic: bool, start: str,
                            seed: int, max_episodes: int) -> str:
    """The canonical command line that regenerates a ``--paper-protocol`` dataset."""
    parts = ["python -m pbicrl.envs demos", f"--env {args.env}", "--paper-protocol", f"--p-good {p_good:g}",
             "--deterministic" if deterministic else "--stochastic", f"--start {start}", f"-n {args.n}",
             f"--seed {seed}", f"--max-episodes {max_episodes}"]
    for flag, value in (("--good-policy", args.good_policy), ("--violating-policy", args.violating_policy)):
        if value is not None:
            parts.append(f"{flag} {value}")
    parts.append(f"--out {args.out}")
    return " ".join(parts)


def _cmd_demos(args: argparse.Namespace) -> int:
    from pbicrl.demonstrators.navigation import PAPER_PROTOCOL, generate_navigation_demos, generate_paper_protocol_demos

    if args.paper_protocol and args.g1_from_violating:
        print("error: --g1-from-violating: not with --paper-protocol (which labels every rollout by the regions "
              "it entered)", file=sys.stderr)
        return 2
    if not args.paper_protocol:
        only = (("--p-good", args.p_good), ("--start", args.start), ("--deterministic", args.deterministic or None))
        for flag, value in only:
            if value is not None:
                print(f"error: {flag}: only with --paper-protocol", file=sys.stderr)
                return 2
    if args.start is not None and args.start not in _start_names(args.env):
        print(f"error: --start: expected one of {', '.join(_start_names(args.env))} for {args.env}, got "
              f"{args.start!r}", file=sys.stderr)
        return 2
    good = None if args.g1_from_violating else (args.good_policy or shipped_policy(args.env, "good"))
    bad = args.violating_policy or shipped_policy(args.env, "violating")
    for name, p in (("--good-policy", good), ("--violating-policy", bad)):
        if p is not None and not Path(p).is_file():
            print(f"error: {name}: no such file {p} (train it with `python -m pbicrl.envs train`)", file=sys.stderr)
            return 2
    out = npz_path(args.out)
    check_outputs([out, out.with_suffix(".json")], args.overwrite, [good, bad])
    if args.paper_protocol:
        defaults = PAPER_PROTOCOL[args.env]
        p_good = defaults["p_good"] if args.p_good is None else args.p_good
        deterministic = defaults["deterministic"] if not (args.stochastic or args.deterministic) else args.deterministic
        start = args.start or defaults["env_kwargs"]["start"]
        seed = args.seed if args.seed is not None else defaults["seed"]
        max_episodes = args.max_episodes or 50_000
        command = _paper_protocol_command(args, p_good, deterministic, start, seed, max_episodes)
        res = generate_paper_protocol_demos(args.env, good, bad, args.out, p_good=p_good, n_per_group=args.n,
                                            seed=seed, deterministic=deterministic, max_episodes=max_episodes,
                                            env_kwargs={"start": start}, command=command,
                                            return_episodes=args.minari_id is not None)
    else:
        res = generate_navigation_demos(args.env, good, bad, args.out, n_per_group=args.n, seed=args.seed or 0,
                                        max_episodes=args.max_episodes or 20_000, deterministic=not args.stochastic,
                                        return_episodes=args.minari_id is not None)
    report = res[1]
    if args.minari_id is not None:
        from pbicrl.envs.minari_io import episodes_to_minari
        from pbicrl.envs.registration import register_envs

        register_envs()
        import gymnasium as gym

        env_id = "pbicrl/PointMass-v0" if args.env == "point_mass" else "pbicrl/FetchReachConstrained-v0"
        env = gym.make(env_id, reward_weights="true", **report.get("env_kwargs", {}))
        report["minari"] = str(episodes_to_minari(res[2], args.minari_id, env=env, root=args.minari_root,
                                                  overwrite=args.overwrite))
        env.close()
    print(json.dumps(report, indent=2, sort_keys=True))
    return 0


def _cmd_plot(args: argparse.Namespace) -> int:
    from pbicrl.demonstrators.navigation import plot_navigation_demos

    check_outputs([args.out], args.overwrite, [args.dataset])
    print(plot_navigation_demos(args.dataset, args.env, args.out, max_per_group=args.max_per_group,
                                seed=args.seed, title=args.title))
    return 0


def _cmd_grid(args: argparse.Namespace) -> int:
    from pbicrl.envs.grid import grid_dataset

    check_outputs([npz_path(args.out)], args.overwrite)
    print(grid_dataset().save(args.out))
    return 0


def _cmd_minari_to_npz(args: argparse.Namespace) -> int:
    from pbicrl.io.minari import from_minari
    from pbicrl.envs.regions import FEATURE_NAMES

    check_outputs([npz_path(args.out)], args.overwrite)
    nominal = None
    if args.env == "point_mass":
        from pbicrl.envs.point_mass import POINT_MASS_TASK

        nominal = POINT_MASS_TASK.nominal_weights
    elif args.env == "fetch_reach":
        from pbicrl.envs.fetch_reach import FETCH_REACH_TASK  # needs gymnasium only, not mujoco

        nominal = FETCH_REACH_TASK.nominal_weights
    print(from_minari(args.id, root=args.root, feature_names=FEATURE_NAMES, nominal_weights=nominal,
                      actions=False).save(args.out))
    return 0


def add_subcommands(subparsers: argparse._SubParsersAction) -> None:
    """Add ``train``, ``demos``, ``plot``, ``grid`` and ``minari-to-npz``; each sets ``func``."""
    envs = ["point_mass", "fetch_reach"]
    p = subparsers.add_parser("train", help="train/resume a SAC demonstrator (point mass or Fetch-Reach)")
    p.add_argument("--env", required=True, choices=envs)
    p.add_argument("--reward", required=True, choices=["true", "nominal"],
                   help="true: good demonstrator (penalties); nominal: violating demonstrator")
    p.add_argument("--steps", type=_positive_int, default=None,
                   help="total SAC steps across resumes (default: the shipped policies' budget)")
    p.add_argument("--out", type=Path, default=None, help="run directory (default runs/envs/<env>_<reward>)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--learning-starts", type=int, default=None, help="random-action steps (default 40 episodes)")
    p.add_argument("--shaping-scale", type=float, default=None,
                   help="potential-based shaping scale during training (default per env; 0 = off)")
    p.add_argument("--init-from", type=Path, default=None,
                   help="warm start from an SB3 model zip (e.g. the nominal run's final_model.zip); "
                        "the shipped good policies were trained this way")
    p.add_argument("--relabel-from", type=Path, default=None,
                   help="start from this run's networks and replay buffer, rewards recomputed for --reward "
                        "(how the shipped good policies were trained from the nominal runs)")
    p.add_argument("--tau", type=float, default=0.05, help="target update rate of a --relabel-from run")
    p.add_argument("--checkpoint-every", type=_positive_int, default=10_000)
    p.add_argument("--log-every", type=_positive_int, default=2_000)
    p.add_argument("--torch-threads", type=_positive_int, default=1)
    p.add_argument("--ship", type=Path, default=None,
                   help="copy policy.zip and budget.json here as <env>_<good|violating>.zip/.budget.json")
    p.add_argument("--quiet", action="store_true")
    p.set_defaults(func=_cmd_train)

    p = subparsers.add_parser("demos", help="roll out both demonstrators into a ranked dataset")
    p.add_argument("--env", required=True, choices=envs)
    p.add_argument("--good-policy", type=Path, default=None, help="default: the shipped policy")
    p.add_argument("--violating-policy", type=Path, default=None, help="default: the shipped policy")
    p.add_argument("--paper-protocol", action="store_true",
                   help="the paper's design (how the shipped data are made): every rollout from one start "
                        "distribution, made by the good policy with probability --p-good else by the violating "
                        "one, grouped by the worst region it entered; all rollouts kept except those that miss "
                        "the goal; runs until every group holds at least -n")
    p.add_argument("--p-good", type=probability, default=None,
                   help="--paper-protocol: probability that a rollout uses the good policy (default: the shipped "
                        "data's, PAPER_PROTOCOL)")
    p.add_argument("--start", default=None,
                   help="--paper-protocol: start distribution; point_mass: balanced (default) | random | left | "
                        "bottom; fetch_reach: balanced (default) | equidistant | wide")
    p.add_argument("--g1-from-violating", action="store_true",
                   help="take G1 from the violating policy's rollouts that enter no region (no good policy)")
    p.add_argument("-n", type=_positive_int, default=300,
                   help="trajectories per group (--paper-protocol: at least this many per group)")
    p.add_argument("--seed", type=int, default=None, help="default 0")
    p.add_argument("--max-episodes", type=_positive_int, default=None,
                   help="rollout cap per policy (default 20,000); --paper-protocol: total rollouts (default 50,000)")
    actions = p.add_mutually_exclusive_group()
    actions.add_argument("--stochastic", action="store_true",
                         help="sample actions instead of the policy mean (default with --paper-protocol)")
    actions.add_argument("--deterministic", action="store_true",
                         help="--paper-protocol: use the policy mean (the default without --paper-protocol)")
    p.add_argument("--out", required=True, type=Path, help="output .npz (a .json report is written beside it)")
    p.add_argument("--minari-id", default=None, help="also write a local Minari dataset with this id")
    p.add_argument("--minari-root", type=Path, default=None, help="Minari datasets directory")
    p.add_argument("--overwrite", action="store_true",
                   help="replace an existing --out file (and its .json) or Minari dataset (never a policy)")
    p.set_defaults(func=_cmd_demos)

    p = subparsers.add_parser("plot", help="PNG of trajectories coloured by group")
    p.add_argument("--env", required=True, choices=envs)
    p.add_argument("--dataset", required=True, type=Path)
    p.add_argument("--out", required=True, type=Path)
    p.add_argument("--max-per-group", type=_positive_int, default=60)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--title", default=None)
    p.add_argument("--overwrite", action="store_true", help="replace an existing --out file")
    p.set_defaults(func=_cmd_plot)

    p = subparsers.add_parser("grid", help="write the 3x3 grid example dataset")
    p.add_argument("--out", required=True, type=Path)
    p.add_argument("--overwrite", action="store_true", help="replace an existing --out file")
    p.set_defaults(func=_cmd_grid)

    p = subparsers.add_parser("minari-to-npz", help="convert a local Minari dataset to .npz")
    p.add_argument("--id", required=True)
    p.add_argument("--root", type=Path, default=None)
    p.add_argument("--env", choices=envs, default=None, help="store this environment's nominal weights")
    p.add_argument("--out", required=True, type=Path)
    p.add_argument("--overwrite", action="store_true", help="replace an existing --out file")
    p.set_defaults(func=_cmd_minari_to_npz)


def build_parser() -> argparse.ArgumentParser:
    """Parser of ``python -m pbicrl.envs``."""
    from pbicrl.cli.argtypes import standalone_parser

    return standalone_parser("python -m pbicrl.envs", "pbicrl grid / point-mass / Fetch-Reach demonstrations", add_subcommands)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the CLI; returns the exit code."""
    args = build_parser().parse_args(argv)
    return int(args.func(args))
