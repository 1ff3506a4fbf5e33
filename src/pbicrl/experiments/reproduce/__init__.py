"""``pbicrl reproduce``: the paper's experiments on the shipped demonstrations, each number next to the paper's.

Every experiment expands into independent runs (one MCMC chain each: a dataset subsample, a sampler, margins,
a seed), each an ``infer`` task (:mod:`pbicrl.experiments.tasks`, the kind sweeps use, with the settings of
:class:`pbicrl.config.InferConfig`) on the local process pool or Ray, so a killed reproduction resumes where
it stopped. Each writes ``<out>/<experiment>/report.md``, ``results.json`` and PNG figures. Pairs (``--pairs``,
formerly ``--protocol``): ``all`` (every cross-group pair of the N demonstrations per group, paper Eq. 7) or
``sampled`` (N random pairs per group pair, as the authors' code did).

The package: :mod:`~.paper` (the paper's numbers), :mod:`~.configs` (models, run context, running tasks),
:mod:`~.stats`, :mod:`~.markdown` (tables and report files), :mod:`~.figures` (matplotlib), and the experiments
(:mod:`~.navigation`, :mod:`~.walls`, :mod:`~.icl`). The command line is :mod:`pbicrl.cli.reproduce`.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any, Callable

from pbicrl._moved import moved_to_cli
from pbicrl.experiments.reproduce.configs import Context
from pbicrl.experiments.reproduce.icl import exp_icl
from pbicrl.experiments.reproduce.navigation import exp_fetch_reach, exp_grid, exp_point_mass
from pbicrl.experiments.reproduce.paper import PAPER
from pbicrl.experiments.reproduce.walls import exp_ant, exp_halfcheetah, exp_sensitivity

__all__ = ["EXPERIMENTS", "PAPER", "reproduce", "run_unit"]


def run_unit(config: dict, out_dir: Path) -> dict[str, Any]:
    """Deprecated (until pbicrl 0.3): a run of the retired ``reproduce-run`` task kind, in its old names.

    Runs :func:`pbicrl.experiments.tasks.run_infer` on the same settings in :class:`~pbicrl.config.InferConfig`'s
    names (:func:`~pbicrl.experiments.tasks.infer_config_of_reproduce_run`): the same draws.
    """
    from pbicrl.errors import warn
    from pbicrl.experiments.tasks import infer_config_of_reproduce_run, prepare_infer, run_infer

    warn("run_unit is deprecated and will be removed in pbicrl 0.3: reproductions are 'infer' tasks "
         "(pbicrl.experiments.tasks.run_infer)")
    return run_infer(prepare_infer(infer_config_of_reproduce_run(config)), out_dir)


EXPERIMENTS: dict[str, Callable[[Context], Path]] = {
    "grid": exp_grid, "point-mass": exp_point_mass, "fetch-reach": exp_fetch_reach, "halfcheetah": exp_halfcheetah,
    "ant": exp_ant, "sensitivity": exp_sensitivity,
}
EXPERIMENTS["icl"] = exp_icl  # not in `reproduce all`: hours of RL per seed


#: The datasets whose file ``data`` may replace.
DATA_NAMES = ("point_mass", "fetch_reach", "halfcheetah", "ant")


def _check_data_overrides(data: dict[str, str] | None) -> None:
    """Every override names a known dataset and has the shipped dataset's layout (features, state dimensions)."""
    from pbicrl.experiments.reproduce.configs import has_data, shipped_path
    from pbicrl.inference.data import load_dataset

    for name, path in (data or {}).items():
        if name not in DATA_NAMES and name != "grid":
            raise ValueError(f"data: unknown dataset name {name!r}; the experiments read {', '.join(DATA_NAMES)}")
        if not Path(path).exists() or not has_data(name):
            continue  # a missing file fails clearly where an experiment reads it (an experiment not run never does)
        ds = load_dataset(path)
        ref = load_dataset(shipped_path(name))
        # the layout the experiments index into: the number of features and the width of the states (names may
        # differ: a stand-in or a relabelled copy)
        checks = (("features", ds.n_features, ref.n_features),
                  ("state dimensions", None if ds.states is None else ds.states.shape[1:],
                   None if ref.states is None or ds.states is None else ref.states.shape[1:]))
        for what, got, want in checks:
            if got != want:
                raise ValueError(f"data: {name}={path} has {what} {got}, the experiments on {name} need {want} "
                                 f"(those of the shipped {name}.npz)")


def reproduce(experiment: str, *, out: str | Path = "results", quick: bool = False, pairs: str = "all",
              seeds: int = 5, executor: Any = "local", workers: int | None = None, progress: bool = True,
              iterations: int | None = None, data: dict[str, str] | None = None, **deprecated: Any) -> list[Path]:
    """Run one experiment (or ``"all"``) and return the report paths.

    Parameters
    ----------
    experiment : str
        A key of :data:`EXPERIMENTS` or ``"all"`` (every one but ``icl``).
    pairs : {"all", "sampled"}
        The pairs of the paper's likelihood: every cross-group pair (Eq. 7) or N random pairs per group pair
        with N the demonstrations per group (the authors' code). Formerly ``protocol``.
    data : dict, optional
        Dataset name (``point_mass``, ``fetch_reach``, ``halfcheetah``, ``ant``) -> a file to use instead of the
        shipped one. Formerly ``datasets``.
    iterations : int, optional
        Overrides the paper's 400,000 per chain (``quick``: 40,000).
    **deprecated
        ``protocol`` and ``datasets``, accepted until pbicrl 0.3 with a :class:`~pbicrl.errors.PbicrlWarning`.
    """
    from pbicrl.errors import warn

    for old, new in (("protocol", "pairs"), ("datasets", "data")):
        if old in deprecated:
            warn(f"reproduce() argument '{old}' is deprecated and will be removed in pbicrl 0.3: use '{new}'")
            value = deprecated.pop(old)
            if new == "pairs":
                pairs = value
            else:
                data = value
    if deprecated:
        raise TypeError(f"reproduce() got an unexpected keyword argument {next(iter(deprecated))!r}")
    if pairs not in ("all", "sampled"):
        raise ValueError(f"pairs: expected 'all' or 'sampled', got {pairs!r}")
    names = [n for n in EXPERIMENTS if n != "icl"] if experiment == "all" else [experiment]  # icl: hours
    for n in names:
        if n not in EXPERIMENTS:
            raise ValueError(f"experiment: unknown {n!r}; choose one of {', '.join(EXPERIMENTS)} or all")
    if int(seeds) < 1:
        raise ValueError(f"seeds: need at least 1, got {seeds}")
    _check_data_overrides(data)  # before hours of sampling: a wrong file must not fail at the end
    ctx = Context(Path(out), quick, pairs, int(seeds), executor, workers, progress, iterations, data)
    reports = []
    import warnings

    from pbicrl.errors import PbicrlWarning

    for n in names:
        t0 = time.perf_counter()
        try:
            with warnings.catch_warnings():  # hundreds of runs: the reports say what matters, not each run
                warnings.simplefilter("ignore", PbicrlWarning)
                reports.append(EXPERIMENTS[n](ctx))
        except FileNotFoundError as exc:
            if experiment != "all":
                raise
            print(f"reproduce: skipping {n}: {exc}")
            continue
        print(f"{n}: {time.perf_counter() - t0:.1f} s -> {reports[-1]}")
    return reports


__getattr__ = moved_to_cli(__name__, {"add_subcommands": "pbicrl.cli.reproduce"})  # the command line moved
