"""Inference configuration: one validated record built from a TOML file and/or command-line options."""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

__all__ = ["InferConfig", "ConfigError", "load_config"]


class ConfigError(ValueError):
    """Invalid configuration; the message names the key."""


@dataclass(frozen=True)
class InferConfig:
    r"""Settings of ``pbicrl infer`` (same names in the TOML file, top level or under ``[infer]``).

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
    sampler : "pbicrl" | "paper" | "bpl"
    iterations, burn_in, thin, chains, seed, jobs : int
    sigma, f_s, p_flip, init_scale : sampler settings
    init_range : [low, high]
        ``authors`` sampler: initial penalties uniform on this range (the authors' code: [-30, -1] for point
        mass, [-100, -10] for Fetch-Reach).
    likelihood : "grouped" | "pairwise"
        ``grouped`` (default): the exact grouped Plackett-Luce likelihood, calibrated for grouped rankings;
        ``pairwise``: the paper's Eq. 7 over cross-group pairs (``pairs`` and ``power`` apply to it only).
    prior : "student_t" | "flat" | "normal"
        Prior on each penalty weight (default ``student_t``: half-Student-t on (-inf, 0]).
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
    """

    nominal_weights: list[float] | None = None
    margins: list | None = None
    beta: float = 1.0
    power: float | str | None = None
    pairs: str | int | None = None
    pairs_seed: int = 0
    sampler: str = "pbicrl"
    iterations: int = 400_000
    burn_in: int | None = None
    thin: int | None = None
    chains: int = 4
    seed: int = 0
    jobs: int | None = None
    sigma: float = 0.1
    f_s: int = 4
    p_flip: float = 0.5
    init_scale: float = 1.0
    init_range: list = field(default_factory=lambda: [-30.0, -1.0])
    likelihood: str = "grouped"
    prior: str = "student_t"
    prior_low: float | None = None
    prior_high: float | None = None
    prior_mean: float = 0.0
    prior_scale: float = 2.5
    prior_abs_scale: float | None = None
    prior_df: float = 3.0
    penalty_sign: str = "negative"
    alpha: float = 0.05
    indicator_pi: float = 0.5
    candidates: list | None = None
    constraints: list | None = None
    sigma_theta: float = 0.5
    p_theta: float | None = None

    def updated(self, **values: Any) -> "InferConfig":
        """Copy with the non-``None`` values replaced (command-line options over the file)."""
        return replace(self, **{k: v for k, v in values.items() if v is not None})


_TYPES: dict[str, tuple[type, ...]] = {
    "beta": (int, float), "power": (int, float, str), "sigma": (int, float), "p_flip": (int, float), "init_scale": (int, float),
    "prior_low": (int, float), "prior_high": (int, float), "prior_mean": (int, float), "prior_scale": (int, float),
    "prior_abs_scale": (int, float), "prior_df": (int, float), "penalty_sign": (str,), "likelihood": (str,),
    "alpha": (int, float),
    "indicator_pi": (int, float), "iterations": (int,), "burn_in": (int,), "thin": (int,), "chains": (int,),
    "seed": (int,), "jobs": (int,), "f_s": (int,), "pairs_seed": (int,), "sampler": (str,), "prior": (str,),
    "pairs": (str, int), "nominal_weights": (list,), "margins": (list,), "candidates": (list,),
    "constraints": (list,), "init_range": (list,), "sigma_theta": (int, float), "p_theta": (int, float),
}


def load_config(path: str | Path) -> InferConfig:
    """Read a TOML config; unknown keys and wrong types are errors that name the key."""
    path = Path(path)
    if not path.exists():
        raise ConfigError(f"--config: {path}: no such file")
    try:
        raw = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"--config: {path} is not valid TOML ({exc})") from None
    table = raw.get("infer", raw)
    if not isinstance(table, dict):
        raise ConfigError("--config: [infer] must be a table")
    known = {f.name for f in fields(InferConfig)}
    values = {}
    for key, value in table.items():
        if key == "infer":
            continue
        if key not in known:
            raise ConfigError(f"config key '{key}': unknown; known keys are {', '.join(sorted(known))}")
        types = _TYPES.get(key, (object,))
        if isinstance(value, bool) or not isinstance(value, types):
            raise ConfigError(f"config key '{key}': expected {' or '.join(t.__name__ for t in types)}, got {value!r}")
        values[key] = value
    if "constraints" in values:
        from pbicrl.constraints import constraint_from_dict

        for spec in values["constraints"]:
            if not isinstance(spec, dict):
                raise ConfigError("config key 'constraints': expected [[constraints]] tables")
            constraint_from_dict(spec)  # validate now: family, dims, direction, bounds
    return InferConfig(**values)
