"""Command-line interface: ``pbicrl infer``, ``pbicrl info``, ``pbicrl synthetic`` (+ subcommands of the extras).

User errors (bad data, options or config) end with one line ``pbicrl: error: ...`` and exit status 2
(set ``PBICRL_DEBUG=1`` for the traceback); output directories are written atomically, so a failed run leaves nothing behind.
"""

from __future__ import annotations

import argparse
import errno
import functools
import json
import os
import re
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from pbicrl.cli.argtypes import floats as _floats
from pbicrl.cli.argtypes import iterations as _iterations
from pbicrl.cli.argtypes import margins as _margins
from pbicrl.cli.argtypes import nonneg_int as _nonneg_int
from pbicrl.cli.argtypes import pairs as _pairs
from pbicrl.cli.argtypes import positive_float as _positive_float
from pbicrl.cli.argtypes import positive_int as _positive_int
from pbicrl.cli.argtypes import power as _power
from pbicrl.cli.argtypes import rhat_target as _rhat_target
from pbicrl.config import InferConfig
from pbicrl.inference.data import resolve_dataset_path

_D = InferConfig()  # the defaults the help texts state (InferConfig is their one source)

__all__ = ["build_parser", "main"]

_USER_ERRORS: tuple[type[BaseException], ...] = (ValueError, FileExistsError, FileNotFoundError, ImportError,
                                               PermissionError, IsADirectoryError, NotADirectoryError)


# OSErrors that are about the user's files and file systems, not pbicrl: a line, not a traceback
_USER_ERRNOS = frozenset(getattr(errno, n) for n in ("EACCES", "EPERM", "EROFS", "ENOSPC", "EDQUOT", "ENAMETOOLONG",
                                                     "ENOENT", "ENOTDIR", "EISDIR", "EEXIST", "ELOOP", "EXDEV")
                         if hasattr(errno, n))
# What pbicrl writes beside an output while it works: the claim ``.<name>.lock`` and the temporaries
# ``.<name>.tmp-<host>.<pid>.<random>`` / ``.<name>.old-...`` (pbicrl._atomic.temporary_prefix)
_WORK_NAME = re.compile(r"^\.(?P<name>.+?)\.(?:lock|(?:tmp|old)-.*)$")


def _output_error(exc: OSError, args: argparse.Namespace) -> str | None:
    """The message for a failed write through one of pbicrl's own lock or temporary paths: it names the output
    the user asked for (``--out``) and the problem, not the internal path (``None`` for any other error)."""
    if not isinstance(exc.filename, (str, bytes, os.PathLike)) or not exc.filename:
        return None
    path = Path(os.fsdecode(exc.filename))
    for part in (path, *path.parents):
        m = _WORK_NAME.match(part.name)
        if m:
            target = part.parent / m.group("name")
            break
    else:
        return None
    out = getattr(args, "out", None)
    field = "out: " if out is not None and os.path.abspath(out) == os.path.abspath(target) else ""
    why = (exc.strerror or type(exc).__name__).lower()
    if exc.errno in (errno.EACCES, errno.EPERM, errno.EROFS):
        return f"{field}cannot write {target}: {why} in {target.parent} (choose a directory you can write to)"
    return f"{field}cannot write {target}: {why}"


def _add_model_options(p: argparse.ArgumentParser) -> None:
    """Options that define the model (shared by ``infer`` and ``identify``)."""
    p.add_argument("--config", type=Path, help="TOML file with the same settings (options below override it)")
    p.add_argument("--nominal-weights", type=_floats, help="known nominal weights w_n, e.g. '1,0,0,-1'")
    p.add_argument("--margins", type=_margins, help="K-1 consecutive gaps '0,2.9' or a matrix '0,0,6;0,0,2.9;0,0,0'")
    p.add_argument("--beta", type=_positive_float, help=f"inverse temperature (default {_D.beta:g})")
    p.add_argument("--candidates", help="comma-separated features that may be constraints (default: all)")
    p.add_argument("--penalty-sign", choices=["negative", "any"],
                   help="negative (default): penalties penalise, w_p <= 0; any: both signs")
    p.add_argument("--alpha", type=_positive_float,
                   help=f"identifiability level: pairs ordered with probability >= 1 - alpha (default {_D.alpha:g})")


def _add_pair_options(p: argparse.ArgumentParser) -> None:
    """Which comparisons the likelihood uses (shared by ``infer`` and ``identify``, which analyses the same ones)."""
    p.add_argument("--likelihood", choices=["grouped", "pairwise"],
                   help="grouped (default): exact grouped Plackett-Luce, calibrated; pairwise: the paper's Eq. 7")
    p.add_argument("--pairs", type=_pairs, help="pairwise only: 'all' cross-group pairs (default) or N per group pair")
    p.add_argument("--pairs-seed", type=_nonneg_int,
                   help="seed of the random pairs of --pairs N (default 0; identify analyses the same pairs)")


def _add_infer(sub: Any) -> None:
    p = sub.add_parser("infer", help="infer constraints from a grouped dataset (.npz)",
                       description="Sample the posterior over constraint indicators and penalty weights.")
    p.add_argument("data", type=Path, help="dataset .npz (see pbicrl.inference.data), or a name of a shipped dataset")
    p.add_argument("--out", type=Path, required=True, help="output directory (summary.json, chains.npz)")
    _add_model_options(p)
    _add_pair_options(p)
    p.add_argument("--power", type=_power, help="pairwise only: likelihood power in (0, 1] (default 1) or 'pairs'")
    p.add_argument("--sampler", choices=["pbicrl", "paper", "authors", "bpl"],
                   help="pbicrl (default), paper (Algorithm 1), authors (the authors' code), bpl")
    p.add_argument("--iterations", type=_iterations,
                   help="iterations per chain, or 'auto' (default): run until every reported quantity has converged "
                   "(--target-ess, --target-rhat) or --max-time is spent")
    p.add_argument("--target-ess", type=_positive_float,
                   help=f"--iterations auto: bulk and tail ESS every reported quantity needs (default {_D.target_ess:g})")
    p.add_argument("--target-rhat", type=_rhat_target,
                   help=f"--iterations auto: largest split R-hat (default {_D.target_rhat:g})")
    p.add_argument("--max-time", type=_positive_float,
                   help=f"--iterations auto: stop after this many seconds, converged or not (default {_D.max_time:g})")
    p.add_argument("--burn-in", type=_nonneg_int, help="warm-up iterations (default: 2,000 with --iterations auto, "
                   "else a quarter)")
    p.add_argument("--thin", type=_positive_int, help="keep every n-th draw (default: <= 10000 draws per chain)")
    p.add_argument("--chains", type=_positive_int, help=f"independent chains (default {_D.chains})")
    p.add_argument("--jobs", type=_positive_int, help="worker processes (default: one per core)")
    p.add_argument("--seed", type=_nonneg_int, help=f"random seed (default {_D.seed})")
    p.add_argument("--sigma", type=_positive_float, help=f"random-walk step (default {_D.sigma:g}; adapted for pbicrl)")
    p.add_argument("--fs", dest="f_s", type=_positive_int,
                   help=f"paper sampler: sampling frequency f_s (default {_D.f_s})")
    p.add_argument("--p-flip", type=float, help="pbicrl sampler: probability of a flip move (default 0.3 with "
                   "--iterations auto, else 0.5)")
    p.add_argument("--p-joint", type=float, help="pbicrl/bpl samplers: probability in [0, 1) of a joint step of all "
                   "active weights (adapted covariance; default 0.3 for pbicrl with --iterations auto, else 0)")
    p.add_argument("--prior", choices=["student-t", "flat", "normal"],
                   help="prior on penalty weights (default student-t: half-t on (-inf, 0], scale-aware)")
    p.add_argument("--prior-bounds", type=_floats,
                   help="bounds of the weight prior 'low,high' (default: -1000,1000 for flat, none otherwise)")
    p.add_argument("--prior-scale", type=_positive_float,
                   help=f"student-t/normal scale in units of 1/(beta*sd_j) of each feature (default {_D.prior_scale:g})")
    p.add_argument("--prior-df", type=_positive_float,
                   help=f"degrees of freedom of the student-t prior (default {_D.prior_df:g})")
    p.add_argument("--indicator-pi", type=float, help=f"Bernoulli prior P(c_j = 1) (default {_D.indicator_pi:g})")
    p.add_argument("--init-range", type=_floats, help="authors sampler: initial penalties uniform on 'low,high' "
                   f"(default {','.join(f'{x:g}' for x in _D.init_range)})")
    p.add_argument("--check", type=_positive_int, metavar="K",
                   help="also run a stratified K-fold posterior predictive check (K extra fits; check.json)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing output directory")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--json", action="store_true", help="print summary.json instead of the table")
    p.set_defaults(func=_cmd_infer)


def _config_from_args(args: argparse.Namespace) -> Any:
    from pbicrl.config import ConfigError, InferConfig, load_config

    cfg = load_config(args.config) if args.config else InferConfig()
    bounds = getattr(args, "prior_bounds", None)
    if bounds is not None and len(bounds) != 2:
        raise ConfigError(f"--prior-bounds: expected two numbers 'low,high', got {len(bounds)}")
    prior = getattr(args, "prior", None)
    return cfg.updated(
        nominal_weights=args.nominal_weights, margins=args.margins, beta=args.beta,
        power=getattr(args, "power", None), pairs=getattr(args, "pairs", None),
        pairs_seed=getattr(args, "pairs_seed", None),
        likelihood=getattr(args, "likelihood", None), sampler=getattr(args, "sampler", None),
        iterations=getattr(args, "iterations", None), burn_in=getattr(args, "burn_in", None),
        thin=getattr(args, "thin", None), chains=getattr(args, "chains", None), jobs=getattr(args, "jobs", None),
        seed=getattr(args, "seed", None), sigma=getattr(args, "sigma", None), f_s=getattr(args, "f_s", None),
        p_flip=getattr(args, "p_flip", None), p_joint=getattr(args, "p_joint", None),
        target_ess=getattr(args, "target_ess", None), target_rhat=getattr(args, "target_rhat", None),
        max_time=getattr(args, "max_time", None),
        prior=None if prior is None else prior.replace("-", "_"),
        prior_low=None if bounds is None else bounds[0], prior_high=None if bounds is None else bounds[1],
        prior_scale=getattr(args, "prior_scale", None), prior_df=getattr(args, "prior_df", None),
        penalty_sign=args.penalty_sign, alpha=args.alpha, indicator_pi=getattr(args, "indicator_pi", None),
        init_range=getattr(args, "init_range", None),
        candidates=None if args.candidates is None else [c.strip() for c in args.candidates.split(",") if c.strip()])


def _cmd_infer(args: argparse.Namespace) -> int:
    from pbicrl.api import infer_from_config
    from pbicrl.inference.data import load_dataset

    from pbicrl.io.runs import check_out_dir

    cfg = _config_from_args(args)
    data = resolve_dataset_path(args.data)
    inputs = [data, args.config]
    if args.out.resolve() == data.resolve():
        raise FileExistsError(f"out: {args.out} is the input dataset; choose another directory")
    # before sampling; claimed until written
    check_out_dir(args.out, overwrite=args.overwrite, claim=True, inputs=inputs)
    ds = load_dataset(data)
    post = infer_from_config(ds, cfg, progress=not args.no_progress)
    post.require_usable_draws()
    post.extra["data"]["path"] = str(data)
    extra_json = {}
    if args.check:
        from pbicrl.analysis.check import cross_validate

        print(f"posterior predictive check: {args.check}-fold cross-validation ({args.check} more fits)",
              file=sys.stderr)
        res = cross_validate(ds, args.check, lambda d: infer_from_config(d, cfg, progress=False), seed=cfg.seed)
        extra_json["check.json"] = res.to_dict()
        post.extra["check"] = {k: v for k, v in res.to_dict().items() if k != "folds"}
    post.save(args.out, overwrite=args.overwrite, extra_json=extra_json, inputs=inputs)
    if args.json:
        print(json.dumps(post.summary(), indent=2, allow_nan=False))
    else:
        print(post.table())
        if args.check:
            print(res.table())
        print(f"wrote {args.out / 'summary.json'} and {args.out / 'chains.npz'}")
    line = convergence_line(post)
    if line:
        print(line, file=sys.stderr if post.converged is False else sys.stdout)
    return 0


def convergence_line(post: Any) -> str:
    """One line on a run until converged: converged in how long, or NOT CONVERGED and what falls short."""
    conv = post.convergence
    if conv is None:
        return ""
    it = conv.get("iterations_run")
    if conv.get("converged"):
        return (f"converged in {conv['wall_s']:.1f} s ({it:,} iterations per chain, {conv['rounds']} rounds): every "
                f"reported quantity has R-hat < {conv['target_rhat']:g} and bulk/tail ESS >= {conv['target_ess']:g} "
                f"(smallest ESS {conv['min_ess']:.0f})")
    failing = conv.get("failing") or {}
    worst = "; ".join(f"{k}: {v}" for k, v in list(failing.items())[:3])
    return (f"NOT CONVERGED after {conv['wall_s']:.0f} s ({it:,} iterations per chain): {len(failing)} reported "
            f"quantities fall short ({worst}); do not trust the summaries yet - rerun with a larger --max-time")


def _add_identify(sub: Any) -> None:
    p = sub.add_parser("identify", help="what do the rankings identify? (separation analysis, no sampling)",
                       description="For each feature: whether the rankings bound its penalty, the separation "
                                   "scale min_penalty, and the directions along which the likelihood keeps "
                                   "increasing; identified intervals of parametric constraints.")
    p.add_argument("data", type=Path, help="dataset .npz, or a name of a shipped dataset")
    _add_model_options(p)
    _add_pair_options(p)
    p.add_argument("--json", action="store_true", help="print JSON instead of the table")
    p.add_argument("--companions", action=argparse.BooleanOptionalAction, default=None,
                   help="find, for every unbounded penalty, the sparsest set of penalties that must run off with it "
                        "(one LP each; default: for up to 200 unbounded penalties, when the LPs are small)")
    p.set_defaults(func=_cmd_identify)


def _cmd_identify(args: argparse.Namespace) -> int:
    from pbicrl.inference.data import load_dataset
    from pbicrl.analysis.identify import identify

    cfg = _config_from_args(args)
    ds = load_dataset(resolve_dataset_path(args.data))
    cset = None
    if cfg.constraints:
        from pbicrl.inference.constraints import ConstraintSet, constraint_from_dict

        cset = ConstraintSet(tuple(constraint_from_dict(c) for c in cfg.constraints), ds)
    prefs = None
    if cfg.pairs not in (None, "all"):  # identify what the fitted likelihood uses: the same sampled pairs
        from pbicrl.inference.preferences import Preferences

        if cfg.likelihood != "pairwise":
            raise ValueError(f"--pairs: sampling {cfg.pairs} pairs per group pair applies to --likelihood pairwise "
                             "only; the grouped likelihood uses the whole ranking")

        prefs = Preferences.from_groups(ds.group, cfg.margins, protocol=int(cfg.pairs), seed=cfg.pairs_seed,
                                        distinct=cfg.sampler == "authors")  # as infer samples them
    res = identify(ds, nominal_weights=cfg.nominal_weights, beta=cfg.beta, margins=cfg.margins, alpha=cfg.alpha,
                   candidates=cfg.candidates, penalty_sign=cfg.penalty_sign, constraints=cset,  # type: ignore[arg-type]
                   preferences=prefs, pairs_seed=cfg.pairs_seed if prefs is not None else None,
                   progress=True, companions=args.companions)
    if args.json:
        print(json.dumps(res.to_dict(), indent=2, allow_nan=False))
    else:
        print(res.table())  # its warning lines, once (they used to be printed again on stderr)
    return 0


def _add_info(sub: Any) -> None:
    p = sub.add_parser("info", help="describe a dataset")
    p.add_argument("data", type=Path)
    p.set_defaults(func=_cmd_info)


def _cmd_info(args: argparse.Namespace) -> int:
    from pbicrl.inference.data import load_dataset

    ds = load_dataset(resolve_dataset_path(args.data), allow_unlabelled=True)  # pools and labelling files too
    print(ds)
    print(f"lengths: min {ds.lengths.min()}, mean {ds.lengths.mean():.1f}, max {ds.lengths.max()}")
    print(f"nominal weights: {None if ds.nominal_weights is None else ds.nominal_weights.tolist()}")
    print(f"states: {None if ds.states is None else ds.states.shape[1]} columns; "
          f"actions: {None if ds.actions is None else ds.actions.shape[1]} columns")
    return 0


def _add_synthetic(sub: Any) -> None:
    p = sub.add_parser("synthetic", help="write a synthetic grouped dataset with known constraints")
    p.add_argument("out", type=Path, help="output .npz")
    p.add_argument("--per-group", type=_positive_int, default=60)
    p.add_argument("--seed", type=_nonneg_int, default=0)
    p.add_argument("--overwrite", action="store_true", help="replace an existing file")
    p.set_defaults(func=_cmd_synthetic)


def _cmd_synthetic(args: argparse.Namespace) -> int:
    from pbicrl.inference.synthetic import make_problem

    if args.out.exists() and not args.overwrite:
        raise FileExistsError(f"out: {args.out} already exists; choose another file or pass --overwrite")
    prob = make_problem(args.per_group, labels="violations", violation_rate=0.4, seed=args.seed)
    path = prob.dataset.save(args.out, overwrite=args.overwrite)
    print(f"wrote {path}: {prob.dataset}; true penalty {prob.true_penalty.tolist()}")
    return 0


def _add_tune(sub: Any) -> None:
    p = sub.add_parser("tune-margins", help="search margins so that group-mean returns show a stated gap relation",
                       description="Search margins m_kl so that, under the inferred weights, the gaps between "
                                   "consecutive group-mean returns relate as stated (e.g. --relation 1,4: the G2-G3 gap "
                                   "is 4 times the G1-G2 gap).")
    p.add_argument("data", type=Path, help="dataset .npz or shipped dataset name")
    p.add_argument("--relation", type=_floats, required=True, help="relative sizes of the K-1 consecutive gaps, e.g. 1,4")
    p.add_argument("--out", type=Path, required=True, help="output directory (tuning.json, summary.json, chains.npz)")
    p.add_argument("--grid", type=_floats, help="values tried for each consecutive gap (default 0,0.5,1,1.5,2,3,4,6)")
    p.add_argument("--config", type=Path, help="TOML with the inference settings (as for infer)")
    p.add_argument("--iterations", type=_positive_int, help="iterations per candidate run (default 50000)")
    p.add_argument("--chains", type=_positive_int, help="chains per candidate run (default 1)")
    p.add_argument("--sampler", choices=["pbicrl", "paper", "authors", "bpl"])
    p.add_argument("--seed", type=_nonneg_int)
    p.add_argument("--estimator", choices=["selected", "map", "mean"], default="selected",
                   help="weights for the group means: selected set with conditional medians (default), map, mean")
    p.add_argument("--overwrite", action="store_true")
    p.add_argument("--no-progress", action="store_true")
    p.set_defaults(func=_cmd_tune)


def _cmd_tune(args: argparse.Namespace) -> int:
    from pbicrl.api import infer_from_config
    from pbicrl.config import InferConfig, load_config
    from pbicrl.inference.data import load_dataset
    from pbicrl.analysis.margins import DEFAULT_GAP_GRID, tune_margins
    from pbicrl.io.runs import write_run_dir

    cfg = load_config(args.config) if args.config else InferConfig(iterations=50_000, chains=1)
    cfg = cfg.updated(iterations=args.iterations, chains=args.chains, sampler=args.sampler, seed=args.seed)
    from pbicrl.io.runs import check_out_dir

    if args.grid is not None and len(args.grid) == 0:
        raise ValueError("--grid: no values; give the gaps to try, e.g. --grid 0,0.5,1,2 (or leave it out for the "
                         "default)")
    data = resolve_dataset_path(args.data)
    check_out_dir(args.out, overwrite=args.overwrite, claim=True, inputs=[data, args.config])
    ds = load_dataset(data)
    from dataclasses import replace

    res = tune_margins(ds, args.relation, gap_grid=DEFAULT_GAP_GRID if args.grid is None else args.grid, estimator=args.estimator,
                       progress=not args.no_progress,
                       run=lambda m: infer_from_config(ds, replace(cfg, margins=m.matrix.tolist()), progress=False))
    post = res.posterior
    post.require_usable_draws()
    post.extra.setdefault("data", {})["path"] = str(data)
    post.extra["margin_tuning"] = res.to_dict()
    summary = post.summary()
    arrays = {"indicators": post.indicators, "penalty_weights": post.penalty_weights, "parameters": post.parameters,
              "log_likelihood": post.log_likelihood}
    write_run_dir(args.out, {"summary.json": summary, "tuning.json": res.to_dict()}, {"chains.npz": arrays},
                  overwrite=args.overwrite, inputs=[data, args.config])
    print(f"chosen margins: {res.margins.as_dict()}")
    print(f"gap relation asked {np.round(res.relation_target, 3).tolist()}, achieved "
          f"{np.round(res.relation_achieved, 3).tolist()} (error {res.error:.4f}; {len(res.table)} candidates)")
    print(post.table())
    print(f"wrote {args.out / 'tuning.json'}")
    return 0


def _add_check(sub: Any) -> None:
    p = sub.add_parser("check", help="posterior predictive check on held-out demonstrations",
                       description="Log score of the held-out grouping: the log posterior predictive probability "
                                   "of how the held-out demonstrations are grouped (grouped likelihood, the run's "
                                   "beta and margins, averaged over draws) against the nominal-only model and the "
                                   "prior; a reliability table of the predicted group probabilities; and, as one "
                                   "line, the pair accuracy.")
    p.add_argument("run", type=Path, help="run directory written by 'pbicrl infer'")
    p.add_argument("--data", type=Path, required=True, help="held-out grouped dataset (.npz or a shipped name)")
    p.add_argument("--draws", type=_positive_int, default=400, help="posterior draws to score (default 400)")
    p.add_argument("--calibration-draws", type=_nonneg_int, default=50,
                   help="posterior draws for the reliability table (default 50; 0: no table; costs N x K "
                        "likelihoods per draw)")
    p.add_argument("--seed", type=_nonneg_int, default=0)
    p.add_argument("--json", action="store_true", help="print JSON instead of the table")
    p.set_defaults(func=_cmd_check)


def _cmd_check(args: argparse.Namespace) -> int:
    from pbicrl.analysis.check import predictive_check
    from pbicrl.inference.data import load_dataset
    from pbicrl.io.runs import read_run

    run = read_run(args.run)
    res = predictive_check(run, load_dataset(resolve_dataset_path(args.data)), n_draws=args.draws, seed=args.seed,
                           calibration_draws=args.calibration_draws)
    print(json.dumps(res.to_dict(), indent=2) if args.json else res.table())
    return 0


def build_parser() -> argparse.ArgumentParser:
    from pbicrl._version import __version__

    parser = argparse.ArgumentParser(prog="pbicrl", description="Bayesian constraint inference from ranked demonstrations")
    parser.add_argument("--version", action="version", version=f"pbicrl {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    _add_infer(sub)
    _add_identify(sub)
    _add_info(sub)
    _add_synthetic(sub)
    _add_tune(sub)
    _add_check(sub)
    for mount, commands in _EXTENSIONS.items():
        _mount(sub, mount, commands)
    return parser


# Subcommands contributed by other subpackages (module -> the subcommands it adds); each module exposes
# add_subcommands(subparsers) and must not import optional dependencies at module level.
_EXTENSIONS: dict[str, tuple[str, ...]] = {
    "pbicrl.cli.sweep": ("sweep",), "pbicrl.cli.reproduce": ("reproduce",),
    "pbicrl.cli.posterior": ("diagnose", "plot", "export", "import"), "pbicrl.cli.envs": ("envs",),
    "pbicrl.cli.train_safe": ("train-safe",), "pbicrl.cli.icrl_benchmark": ("benchmark",), "pbicrl.cli.label": ("label", "pool", "suggest"),
}

# Top-level modules of optional dependencies -> the extra that installs them (pyproject.toml).
_EXTRAS: dict[str, str] = {
    "matplotlib": "plot", "gymnasium": "envs", "mujoco": "envs", "gymnasium_robotics": "envs", "torch": "rl",
    "stable_baselines3": "rl", "minari": "minari", "ray": "ray", "arviz": "diag", "h5netcdf": "diag",
    "h5py": "diag", "pandas": "diag", "pyarrow": "io", "starlette": "ui", "uvicorn": "ui",
}


def _mount(sub: Any, module_name: str, commands: Sequence[str]) -> None:
    """Add a module's subcommands; if an optional dependency is missing, commands that say which extra to install.

    Any other ImportError (a broken pbicrl module) is raised: a subcommand is never dropped silently.
    """
    import importlib

    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        missing = (exc.name or "").partition(".")[0]
        extra = _EXTRAS.get(missing)
        if extra is None:
            raise
        for command in commands:
            p = sub.add_parser(command, help=f'(needs pip install "pbicrl[{extra}]")')
            p.add_argument("args", nargs=argparse.REMAINDER, help=argparse.SUPPRESS)
            p.set_defaults(func=functools.partial(_needs_extra, command, missing, extra))
        return
    module.add_subcommands(sub)


def _needs_extra(command: str, missing: str, extra: str, args: argparse.Namespace) -> int:
    raise ImportError(f'pbicrl {command} needs {missing}, which is not installed: pip install "pbicrl[{extra}]"')


_NEGATIVE_VALUE = re.compile(r"^-(\d|\.\d|inf|nan)", re.IGNORECASE)


def _join_negative_values(argv: Sequence[str]) -> list[str]:
    """``--prior-bounds -1000,1000`` -> ``--prior-bounds=-1000,1000``.

    argparse takes a value starting with ``-`` for an option unless it is a plain negative number, so lists
    such as ``-1000,1000`` or ``-1,0,0,1`` would fail with "expected one argument".
    """
    out: list[str] = []
    i = 0
    argv = list(argv)
    while i < len(argv):
        tok = argv[i]
        if (tok.startswith("--") and "=" not in tok and len(tok) > 2 and i + 1 < len(argv)
                and _NEGATIVE_VALUE.match(argv[i + 1])):
            out.append(f"{tok}={argv[i + 1]}")
            i += 2
            continue
        out.append(tok)
        i += 1
    return out


def _one_line_warnings(show: Any) -> Any:
    """``warnings.showwarning`` that prints a :class:`~pbicrl.errors.PbicrlWarning` as ``pbicrl: warning: ...``."""
    from pbicrl.errors import PbicrlWarning

    def one_line(message: Warning | str, category: type[Warning], filename: str, lineno: int, file: Any = None,
                 line: str | None = None) -> None:
        if issubclass(category, PbicrlWarning):
            print(f"pbicrl: warning: {message}", file=sys.stderr)
        else:
            show(message, category, filename, lineno, file, line)

    one_line.pbicrl_one_line = True  # type: ignore[attr-defined]
    return one_line


def main(argv: Sequence[str] | None = None) -> int:
    import warnings

    from pbicrl.errors import PbicrlWarning

    # The commands print the library's warnings themselves ("warning: ..." after the table); Python's own
    # print of the same PbicrlWarning would repeat each one with a source line. Deprecated setting names (in a
    # --config or sweep file) are printed by no command: those are shown, once each, as one line.
    warnings.simplefilter("ignore", PbicrlWarning)
    warnings.filterwarnings("default", message=r".* is deprecated and will be removed in pbicrl", category=PbicrlWarning)
    if not getattr(warnings.showwarning, "pbicrl_one_line", False):
        warnings.showwarning = _one_line_warnings(warnings.showwarning)
    parser = build_parser()
    args = parser.parse_args(_join_negative_values(sys.argv[1:] if argv is None else argv))
    try:
        return int(args.func(args) or 0)
    except (*_USER_ERRORS, OSError) as exc:
        if os.environ.get("PBICRL_DEBUG") or (not isinstance(exc, _USER_ERRORS) and exc.errno not in _USER_ERRNOS):
            raise
        msg = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        if isinstance(exc, OSError):
            msg = _output_error(exc, args) or msg
        from pbicrl.io.runs import OutputExistsError

        if isinstance(exc, OutputExistsError):  # the library says overwrite=True; the command line has a flag
            msg = f"{exc.field}: {exc.path} already exists; choose another {exc.kind} or pass --overwrite"
        if msg.startswith("out_dir: "):  # the library names its argument; the command line's is --out
            msg = "out: " + msg[len("out_dir: "):]
        print(f"pbicrl: error: {msg}", file=sys.stderr)
        return 2
    except MemoryError:
        fewer = "candidates (--candidates)" if getattr(args, "func", None) is _cmd_identify else "chains/draws"
        print(f"pbicrl: error: out of memory; use a smaller dataset or fewer {fewer}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("pbicrl: interrupted; no output written", file=sys.stderr)
        return 130
    finally:
        from pbicrl.io.runs import release_out_dir

        release_out_dir()  # output directories the command claimed and did not write (it failed)

