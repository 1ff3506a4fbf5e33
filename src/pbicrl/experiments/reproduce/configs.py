"""The settings of a reproduction: the models the reports compare (in :class:`pbicrl.config.InferConfig`'s
names), the run context (:class:`Context`: output root, budget, pairs, executor, datasets) and running a list of
``infer`` tasks for one experiment."""

from __future__ import annotations

from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

from pbicrl.experiments.reproduce.paper import PAPER

__all__ = ["PAPER_PRIOR", "FLAT_PRIOR", "DEFAULT_MODEL", "NOT_DEFAULT", "BOOKKEEPING", "pairwise", "subsample",
           "Context", "run_infer_tasks", "has_data", "shipped_path", "wall_configs"]

# Settings of the models the reports compare, in InferConfig's names; every run is one chain.
PAPER_PRIOR = {"prior": "improper", "penalty_sign": "any"}  # the paper's flat improper prior (Algorithms 1-3)
FLAT_PRIOR = {"prior": "flat", "prior_low": -1000.0, "prior_high": 1000.0, "penalty_sign": "any"}
DEFAULT_MODEL = {"likelihood": "grouped", "chains": 1, "iterations": "auto"}  # pbicrl's default: grouped, half-t, until converged
NOT_DEFAULT = ("pairs", *PAPER_PRIOR, *FLAT_PRIOR)  # settings a default-model row drops (takes the defaults)
BOOKKEEPING = ("label", "n", "wall")  # keys of a run's config that only the report reads (not settings)


def pairwise(pairs: str | int) -> dict[str, Any]:
    """The paper's likelihood (Eq. 7) over ``pairs``, one chain."""
    return {"likelihood": "pairwise", "pairs": pairs, "chains": 1}


def subsample(n: int, seed: int) -> dict[str, Any]:
    """``n`` demonstrations per group drawn with ``seed``, which also draws the pairs (``pairs`` a number)."""
    return {"demos_per_group": n, "demos_seed": seed, "pairs_seed": seed}


@dataclass(frozen=True)
class Context:
    """What every experiment of one ``reproduce`` call shares.

    Attributes
    ----------
    out : Path
        Results root (``<out>/<experiment>/`` reports, ``<out>/runs/`` the cached runs).
    quick : bool
        40,000 iterations per chain instead of the paper's 400,000.
    pairs : {"all", "sampled"}
        Pairs of the paper's Eq. 7: every cross-group pair, or N random ones per group pair.
    seeds : int
        Seeds per setting (each seeds the subsample, the pairs and the chain).
    executor, workers, progress
        Passed to :func:`pbicrl.experiments.sweep.run_tasks`.
    iterations_override : int, optional
        Iterations per chain instead of the budget's.
    data : dict, optional
        Dataset name -> file used instead of the shipped one.
    """

    out: Path
    quick: bool
    pairs: str  # "all" or "sampled"
    seeds: int
    executor: Any
    workers: int | None
    progress: bool
    iterations_override: int | None = None
    data: dict[str, str] | None = None

    @property
    def iterations(self) -> int:
        if self.iterations_override is not None:
            return int(self.iterations_override)
        return 40_000 if self.quick else PAPER["hyperparameters"]["iterations"]

    def dataset(self, name: str) -> str:
        """Path of the dataset for ``name`` (a user override, else the shipped one)."""
        if self.data and name in self.data:
            return str(Path(self.data[name]).resolve())
        if not has_data(name):
            raise FileNotFoundError(f"the shipped dataset '{name}.npz' is missing; regenerate it with "
                                    f"'pbicrl envs demos' (see README) or pass --data {name}=PATH")
        return str(shipped_path(name))

    def pairs_for(self, n_per_group: int) -> str | int:
        """``pairs`` setting of a run with ``n_per_group`` demonstrations per group."""
        return "all" if self.pairs == "all" else int(n_per_group)


def run_infer_tasks(ctx: Context, configs: list[dict], names: list[str]) -> list[dict]:
    """Run ``infer`` tasks (the configs less their :data:`BOOKKEEPING` keys); their results in order, each with
    the run's ``runtime_s``."""
    from pbicrl.experiments.sweep import run_tasks
    from pbicrl.experiments.tasks import Task

    tasks = [Task("infer", {k: v for k, v in c.items() if k not in BOOKKEEPING}, name=n)
             for c, n in zip(configs, names)]
    res = run_tasks(tasks, ctx.out / "runs", ctx.executor, workers=ctx.workers, progress=ctx.progress, manifest=False)
    out = []
    for r in res.records:
        if r.status == "failed":
            raise RuntimeError(f"reproduce: run {r.task.dir_name} failed: {r.error}")
        out.append(dict(r.result) | {"runtime_s": r.runtime_s})  # the task's wall time (load, sample, save)
    return out


def shipped_path(name: str) -> Path:
    """Where the shipped dataset ``name`` (``point_mass``, ``grid``, ...) lives in the installed package."""
    return Path(str(resources.files("pbicrl") / "data" / f"{name}.npz"))


def has_data(name: str) -> bool:
    return shipped_path(name).is_file()


def wall_configs(ctx: Context, name: str, dataset: str, n: int, seeds: int,
                  model: str = "paper") -> tuple[list[dict], list[str]]:
    """Runs of one wall experiment at ``n`` per group. ``model``: ``paper`` (Algorithm 2 with the paper's Eq. 7 and
    flat improper prior) or ``default`` (pbicrl's default: grouped likelihood, half-t prior, reversible jump)."""
    paper = PAPER[name]
    hp = PAPER["hyperparameters"]
    configs, names = [], []
    for s in range(seeds):
        cfg = {"data": dataset, **subsample(n, s), "sampler": "paper", "iterations": ctx.iterations,
               "seed": s, "sigma": hp["sigma1_wall"], "sigma_theta": hp["sigma2_wall"], "f_s": hp["f_s_wall"],
               **pairwise(ctx.pairs_for(n)), **PAPER_PRIOR,
               "constraints": [{"family": "axis_halfspace", "dims": [0], "direction": ">=", "name": "wall"}],
               "n": n, "wall": paper["wall"]}
        if model == "default":
            cfg = {k: v for k, v in cfg.items() if k not in NOT_DEFAULT}
            cfg.update({"sampler": "pbicrl", **DEFAULT_MODEL, "label": "default"})
        elif model != "paper":
            raise ValueError(f"model: expected 'paper' or 'default', got {model!r}")
        configs.append(cfg)
        names.append(f"{name}-{'default-' if model == 'default' else ''}n{n}")
    return configs, names
