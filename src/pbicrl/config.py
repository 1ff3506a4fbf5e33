"""Inference settings: one record, :class:`InferConfig`, and the names every entry point uses.

:class:`InferConfig` is the single source of the names, types and defaults of the inference settings: the
command line (``pbicrl infer --iterations``), TOML files (``iterations = ...``), :func:`pbicrl.infer`
(``iterations=...``), sweeps (``[base] iterations = ...``) and ``pbicrl reproduce`` all use its field names.
Old names (:data:`DEPRECATED_NAMES`, e.g. ``method`` for ``sampler``) are accepted until pbicrl 0.3 with a
:class:`~pbicrl.errors.PbicrlWarning`.
"""

from __future__ import annotations

import copy
from collections.abc import Mapping
from dataclasses import MISSING, dataclass, field, fields, replace
from pathlib import Path
from typing import Any

from pbicrl._atomic import read_toml

__all__ = ["InferConfig", "ConfigError", "DEPRECATED_NAMES", "canonical_names", "accept_old_names", "check_setting",
           "load_config"]


class ConfigError(ValueError):
    """Invalid configuration; the message names the key."""


def _setting(default: Any, *types: type, minimum: int | None = None,
             half_open: tuple[float, float] | None = None) -> Any:
    """A field of :class:`InferConfig` with the types a file may give it and, for integers, the least value; for
    a probability-like number, the half-open range ``[low, high)`` it must lie in."""
    meta = {"types": types, "minimum": minimum, "half_open": half_open}
    if isinstance(default, list):
        return field(default_factory=lambda: list(default), metadata=meta)
    return field(default=default, metadata=meta)


@dataclass(frozen=True)
class InferConfig:
    r"""Settings of ``pbicrl infer`` (same names in the TOML file, all at the top level or all under ``[infer]``).

    Attributes
    ----------
    nominal_weights : list of float or None
        Known :math:`w_n` (default: from the dataset, else zeros).
    margins : list of float, or list of lists, or None
        K-1 consecutive gaps or a K x K upper-triangular matrix :math:`m_{k\\ell}`.
    beta : float
        Inverse temperature.
    power : float or "pairs" or None
        ``pairwise`` only: likelihood power in (0, 1]; 1 (default) = the paper's likelihood.
    pairs : "all" or int or None
        ``pairwise`` only: all cross-group pairs (default), or that many random pairs per group pair.
    pairs_seed : int
        Seed of the random pairs (``pairs`` a number).
    sampler : "pbicrl" | "paper" | "authors" | "bpl"
        The MCMC sampler (formerly ``method``).
    iterations, burn_in, thin, chains, seed, jobs : int
        Iterations per chain (formerly ``n_iterations``), warm-up, thinning, independent chains (formerly
        ``n_chains``), random seed, worker processes (formerly ``n_jobs``; never changes the draws).
    sigma, f_s, p_flip, init_scale : sampler settings
        ``p_flip`` default (None): 0.3 for the ``pbicrl`` sampler run until converged (more of the iterations move
        the penalties, whose mixing limits the ESS), else 0.5.
    init_range : [low, high]
        ``authors`` sampler: initial penalties uniform on this range (the authors' code: [-30, -1] for point
        mass, [-100, -10] for Fetch-Reach).
    likelihood : "grouped" | "pairwise"
        ``grouped`` (default): the exact grouped Plackett-Luce likelihood, calibrated for grouped rankings;
        ``pairwise``: the paper's Eq. 7 over cross-group pairs (``pairs`` and ``power`` apply to it only).
    prior : "student_t" | "flat" | "normal" | "improper"
        Prior on each penalty weight (default ``student_t``: half-Student-t on (-inf, 0]); ``improper`` is the
        paper's flat prior without bounds (Algorithms 1 and 3).
    prior_scale : float
        ``student_t``/``normal``: scale in units of :math:`1/(\beta\,\mathrm{sd}_j)`, sd_j the spread of
        feature j's per-trajectory mean (default 2.5), so rescaling a feature rescales only its penalty.
    prior_abs_scale : float or None
        An absolute prior scale for every feature instead (overrides ``prior_scale``).
    prior_df : float
        Degrees of freedom of the Student-t prior (default 3).
    prior_low, prior_high : float or None
        Bounds of the prior (``flat``: default -1000, 1000; others: unbounded).
    prior_mean : float
        Location of the ``normal`` prior.
    penalty_sign : "negative" | "any"
        ``negative`` (default): a penalty penalises, :math:`w_p \le 0`; ``any``: both signs.
    alpha : float
        Level of the identifiability analysis (every cross-group pair ordered with probability >= 1 - alpha).
    indicator_pi : float
        Bernoulli prior probability of each constraint.
    candidates : list of str or int, or None
        Features that may be constraints (names or indices).
    constraints : list of tables, or None
        Parametric constraints, in TOML as ``[[constraints]]`` tables:
        ``family = "axis_halfspace"``, ``dims = [0]``, ``direction = ">="``, ``name = "wall"``,
        ``bounds = [[0.0, 20.0]]`` (one ``[low, high]`` per parameter; default: the data's range).
    sigma_theta, p_theta : float
        Parameter step and parameter-move probability.
    p_joint : float
        ``pbicrl``/``bpl`` samplers: probability per iteration of moving all active penalty weights together (a
        Gaussian step whose covariance is adapted during warm-up, then fixed), in [0, 1); it is taken from the
        single-weight steps' share, so ``p_flip`` + ``p_theta`` + ``p_joint`` must stay below 1. Default (None): 0.3
        for ``pbicrl`` with ``iterations = "auto"`` (its joint step moves :math:`\log|w|` of the sign-constrained
        penalties: it mixes the correlated penalties of required constraints, ``benchmarks/reports/fast_default.md``),
        otherwise 0 (fixed-length runs keep the single-site moves); the ``paper``/``authors`` samplers have no joint
        move.
    iterations : int or "auto"
        ``"auto"`` (default): run until converged: every reported quantity has split R-hat < ``target_rhat`` and
        bulk and tail ESS >= ``target_ess``, or ``max_time`` seconds are spent
        (:class:`pbicrl.inference.samplers.driver.StoppingRule`; ``burn_in`` then sets the warm-up, default 2,000).
        A number: exactly that many iterations per chain (warm-up included), as in earlier releases.
    target_ess, target_rhat, max_time : float
        The stopping rule of ``iterations = "auto"`` (defaults 400, 1.01, 600 s).
    """

    nominal_weights: list[float] | None = _setting(None, list)
    margins: list | None = _setting(None, list)
    beta: float = _setting(1.0, int, float)
    power: float | str | None = _setting(None, int, float, str)
    pairs: str | int | None = _setting(None, str, int)
    pairs_seed: int = _setting(0, int, minimum=0)
    sampler: str = _setting("pbicrl", str)
    iterations: int | str = _setting("auto", int, str, minimum=1)
    burn_in: int | None = _setting(None, int, minimum=0)
    thin: int | None = _setting(None, int, minimum=1)
    chains: int = _setting(4, int, minimum=1)
    seed: int = _setting(0, int, minimum=0)
    jobs: int | None = _setting(None, int, minimum=1)
    sigma: float = _setting(0.1, int, float)
    f_s: int = _setting(4, int, minimum=1)
    p_flip: float | None = _setting(None, int, float)
    init_scale: float = _setting(1.0, int, float)
    init_range: list = _setting([-30.0, -1.0], list)
    likelihood: str = _setting("grouped", str)
    prior: str = _setting("student_t", str)
    prior_low: float | None = _setting(None, int, float)
    prior_high: float | None = _setting(None, int, float)
    prior_mean: float = _setting(0.0, int, float)
    prior_scale: float = _setting(2.5, int, float)
    prior_abs_scale: float | None = _setting(None, int, float)
    prior_df: float = _setting(3.0, int, float)
    penalty_sign: str = _setting("negative", str)
    alpha: float = _setting(0.05, int, float)
    indicator_pi: float = _setting(0.5, int, float)
    candidates: list | None = _setting(None, list)
    constraints: list | None = _setting(None, list)
    sigma_theta: float = _setting(0.5, int, float)
    p_theta: float | None = _setting(None, int, float)
    p_joint: float | None = _setting(None, int, float, half_open=(0.0, 1.0))
    target_ess: float = _setting(400.0, int, float)
    target_rhat: float = _setting(1.01, int, float)
    max_time: float = _setting(600.0, int, float)

    def updated(self, **values: Any) -> "InferConfig":
        """Copy with the non-``None`` values replaced (command-line options over the file).

        Deprecated names (:data:`DEPRECATED_NAMES`) are accepted with a :class:`~pbicrl.errors.PbicrlWarning`.
        """
        values = canonical_names(values, where="setting", stacklevel=3)
        return replace(self, **{k: v for k, v in values.items() if v is not None})

    @classmethod
    def defaults(cls) -> dict[str, Any]:
        """Every setting and its default value (fresh lists: safe to modify)."""
        return {f.name: (f.default_factory() if f.default is MISSING else f.default)  # type: ignore[misc]
                for f in fields(cls)}

    @classmethod
    def setting_types(cls) -> dict[str, tuple[type, ...]]:
        """Every setting and the Python types a file or mapping may give it (``bool`` is never a number)."""
        return {f.name: f.metadata["types"] for f in fields(cls)}

    @classmethod
    def from_mapping(cls, values: Mapping[str, Any], *, where: str = "config") -> "InferConfig":
        """Validated settings from a mapping (a TOML table, a sweep's task config).

        Parameters
        ----------
        values : mapping
            Setting names (:data:`DEPRECATED_NAMES` are renamed with a :class:`~pbicrl.errors.PbicrlWarning`)
            and values; missing settings keep their defaults. ``None`` stands for the default.
        where : str
            How messages name the source: ``"<where> key 'iterations': ..."``.

        Raises
        ------
        ConfigError
            Unknown keys, wrong types (``true`` is not a number), integers below their minimum, malformed
            ``[[constraints]]`` tables; the message names the key.
        """
        values = canonical_names(values, where=f"{where} key", stacklevel=3)
        out = {}
        for key, value in values.items():
            check_setting(key, value, where=where)
            if value is not None:
                out[key] = value
        if out.get("constraints"):
            from pbicrl.inference.constraints import constraint_from_dict

            for k, spec in enumerate(out["constraints"]):
                if not isinstance(spec, dict):
                    raise ConfigError(f"{where} key 'constraints': expected [[constraints]] tables")
                _check_dims(spec, k, where)
                constraint_from_dict(spec)  # validate now: family, dims, direction, bounds
        return cls(**out)

    def to_dict(self) -> dict[str, Any]:
        """Every setting by name (a plain copy; what :meth:`from_mapping` reads back)."""
        return {f.name: copy.deepcopy(getattr(self, f.name)) for f in fields(self)}


DEPRECATED_NAMES: dict[str, str] = {"method": "sampler", "n_iterations": "iterations", "n_chains": "chains",
                                    "n_jobs": "jobs"}
"""Old names of settings, accepted until pbicrl 0.3 with a :class:`~pbicrl.errors.PbicrlWarning`: old -> new."""


def canonical_names(values: Mapping[str, Any], *, where: str = "setting", stacklevel: int = 2) -> dict[str, Any]:
    """``values`` with deprecated setting names (:data:`DEPRECATED_NAMES`) replaced by the current ones.

    Each old name issues a :class:`~pbicrl.errors.PbicrlWarning` naming the new one (``stacklevel`` as for
    :func:`warnings.warn`, counted from the caller of this function).

    Raises
    ------
    ConfigError
        Both an old name and its new one are given.
    """
    out: dict[str, Any] = {}
    for key, value in values.items():
        new = DEPRECATED_NAMES.get(key)
        if new is None:
            out[key] = value
            continue
        if new in values:
            raise ConfigError(f"{where} '{key}': deprecated name of '{new}', which is given too; keep only '{new}'")
        from pbicrl.errors import warn

        warn(f"{where} '{key}' is deprecated and will be removed in pbicrl 0.3: use '{new}'",
             stacklevel=stacklevel + 1)
        out[new] = value
    return out


def accept_old_names(cls: type, where: str) -> type:
    """Class decorator: the constructor of dataclass ``cls`` also takes the old names of its fields
    (:data:`DEPRECATED_NAMES` that name one of them), with a :class:`~pbicrl.errors.PbicrlWarning`, and each old
    name reads as a deprecated property.

    ``where`` names the class in the messages (``"SamplerSettings"``).
    """
    init = cls.__init__
    olds = {old: new for old, new in DEPRECATED_NAMES.items() if new in getattr(cls, "__dataclass_fields__", {})}

    every = {f.name for f in fields(cls) if f.init}

    def __init__(self: Any, *args: Any, **kw: Any) -> None:
        if kw.keys() & olds.keys():
            if every <= kw.keys():  # dataclasses.replace passes every field: the old name is the change asked for
                for old in kw.keys() & olds.keys():
                    kw.pop(olds[old])
            kw = canonical_names(kw, where=f"{where} argument", stacklevel=2)
        init(self, *args, **kw)

    __init__.__doc__, __init__.__wrapped__ = init.__doc__, init  # type: ignore[attr-defined]
    cls.__init__ = __init__  # type: ignore[method-assign]

    def alias(old: str, new: str) -> property:
        def get(self: Any) -> Any:
            from pbicrl.errors import warn

            warn(f"{where}.{old} is deprecated and will be removed in pbicrl 0.3: use {where}.{new}", stacklevel=2)
            return getattr(self, new)

        return property(get, doc=f"Deprecated name of :attr:`{new}` (until pbicrl 0.3).")

    for old, new in olds.items():
        setattr(cls, old, alias(old, new))
    return cls


def check_setting(key: str, value: Any, *, where: str = "config") -> None:
    """Check one setting's name, type and range (``None`` passes: it stands for the default).

    Raises
    ------
    ConfigError
        ``"<where> key '<key>': ..."``: unknown key, wrong type, integer below its minimum, a number outside its
        range (``p_joint``: [0, 1)).
    """
    spec = _FIELDS.get(key)
    if spec is None:
        raise ConfigError(f"{where} key '{key}': unknown; known keys are {', '.join(sorted(_FIELDS))}")
    if value is None:
        return
    types = spec.metadata["types"]
    if isinstance(value, bool) or not isinstance(value, types):
        raise ConfigError(f"{where} key '{key}': expected {' or '.join(t.__name__ for t in types)}, got {value!r}")
    if key == "iterations" and isinstance(value, str):
        if value != "auto":
            raise ConfigError(f"{where} key 'iterations': expected a number of iterations or \"auto\", got {value!r}")
        return
    if key in ("target_ess", "max_time") and not (0 < value < float("inf")):
        raise ConfigError(f"{where} key '{key}': expected a positive number, got {value!r}")
    if key == "target_rhat" and not (1.0 < value < float("inf")):
        raise ConfigError(f"{where} key 'target_rhat': expected a number > 1, got {value!r}")
    low = spec.metadata["minimum"]
    if low is not None and value < low:
        raise ConfigError(f"{where} key '{key}': expected an integer >= {low}, got {value}")
    span = spec.metadata.get("half_open")
    if span is not None and not (span[0] <= value < span[1]):  # NaN fails too
        raise ConfigError(f"{where} key '{key}': expected a number in [{span[0]:g}, {span[1]:g}), got {value!r}")


_FIELDS = {f.name: f for f in fields(InferConfig)}


def load_config(path: str | Path) -> InferConfig:
    """Read a TOML config; every problem is a :class:`ConfigError` that names the key or table.

    The settings are either all at the top level or all in an ``[infer]`` table (with ``[[constraints]]`` /
    ``[[infer.constraints]]`` tables for parametric constraints); a file with both, or with any other table,
    is refused rather than partly ignored.

    Raises
    ------
    ConfigError
        Missing or unreadable file, invalid TOML, unknown keys or tables, wrong types, integers out of range,
        malformed constraint ``dims`` (not non-negative integers, repeated).
    """
    raw = read_toml(path, "config", error=ConfigError, missing=ConfigError)
    known = set(_FIELDS) | set(DEPRECATED_NAMES)
    if "infer" in raw:
        table = raw["infer"]
        if not isinstance(table, dict):
            raise ConfigError("config: 'infer' must be a table ([infer])")
        beside = sorted(k for k in raw if k != "infer")
        if beside:
            where = ", ".join(_toml_name(k, raw[k]) for k in beside)
            raise ConfigError(f"config: {where} outside the [infer] table; put every setting under [infer] "
                              "or none (settings outside it would be ignored)")
    else:
        table = raw
    tables = sorted(k for k, v in table.items() if isinstance(v, dict) and k not in known)
    if tables:
        raise ConfigError(f"config: unknown table(s) {', '.join(f'[{t}]' for t in tables)}; the settings are keys "
                          "at the top level or under [infer], constraints are [[constraints]] tables")
    return InferConfig.from_mapping(table, where="config")


def _toml_name(key: str, value: Any) -> str:
    """How the file spells ``key``: ``[table]``, ``[[array of tables]]`` or ``'key'``."""
    if isinstance(value, dict):
        return f"[{key}]"
    if isinstance(value, list) and value and all(isinstance(v, dict) for v in value):
        return f"[[{key}]]"
    return f"'{key}'"


def _check_dims(spec: dict[str, Any], k: int, where: str = "config") -> None:
    """``dims`` of a constraint table: distinct non-negative integers (TOML ``true`` or ``0.5`` are not)."""
    if "dims" not in spec:
        return  # constraint_from_dict says it is required
    dims = spec["dims"]
    label = f"constraint {spec.get('name', k + 1)!r}"
    items = dims if isinstance(dims, list) else [dims]
    bad = [d for d in items if isinstance(d, bool) or not isinstance(d, int) or d < 0]
    if bad or not items:
        raise ConfigError(f"{where}: {label}: 'dims' must be state column indices (non-negative integers), "
                          f"got {dims!r}")
    if len(set(items)) != len(items):
        raise ConfigError(f"{where}: {label}: 'dims' repeats a column ({dims!r}); each state column once")
