"""Subcommands for using a posterior and bringing data in, mounted into ``pbicrl`` (see :mod:`pbicrl.cli`):

``pbicrl diagnose RUN_DIR``   R-hat and bulk / tail ESS of every penalty, indicator and parameter
``pbicrl plot RUN_DIR``       traces, posterior densities, P(constraint), penalty-vs-location pairs, MAP rewards
``pbicrl export RUN_DIR``     ArviZ InferenceData / DataTree as NetCDF
``pbicrl import csv|parquet|minari``  a table or a Minari dataset -> a dataset ``.npz``

Optional dependencies (ArviZ, matplotlib, pyarrow, minari) are imported only when a command runs.

Inputs are checked before anything is computed: a run directory's ``chains.npz`` must be a readable archive
whose arrays fit in memory, its ``summary.json`` a JSON object with the expected types, and no output may be
(or replace) an input file, ``--overwrite`` or not.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

from pbicrl._atomic import read_json
from pbicrl.cli.argtypes import floats as _floats
from pbicrl.cli.argtypes import positive_int as _positive_int

__all__ = ["add_subcommands", "check_run_dir", "load_run_checked"]

from pbicrl.io.runs import check_run_dir  # noqa: E402  (re-exported: the checks live with the reader)

# ---------------------------------------------------------------------------------------------- inputs
def _same_file(a: Path, b: Path) -> bool:
    try:
        return a.exists() and b.exists() and os.path.samefile(a, b)
    except OSError:
        return False


def _refuse_inputs(out: Path, inputs: Sequence[Path | None], flag: str) -> None:
    """An output may never be (or replace) an input file, with ``--overwrite`` or without."""
    for inp in inputs:
        if inp is None:
            continue
        if _same_file(out, inp) or Path(os.path.abspath(out)) == Path(os.path.abspath(inp)):
            raise ValueError(f"{flag}: {out} is an input of this command ({inp}); choose another output "
                             "(--overwrite never replaces an input)")


def load_run_checked(run_dir: str | os.PathLike[str]) -> Any:
    """:func:`pbicrl.io.runs.read_run` (which checks the files first; any malformation is a ``RunError``).

    The commands read runs as :class:`~pbicrl.io.runs.RunRecord` (no warnings issued on reading; ``pbicrl.load_run``
    gives a full :class:`~pbicrl.inference.posterior.Posterior`)."""
    from pbicrl.io.runs import read_run

    return read_run(run_dir)


@contextlib.contextmanager
def _flag_wording(flags: dict[str, str]) -> Iterator[None]:
    """Reword a library error that names an argument (``"truth: ..."``) with the command's flag (``--truth``)."""
    try:
        yield
    except (ValueError, FileNotFoundError) as exc:
        field, sep, rest = str(exc).partition(": ")
        if not sep or field not in flags or type(exc) not in (ValueError, FileNotFoundError):
            raise
        raise type(exc)(f"{flags[field]}: {rest}") from None


# ---------------------------------------------------------------------------------------------- diagnose
def _cmd_diagnose(args: argparse.Namespace) -> int:
    from pbicrl.analysis import diagnostics
    run = load_run_checked(args.run)
    diag = diagnostics.compute(run, backend="arviz" if args.require_arviz else "auto")
    if args.json:
        print(json.dumps(diag.to_dict(), indent=2))
    else:
        print(diag.table())
        for msg in diag.warnings():
            print(f"warning: {msg}")
    return 0


# ---------------------------------------------------------------------------------------------- plot
def _cmd_plot(args: argparse.Namespace) -> int:
    from pbicrl.analysis.plots import parse_truth, plot_run

    run = load_run_checked(args.run)
    with _flag_wording({"truth": "--truth", "fmt": "--format", "dpi": "--dpi"}):
        truth = parse_truth(args.truth, run.feature_names, tuple(getattr(run, "parameter_names", None) or ()))
    if args.data is not None:
        from pbicrl.inference.data import resolve_dataset_path

        args.data = resolve_dataset_path(args.data)
    if args.out is not None:
        if args.out.exists() and not args.out.is_dir():
            raise ValueError(f"--out: {args.out} is a file; plots go into a directory")
    with _flag_wording({"truth": "--truth", "fmt": "--format", "dpi": "--dpi"}):
        files = plot_run(run, args.out, dataset=args.data, truth=truth, fmt=args.format, dpi=args.dpi,
                         overwrite=args.overwrite)
    for f in files:
        print(f"wrote {f}")
    if not any(f.stem == "rewards" for f in files):
        print("note: no rewards plot (the run's dataset was not found; pass --data DATA.npz)")
    return 0


# ---------------------------------------------------------------------------------------------- export
def _cmd_export(args: argparse.Namespace) -> int:
    from pbicrl.analysis.export import to_netcdf

    run = load_run_checked(args.run)
    out = args.netcdf if args.netcdf is not None else Path(args.run) / "posterior.nc"
    if out.is_dir():
        raise ValueError(f"--netcdf: {out} is a directory; give a file name such as {out / 'posterior.nc'}")
    from pbicrl._atomic import OutputExistsError
    from pbicrl.inference.data import resolve_dataset_path

    recorded = getattr(run, "data_path", None)  # the dataset the run recorded: read for pointwise values
    data = resolve_dataset_path(args.data) if args.data else None
    _refuse_inputs(out, [args.run, Path(args.run) / "summary.json", Path(args.run) / "chains.npz", data,
                         None if recorded is None else Path(recorded)], "--netcdf")

    try:
        path = to_netcdf(run, out, overwrite=args.overwrite,
                         dataset=data,
                         pointwise=not args.no_pointwise, pointwise_draws=args.pointwise_draws)
    except OutputExistsError as exc:  # worded for Python (overwrite=True); here the flag is --overwrite
        raise FileExistsError(f"--netcdf: {exc.path} already exists; choose another file or pass --overwrite") from None
    if args.netcdf is None:  # RUN/posterior.nc belongs to the run: a later --overwrite of the run may replace it
        from pbicrl._atomic import mark_output, read_marker

        marker = read_marker(args.run)
        if marker is not None and marker[0] == "run":
            mark_output(args.run, "run", ["posterior.nc"])
    print(f"wrote {path}")
    return 0


# ---------------------------------------------------------------------------------------------- import
def _check_out(out: Path, overwrite: bool, inputs: Sequence[Path | None] = ()) -> None:
    """``--out`` of an import: a new ``.npz`` file name (an existing one only with ``--overwrite``), never a
    directory and never one of the command's inputs."""
    if out.is_dir():
        raise ValueError(f"--out: {out} is a directory; give a file name such as {out / 'demos.npz'}")
    if out.suffix != ".npz":
        raise ValueError(f"--out: expected a .npz file name, got {out}")
    _refuse_inputs(out, inputs, "--out")
    if (out.exists() or out.is_symlink()) and not overwrite:
        raise FileExistsError(f"--out: {out} already exists; choose another file or pass --overwrite")


def _spec_file(spec: str | None) -> Path | None:
    """The file of a 'file.py:function' spec (an input of the command), if it names one."""
    if not spec or ":" not in spec:
        return None
    mod = spec.rpartition(":")[0]
    return Path(mod) if mod.endswith(".py") else None


def _cmd_import_table(args: argparse.Namespace) -> int:
    from pbicrl.io import read_table

    _check_out(args.out, args.overwrite, [args.file])
    fmt = args.format
    kwargs: dict[str, Any] = {}
    if fmt in ("csv", "tsv") and args.delimiter is not None:
        kwargs["delimiter"] = args.delimiter
    ds = read_table(args.file, format=fmt, id_col=args.id_col, group_col=args.group_col,
                    feature_cols=args.feature_cols, state_cols=args.state_cols, action_cols=args.action_cols,
                    step_col=args.step_col, nominal_weights=args.nominal_weights, group_order=args.group_order,
                    **kwargs)
    ds.save(args.out, overwrite=args.overwrite)
    print(f"wrote {args.out}: {ds}")
    return 0


def _cmd_import_minari(args: argparse.Namespace) -> int:
    from pbicrl.io.minari import load_minari, require_minari
    from pbicrl.io import from_minari, load_feature_function

    groups_file = Path(args.groups) if args.groups and args.groups.endswith(".json") else _spec_file(args.groups)
    _check_out(args.out, args.overwrite, [_spec_file(args.features), groups_file])
    require_minari()  # before any user code runs: executing a feature file is pointless without minari
    # the dataset too: a typo in its id must not run the feature file first (the one place pbicrl runs a
    # user's code on purpose, with --groups module:function and a sweep's kind = "module:function")
    dataset = load_minari(args.dataset_id, args.root)
    fn = load_feature_function(args.features) if args.features else None
    groups: Any = None
    if args.groups:
        gp = Path(args.groups)
        if gp.suffix == ".json":
            groups = read_json(gp, "--groups")
            if isinstance(groups, dict):
                groups = {str(k): v for k, v in groups.items()}
        else:
            groups = load_feature_function(args.groups, option="--groups")
    names = [c.strip() for c in args.feature_names.split(",")] if args.feature_names else None
    ds = from_minari(dataset, fn, groups=groups, root=args.root, feature_names=names,
                     nominal_weights=args.nominal_weights, states=not args.no_states, actions=not args.no_actions)
    ds.save(args.out, overwrite=args.overwrite)
    print(f"wrote {args.out}: {ds}")
    return 0


def add_subcommands(sub: Any) -> None:
    """Add ``diagnose``, ``plot``, ``export`` and ``import`` to a subparsers object."""
    p = sub.add_parser("diagnose", help="R-hat and ESS of a run (pbicrl infer --out DIR)",
                       description="Convergence diagnostics of every penalty, indicator and parameter of a run.")
    p.add_argument("run", type=Path, help="run directory (summary.json + chains.npz)")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.add_argument("--require-arviz", action="store_true", help="compute R-hat and ESS with ArviZ itself (fails without it) instead of pbicrl's equal implementation")
    p.set_defaults(func=_cmd_diagnose)

    p = sub.add_parser("plot", help="figures of a run: traces, densities, P(constraint), pairs, rewards",
                       description="Write trace.png, posterior.png, p_constraint.png, pairs.png (parametric "
                                   "constraints) and rewards.png (when the dataset is known) for a run.")
    p.add_argument("run", type=Path, help="run directory (summary.json + chains.npz)")
    p.add_argument("--data", type=Path, help="dataset .npz for the rewards plot (default: the one the run used)")
    p.add_argument("--truth", help="true penalties/parameters: 'name=value,...' (e.g. in_red=-100,wall.threshold=8; unknown "
                        "names are an error), one value per feature, or a JSON file")
    p.add_argument("--out", type=Path, help="output directory (default RUN_DIR/plots)")
    p.add_argument("--format", choices=["png", "pdf", "svg"], default="png")
    p.add_argument("--dpi", type=_positive_int, default=None, help="resolution of PNG figures (default 200)")
    p.add_argument("--overwrite", action="store_true", help="replace figures of the same names in the directory")
    p.set_defaults(func=_cmd_plot)

    p = sub.add_parser("export", help="export a run to ArviZ NetCDF",
                       description="Write the posterior as ArviZ InferenceData (arviz < 1) or DataTree (arviz >= 1) "
                                   "in NetCDF: posterior indicator, penalty (c*w_p; penalty_weight for the paper "
                                   "sampler only), parameter; log_likelihood = each trajectory's share, for az.loo; "
                                   "sample_stats = total_log_likelihood, lp, log_prior, per-draw move and "
                                   "acceptance.")
    p.add_argument("run", type=Path, help="run directory (summary.json + chains.npz)")
    p.add_argument("--netcdf", type=Path, help="output .nc file (default RUN_DIR/posterior.nc)")
    p.add_argument("--data", type=Path, help="dataset of the run (default: the one recorded in the run)")
    p.add_argument("--pointwise-draws", type=_positive_int, default=500,
                   help="draws per chain for the per-trajectory log-likelihood (default 500)")
    p.add_argument("--no-pointwise", action="store_true", help="no per-trajectory log-likelihood")
    p.add_argument("--overwrite", action="store_true")
    p.set_defaults(func=_cmd_export)

    p = sub.add_parser("import", help="convert a CSV / Parquet table or a Minari dataset to a dataset .npz")
    isub = p.add_subparsers(dest="import_kind", required=True, metavar="SOURCE")
    for kind in ("csv", "parquet"):
        q = isub.add_parser(kind, help=f"one row per state: trajectory id, group, features ({kind})")
        q.add_argument("file", type=Path)
        q.add_argument("--out", type=Path, required=True, help="output dataset .npz")
        q.add_argument("--id-col", default="trajectory", help="trajectory id column (default 'trajectory')")
        q.add_argument("--group-col", default="group", help="group column, 1 = best (default 'group')")
        q.add_argument("--feature-cols", help="comma-separated feature columns (default: all other columns)")
        q.add_argument("--state-cols", help="comma-separated state columns (optional)")
        q.add_argument("--action-cols", help="comma-separated action columns (optional)")
        q.add_argument("--step-col", help="column ordering the rows of a trajectory (default: file order)")
        q.add_argument("--nominal-weights", type=_floats, help="known nominal weights, one per feature column")
        q.add_argument("--group-order", help="group names best first, when the group column holds names: "
                                             "'good,bad,very bad' (default: groups are integers, 1 = best)")
        if kind == "csv":
            q.add_argument("--delimiter", help="field separator, one character or 'tab' (default ',')")
        q.add_argument("--overwrite", action="store_true")
        q.set_defaults(func=_cmd_import_table, format=kind)
    q = isub.add_parser("minari", help="a local Minari dataset plus a feature function")
    q.add_argument("dataset_id", help="Minari dataset id (read locally, never downloaded)")
    q.add_argument("--out", type=Path, required=True, help="output dataset .npz")
    q.add_argument("--features", help="feature function 'module:function' (a module in the working directory "
                                      "or installed) or 'file.py:function', episode -> (T, d) array "
                                      "(default: infos['features'])")
    q.add_argument("--groups", help="JSON file {episode id: group} or [group, ...], or 'module:function' "
                                    "episode -> group (default: infos['group'])")
    q.add_argument("--root", type=Path, help="directory holding Minari datasets")
    q.add_argument("--feature-names", help="comma-separated feature names")
    q.add_argument("--nominal-weights", type=_floats)
    q.add_argument("--no-states", action="store_true", help="do not keep observations as states")
    q.add_argument("--no-actions", action="store_true", help="do not keep the episodes' actions")
    q.add_argument("--overwrite", action="store_true")
    q.set_defaults(func=_cmd_import_minari)
