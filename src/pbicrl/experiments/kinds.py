"""The built-in task kinds: ``infer`` (one inference run, what sweeps and ``pbicrl reproduce`` run),
``reproduce-icl`` (the ICL baseline, :func:`pbicrl.baselines.icl.run_icl_task`) and ``selftest`` (checks an
executor). Each is a top-level function ``run(config, out_dir) -> dict`` registered by name with
:func:`pbicrl.experiments.registry.register_task`; the engine that runs and caches them is
:mod:`pbicrl.experiments.tasks`. Also the renaming of the kinds' settings between cache versions
(:func:`rename_v2`), which :func:`pbicrl.experiments.tasks.adopt_older_runs` applies.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import time
from pathlib import Path
from typing import Any, Mapping

from pbicrl.experiments.registry import TaskError, in_task_worker, register_task, task_jobs

__all__ = ["INFER_EXTRA", "file_sha256", "shipped_data_tag", "prepare_data", "prepare_infer", "run_infer", "summarize_infer",
           "infer_result", "run_selftest", "infer_config_of_reproduce_run", "rename_v2"]


# --------------------------------------------------------------------------------------------- kind "infer"
_sha_cache: dict[tuple[str, int, int], str] = {}

INFER_EXTRA: dict[str, Any] = {"demos_per_group": None, "demos_seed": 0}
"""Settings of the ``infer`` kind besides ``data`` and the :class:`~pbicrl.config.InferConfig` fields: subsample
``demos_per_group`` demonstrations per group (default all) with seed ``demos_seed``."""


def _resolve_data(data: str) -> Path:
    from pbicrl.inference.data import DatasetNotFoundError, resolve_dataset_path

    try:
        return resolve_dataset_path(data)
    except DatasetNotFoundError as exc:
        raise TaskError(str(exc)) from None


def file_sha256(path: str | os.PathLike[str]) -> str:
    """SHA-256 (hex) of a file's content, cached per (path, size, modification time) in this process."""
    path = Path(path)
    st = path.stat()
    key = (str(path.resolve()), st.st_size, st.st_mtime_ns)
    if key not in _sha_cache:
        h = hashlib.sha256()
        with open(path, "rb") as fh:
            for block in iter(lambda: fh.read(1 << 20), b""):
                h.update(block)
        _sha_cache[key] = h.hexdigest()
    return _sha_cache[key]


def shipped_data_tag(name: str) -> str:
    """``<name>-<first 12 hex digits of the dataset file's SHA-256>``, e.g. ``point_mass-51c6750fa6d9``.

    Names cached results that depend on a shipped dataset, so that a regenerated file is never read through
    results computed on an older one.
    """
    from pbicrl.inference.data import resolve_dataset_path

    return f"{name}-{file_sha256(resolve_dataset_path(name))[:12]}"


def prepare_data(config: dict, *, allow: tuple[str, ...] = ()) -> dict:
    """Resolve a config's ``data`` (a dataset file or a shipped name) and record its content hash.

    Returns a copy with ``data`` (an existing file by absolute path, so that workers started elsewhere find
    it; a shipped dataset by name) and ``data_sha256``; the task kind hashes the content, not the path, so
    moving files keeps finished runs. ``allow`` lists values of ``data`` that name no file (e.g. ICL's
    ``"scripted"``); they pass unchanged.
    """
    config = dict(config)
    if "data" not in config:
        raise TaskError("data: missing; give a dataset .npz path or the name of a shipped dataset")
    data = config.pop("data")
    config.pop("data_sha256", None)
    if not isinstance(data, str):
        raise TaskError(f"data: expected a path or a dataset name, got {data!r}")
    if data in allow:
        return {"data": data} | config
    path = _resolve_data(data)
    if not path.is_file():
        raise TaskError(f"data: {data}: not a regular file")
    return {"data": str(path.resolve()) if Path(data).expanduser().is_file() else data,
            "data_sha256": file_sha256(path)} | config


def prepare_infer(config: dict) -> dict:
    """Validate an ``infer`` config and fill in every default (so that equivalent configs hash alike).

    Keys: ``data`` (a dataset .npz or the name of a shipped dataset), every :class:`~pbicrl.config.InferConfig`
    field (deprecated names such as ``method`` are renamed, with a :class:`~pbicrl.errors.PbicrlWarning`,
    before hashing: the old and the new name are the same run), and :data:`INFER_EXTRA`. The dataset's
    content is hashed (``data_sha256``); its path is not, so moving files keeps finished runs.
    """
    from pbicrl.config import ConfigError, canonical_names, check_setting

    defaults = _infer_fields()
    try:
        config = canonical_names(config, where="infer config key", stacklevel=4)
    except ConfigError as exc:
        raise TaskError(str(exc)) from None
    out = prepare_data(config)
    for key, value in config.items():
        if key in ("data", "data_sha256"):
            continue
        if key in INFER_EXTRA:
            low = 1 if key == "demos_per_group" else 0
            if value is not None and (isinstance(value, bool) or not isinstance(value, int) or value < low):
                raise TaskError(f"{key}: expected a {'positive' if low else 'non-negative'} integer, got {value!r}")
            continue
        if key not in defaults:
            known = ", ".join(sorted({"data", *defaults, *INFER_EXTRA}))
            raise TaskError(f"infer config key '{key}': unknown; known keys are {known}")
        try:
            check_setting(key, value, where="infer config")
        except ConfigError as exc:
            raise TaskError(str(exc)) from None
    given = {k: v for k, v in config.items() if k not in ("data", "data_sha256") and v is not None}  # None: default
    return {"data": out["data"], "data_sha256": out["data_sha256"]} | defaults | INFER_EXTRA | given


def _infer_fields() -> dict[str, Any]:
    from pbicrl.config import InferConfig

    return InferConfig.defaults()


def _infer_defaults() -> dict[str, Any]:
    return _infer_fields() | INFER_EXTRA


def _infer_dataset(config: Mapping[str, Any]) -> tuple[Any, Path, str]:
    """The (subsampled) dataset of an ``infer`` config, its path and content hash (checked against the config)."""
    from pbicrl.inference.data import load_dataset

    path = _resolve_data(config["data"])
    digest = file_sha256(path)
    if config.get("data_sha256") not in (None, digest):
        raise TaskError(f"data: {path} changed since the task was created (content hash differs)")
    ds = load_dataset(path)
    if config.get("demos_per_group") is not None:
        ds = ds.sample_per_group(int(config["demos_per_group"]), seed=int(config.get("demos_seed", 0)))
    return ds, path, digest


def run_infer(config: dict, out_dir: Path) -> dict[str, Any]:
    """Task kind ``infer`` (sweeps and ``pbicrl reproduce``): :func:`pbicrl.api.infer_from_config` on a dataset.

    Writes ``summary.json`` + ``chains.npz``. Inside an executor the chains use :func:`task_jobs` processes
    (usually 1: the executor already uses every core); the draws do not depend on it. The posterior's
    warnings are not printed (one run of many) but returned under ``warnings``. Returns
    :func:`infer_result`.
    """
    import warnings
    from dataclasses import replace

    from pbicrl.api import infer_from_config
    from pbicrl.config import InferConfig
    from pbicrl.errors import PbicrlWarning

    ds, path, digest = _infer_dataset(config)
    cfg = InferConfig(**{k: config[k] for k in _infer_fields() if k in config})
    if in_task_worker():
        cfg = replace(cfg, jobs=task_jobs())
    with warnings.catch_warnings():  # one run of many: the result lists them, the terminal does not repeat them
        warnings.simplefilter("ignore", PbicrlWarning)
        post = infer_from_config(ds, cfg, progress=False)
    post.extra["data"]["path"] = str(path)
    post.extra["data"]["sha256"] = digest
    post.save(out_dir, overwrite=True)
    return infer_result(post, ds)


def summarize_infer(config: dict, out_dir: Path) -> dict[str, Any]:
    """:func:`infer_result` of a finished ``infer`` run read back from its directory (adopting older runs)."""
    from pbicrl.inference.posterior import Posterior

    ds, _, _ = _infer_dataset(config)
    return infer_result(Posterior.load(out_dir, issue_warnings=False), ds)


def infer_result(post: Any, dataset: Any) -> dict[str, Any]:
    """Headline numbers of an ``infer`` run, per feature in ``features`` order.

    ``p_constraint``, MAP and mean effective penalties, the selected set's effective penalties (conditional
    medians, 0 off the set), indicators and parameters (``None`` where off), the group-mean returns under the
    MAP and the selected weights, 90% intervals of the parameters while on, the identified parameter
    intervals, ``map_log_posterior``, the largest finite R-hat, the acceptance rate, the number of pairs and
    the posterior's warnings. Nothing here depends on the machine (the run's time is in ``result.json``'s
    ``runtime_s``), so every executor gives the same numbers.
    """
    import numpy as np

    from pbicrl.inference.draws import SELECTION_THRESHOLD
    from pbicrl.analysis.margins import group_mean_returns, point_weights

    def finite_or_none(x: Any) -> list[float | None]:
        return [None if not np.isfinite(v) else float(v) for v in np.atleast_1d(x)]

    w, cols = point_weights(post, dataset, "map")
    w_sel, cols_sel = point_weights(post, dataset, "selected")
    sel_eff, sel_theta = post.point_estimate("selected")
    pc = post.parameter_conditional()
    rhat = [r for r in post.rhat()["effective_penalty"] if math.isfinite(r)]
    return {
        "features": list(post.feature_names),
        "p_constraint": [float(x) for x in post.p_constraint],
        "map_effective_penalty": [float(x) for x in post.map_effective_penalty],
        "map_indicators": np.asarray(post.map_indicators).astype(int).tolist(),
        "map_parameters": finite_or_none(post.map_parameters_active),
        "mean_effective_penalty": [float(x) for x in post.mean_effective_penalty],
        "selected_effective_penalty": [float(x) for x in np.nan_to_num(sel_eff)],
        "selected_indicators": (post.p_constraint > SELECTION_THRESHOLD).astype(int).tolist(),
        "selected_parameters": finite_or_none(sel_theta),
        "group_means_map": group_mean_returns(dataset, w, cols).tolist(),
        "group_means_selected": group_mean_returns(dataset, w_sel, cols_sel).tolist(),
        "parameter_ci90": [list(pair) for pair in zip(finite_or_none(pc["low"]), finite_or_none(pc["high"]))],
        "identified_parameters": dict((post.identified or {}).get("parameters") or {}),
        "map_log_posterior": float(post.map_log_posterior),
        "max_rhat": max(rhat) if rhat else None,
        "acceptance": float(post.acceptance_rate()["overall"]),
        "n_pairs": int(post.settings.get("n_pairs") or 0),
        "warnings": list(post.warnings()),
    }


register_task("infer", run_infer, prepare=prepare_infer, unhashed=("data", "jobs"), path_keys=("data",),
              columns=("p_constraint", "map_effective_penalty", "max_rhat"), defaults=_infer_defaults,
              summarize=summarize_infer)


def _prepare_icl(config: dict) -> dict:
    """``reproduce-icl``: the dataset's content is hashed, not its path (as for ``infer``)."""
    return prepare_data(config, allow=("scripted",))


register_task("reproduce-icl", "pbicrl.baselines.icl:run_icl_task", prepare=_prepare_icl,
              unhashed=("data", "checkpoint_dir"), path_keys=("data",))


# --------------------------------------------------------------------------------------------- kind "selftest"
def run_selftest(config: dict, out_dir: Path) -> dict[str, Any]:
    """Task kind ``selftest``: checks an executor without heavy work.

    Config: ``value`` (any JSON, echoed back), ``sleep`` (seconds, default 0), ``fail`` (raise with this
    message if set), ``crash`` (end the worker process abruptly, as a crash or an out-of-memory kill would;
    only in a child process). Writes ``value.json`` and returns ``{"value": ..., "in_worker": ...}``.
    """
    if config.get("sleep"):
        time.sleep(float(config["sleep"]))
    if config.get("fail"):
        raise RuntimeError(str(config["fail"]))
    if config.get("crash"):
        import multiprocessing

        if multiprocessing.parent_process() is None:
            raise RuntimeError("crash: only simulated in a pool worker process")
        os._exit(70)
    (out_dir / "value.json").write_text(json.dumps(config.get("value")) + "\n")
    return {"value": config.get("value"), "in_worker": in_task_worker()}


register_task("selftest", run_selftest)


# --------------------------------------------------------------------------------------------- older cache versions
def infer_config_of_reproduce_run(config: Mapping[str, Any]) -> dict[str, Any]:
    """A version-2 ``reproduce-run`` config in the ``infer`` kind's names, for the same draws.

    ``reproduce-run`` ran :func:`pbicrl.api.infer` with one chain, the pairwise likelihood and a flat prior on
    [-1000, 1000] of both signs unless told otherwise; ``sample_seed`` seeded both the subsample and the pairs;
    ``label``, ``n`` and ``wall`` were bookkeeping of the report.
    """
    c = dict(config)
    likelihood = c.get("likelihood", "pairwise")
    out: dict[str, Any] = {
        "data": c["dataset"], "data_sha256": c.get("dataset_sha256"), "demos_per_group": c.get("n_per_group") or None,
        "demos_seed": int(c.get("sample_seed", 0)), "pairs_seed": int(c.get("sample_seed", 0)),
        "sampler": c["method"], "margins": c.get("margins"), "iterations": int(c["iterations"]),
        "chains": int(c.get("chains", 1)), "seed": int(c["seed"]), "sigma": float(c.get("sigma") or 0.1),
        "f_s": int(c.get("f_s", 4)), "init_range": list(c.get("init_range") or (-30.0, -1.0)),
        "sigma_theta": float(c.get("sigma_theta", 0.5)), "init_scale": float(c.get("init_scale", 1.0)),
        "constraints": c.get("constraints"), "candidates": c.get("candidates"),
        "nominal_weights": c.get("nominal_weights"), "likelihood": likelihood,
        "pairs": c.get("pairs", "all") if likelihood == "pairwise" else None,
    }
    prior = c.get("prior", "flat")
    if prior == "improper":
        out |= {"prior": "improper", "penalty_sign": "any"}
    elif prior != "default":
        low, high = c.get("prior_bounds", (-1000.0, 1000.0))
        out |= {"prior": prior, "prior_low": float(low), "prior_high": float(high), "penalty_sign": "any"}
    return {k: v for k, v in out.items() if v is not None}  # None: the default


def rename_v2(kind: str, config: Mapping[str, Any]) -> tuple[str, dict[str, Any]]:
    """Cache version 2 -> 3: settings renamed, no numbers changed."""
    if kind == "reproduce-run":
        return "infer", infer_config_of_reproduce_run(config)
    if kind == "reproduce-icl":
        names = {"dataset": "data", "dataset_sha256": "data_sha256", "sample_seed": "demos_seed"}
        return kind, {names.get(k, k): v for k, v in config.items()}
    return kind, dict(config)
