r"""Which reported numbers come from the prior? Measured per quantity by importance reweighting of the draws.

For every summary a run reports (:math:`P(c_j = 1)`, the mean and 90% interval of :math:`c_j w_{p,j}`, and the
mean, median and 90% interval of :math:`w_{p,j}` given :math:`c_j = 1`) this module recomputes it under the
fitted weight prior made :data:`WIDER` times wider (scale, or box half-width, about the same centre; the same
support sign), without sampling again: the kept draws are reweighted by

.. math:: \omega_s \propto \prod_{j:\,c_{s,j} = 1} p_{\text{wide},j}(w_{s,j}) / p_{\text{fit},j}(w_{s,j}),

the ratio of the two joint priors of :math:`(c, w_p)` (the indicator prior is the same and cancels). A number
the data pin down hardly moves; one the prior sets moves with it. A quantity is **prior-driven** when it moves
by more than :data:`SHIFT_TOL` of the width of its fitted 90% interval (:data:`P_TOL` in absolute terms for
:math:`P(c_j = 1)`). Reweighted quantiles cannot pass the outermost draw, so an interval end is also flagged when
the wider prior puts more than :data:`TAIL_FACTOR` times its tail mass (5%) beyond it.

Importance weights cannot put mass where no draw is. A prior with a finite bound (``flat``, or a box) is only
rescaled inside the box by widening it, so there an end (and the mean and median with it) is also flagged when
the draws reach the bound: the end lies within :data:`BOUND_FRACTION` of the box width from it, i.e. the
likelihood has not fallen off where the prior stops. Where the prior cannot be reweighted (the ``paper`` and
``authors`` samplers ignore it; an ``improper`` prior) nothing is measured (``None``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

__all__ = ["PriorSensitivity", "prior_sensitivity", "weight_prior_spec", "sample_prior", "QUANTITIES", "WIDER", "SHIFT_TOL", "P_TOL", "TAIL_FACTOR",
           "BOUND_FRACTION",
           "log_prior_density"]

WIDER = 10.0
"""How much wider the comparison prior is (its scale, or a box's half-width)."""
SHIFT_TOL = 0.1
"""A summary is prior-driven when it moves by more than this fraction of its fitted 90% interval's width."""
P_TOL = 0.1
""":math:`P(c_j = 1)` is prior-driven when it moves by more than this (absolute)."""
TAIL_FACTOR = 2.0
"""An interval end is prior-driven too when the wider prior puts more than this times its tail mass beyond it."""
BOUND_FRACTION = 0.05
"""An interval end within this fraction of the box width from a finite prior bound reaches the bound."""
QUANTITIES = ("p_constraint", "mean_effective_penalty", "ci90_low", "ci90_high", "given_active_mean",
              "given_active_median", "given_active_low", "given_active_high")
"""The summaries measured, each (d,): :math:`P(c_j = 1)`; mean, 5% and 95% quantile of :math:`c_j w_{p,j}`; mean,
median, 5% and 95% quantile of :math:`w_{p,j}` given :math:`c_j = 1`."""


@dataclass(frozen=True)
class PriorSensitivity:
    """The measured prior-sensitivity of every reported summary.

    Attributes
    ----------
    basis : str
        How it was measured (a sentence); ``""`` when nothing could be.
    fitted, wider : dict of str to ndarray (d,)
        Each of :data:`QUANTITIES` under the fitted prior (the plain draws) and under the wider one
        (reweighted); NaN where undefined.
    flags : dict of str to list of (bool or None)
        Per quantity and feature: prior-driven? ``None``: not measured (no active draws, not in the model, or no
        prior to reweight).
    ess : float
        Effective sample size of the importance weights (Kish), over all kept draws; NaN when not measured.
    draws : int
        Kept draws reweighted.
    """

    basis: str
    fitted: dict[str, NDArray[np.float64]]
    wider: dict[str, NDArray[np.float64]]
    flags: dict[str, list[bool | None]]
    ess: float
    draws: int

    @property
    def measured(self) -> bool:
        return bool(self.basis)

    def flag(self, quantity: str, j: int) -> bool | None:
        return self.flags[quantity][j]

    def to_dict(self, names: Sequence[str]) -> dict[str, Any]:
        """JSON-ready: ``basis``, ``wider_by``, ``tolerance``, ``importance_ess``, and per quantity
        ``{name: {"fitted": x, "wider_prior": y, "prior_driven": bool | None}}``."""
        def num(x: float) -> float | None:
            return float(x) if math.isfinite(float(x)) else None

        return {"basis": self.basis or "not measured: the sampler ignores the prior or it cannot be reweighted",
                "wider_by": WIDER, "tolerance": {"shift_of_interval_width": SHIFT_TOL, "p_constraint": P_TOL,
                                                 "tail_factor": TAIL_FACTOR, "bound_fraction": BOUND_FRACTION},
                "importance_ess": num(self.ess), "draws": self.draws,
                "quantities": {q: {n: {"fitted": num(self.fitted[q][j]), "wider_prior": num(self.wider[q][j]),
                                       "prior_driven": self.flags[q][j]} for j, n in enumerate(names)}
                               for q in QUANTITIES}}


# ---------------------------------------------------------------------------------------------- densities
def weight_prior_spec(src: Any, feature_names: Sequence[str], j: int) -> dict[str, Any] | None:
    """The prior of :math:`w_{p,j}` as one flat dict (``kind``, ``support``/``low``/``high``, ``mean``, ``scale``,
    ``df``) from a run's prior summary or its settings' ``weight_prior`` (``src``); ``None`` if unreadable or
    not applied by the sampler.

    A summary is a prior's dict (``kind`` at the top, or under ``weight_prior`` / ``weight``) with optional
    per-feature entries under ``features``, keyed by feature name or index, that override it (e.g. the resolved
    scale of a scale-aware prior).
    """
    if not isinstance(src, Mapping):
        return None
    base = src if "kind" in src else next((src[k] for k in ("weight_prior", "weight")
                                           if isinstance(src.get(k), Mapping)), None)
    if base is None:
        return None
    feats = base.get("features", src.get("features"))
    name = feature_names[j]
    entry = (feats.get(name, feats.get(str(j))) if isinstance(feats, Mapping) else None) or {}
    if base.get("applied") is False:  # e.g. the paper's Algorithm 1, which ignores the prior
        return None
    spec = {k: v for k, v in base.items() if k != "features"}
    spec.update(entry if isinstance(entry, Mapping) else {})
    return spec


def sample_prior(spec: Mapping[str, Any], rng: np.random.Generator, size: int) -> NDArray[np.float64] | None:
    """``size`` draws from the (truncated) prior a spec describes (:func:`log_prior_density`); ``None`` if unknown."""
    kind = str(spec.get("kind", "")).lower()
    lo, hi = _support(spec)
    if kind in ("flat", "uniform"):
        return rng.uniform(lo, hi, size) if math.isfinite(lo) and math.isfinite(hi) and hi > lo else None
    loc, scale = spec.get("loc", spec.get("mean", 0.0)), spec.get("scale")
    if not isinstance(scale, (int, float)) or not scale > 0 or loc is None:
        return None
    dist = _standard_dist(kind, spec)
    if dist is None:
        return None
    fa, fb = dist.cdf((lo - loc) / scale), dist.cdf((hi - loc) / scale)
    u = rng.uniform(fa, fb, size)
    return loc + scale * dist.ppf(u)


def _support(spec: Mapping[str, Any]) -> tuple[float, float]:
    sup = spec.get("support")
    if isinstance(sup, (list, tuple)) and len(sup) == 2:
        lo, hi = sup
    else:
        lo, hi = spec.get("low"), spec.get("high")
    lo = -math.inf if lo is None else float(lo)
    hi = math.inf if hi is None else float(hi)
    return lo, hi


def log_prior_density(spec: Mapping[str, Any], w: NDArray[np.float64], *, widen: float = 1.0) -> NDArray[np.float64] | None:
    """Log density of a one-dimensional weight prior described by a dict, at ``w``; ``None`` if unknown.

    ``kind`` ``flat`` / ``uniform`` (``low``, ``high`` or ``support``), ``normal`` and ``student_t`` / ``t`` /
    ``cauchy`` (``mean`` or ``loc``, ``scale``, ``df``), truncated to ``support``. ``widen`` multiplies the scale
    (a box's half-width about its centre; a support end at 0, a sign restriction, stays).
    """
    kind = str(spec.get("kind", "")).lower()
    lo, hi = _support(spec)
    w = np.asarray(w, dtype=np.float64)
    if kind in ("flat", "uniform"):
        if not (math.isfinite(lo) and math.isfinite(hi) and hi > lo):
            return None
        if lo == 0.0 or hi == 0.0:  # a sign restriction stays; the far end moves out
            lo, hi = lo * widen, hi * widen
        else:
            c = 0.5 * (lo + hi)
            lo, hi = c + widen * (lo - c), c + widen * (hi - c)
        return np.where((w >= lo) & (w <= hi), -math.log(hi - lo), -np.inf)
    loc = spec.get("loc", spec.get("mean", 0.0))
    scale = spec.get("scale")
    if not isinstance(scale, (int, float)) or isinstance(scale, bool) or not scale > 0 or loc is None:
        return None
    loc, scale = float(loc), float(scale) * widen
    # a finite support end that is not the centre (a box around the location) widens with the scale
    lo = lo if not math.isfinite(lo) or lo == loc else loc + widen * (lo - loc)
    hi = hi if not math.isfinite(hi) or hi == loc else loc + widen * (hi - loc)
    dist = _standard_dist(kind, spec)
    if dist is None:
        return None
    a, b = (lo - loc) / scale, (hi - loc) / scale
    mass = float(dist.cdf(b) - dist.cdf(a))
    if not mass > 0:
        return None
    z = (w - loc) / scale
    out = dist.logpdf(z) - math.log(scale) - math.log(mass)
    return np.where((w >= lo) & (w <= hi), out, -np.inf)


# ---------------------------------------------------------------------------------------------- weighted summaries
def _wquantile(x: NDArray[np.float64], wt: NDArray[np.float64], qs: Sequence[float]) -> NDArray[np.float64]:
    """Weighted quantiles (the inverse of the weighted empirical CDF at mid-points; equal weights: ~np.quantile)."""
    if x.size == 0 or not wt.sum() > 0:
        return np.full(len(qs), np.nan)
    o = np.argsort(x, kind="stable")
    x, wt = x[o], wt[o]
    cw = np.cumsum(wt)
    cw = (cw - 0.5 * wt) / cw[-1]
    return np.interp(qs, cw, x)


def _summaries(c: NDArray[np.bool_], w: NDArray[np.float64], wt: NDArray[np.float64],
               level: float) -> dict[str, NDArray[np.float64]]:
    d = c.shape[1]
    q = (1.0 - level) / 2.0
    out = {k: np.full(d, np.nan) for k in QUANTITIES}
    tot = wt.sum()
    eff = np.where(c, w, 0.0)
    for j in range(d):
        out["p_constraint"][j] = float(wt[c[:, j]].sum() / tot)
        out["mean_effective_penalty"][j] = float(np.dot(wt, eff[:, j]) / tot)
        out["ci90_low"][j], out["ci90_high"][j] = _wquantile(eff[:, j], wt, [q, 1.0 - q])
        on = c[:, j] & np.isfinite(w[:, j])
        if on.any() and wt[on].sum() > 0:
            x, ww = w[on, j], wt[on]
            out["given_active_mean"][j] = float(np.dot(ww, x) / ww.sum())
            out["given_active_median"][j], out["given_active_low"][j], out["given_active_high"][j] = \
                _wquantile(x, ww, [0.5, q, 1.0 - q])
    return out


# ---------------------------------------------------------------------------------------------- the measurement
def prior_sensitivity(indicators: NDArray[Any], penalty_weights: NDArray[np.float64],
                      spec_of: Callable[[int], Mapping[str, Any] | None], in_model: NDArray[np.bool_], *,
                      level: float = 0.9) -> PriorSensitivity:
    """Measure which summaries move when the weight prior is :data:`WIDER` times wider (module docstring).

    Parameters
    ----------
    indicators, penalty_weights : ndarray (..., d)
        Kept draws (any leading shape).
    spec_of : callable
        ``spec_of(j)``: the fitted prior of :math:`w_{p,j}` as a dict (see :func:`log_prior_density`), or
        ``None`` when the sampler did not use one.
    in_model : ndarray (d,) bool
        Features whose penalty is part of the model (others are never measured).
    level : float
        Mass of the intervals.
    """
    ind = np.asarray(indicators)
    d = ind.shape[-1]
    c = ind.reshape(-1, d).astype(bool) & np.asarray(in_model, dtype=bool)
    w = np.asarray(penalty_weights, dtype=np.float64).reshape(-1, d)
    S = c.shape[0]
    fitted = _summaries(c, w, np.ones(S), level)
    specs = [spec_of(j) if in_model[j] else None for j in range(d)]
    none = {k: [None] * d for k in QUANTITIES}
    if S == 0 or not any(specs[j] is not None for j in range(d) if in_model[j]):
        return PriorSensitivity("", fitted, {k: np.full(d, np.nan) for k in QUANTITIES}, none, float("nan"), S)
    logr = np.zeros(S)
    bounded: list[tuple[float, float] | None] = [None] * d
    usable = np.zeros(d, dtype=bool)
    for j in range(d):
        spec = specs[j]
        if spec is None:
            continue
        on = c[:, j]
        xs = np.where(on, w[:, j], np.nan)
        lf = log_prior_density(spec, xs[on])
        lw = log_prior_density(spec, xs[on], widen=WIDER)
        if lf is None or lw is None:
            continue
        usable[j] = True
        diff = lw - lf
        diff[~np.isfinite(lf)] = 0.0  # a draw outside the fitted support cannot be (kept as it is)
        logr[on] += diff
        lo, hi = _support(spec)
        if str(spec.get("kind", "")).lower() in ("flat", "uniform") or (math.isfinite(lo) and math.isfinite(hi)):
            bounded[j] = (lo, hi)
    logr -= logr.max()
    wt = np.exp(logr)
    ess = float(wt.sum() ** 2 / np.sum(wt * wt))
    wider = _summaries(c, w, wt, level)
    flags: dict[str, list[bool | None]] = {k: [None] * d for k in QUANTITIES}
    for j in range(d):
        if not usable[j]:
            continue
        flags["p_constraint"][j] = bool(abs(wider["p_constraint"][j] - fitted["p_constraint"][j]) > P_TOL)
        for prefix, qs in (("", ("mean_effective_penalty", "ci90_low", "ci90_high")),
                           ("given_active_", ("given_active_mean", "given_active_median", "given_active_low",
                                              "given_active_high"))):
            lo_k, hi_k = ("ci90_low", "ci90_high") if not prefix else ("given_active_low", "given_active_high")
            width = fitted[hi_k][j] - fitted[lo_k][j]
            for k in qs:
                a, b = fitted[k][j], wider[k][j]
                if not (math.isfinite(a) and math.isfinite(b)):
                    continue
                tol = SHIFT_TOL * width if width > 0 else 1e-12 * max(1.0, abs(a))
                flags[k][j] = bool(abs(b - a) > tol)
            # an end past which the wider prior puts TAIL_FACTOR times the mass: the draws stop before the
            # reweighted quantile can show how far it would go (importance weights cannot extrapolate)
            on = c[:, j] if prefix else np.ones(S, dtype=bool)
            x = w[:, j] if prefix else np.where(c[:, j], w[:, j], 0.0)
            tot = wt[on].sum()
            if tot > 0 and width > 0:
                for k, beyond in ((lo_k, x < fitted[lo_k][j]), (hi_k, x > fitted[hi_k][j])):
                    m = float(wt[on & beyond].sum() / tot)
                    if m > TAIL_FACTOR * (1.0 - level) / 2.0:
                        flags[k][j] = True
        if bounded[j] is not None:  # reweighting cannot move mass past a bound: does the posterior reach it?
            lo, hi = bounded[j]
            span = hi - lo
            for lo_k, hi_k, group in (("given_active_low", "given_active_high",
                                       ("given_active_mean", "given_active_median")),
                                      ("ci90_low", "ci90_high", ("mean_effective_penalty",))):
                hit = False
                for k, bound in ((lo_k, lo), (hi_k, hi)):
                    v = fitted[k][j]
                    if bound == 0.0:  # a sign restriction, not a scale: the data's small-|w| end may sit there
                        continue
                    if math.isfinite(bound) and math.isfinite(v) and math.isfinite(span) \
                            and abs(v - bound) <= BOUND_FRACTION * span:
                        flags[k][j] = True
                        hit = True
                if hit:
                    for k in group:
                        if flags[k][j] is not None:
                            flags[k][j] = True
    basis = (f"importance reweighting of the {S:,} kept draws to the fitted weight prior {WIDER:g} times wider "
             f"(ESS {ess:,.0f}); a summary is prior-driven when it moves by more than {SHIFT_TOL:g} of its 90% "
             f"interval's width ({P_TOL:g} for P(c=1)), an interval end also when the wider prior puts "
             f"{TAIL_FACTOR:g}x its tail mass beyond it or, under a bounded prior, when it reaches the bound")
    return PriorSensitivity(basis, fitted, wider, flags, ess, S)


class _Std:
    """A standardised location-scale distribution (normal, or Student-t with ``df``): ``cdf``, ``ppf``,
    ``logpdf`` from :mod:`scipy.special` (``scipy.stats`` costs about a second to import on every run)."""

    def __init__(self, df: float | None) -> None:
        self.df = df

    def cdf(self, z: Any) -> Any:
        from scipy import special

        return special.ndtr(z) if self.df is None else special.stdtr(self.df, z)

    def ppf(self, u: Any) -> Any:
        from scipy import special

        return special.ndtri(u) if self.df is None else special.stdtrit(self.df, u)

    def logpdf(self, z: Any) -> Any:
        from scipy.special import gammaln

        z = np.asarray(z, dtype=np.float64)
        if self.df is None:
            return -0.5 * z * z - 0.5 * math.log(2.0 * math.pi)
        v = self.df
        return (float(gammaln(0.5 * (v + 1.0)) - gammaln(0.5 * v)) - 0.5 * math.log(v * math.pi)
                - 0.5 * (v + 1.0) * np.log1p(z * z / v))


def _standard_dist(kind: str, spec: Mapping[str, Any]) -> _Std | None:
    """The standardised distribution of a location-scale prior kind (``normal``, Student-t, Cauchy), or None."""
    if kind == "normal":
        return _Std(None)
    if kind in ("student_t", "studentt", "student-t", "t", "cauchy"):
        df = 1.0 if kind == "cauchy" else spec.get("df", spec.get("nu"))
        if not isinstance(df, (int, float)) or not df > 0:
            return None
        return _Std(float(df))
    return None
