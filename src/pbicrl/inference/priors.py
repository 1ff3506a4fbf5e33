r"""Priors on constraint indicators :math:`c` and penalty weights :math:`w_p`.

Model (paper Eq. 7 with the indicators of Algorithm 1): :math:`r(s) = (w_n + c \circ w_p)^\top \phi(s)`,
:math:`c_j \sim \mathrm{Bernoulli}(\pi)` and, for an active constraint, :math:`w_{p,j} \sim p_j(w)`.

Penalties penalise
    A constraint penalty is non-positive by meaning, so by default (``sign="negative"``) every
    :math:`p_j` lives on :math:`(-\infty, 0]`. A symmetric prior (``sign="any"``) lets the sampler "explain"
    small differences of the nominal reward with bonuses on features that are not constraints at all.

Default: half-Student-t, scale-aware
    :math:`p_j(w) = 2\, t_\nu(w / s_j) / s_j` on :math:`(-\infty, 0]` with :math:`\nu = 3` and

    .. math:: s_j = \frac{\text{prior\_scale}}{\beta\, \mathrm{sd}_j},

    :math:`\mathrm{sd}_j` the standard deviation (over all trajectories, ``ddof=0``) of feature
    :math:`j`'s per-trajectory mean :math:`\bar\phi_{ij}`. The likelihood depends on :math:`w_j` only through
    :math:`\beta \bar\phi_{ij} w_j`, so :math:`s_j` is ``prior_scale`` nats of log-odds per standard deviation of
    the feature: rescaling a feature by :math:`k` rescales its penalty (prior and posterior) by :math:`1/k` and
    changes nothing else. This follows the weakly informative logistic-regression prior of Gelman, Jakulin,
    Pittau & Su (2008, Ann. Appl. Stat. 2:1360), which gives scale 2.5 to inputs standardised to sd 0.5;
    ``prior_scale=2.5`` here is per sd 1, i.e. twice as wide (``prior_scale=1.25`` reproduces theirs). With
    separated groups (a penalty the data only bound from one side) the Cauchy (:math:`\nu=1`) posterior mean
    does not exist (Ghosh, Li & Mitra 2018, Bayesian Analysis 13:641); :math:`\nu \ge 3` keeps it.

    * Parametric constraint features (fraction of time in a region, in :math:`[0, 1]`, paper Algorithm 2) use
      :math:`\mathrm{sd} = 0.5` (:data:`PARAMETRIC_FEATURE_SD`): their column moves with
      :math:`\vartheta`, and a prior on :math:`w` that depended on :math:`\vartheta` would have to enter every
      parameter move's acceptance ratio. 0.5 is the largest standard deviation a :math:`[0, 1]`-valued feature
      can have (half the trajectories always inside, half never), Gelman et al.'s standardisation of binary
      inputs.
    * Constant features (:math:`\mathrm{sd}_j = 0`, up to rounding) use :math:`\mathrm{sd} = 1`, i.e.
      :math:`s_j = \text{prior\_scale} / \beta`. Such a feature shifts every return equally, so the rankings say
      nothing about it (its posterior is its prior, :math:`P(c_j = 1) = \pi`); the fallback only keeps the prior
      proper. :func:`feature_sd` reports them.

Other kinds
    ``flat``: uniform on ``[low, high]`` (default ``[-1000, 1000]``) intersected with the sign's half line. A flat
    prior must be bounded for :math:`P(c_j = 1 \mid \mathcal{D})` to exist (with an improper prior the Bayes factor
    between "constraint" and "no constraint" is arbitrary, Lindley's paradox), and its width enters
    :math:`P(c_j = 1)` as an Occam factor. ``normal``: :math:`\mathcal{N}(\mu, s_j^2)`, scale-aware like the
    default unless an absolute ``scale`` is given. ``improper``: constant (only for the paper's Algorithm 1
    and BPL, where no indicator posterior is needed).

Truncation
    Every density restricted to its support :math:`[a, b]` is normalised, :math:`p(w) = f(w) / (F(b) - F(a))`
    (the log normaliser is computed from tail probabilities, so far-tail supports stay accurate), and
    sampled exactly by inverting the CDF; nothing is clipped. The Student-t CDF is the regularised incomplete
    beta function, evaluated here by its continued fraction, so SciPy is not needed.

Note also: when the groups are perfectly separated by a feature, the Bradley-Terry likelihood keeps rising as
that penalty grows, so only a lower bound on its magnitude is learned and the prior sets the scale.
:mod:`pbicrl.inference.posterior` warns when a flat posterior piles up at the bound.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from pbicrl.inference.codes import PRIOR_KINDS

__all__ = ["WeightPrior", "ResolvedWeightPrior", "IndicatorPrior", "PriorError", "feature_sd", "truncated_normal_ppf",
           "prior_quantile", "PARAMETRIC_FEATURE_SD", "FLAT_DEFAULT_BOUND"]

#: Standard deviation assumed for parametric constraint features (fraction of time in a region).
PARAMETRIC_FEATURE_SD = 0.5
#: Default half-width of the ``flat`` prior's box.
FLAT_DEFAULT_BOUND = 1000.0

# Kind codes of the compiled density (:func:`pbicrl.inference.samplers._priorkern.logprior_w`).
_CODES = PRIOR_KINDS
_ALIASES = {"uniform": "flat", "student-t": "student_t", "t": "student_t"}
_SIGNS = ("negative", "any")
_MAX_DF = 1e6  # the incomplete-beta continued fraction needs O(sqrt(df)) terms; beyond this use "normal"
_CONSTANT_RTOL = 1e-12  # sd below this fraction of the feature's magnitude is rounding noise: constant

_LOG_HALF = math.log(0.5)
_LOG_SQRT_2PI = 0.5 * math.log(2.0 * math.pi)
_SQRT2 = math.sqrt(2.0)


class PriorError(ValueError):
    """Invalid prior specification."""


# ------------------------------------------------------------------------------------------ scalar math
# Standardised families: ``fam`` is "normal" or "t" (with ``nu`` degrees of freedom). Both are symmetric, so
# F(z) = S(-z) and everything below is written with the upper tail S(z) = P(Z > z), which stays accurate
# far out in the tail where 1 - F(z) would round to 0.

def _log(x: float) -> float:
    """``log`` with ``log(0) = -inf`` (``math.log`` raises)."""
    return math.log(x) if x > 0.0 else -math.inf


def _log1m(x: float) -> float:
    """:math:`\\log(1 - x)` for :math:`x \\le 1`, ``-inf`` at 1 (``math.log1p(-1)`` raises)."""
    return math.log1p(-x) if x < 1.0 else -math.inf


def _logaddexp(x: float, y: float) -> float:
    m = max(x, y)
    if m == -math.inf:
        return -math.inf
    return m + math.log(math.exp(x - m) + math.exp(y - m))


def _norm_logsf(z: float) -> float:
    """:math:`\\log P(Z > z)`, :math:`Z \\sim \\mathcal{N}(0, 1)`."""
    if z < 0.0:
        return math.log1p(-0.5 * math.erfc(-z / _SQRT2))
    if z < 35.0:
        return math.log(0.5 * math.erfc(z / _SQRT2))
    if math.isinf(z):
        return -math.inf
    # Mills-ratio series: erfc nears the smallest float here; next term ~1e4 / z**12 < 1e-14
    r = 1.0 / (z * z)
    return -0.5 * z * z - math.log(z) - _LOG_SQRT_2PI + math.log1p(r * (-1.0 + r * (3.0 + r * (-15.0 + r * (105.0 - 945.0 * r)))))


def _log1p_sq(z: float, nu: float) -> float:
    """:math:`\\log(1 + z^2/\\nu)` without overflow for huge :math:`|z|`."""
    az = abs(z)
    if az > 1e150:
        return 2.0 * math.log(az) - math.log(nu) + math.log1p(nu / az / az)
    return math.log1p(z * z / nu)


def _lgamma_half_ratio(a: float) -> float:
    """:math:`\\log\\Gamma(a + 1/2) - \\log\\Gamma(a)`.

    The plain difference of ``lgamma`` loses about :math:`\\log(a)\\,a` ulps for large :math:`a` (1e-9 at
    ``df = 1e6``); for :math:`a \\ge 50` Stirling's series is subtracted term by term instead:
    :math:`a\\log(1 + \\tfrac{1}{2a}) - \\tfrac12 + \\tfrac12\\log a + R(a + \\tfrac12) - R(a)`.
    """
    if a < 50.0:
        return math.lgamma(a + 0.5) - math.lgamma(a)

    def rem(z: float) -> float:  # Stirling remainder; next term 1/(1188 z^9) < 1e-18 here
        r = 1.0 / (z * z)
        return (1.0 / 12.0 - r * (1.0 / 360.0 - r * (1.0 / 1260.0 - r / 1680.0))) / z

    return (a * math.log1p(0.5 / a) - 0.5) + 0.5 * math.log(a) + (rem(a + 0.5) - rem(a))


_LGAMMA_HALF = 0.5 * math.log(math.pi)


def _t_logconst(nu: float) -> float:
    """Log normalising constant of the standard Student-t density."""
    return _lgamma_half_ratio(0.5 * nu) - 0.5 * math.log(nu * math.pi)


def _betacf(a: float, b: float, x: float) -> float:
    """Continued fraction of :math:`I_x(a, b)`; converges fast for :math:`x < (a+1)/(a+b+2)`.

    :math:`I_x(a,b) = \\frac{x^a (1-x)^b}{a B(a,b)} \\cdot \\frac{1}{g}`, :math:`g = 1 + d_1/(1 + d_2/(1 + \\dots))` with
    :math:`d_{2m+1} = -\\frac{(a+m)(a+b+m)x}{(a+2m)(a+2m+1)}`, :math:`d_{2m} = \\frac{m(b-m)x}{(a+2m-1)(a+2m)}`;
    :math:`g` is evaluated forwards by the modified Lentz method. Returns :math:`1/g`.
    """
    tiny = 1e-300
    g = 1.0
    C = 1.0
    D = 0.0
    for i in range(1, 200_000):
        m = i // 2
        if i % 2:
            di = -(a + m) * (a + b + m) * x / ((a + 2 * m) * (a + 2 * m + 1))
        else:
            di = m * (b - m) * x / ((a + 2 * m - 1) * (a + 2 * m))
        D = 1.0 + di * D
        D = tiny if abs(D) < tiny else D
        C = 1.0 + di / C
        C = tiny if abs(C) < tiny else C
        D = 1.0 / D
        delta = C * D
        g *= delta
        if abs(delta - 1.0) < 1e-16:
            return 1.0 / g
    raise ArithmeticError(f"incomplete beta: continued fraction did not converge (a={a}, b={b}, x={x})")


def _log_betainc(a: float, b: float, log_x: float, log_1mx: float) -> float:
    """:math:`\\log I_x(a, b)` from :math:`\\log x` and :math:`\\log(1-x)` (passed separately: no cancellation)."""
    if log_x == -math.inf:
        return -math.inf
    if log_1mx == -math.inf:
        return 0.0
    x = math.exp(log_x)
    if b == 0.5:  # the Student-t case, without lgamma's cancellation at large a
        log_beta = _LGAMMA_HALF - _lgamma_half_ratio(a)
    else:
        log_beta = math.lgamma(a) + math.lgamma(b) - math.lgamma(a + b)
    if x < (a + 1.0) / (a + b + 2.0):
        front = a * log_x + b * log_1mx - log_beta - math.log(a)
        return front + math.log(_betacf(a, b, x))
    # I_x(a, b) = 1 - I_{1-x}(b, a), where the fraction converges
    front = b * log_1mx + a * log_x - log_beta - math.log(b)
    return _log1m(math.exp(front) * _betacf(b, a, math.exp(log_1mx)))


def _t_logsf(z: float, nu: float) -> float:
    """:math:`\\log P(T > z)`, :math:`T \\sim t_\\nu`: :math:`\\tfrac12 I_{\\nu/(\\nu+z^2)}(\\nu/2, 1/2)` for z > 0."""
    if z != z:
        return math.nan
    if z < 0.0:
        return math.log1p(-math.exp(_t_logsf(-z, nu)))
    if z == 0.0:
        return _LOG_HALF
    if math.isinf(z):
        return -math.inf
    # x = nu / (nu + z^2) and 1 - x = z^2 / (nu + z^2), each in logs from the side that does not overflow
    lsq = _log1p_sq(z, nu)  # log(1 + z^2/nu)
    log_x = -lsq
    log_1mx = 2.0 * math.log(z) - math.log(nu) - lsq
    return _LOG_HALF + _log_betainc(0.5 * nu, 0.5, log_x, log_1mx)


def _logsf(fam: str, nu: float, z: float) -> float:
    return _norm_logsf(z) if fam == "normal" else _t_logsf(z, nu)


def _logpdf_std(fam: str, nu: float, z: float) -> float:
    if fam == "normal":
        return -0.5 * z * z - _LOG_SQRT_2PI
    return _t_logconst(nu) - 0.5 * (nu + 1.0) * _log1p_sq(z, nu)


def _log_mass(fam: str, nu: float, a: float, b: float) -> float:
    """:math:`\\log(F(b) - F(a))` for standardised bounds :math:`a < b`, from the tail that keeps precision."""
    if a >= 0.0:
        lsa = _logsf(fam, nu, a)
        lsb = _logsf(fam, nu, b)
        return lsa + math.log1p(-math.exp(lsb - lsa)) if lsb < lsa else -math.inf
    if b <= 0.0:
        return _log_mass(fam, nu, -b, -a)
    return math.log1p(-(math.exp(_logsf(fam, nu, b)) + math.exp(_logsf(fam, nu, -a))))


def _isf(fam: str, nu: float, L: float) -> float:
    """The :math:`z` with :math:`\\log S(z) = L`, any :math:`L \\le 0` (safeguarded Newton in :math:`z`)."""
    if L > _LOG_HALF:
        # S(z) > 1/2 means z < 0: S(-z) = 1 - S(z)
        return -_isf(fam, nu, math.log(-math.expm1(L))) if L < 0.0 else -math.inf
    if L == _LOG_HALF:
        return 0.0
    if L == -math.inf:
        return math.inf
    lo, hi = 0.0, 1.0
    while _logsf(fam, nu, hi) > L:  # bracket the root; log S decreases
        lo, hi = hi, 2.0 * hi
        if math.isinf(hi):
            return math.inf
    z = 0.5 * (lo + hi)
    for _ in range(500):
        lsf = _logsf(fam, nu, z)
        g = lsf - L
        if g > 0.0:
            lo = z
        else:
            hi = z
        # d log S / dz = -f(z) / S(z)
        slope = -math.exp(_logpdf_std(fam, nu, z) - lsf)
        z_new = z - g / slope if slope < 0.0 else 0.5 * (lo + hi)
        if not (lo < z_new < hi):
            z_new = 0.5 * (lo + hi)
        if abs(z_new - z) <= 4e-16 * abs(z) or hi - lo <= 4e-16 * hi:
            return z_new
        z = z_new
    return z


def _trunc_ppf(fam: str, nu: float, a: float, b: float, u: float) -> float:
    """Standardised :math:`z \\in [a, b]` with :math:`(F(z) - F(a)) / (F(b) - F(a)) = u` (inverse CDF)."""
    if b <= 0.0:
        # mirror z' = -z into [-b, -a] on the upper half line, where S is accurate: P(Z <= z) = u there reads
        # S(z') = S(-a) + u (F(-a) - F(-b)), anchored at the far end so that 1 - u is never formed
        a2, b2 = -b, -a
        L = _logaddexp(_logsf(fam, nu, b2), _log(u) + _log_mass(fam, nu, a2, b2))
        return -min(max(_isf(fam, nu, L), a2), b2)
    lm = _log_mass(fam, nu, a, b)
    if a >= 0.0:
        lsa = _logsf(fam, nu, a)
        # S(z) = S(a) - u (F(b) - F(a))
        z = _isf(fam, nu, lsa + _log1m(u * math.exp(lm - lsa)))
    else:
        p = math.exp(_logsf(fam, nu, -a)) + u * math.exp(lm)  # F(z)
        z = -_isf(fam, nu, _log(p)) if p <= 0.5 else _isf(fam, nu, _log1m(p))
    return min(max(z, a), b)  # guards the last ulp only; the solve is exact to rounding


def truncated_normal_ppf(u: ArrayLike, loc: ArrayLike, scale: ArrayLike, low: ArrayLike,
                         high: ArrayLike) -> NDArray[np.float64]:
    """Inverse CDF of :math:`\\mathcal{N}(\\mu, s^2)` truncated to :math:`[a, b]`, elementwise (broadcast).

    ``u`` uniform on (0, 1) gives an exact draw; used by the samplers to start inside a prior's support.
    """
    u, loc, scale, low, high = np.broadcast_arrays(*(np.asarray(x, dtype=np.float64) for x in (u, loc, scale, low, high)))
    if np.any(~(scale > 0)) or np.any(~(low < high)):
        raise PriorError("truncated normal: need scale > 0 and low < high")
    out = np.empty(u.shape)
    for idx in np.ndindex(u.shape):
        z = _trunc_ppf("normal", 0.0, (low[idx] - loc[idx]) / scale[idx], (high[idx] - loc[idx]) / scale[idx], float(u[idx]))
        out[idx] = min(max(loc[idx] + scale[idx] * z, low[idx]), high[idx])
    return out


def prior_quantile(spec: Mapping[str, Any] | None, p: float) -> float | None:
    """Quantile ``p`` of a one-dimensional prior described by a dict, or ``None`` if it has none we know.

    Kinds: ``flat`` / ``uniform``; ``normal``; ``student_t`` / ``t`` (``df`` or ``nu``) and ``cauchy``, with
    ``mean`` (or ``loc``) and ``scale``, truncated to ``support`` ``[a, b]`` (``None`` = infinite; else
    ``low`` / ``high``). Explicit ``q05`` / ``q95`` entries win (5% / 95% only). The same inverse CDF the
    samplers draw their starting points with (:func:`truncated_normal_ppf`), so there is one of it.
    """
    if not isinstance(spec, Mapping):
        return None
    explicit = {0.05: spec.get("q05"), 0.95: spec.get("q95")}.get(round(p, 12))
    if _real(explicit) and math.isfinite(explicit):
        return float(explicit)
    kind = str(spec.get("kind", "")).lower()
    sup = spec.get("support")
    if isinstance(sup, (list, tuple)) and len(sup) == 2:
        lo = float(sup[0]) if _real(sup[0]) else -math.inf
        hi = float(sup[1]) if _real(sup[1]) else math.inf
    else:
        lo = float(spec["low"]) if _real(spec.get("low")) else -math.inf
        hi = float(spec["high"]) if _real(spec.get("high")) else math.inf
    if not hi > lo or not 0.0 < p < 1.0:
        return None
    if kind in ("flat", "uniform"):
        return lo + p * (hi - lo) if math.isfinite(lo) and math.isfinite(hi) else None
    loc = spec.get("loc", spec.get("mean", 0.0))
    scale = spec.get("scale")
    if not (_real(scale) and scale > 0 and _real(loc)):
        return None
    a, b = (lo - loc) / scale, (hi - loc) / scale  # standardised support
    if kind == "normal":
        fam, nu = "normal", 0.0
    elif kind in ("student_t", "studentt", "student-t", "t", "cauchy"):
        df = 1.0 if kind == "cauchy" else spec.get("df", spec.get("nu"))
        if not (_real(df) and 1.0 <= df <= _MAX_DF):
            return None
        fam, nu = "t", float(df)
    else:
        return None
    z = _trunc_ppf(fam, nu, a, b, float(p))
    return float(loc + scale * z) if math.isfinite(z) else None


def _real(x: Any) -> bool:
    return isinstance(x, (int, float, np.integer, np.floating)) and not isinstance(x, (bool, np.bool_))


# ------------------------------------------------------------------------------------------ priors
def feature_sd(mean_features: ArrayLike, n_parametric: int = 0) -> tuple[NDArray[np.float64], tuple[str, ...]]:
    """Per-feature standard deviations the scale-aware priors use, and where each comes from.

    Parameters
    ----------
    mean_features : array-like, shape (N, d_known)
        Per-trajectory mean features :math:`\\bar\\phi_i` (the likelihood's ``mean_features``).
    n_parametric : int
        Parametric constraint features appended after the known ones.

    Returns
    -------
    sd : ndarray, shape (d_known + n_parametric,)
        :math:`\\mathrm{sd}_j` over trajectories (``ddof=0``); 0 for constant features;
        :data:`PARAMETRIC_FEATURE_SD` for parametric ones.
    source : tuple of str
        ``"data"``, ``"constant"`` (sd 0: the rankings cannot identify this feature) or ``"parametric"``.
    """
    F = np.asarray(mean_features, dtype=np.float64)
    if F.ndim != 2:
        raise PriorError(f"feature_sd: mean features must have shape (N, d), got {F.shape}")
    if int(n_parametric) < 0:
        raise PriorError(f"feature_sd: n_parametric must be >= 0, got {n_parametric}")
    sd = F.std(axis=0) if F.shape[0] else np.zeros(F.shape[1])
    magnitude = np.abs(F).max(axis=0, initial=0.0)
    const = ~(sd > _CONSTANT_RTOL * magnitude)  # also catches NaN
    sd = np.where(const, 0.0, sd)
    src = tuple("constant" if k else "data" for k in const) + ("parametric",) * int(n_parametric)
    return np.concatenate([sd, np.full(int(n_parametric), PARAMETRIC_FEATURE_SD)]), src


@dataclass(frozen=True)
class WeightPrior:
    r"""Independent prior :math:`p_j` on each penalty weight :math:`w_{p,j}` (see the module docstring).

    Parameters
    ----------
    kind : {"student_t", "flat", "normal", "improper"}
        ``student_t`` (default; alias ``"student-t"``): Student-t with ``df`` degrees of freedom, location
        ``mean`` and scale :math:`s_j`; half-Student-t on :math:`(-\infty, 0]` under ``sign="negative"``.
        ``flat`` (alias ``"uniform"``): uniform on the support. ``normal``: :math:`\mathcal{N}(\mu, s_j^2)`.
        ``improper``: constant on the support (paper Algorithm 1 and BPL only). Every proper density is
        normalised on its support.
    low, high : float or None
        Bounds. Default: ``[-1000, 1000]`` for ``flat`` (which must be bounded), unbounded otherwise.
    mean : float
        Location :math:`\mu` of ``normal`` and ``student_t``.
    scale : float or None
        Absolute scale :math:`s_j = s` of every feature (``normal``/``student_t``). ``None`` (default):
        scale-aware, :math:`s_j = \text{prior\_scale} / (\beta\,\mathrm{sd}_j)`, resolved from the data by
        :meth:`resolve`.
    sign : {"negative", "any"}
        ``negative`` (default): support :math:`[\text{low}, \min(\text{high}, 0)]`, penalties only.
        ``any``: :math:`[\text{low}, \text{high}]`, bonuses allowed (symmetric around ``mean``).
    df : float
        Degrees of freedom :math:`\nu` of ``student_t`` (default 3; in :math:`(0, 10^6]`).
    prior_scale : float
        Log-odds per standard deviation of a feature for scale-aware priors (default 2.5).

    Raises
    ------
    PriorError
        Unknown kind or sign, bounds that leave an empty support (e.g. ``low >= 0`` with ``sign="negative"``),
        an unbounded ``flat`` prior, non-positive ``scale``/``df``/``prior_scale``.
    """

    kind: Literal["student_t", "flat", "uniform", "normal", "improper"] = "student_t"
    low: float | None = None
    high: float | None = None
    mean: float = 0.0
    scale: float | None = None
    sign: Literal["negative", "any"] = "negative"
    df: float = 3.0
    prior_scale: float = 2.5

    def __post_init__(self) -> None:
        kind = _ALIASES.get(self.kind, self.kind)
        if kind not in _CODES:
            raise PriorError(f"weight prior: unknown kind {self.kind!r}; choose one of {sorted(_CODES)}")
        object.__setattr__(self, "kind", kind)
        if self.sign not in _SIGNS:
            raise PriorError(f"weight prior: sign must be 'negative' or 'any', got {self.sign!r}")
        default = FLAT_DEFAULT_BOUND if kind == "flat" else math.inf
        low = -default if self.low is None else float(self.low)
        high = default if self.high is None else float(self.high)
        if math.isnan(low) or math.isnan(high) or not low < high:
            raise PriorError(f"weight prior: need low < high, got [{low}, {high}]")
        object.__setattr__(self, "low", low)
        object.__setattr__(self, "high", high)
        lo, hi = self.support
        if not lo < hi:
            raise PriorError(f"weight prior: the support [{lo}, {hi}] is empty: with sign='negative' penalties live "
                             f"on (-inf, 0], so low must be < 0 (got low={low}); use sign='any' for positive weights")
        if kind == "flat" and not (math.isfinite(lo) and math.isfinite(hi)):
            raise PriorError(f"weight prior: 'flat' needs finite bounds, got support [{lo}, {hi}]")
        if not math.isfinite(float(self.mean)):
            raise PriorError(f"weight prior: mean must be finite, got {self.mean}")
        object.__setattr__(self, "mean", float(self.mean))
        if self.scale is not None:
            if not (math.isfinite(float(self.scale)) and float(self.scale) > 0):
                raise PriorError(f"weight prior: scale must be positive, got {self.scale}")
            object.__setattr__(self, "scale", float(self.scale))
        if not (math.isfinite(float(self.df)) and 0.0 < float(self.df) <= _MAX_DF):
            raise PriorError(f"weight prior: df must lie in (0, {_MAX_DF:g}], got {self.df} (use kind='normal' for "
                             "the limit)")
        object.__setattr__(self, "df", float(self.df))
        if not (math.isfinite(float(self.prior_scale)) and float(self.prior_scale) > 0):
            raise PriorError(f"weight prior: prior_scale must be positive, got {self.prior_scale}")
        object.__setattr__(self, "prior_scale", float(self.prior_scale))

    @property
    def code(self) -> int:
        """Kind code of the compiled density."""
        return _CODES[self.kind]

    @property
    def support(self) -> tuple[float, float]:
        """:math:`[a, b]`: the bounds intersected with :math:`(-\\infty, 0]` under ``sign="negative"``."""
        return float(self.low), (min(float(self.high), 0.0) if self.sign == "negative" else float(self.high))

    @property
    def scale_aware(self) -> bool:
        """Whether :math:`s_j` comes from the data (``normal``/``student_t`` without an absolute ``scale``)."""
        return self.kind in ("normal", "student_t") and self.scale is None

    def resolve(self, mean_features: ArrayLike | None = None, *, beta: float = 1.0, n_parametric: int = 0,
                n_features: int | None = None) -> "ResolvedWeightPrior":
        r"""Per-feature parameters for data with these mean features.

        Parameters
        ----------
        mean_features : array-like (N, d_known), optional
            :math:`\bar\Phi` (the likelihood's ``mean_features``); needed by scale-aware priors.
        beta : float
            Inverse temperature :math:`\beta` of the likelihood.
        n_parametric : int
            Parametric constraint features after the known ones (:math:`\mathrm{sd} = 0.5`).
        n_features : int, optional
            Number of features when ``mean_features`` is not given (scale-free priors only).
        """
        beta = float(beta)
        if not (math.isfinite(beta) and beta > 0):
            raise PriorError(f"weight prior: beta must be positive, got {beta}")
        if mean_features is not None:
            sd, src = feature_sd(mean_features, n_parametric)
            if n_features is not None and int(n_features) != sd.size:
                raise PriorError(f"weight prior: n_features={n_features} but the data give {sd.size} features")
        elif self.scale_aware:
            raise PriorError(f"weight prior: {self.kind!r} without an absolute scale is scale-aware; pass the "
                             "likelihood's mean_features (and beta) to resolve its per-feature scales")
        elif n_features is None:
            raise PriorError("weight prior: give mean_features or n_features")
        else:
            sd, src = np.full(int(n_features), np.nan), ("unknown",) * int(n_features)
        d = sd.size
        lo, hi = self.support
        if self.scale_aware:
            sd_used = np.where(sd > 0, sd, 1.0)  # constant feature: sd 1, see the module docstring
            scale = self.prior_scale / (beta * sd_used)
            unit = scale / self.prior_scale
        else:
            # recorded for reports, not used: the scale is absolute
            scale = np.full(d, self.scale if self.scale is not None else (hi - lo if self.kind == "flat" else 1.0))
            unit = np.ones(d)
        return ResolvedWeightPrior(self, np.full(d, lo), np.full(d, hi), np.full(d, self.mean), scale, sd, tuple(src),
                                   unit, beta)

    def as_arrays(self, d: int, *, mean_features: ArrayLike | None = None, beta: float = 1.0,
                  n_parametric: int = 0) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
        """``(kind codes (d,), params (d, 6))`` for the compiled sampler, see :meth:`ResolvedWeightPrior.as_arrays`."""
        return self.resolve(mean_features, beta=beta, n_parametric=n_parametric, n_features=d).as_arrays()

    def logpdf(self, w: ArrayLike) -> NDArray[np.float64]:
        """Normalised log density of each element of ``w`` (up to a constant for ``improper``).

        Scale-free priors only (the same density for every feature); a scale-aware prior needs
        :meth:`resolve` first.
        """
        w = np.asarray(w, dtype=np.float64)
        return _scalar_resolution(self).logpdf(w[..., None])[..., 0]

    def sample(self, rng: np.random.Generator, size: int) -> NDArray[np.float64]:
        """``size`` exact draws (scale-free priors only; ``improper``: not possible)."""
        return _scalar_resolution(self).sample(rng, int(size))[:, 0]

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready record of every choice (infinite bounds as ``None``) and the resulting support."""
        lo, hi = self.support
        return {"kind": self.kind, "sign": self.sign, "low": _finite_or_none(self.low), "high": _finite_or_none(self.high),
                "support": [_finite_or_none(lo), _finite_or_none(hi)], "mean": self.mean, "scale": self.scale,
                "df": self.df, "prior_scale": self.prior_scale, "scale_aware": self.scale_aware}


@functools.lru_cache(maxsize=64)
def _scalar_resolution(prior: WeightPrior) -> "ResolvedWeightPrior":
    """One-feature resolution of a scale-free prior (cached: the plain-NumPy reference sampler calls
    :meth:`WeightPrior.logpdf` at every iteration)."""
    return prior.resolve(n_features=1)


@dataclass(frozen=True, eq=False)
class ResolvedWeightPrior:
    r"""A :class:`WeightPrior` with its per-feature parameters resolved (:meth:`WeightPrior.resolve`).

    Feature :math:`j` has density :math:`p_j(w) = f((w - \mu_j)/s_j) / (s_j Z_j)` on :math:`[a_j, b_j]`, with
    :math:`Z_j = F((b_j-\mu_j)/s_j) - F((a_j-\mu_j)/s_j)` (``flat``: :math:`1/(b_j - a_j)`).

    Attributes
    ----------
    prior : WeightPrior
    low, high : ndarray (d,)
        Support :math:`[a_j, b_j]`.
    loc, scale : ndarray (d,)
        :math:`\mu_j`, :math:`s_j` (``flat``: the width; ``improper``: 1).
    feature_sd : ndarray (d,)
        :math:`\mathrm{sd}_j` from :func:`feature_sd` (NaN when no data were given); used only by scale-aware
        priors.
    sd_source : tuple of str
        ``"data"``, ``"constant"``, ``"parametric"`` or ``"unknown"`` (no data given).
    unit : ndarray (d,)
        Natural step unit of feature :math:`j`: :math:`1/(\beta\,\mathrm{sd}_j) = s_j/\text{prior\_scale}` for a
        scale-aware prior, else 1. The samplers measure random-walk steps in it.
    beta : float
    log_norm : ndarray (d,)
        :math:`\log(s_j Z_j / c_f)`, :math:`c_f` the standard density's constant (``flat``: the width's log;
        ``improper``: 0), computed on construction: log density = log kernel at :math:`z` - ``log_norm``.
    """

    prior: WeightPrior
    low: NDArray[np.float64]
    high: NDArray[np.float64]
    loc: NDArray[np.float64]
    scale: NDArray[np.float64]
    feature_sd: NDArray[np.float64]
    sd_source: tuple[str, ...]
    unit: NDArray[np.float64]
    beta: float = 1.0
    log_norm: NDArray[np.float64] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        d = self.low.size
        for name in ("low", "high", "loc", "scale", "feature_sd", "unit"):
            arr = np.ascontiguousarray(getattr(self, name), dtype=np.float64).reshape(-1)
            if arr.size != d:
                raise PriorError(f"resolved prior: {name} has {arr.size} entries, expected {d}")
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        if len(self.sd_source) != d:
            raise PriorError(f"resolved prior: sd_source has {len(self.sd_source)} entries, expected {d}")
        if not np.all(self.low < self.high):
            raise PriorError("resolved prior: empty support")
        if not np.all((self.scale > 0) & np.isfinite(self.scale)):
            raise PriorError(f"resolved prior: scales must be positive and finite, got {self.scale.tolist()}")
        lognorm = np.array([self._log_norm(j) for j in range(d)])
        if not np.all(np.isfinite(lognorm)):
            bad = np.flatnonzero(~np.isfinite(lognorm)).tolist()
            raise PriorError(f"weight prior: the support holds no prior mass (to double precision) for features {bad}")
        lognorm.setflags(write=False)
        object.__setattr__(self, "log_norm", lognorm)

    @property
    def n_features(self) -> int:
        return int(self.low.size)

    @property
    def kind(self) -> str:
        return self.prior.kind

    def _std_bounds(self, j: int) -> tuple[float, float]:
        return (float(self.low[j] - self.loc[j]) / float(self.scale[j]),
                float(self.high[j] - self.loc[j]) / float(self.scale[j]))

    def _fam(self) -> str:
        return "normal" if self.kind == "normal" else "t"

    def _log_norm(self, j: int) -> float:
        """:math:`\\log` of the constant subtracted from the kernel: log density = kernel(z) - this."""
        kind = self.kind
        if kind == "improper":
            return 0.0
        if kind == "flat":
            return math.log(float(self.high[j] - self.low[j]))
        a, b = self._std_bounds(j)
        nu = self.prior.df
        base = _LOG_SQRT_2PI if kind == "normal" else -_t_logconst(nu)
        return math.log(float(self.scale[j])) + base + _log_mass(self._fam(), nu, a, b)

    def logpdf(self, w: ArrayLike, j: int | None = None) -> NDArray[np.float64]:
        """Log density; ``w`` has features on its last axis, or holds values of feature ``j`` only."""
        w = np.asarray(w, dtype=np.float64)
        sl = slice(None) if j is None else int(j)
        lo, hi, mu, s, ln = self.low[sl], self.high[sl], self.loc[sl], self.scale[sl], self.log_norm[sl]
        z = (w - mu) / s
        kind = self.kind
        with np.errstate(over="ignore", invalid="ignore"):
            if kind == "flat" or kind == "improper":
                val = np.broadcast_to(-ln, np.broadcast(w, ln).shape).astype(np.float64)
            elif kind == "normal":
                val = -0.5 * z * z - ln
            else:
                nu = self.prior.df
                az = np.abs(z)
                big = az > 1e150
                azb = np.where(big, az, 1.0)
                l1p = np.where(big, 2.0 * np.log(azb) - math.log(nu) + np.log1p(nu / azb / azb),
                               np.log1p(np.where(big, 0.0, z) ** 2 / nu))
                val = -0.5 * (nu + 1.0) * l1p - ln
        inside = (w >= lo) & (w <= hi)
        return np.where(inside, val, -np.inf)

    def ppf(self, q: float | ArrayLike, j: int | None = None) -> NDArray[np.float64]:
        """Quantile :math:`F_j^{-1}(q)` of every feature (or of feature ``j``) at probability ``q`` in [0, 1]."""
        if self.kind == "improper":
            raise PriorError("weight prior: an improper prior has no quantiles")
        q = np.asarray(q, dtype=np.float64)
        if np.any(~((q >= 0) & (q <= 1))):
            raise PriorError("weight prior: quantile probabilities must lie in [0, 1]")
        feats = range(self.n_features) if j is None else [int(j)]
        out = np.empty(q.shape + (len(feats),))
        for k, jj in enumerate(feats):
            for idx, u in np.ndenumerate(q):
                out[idx + (k,)] = self._ppf1(jj, float(u))
        return out if j is None else out[..., 0]

    def _ppf1(self, j: int, u: float) -> float:
        lo, hi = float(self.low[j]), float(self.high[j])
        if self.kind == "flat":
            return lo + u * (hi - lo)
        a, b = self._std_bounds(j)
        z = _trunc_ppf(self._fam(), self.prior.df, a, b, u)
        return min(max(float(self.loc[j]) + float(self.scale[j]) * z, lo), hi)

    def sample(self, rng: np.random.Generator, size: int | None = None) -> NDArray[np.float64]:
        """Exact draws, shape (d,) or (size, d): ``flat`` by ``rng.uniform``, others by the inverse CDF."""
        if self.kind == "improper":
            raise PriorError("weight prior: cannot sample from an improper prior")
        shape = (self.n_features,) if size is None else (int(size), self.n_features)
        if self.kind == "flat":
            return rng.uniform(self.low, self.high, shape)
        u = rng.random(shape)
        out = np.empty(shape)
        for idx, uu in np.ndenumerate(u):
            out[idx] = self._ppf1(idx[-1], float(uu))
        return out

    def proposal(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        r"""Initial flip-and-draw proposal :math:`q_j = \mathcal{N}(m_j, r_j^2)` per feature: ``(m, r)``.

        ``normal``/``student_t``: centred on the prior's median, with the larger distance from it to the
        prior's 1% or 99% quantile as standard deviation (half-t, 3 df: :math:`m_j = -0.765\,s_j`,
        :math:`r_j = 5.08\,s_j`). The first switch-ons thus reach into the prior's tail, where data that
        separate the groups put the posterior of a penalty; a proposal with only the prior's quartiles was seen
        to leave chains in a poor mode of a parametric box constraint (log posterior 150 below the true one).
        ``flat``: the centre of the box and a twentieth of its width (the samplers' rule since the start: a
        box is meant to be far wider than the penalties). Warm-up then fits :math:`q_j` to the posterior, so
        the kept draws do not depend on this choice, only how fast warm-up finds the posterior.
        """
        if self.kind == "improper":
            raise PriorError("weight prior: an improper prior has no proposal scale")
        if self.kind == "flat":
            return 0.5 * (self.low + self.high), (self.high - self.low) / 20.0
        qs = self.ppf(np.array([0.01, 0.5, 0.99]))
        med = qs[1].copy()
        return med, np.maximum(np.maximum(med - qs[0], qs[2] - med), np.finfo(float).tiny)

    def as_arrays(self) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
        """``(kind codes (d,), params (d, 6))`` for :func:`pbicrl.inference.samplers._priorkern.logprior_w`.

        Parameter columns: ``[low, high, loc, scale, df, log_norm]``; the compiled density is the kernel at
        :math:`z = (w - \\mu_j)/s_j` minus ``log_norm`` (the normaliser is computed here, once).
        """
        prm = np.column_stack([self.low, self.high, self.loc, self.scale, np.full(self.n_features, self.prior.df),
                               self.log_norm]).astype(np.float64)
        return np.full(self.n_features, self.prior.code, dtype=np.int64), np.ascontiguousarray(prm)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: the prior's choices and, by feature index (as a string), its resolved ``scale``
        :math:`s_j` (``None`` for ``flat``/``improper``), ``feature_sd``, ``sd_source``, ``support`` and the
        exact prior quantiles ``q05``, ``q50``, ``q95`` (``None`` for ``improper``)."""
        out = self.prior.to_dict() | {"beta": self.beta}
        proper = self.kind != "improper"
        qs = self.ppf(np.array([0.05, 0.5, 0.95])) if proper else None
        feats = {}
        for j in range(self.n_features):
            feats[str(j)] = {"scale": float(self.scale[j]) if self.kind in ("normal", "student_t") else None,
                             "feature_sd": _finite_or_none(float(self.feature_sd[j])), "sd_source": self.sd_source[j],
                             "support": [_finite_or_none(float(self.low[j])), _finite_or_none(float(self.high[j]))],
                             "q05": _finite_or_none(float(qs[0, j])) if proper else None,
                             "q50": _finite_or_none(float(qs[1, j])) if proper else None,
                             "q95": _finite_or_none(float(qs[2, j])) if proper else None}
        out["features"] = feats
        return out


def _finite_or_none(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


@dataclass(frozen=True)
class IndicatorPrior:
    """Independent Bernoulli(:math:`\\pi`) prior on each indicator :math:`c_j` (``pi = 0.5`` is flat)."""

    pi: float = 0.5

    def __post_init__(self) -> None:
        if not (0.0 < self.pi < 1.0):
            raise PriorError(f"indicator prior: pi must lie strictly between 0 and 1, got {self.pi}")

    @property
    def log_odds(self) -> float:
        """:math:`\\log \\frac{\\pi}{1-\\pi}`, added when a constraint is switched on."""
        return math.log(self.pi) - math.log1p(-self.pi)
