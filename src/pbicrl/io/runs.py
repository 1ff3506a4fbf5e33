"""Run directories: write one (:func:`save_run`), read one back (:func:`load_run`).

A run directory (``pbicrl infer --out``, :meth:`pbicrl.inference.posterior.Posterior.save`) holds
``summary.json`` (:mod:`pbicrl.inference.summary`) and ``chains.npz`` (all kept draws, per-chain ``counts``,
per-draw ``move``, ``accepted``, ``acceptance_fraction``), and :data:`DATASET_FILE` for a run on an in-memory
dataset. :func:`load_run` gives back a full :class:`~pbicrl.inference.posterior.Posterior` (also
``pbicrl.load_run`` and :meth:`~pbicrl.inference.posterior.Posterior.load`); :func:`read_run` is the checked
reader underneath, returning a :class:`RunRecord`: the draws of ``chains.npz`` and the numbers of ``summary.json``
with the same attribute names as a posterior (``indicators``, ``penalty_weights``, ``log_likelihood``,
``feature_names``, ``map_indicators``, ...), so diagnostics, export and plots accept either, without warnings.

``summary.json`` carries a ``schema_version`` (:data:`SCHEMA_VERSION`; files written before
it existed are version 1; version 3 names the sampler ``sampler``, was ``method``, also in ``settings``). Every
version up to the current one loads: the fields added in version 2
(``selected``, ``most_frequent_set``, conditional medians, ...) are computed from the draws by the
:class:`~pbicrl.inference.draws.DrawsView` methods, so they exist for old runs too; :attr:`RunRecord.identified`
is ``None`` there. A newer version is refused with a message saying so.

Writing (:func:`write_run_dir`, the claims and checks of output directories) is :mod:`pbicrl.io.outdir`,
re-exported here.
"""

from __future__ import annotations

import json
import os
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np
from numpy.typing import NDArray

from pbicrl.inference.draws import DrawsView
from pbicrl.inference.posterior import Posterior
from pbicrl.inference.summary import SCHEMA_VERSION
from pbicrl.io.outdir import (OutputBusyError, OutputExistsError, check_out_dir, claim_out_dir, is_run_dir,
                              release_out_dir, write_run_dir)

__all__ = ["load_run", "save_run", "read_run", "check_run_dir", "RunRecord", "RunError", "SCHEMA_VERSION",
           "DATASET_FILE", "recorded_dataset", "write_run_dir", "check_out_dir", "claim_out_dir", "release_out_dir",
           "is_run_dir", "OutputExistsError", "OutputBusyError"]

DATASET_FILE = "dataset.npz"
"""The copy of an in-memory dataset (no ``extra.data.path``) that :func:`save_run`
stores in the run directory, so that the export can rebuild the likelihood of an API run."""

_MAX_SUMMARY_BYTES = 64 << 20  # a summary.json is a few hundred KiB at most; more is not a summary

# summary.json keys that readers use, and the JSON types they must have when present
_SUMMARY_TYPES: dict[str, tuple[type, ...]] = {
    "sampler": (str,), "method": (str,), "feature_names": (list,), "parameter_names": (list,), "settings": (dict,), "extra": (dict,),
    "map": (dict,), "posterior": (dict,), "seed": (int,), "chains": (int,), "iterations": (int,),
    "warnings": (list,),  # schema_version: checked (positive integer, known version) by the reader
}


class RunError(ValueError):
    """A run directory that cannot be read; the message names the file or field."""


@dataclass(frozen=True, eq=False)
class RunRecord(DrawsView):
    """Draws and summary of a finished run.

    Attributes
    ----------
    path : Path
        The run directory.
    summary : dict
        ``summary.json``.
    indicators : ndarray, (chains, draws, d) int8
    penalty_weights : ndarray, (chains, draws, d)
    log_likelihood, log_prior : ndarray, (chains, draws)
    feature_names : tuple of str
    map_indicators, map_penalty_weights : ndarray, (d,)
    parameters : ndarray (chains, draws, p) or None
        Parameters of parametric constraints, when the run has them.
    parameter_names : tuple of str
    map_parameters : ndarray (p,) or None
    parameter_owner : tuple of int
        Feature index of the constraint each parameter belongs to (from ``chains.npz``, else from the
        ``"<constraint>.<parameter>"`` names).
    counts : ndarray (chains, 7) or None
        Per-chain move counters (:attr:`pbicrl.inference.posterior.Posterior.counts`), when the run recorded them.
    move, accepted, acceptance_fraction : ndarray (chains, draws) or None
        Per-draw move type, acceptance and acceptance fraction, when the run recorded them.
    """

    path: Path
    summary: dict
    indicators: NDArray[np.int8]
    penalty_weights: NDArray[np.float64]
    log_likelihood: NDArray[np.float64]
    log_prior: NDArray[np.float64]
    feature_names: tuple[str, ...]
    map_indicators: NDArray[np.int8]
    map_penalty_weights: NDArray[np.float64]
    parameters: NDArray[np.float64] | None = None
    parameter_names: tuple[str, ...] = field(default=())
    map_parameters: NDArray[np.float64] | None = None
    parameter_owner: tuple[int, ...] = field(default=())
    counts: NDArray[np.int64] | None = None
    move: NDArray[np.int8] | None = None
    accepted: NDArray[np.bool_] | None = None
    acceptance_fraction: NDArray[np.float64] | None = None

    def __repr__(self) -> str:
        C, D, d = self.indicators.shape
        names = ", ".join(repr(n) for n in self.feature_names[:6]) + (", ..." if d > 6 else "")
        return (f"RunRecord(path={str(self.path)!r}, sampler={self.sampler!r}, chains={C}, draws={D}, "
                f"features={d} [{names}], parameters={len(self.parameter_names)})")

    # Posterior-compatible views --------------------------------------------------------------
    @property
    def sampler(self) -> str:
        """``summary.json``'s ``sampler`` (``method`` before schema 3)."""
        return str(self.summary.get("sampler", self.summary.get("method", "pbicrl")))

    @property
    def method(self) -> str:
        """Deprecated name of :attr:`sampler` (until pbicrl 0.3)."""
        from pbicrl.errors import warn

        warn("RunRecord.method is deprecated and will be removed in pbicrl 0.3: use RunRecord.sampler", stacklevel=2)
        return self.sampler

    @property
    def settings(self) -> dict:
        return dict(self.summary.get("settings", {}))

    @property
    def extra(self) -> dict:
        return dict(self.summary.get("extra", {}))

    @property
    def seed(self) -> int:
        return int(self.summary.get("seed", 0))

    @property
    def schema_version(self) -> int:
        """Layout version of ``summary.json`` (1 for files written before versions were recorded)."""
        return int(self.summary.get("schema_version", 1))

    @property
    def identified(self) -> dict | None:
        """The identification the run was reported with (``None`` for version-1 runs and runs without one)."""
        v = self.summary.get("identified")
        return dict(v) if isinstance(v, dict) else None

    def not_identifiable(self) -> dict[str, str]:
        """``{feature: reason}`` recorded in ``summary.json`` (empty for version-1 runs); the diagnostics of
        a loaded run leave these features out, as the run's own summary did."""
        v = self.summary.get("not_identifiable")
        return {str(k): str(r) for k, r in v.items()} if isinstance(v, dict) else {}

    @property
    def data_path(self) -> Path | None:
        """The dataset the run used: ``extra.data.path`` of ``summary.json``, else the copy :data:`DATASET_FILE`
        stored in the run directory, if any."""
        return recorded_dataset(self)


def recorded_dataset(run: Any) -> Path | None:
    """The dataset file of a run: ``extra.data.path`` when recorded, else the copy :data:`DATASET_FILE` in the run
    directory ``run.path`` (stored for an in-memory dataset); None when neither is there. A recorded path may
    have moved since the run."""
    data = dict(getattr(run, "extra", {}) or {}).get("data") or {}
    p = data.get("path")
    if isinstance(p, str) and p:
        return Path(p)
    where = getattr(run, "path", None)
    if where is not None and (Path(where) / DATASET_FILE).is_file():
        return Path(where) / DATASET_FILE
    return None


def _array(z: Any, key: str, path: Path, ndim: int) -> NDArray:
    if key not in z:
        raise RunError(f"{path}: missing array '{key}'")
    a = np.asarray(z[key])
    if a.ndim != ndim:
        raise RunError(f"{path}: '{key}' should have {ndim} dimensions, has shape {a.shape}")
    return a


def _read_summary(path: Path) -> dict[str, Any]:
    """``summary.json`` of a run, checked: a JSON object of a sane size whose known keys have the right types."""
    try:
        size = path.stat().st_size
    except OSError as exc:
        raise RunError(f"{path}: cannot be read ({exc.strerror or exc})") from None
    if not path.is_file():
        raise RunError(f"{path}: not a regular file")
    if size > _MAX_SUMMARY_BYTES:
        raise RunError(f"{path}: {size:,} bytes, too large for a run summary (is it the right file?)")
    try:
        summary = json.loads(path.read_bytes().decode("utf-8"))
    except UnicodeDecodeError:
        raise RunError(f"{path}: not UTF-8 text (not a summary.json written by pbicrl)") from None
    except (ValueError, RecursionError) as exc:  # JSONDecodeError is a ValueError; absurd nesting recurses
        why = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise RunError(f"{path}: not valid JSON ({why})") from None
    if not isinstance(summary, dict):
        raise RunError(f"{path}: expected a JSON object, got a JSON {type(summary).__name__}")
    for key, types in _SUMMARY_TYPES.items():
        value = summary.get(key)
        if value is not None and (not isinstance(value, types) or isinstance(value, bool) and bool not in types):
            raise RunError(f"{path}: '{key}' should be a JSON {' or '.join(_json_type(t) for t in types)}, "
                           f"got {_json_type(type(value))} {json.dumps(value)[:60]}")
    for key in ("feature_names", "parameter_names"):
        names = summary.get(key)
        if names is not None and not all(isinstance(n, str) for n in names):
            raise RunError(f"{path}: '{key}' should be a list of strings")
    data = (summary.get("extra") or {}).get("data")
    if data is not None and (not isinstance(data, dict) or not isinstance(data.get("path", ""), (str, type(None)))):
        raise RunError(f"{path}: 'extra.data' should be an object with a string 'path'")
    return summary


def _json_type(t: type) -> str:
    return {str: "string", list: "array", dict: "object", int: "integer", float: "number", bool: "boolean",
            type(None): "null"}.get(t, t.__name__)


def check_run_dir(run_dir: str | os.PathLike[str]) -> None:
    """Check a run directory's files before reading them; errors name the file and what is wrong.

    Raises
    ------
    FileNotFoundError
        No such directory, or ``summary.json`` / ``chains.npz`` missing.
    pbicrl.io.runs.RunError
        ``chains.npz`` empty, not an archive, with an unreadable or huge header or arrays larger than memory;
        ``summary.json`` not a JSON object or a known key of the wrong type.
    """
    from pbicrl.inference.data import DatasetError, inspect_npz

    run = Path(run_dir)
    if not run.is_dir():
        what = "not a directory" if run.exists() else "no such directory"
        raise FileNotFoundError(f"run: {run}: {what} (expected the --out directory of pbicrl infer)")
    sj, cz = run / "summary.json", run / "chains.npz"
    for f in (sj, cz):
        if not f.exists():
            raise FileNotFoundError(f"run: {f}: missing (a run directory holds summary.json and chains.npz)")
    _read_summary(sj)
    try:
        inspect_npz(cz, what="chains file")
    except DatasetError as exc:
        raise RunError(str(exc)) from None


def read_run(run_dir: str | os.PathLike[str]) -> RunRecord:
    """Read a run directory after :func:`check_run_dir`; any malformation left is a :class:`RunError`.

    Raises
    ------
    FileNotFoundError
        If the directory or one of its two files does not exist.
    RunError
        If a file is malformed, or ``summary.json`` has a ``schema_version`` newer than this pbicrl reads
        (the message names the file).
    """
    check_run_dir(run_dir)
    try:
        return _read_run(run_dir)
    except (FileNotFoundError, RunError):
        raise
    except (TypeError, KeyError, AttributeError, IndexError, EOFError, UnicodeDecodeError, OverflowError) as exc:
        # a structurally valid file with contents pbicrl never writes (e.g. a string array of indicators)
        raise RunError(f"{run_dir}: malformed run directory ({type(exc).__name__}: {exc})") from None


def _read_run(run_dir: str | os.PathLike[str]) -> RunRecord:
    """Read ``summary.json`` and ``chains.npz`` of a run directory that :func:`check_run_dir` passed (see
    :func:`read_run`)."""
    run = Path(run_dir)
    sj, cz = run / "summary.json", run / "chains.npz"
    summary = _read_summary(sj)
    version = summary.get("schema_version", 1)
    if isinstance(version, bool) or not isinstance(version, int) or version < 1:
        raise RunError(f"{sj}: 'schema_version' should be a positive integer, got {version!r}")
    if version > SCHEMA_VERSION:
        raise RunError(f"{sj}: written by a newer pbicrl (summary.json schema_version {version}); this version "
                       f"reads versions 1 to {SCHEMA_VERSION}: upgrade pbicrl to read it")
    try:
        with np.load(cz, allow_pickle=False) as z:
            ind = _array(z, "indicators", cz, 3).astype(np.int8)
            wp = _array(z, "penalty_weights", cz, 3).astype(np.float64)
            ll = _array(z, "log_likelihood", cz, 2).astype(np.float64)
            lp = z["log_prior"].astype(np.float64) if "log_prior" in z else np.zeros_like(ll)
            names = tuple(str(n) for n in z["feature_names"].tolist()) if "feature_names" in z else \
                tuple(summary.get("feature_names") or [f"f{j}" for j in range(ind.shape[2])])
            map_c = z["map_indicators"].astype(np.int8) if "map_indicators" in z else None
            map_w = z["map_penalty_weights"].astype(np.float64) if "map_penalty_weights" in z else None
            params = z["parameters"].astype(np.float64) if "parameters" in z else None
            pnames = tuple(str(n) for n in z["parameter_names"].tolist()) if "parameter_names" in z else ()
            map_params = z["map_parameters"].astype(np.float64) if "map_parameters" in z else None
            owner = tuple(int(j) for j in z["parameter_owner"].tolist()) if "parameter_owner" in z else ()
            counts = z["counts"].astype(np.int64) if "counts" in z else None
            per_draw = {k: z[k] for k in ("move", "accepted", "acceptance_fraction") if k in z}
    except (OSError, ValueError, zipfile.BadZipFile) as exc:
        if isinstance(exc, RunError):
            raise
        raise RunError(f"{cz}: not a readable .npz archive ({exc})") from None
    if wp.shape != ind.shape or ll.shape != ind.shape[:2]:
        raise RunError(f"{cz}: inconsistent shapes: indicators {ind.shape}, penalty_weights {wp.shape}, "
                       f"log_likelihood {ll.shape}")
    if len(names) != ind.shape[2]:
        raise RunError(f"{cz}: {len(names)} feature names for {ind.shape[2]} features")
    if map_c is None or map_w is None:
        m = summary.get("map", {})
        map_c = np.array([m.get("indicators", {}).get(n, 0) for n in names], dtype=np.int8)
        map_w = np.array([m.get("penalty_weights", {}).get(n, 0.0) or 0.0 for n in names], dtype=np.float64)
    if params is not None and params.size == 0:
        params, pnames, map_params, owner = None, (), None, ()  # a run without parametric constraints
    if params is not None:
        if params.ndim == 2:
            params = params[:, :, None]
        if params.shape[:2] != ind.shape[:2]:
            raise RunError(f"{cz}: parameters have shape {params.shape}, draws are {ind.shape[:2]}")
        if not pnames:
            pnames = tuple(summary.get("parameter_names") or [f"theta{k}" for k in range(params.shape[2])])
        if len(owner) != len(pnames):
            heads = [n.rsplit(".", 1)[0] for n in pnames]
            owner = tuple(names.index(h) for h in heads) if all(h in names for h in heads) else ()
    for key, arr in (("penalty_weights", wp), ("log_likelihood", ll), ("parameters", params)):
        if arr is not None and key == "parameters":
            # NaN marks the parameters of a constraint that is switched off in that draw (by design); only an
            # infinite value, or NaN where its constraint is on, is a draw without meaning
            on = ind[:, :, list(owner)].astype(bool) if owner and len(owner) == arr.shape[2] else np.ones(arr.shape, bool)
            arr = np.where(on, arr, 0.0)
        bad = 0 if arr is None else int(arr.size - np.count_nonzero(np.isfinite(arr)))
        if bad:  # NaN draws: every figure, diagnostic, export or check of them would be a number without meaning
            raise RunError(f"{cz}: field '{key}' holds {bad:,} NaN or infinite values: the run has no usable draws "
                           "(the returns overflowed or the file was altered); rerun pbicrl infer with a beta and "
                           "margins in range")
    if counts is not None and (counts.ndim != 2 or counts.shape[0] != ind.shape[0] or counts.shape[1] < 5):
        raise RunError(f"{cz}: 'counts' has shape {counts.shape}, expected ({ind.shape[0]}, 7)")
    for k, v in per_draw.items():
        if v.shape != ind.shape[:2]:
            raise RunError(f"{cz}: '{k}' has shape {v.shape}, the draws are {ind.shape[:2]}")
    return RunRecord(run, summary, ind, wp, ll, lp, names, map_c, map_w, params, pnames, map_params, owner,
                     counts=counts, move=per_draw["move"].astype(np.int8) if "move" in per_draw else None,
                     accepted=per_draw["accepted"].astype(bool) if "accepted" in per_draw else None,
                     acceptance_fraction=(per_draw["acceptance_fraction"].astype(np.float64)
                                          if "acceptance_fraction" in per_draw else None))


def load_run(run_dir: str | os.PathLike[str], *, issue_warnings: bool = True) -> Posterior:
    """Read a run directory (``pbicrl infer --out``, :func:`save_run`) back into a
    :class:`~pbicrl.inference.posterior.Posterior`.

    The same object a fresh :func:`pbicrl.infer` returns: ``table()``, ``to_arviz()``, ``summary()``,
    ``point_estimate()``, ``save()``, ... give what they gave before saving. Every ``summary.json`` schema version
    up to :data:`SCHEMA_VERSION` loads. This is ``pbicrl.load_run``.

    Parameters
    ----------
    run_dir : path
    issue_warnings : bool
        Issue the posterior's warnings (:class:`~pbicrl.errors.PbicrlWarning`), as sampling did.

    Raises
    ------
    FileNotFoundError
        No such directory, or ``summary.json`` / ``chains.npz`` missing.
    RunError
        A malformed file or a ``summary.json`` written by a newer pbicrl (the message names the file).
    """
    post = Posterior.from_record(read_run(run_dir), issue_warnings=False)
    if issue_warnings:
        post.emit_warnings(stacklevel=3)  # attributed to the caller of load_run
    return post


def save_run(post: Posterior, out_dir: str | os.PathLike[str], *, overwrite: bool = False,
             extra_json: dict[str, Any] | None = None, inputs: Sequence[Any] = ()) -> Path:
    """Write ``summary.json`` and ``chains.npz`` of ``post`` (and any ``extra_json`` files) to ``out_dir``
    atomically; with a dataset kept in memory (:meth:`~pbicrl.inference.posterior.Posterior.keep_dataset`) and no
    file recorded, also a copy of it, :data:`DATASET_FILE`, so that the export can rebuild the pointwise
    log-likelihood.

    :func:`load_run` reads it back. ``overwrite=True`` replaces a previous run directory holding only what
    pbicrl wrote there, never anything else, nor a directory holding one of ``inputs`` (paths).

    Raises
    ------
    OutputExistsError
        ``out_dir`` exists (a :class:`FileExistsError`; pass ``overwrite=True`` to replace a previous run).
    OutputBusyError
        Another process is writing ``out_dir`` at the same time.
    FileExistsError
        ``out_dir`` is a file, a symbolic link or a directory that is not a run (even with ``overwrite``).
    """
    arrays = {"indicators": post.indicators, "penalty_weights": post.penalty_weights,
              "effective_penalty": post.effective_penalty, "log_likelihood": post.log_likelihood,
              "log_prior": post.log_prior, "feature_names": np.array(post.feature_names, dtype=np.str_),
              "map_indicators": post.map_indicators, "map_penalty_weights": post.map_penalty_weights,
              "parameters": post.parameters, "map_parameters": post.map_parameters,
              "parameter_names": np.array(post.parameter_names, dtype=np.str_),
              "parameter_owner": np.array(post.parameter_owner, dtype=np.int64)}
    if not post.recorded:  # a loaded run without counts keeps its recorded rates instead
        arrays["counts"] = np.asarray(post.counts, dtype=np.int64)
    for key in ("move", "accepted", "acceptance_fraction"):
        v = getattr(post, key)
        if v is not None:
            arrays[key] = np.asarray(v)
    npz = {"chains.npz": arrays}
    if post.dataset is not None and not (post.extra.get("data") or {}).get("path"):
        # an in-memory dataset: stored with the run, so that the export can always rebuild the likelihood
        npz[DATASET_FILE] = post.dataset.to_arrays()
    return write_run_dir(out_dir, {"summary.json": post.summary(), **(extra_json or {})}, npz,
                         overwrite=overwrite, inputs=inputs)
