r"""When is a run done: rank-normalised split :math:`\hat R`, bulk and tail ESS, and the stopping rule.

The statistics follow Vehtari, Gelman, Simpson, Carpenter and Bürkner (2021), *Rank-normalization, folding, and
localization: an improved R-hat*: split chains, rank-normalise the pooled draws, :math:`\hat R` the larger of the
bulk and the folded (:math:`|x - \mathrm{median}|`) values, the effective sample size from the chains'
autocorrelations with Geyer's initial monotone sequence, tail ESS the smaller of the ESS of the indicators
:math:`x \le q_{0.05}` and :math:`x \ge q_{0.95}`. They are written here with NumPy and SciPy only, so the core
(and the sampler's stopping rule) does not need ArviZ; the tests compare them with ArviZ's.

**Which quantities a run reports, and how each is checked** (:func:`reported_quantities`):

* ``P(c=1) <feature>``: the indicator :math:`c_j` of every feature (its draws, whose mean is the reported
  probability);
* ``<feature> | c=1``: the conditional median and 90% interval of the penalty given :math:`c_j = 1`. These are
  checked through quantities defined for every draw: the indicators :math:`1[c_j = 1,\ w_j \le q]` at the
  conditional 5%, 50% and 95% quantiles :math:`q` (their means estimate the conditional probabilities that
  define those quantiles; the smallest ESS of the three counts). Where the feature is selected (on in at least
  half the draws) the penalty's own draws while it is active, :math:`\log|w_j|`, are checked too (each chain's
  active draws in order, cut to a common length);
* every constraint parameter :math:`\vartheta` on the draws where its constraint is active (as above);
* ``log-likelihood``: the total log-likelihood.

A quantity that never changes in any chain (e.g. the indicator of a feature that is always on) has converged by
definition (its :math:`\hat R` and ESS are not defined). Chains that are each constant at different values have
:math:`\hat R = \infty`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

__all__ = ["rhat", "ess_bulk", "ess_tail", "Convergence", "QuantityCheck", "check_convergence",
           "reported_quantities", "TARGET_ESS", "TARGET_RHAT"]

TARGET_ESS = 400.0
"""Default bulk and tail ESS every reported quantity needs (Vehtari et al. 2021: 100 per chain with 4 chains)."""
TARGET_RHAT = 1.01
"""Default largest rank-normalised split :math:`\\hat R`."""


def _split(x: NDArray[np.float64]) -> NDArray[np.float64]:
    x = np.asarray(x, dtype=np.float64)
    if x.ndim == 1:
        x = x[None, :]
    n = x.shape[1] // 2
    return np.concatenate([x[:, :n], x[:, x.shape[1] - n:]], axis=0)


def _average_ranks(x: NDArray[np.float64]) -> NDArray[np.float64]:
    """1-based ranks of the flattened draws, ties sharing their average rank (``scipy.stats.rankdata``'s
    ``average``, without importing ``scipy.stats``, which costs about a second of start-up)."""
    flat = x.ravel()
    lo, hi = flat.min(), flat.max()
    is_lo = flat == lo
    if lo != hi and np.all(is_lo | (flat == hi)):  # two values (indicators, most reported quantities): no sort
        n_lo = int(np.count_nonzero(is_lo))
        return np.where(is_lo, 0.5 * (n_lo - 1) + 1.0, 0.5 * (n_lo + flat.size - 1) + 1.0).reshape(x.shape)
    order = np.argsort(flat, kind="mergesort")
    srt = flat[order]
    new = np.empty(srt.size, dtype=bool)
    new[:1] = True
    np.not_equal(srt[1:], srt[:-1], out=new[1:])
    group = np.cumsum(new) - 1
    starts = np.flatnonzero(np.r_[new, True])
    avg = 0.5 * (starts[:-1] + starts[1:] - 1) + 1.0
    r = np.empty(srt.size)
    r[order] = avg[group]
    return r.reshape(x.shape)


def _rank_normalise(x: NDArray[np.float64]) -> NDArray[np.float64]:
    from scipy.special import ndtri

    return ndtri((_average_ranks(x) - 0.375) / (x.size + 0.25))


def _rhat_basic(x: NDArray[np.float64]) -> float:
    m, n = x.shape
    if m < 2 or n < 2:
        return math.nan
    means = x.mean(axis=1)
    w = x.var(axis=1, ddof=1).mean()
    b = n * means.var(ddof=1)
    if w == 0:
        return math.nan if b == 0 else math.inf
    return float(math.sqrt(((n - 1) / n * w + b / n) / w))


def rhat(x: NDArray[np.float64]) -> float:
    """Rank-normalised split :math:`\\hat R` of draws shaped (chains, draws): the larger of bulk and folded.

    NaN for fewer than 4 draws per chain or draws that never change; infinite for chains each constant at
    different values.
    """
    x = np.asarray(x, dtype=np.float64)
    if x.ndim != 2 or x.shape[1] < 4:
        return math.nan
    if np.all(x == x.flat[0]):
        return math.nan
    s = _split(x)
    if np.all(s.var(axis=1) == 0):
        return math.inf
    return _rhat_split(s, _rank_normalise(s))


def _rhat_split(s: NDArray[np.float64], z: NDArray[np.float64]) -> float:
    """:func:`rhat` from the split chains ``s`` and their rank normalisation ``z``."""
    bulk = _rhat_basic(z)
    folded = _rhat_basic(_rank_normalise(np.abs(s - np.median(s))))
    return float(max(bulk, folded))


def _autocov(x: NDArray[np.float64]) -> NDArray[np.float64]:
    """Autocovariances (biased, divided by n) of each row, by FFT."""
    m, n = x.shape
    y = x - x.mean(axis=1, keepdims=True)
    size = 1 << (2 * n - 1).bit_length()
    f = np.fft.rfft(y, size, axis=1)
    return np.fft.irfft(f * np.conj(f), size, axis=1)[:, :n] / n


def _ess(x: NDArray[np.float64]) -> float:
    """ESS of (already split) chains (m, n): Geyer's initial positive and monotone sequence."""
    m, n = x.shape
    if n < 4:
        return math.nan
    acov = _autocov(x)
    chain_var = acov[:, 0] * n / (n - 1.0)
    mean_var = chain_var.mean()
    var_plus = mean_var * (n - 1.0) / n
    if m > 1:
        var_plus += x.mean(axis=1).var(ddof=1)
    if not var_plus > 0:
        return math.nan
    rho = np.zeros(n)
    rho[0] = 1.0
    mean_acov = acov.mean(axis=0)
    rho_even = 1.0
    rho_odd = 1.0 - (mean_var - mean_acov[1]) / var_plus
    rho[1] = rho_odd
    t = 1
    while t < n - 3 and rho_even + rho_odd > 0.0:
        rho_even = 1.0 - (mean_var - mean_acov[t + 1]) / var_plus
        rho_odd = 1.0 - (mean_var - mean_acov[t + 2]) / var_plus
        if rho_even + rho_odd >= 0.0:
            rho[t + 1] = rho_even
            rho[t + 2] = rho_odd
        t += 2
    max_t = t - 2
    if rho_even > 0.0:  # the last even lag, for the tail term of tau (Stan's convention)
        rho[max_t + 1] = rho_even
    t = 1
    while t <= max_t - 2:  # initial monotone sequence
        if rho[t + 1] + rho[t + 2] > rho[t - 1] + rho[t]:
            rho[t + 1] = rho[t + 2] = 0.5 * (rho[t - 1] + rho[t])
        t += 2
    tau = -1.0 + 2.0 * rho[:max_t + 1].sum() + rho[max_t + 1]
    tau = max(tau, 1.0 / math.log10(m * n))
    return float(m * n / tau)


def ess_bulk(x: NDArray[np.float64]) -> float:
    """Bulk effective sample size of draws (chains, draws): ESS of the rank-normalised split chains."""
    x = np.asarray(x, dtype=np.float64)
    if x.ndim != 2 or x.shape[1] < 4 or np.all(x == x.flat[0]):
        return math.nan
    return _ess(_rank_normalise(_split(x)))


def ess_tail(x: NDArray[np.float64], prob: tuple[float, float] = (0.05, 0.95)) -> float:
    """Tail effective sample size: the smaller ESS of :math:`1[x \\le q_{0.05}]` and :math:`1[x \\ge q_{0.95}]`."""
    x = np.asarray(x, dtype=np.float64)
    if x.ndim != 2 or x.shape[1] < 4 or np.all(x == x.flat[0]):
        return math.nan
    s = _split(x)
    out = math.inf
    for p, below in ((prob[0], True), (prob[1], False)):
        q = np.quantile(s, p)
        ind = (s <= q) if below else (s >= q)
        ind = ind.astype(np.float64)
        e = _ess(ind) if ind.min() != ind.max() else math.nan
        if not math.isnan(e):
            out = min(out, e)
    return math.nan if out == math.inf else float(out)


@dataclass(frozen=True)
class QuantityCheck:
    """Convergence of one reported quantity: ``rhat``, ``ess_bulk``, ``ess_tail`` (None: constant, hence
    converged) and whether it meets the targets."""

    name: str
    rhat: float | None
    ess_bulk: float | None
    ess_tail: float | None
    ok: bool

    def shortfall(self, target_ess: float, target_rhat: float) -> str:
        """What falls short, in words (``""`` when nothing does)."""
        parts = []
        if self.rhat is not None and not self.rhat < target_rhat:
            parts.append(f"R-hat {self.rhat:.3f} (target < {target_rhat:g})")
        for label, v in (("bulk ESS", self.ess_bulk), ("tail ESS", self.ess_tail)):
            if v is not None and not v >= target_ess:
                parts.append(f"{label} {v:.0f} (target >= {target_ess:g})")
        return ", ".join(parts)

    def to_dict(self) -> dict[str, Any]:
        def f(v: float | None) -> float | None:
            return None if v is None or not math.isfinite(v) else float(v)

        return {"rhat": f(self.rhat) if self.rhat != math.inf else "inf", "ess_bulk": f(self.ess_bulk),
                "ess_tail": f(self.ess_tail), "ok": self.ok}


@dataclass(frozen=True)
class Convergence:
    """The stopping rule's verdict on a set of chains.

    Attributes
    ----------
    converged : bool
        Every reported quantity has :math:`\\hat R` < ``target_rhat`` and bulk and tail ESS >= ``target_ess``.
    checks : tuple of QuantityCheck
    target_ess, target_rhat : float
    """

    converged: bool
    checks: tuple[QuantityCheck, ...]
    target_ess: float = TARGET_ESS
    target_rhat: float = TARGET_RHAT
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def min_ess(self) -> float:
        """Smallest bulk or tail ESS over the quantities (inf when all are constant)."""
        vals = [v for c in self.checks for v in (c.ess_bulk, c.ess_tail) if v is not None]
        return min(vals) if vals else math.inf

    @property
    def max_rhat(self) -> float:
        """Largest :math:`\\hat R` over the quantities (1 when all are constant)."""
        vals = [c.rhat for c in self.checks if c.rhat is not None]
        return max(vals) if vals else 1.0

    def failing(self) -> dict[str, str]:
        """Quantities that fall short, with what falls short and by how much."""
        return {c.name: c.shortfall(self.target_ess, self.target_rhat) for c in self.checks if not c.ok}

    def line(self) -> str:
        """One line for the terminal."""
        if self.converged:
            return (f"converged: every reported quantity has R-hat < {self.target_rhat:g} and bulk/tail ESS >= "
                    f"{self.target_ess:g} (smallest ESS {self.min_ess:.0f}, largest R-hat {self.max_rhat:.3f})")
        bad = self.failing()
        worst = ", ".join(f"{k}: {v}" for k, v in list(bad.items())[:3])
        more = f" and {len(bad) - 3} more" if len(bad) > 3 else ""
        return f"NOT CONVERGED: {len(bad)} reported quantit{'y' if len(bad) == 1 else 'ies'} short ({worst}{more})"

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (``summary.json``'s ``convergence``)."""
        me = self.min_ess
        return {"converged": self.converged, "target_ess": self.target_ess, "target_rhat": self.target_rhat,
                "min_ess": None if me == math.inf else me, "max_rhat": self.max_rhat,
                "failing": self.failing(), "quantities": {c.name: c.to_dict() for c in self.checks}, **self.extra}


def _active(x: NDArray[np.float64], on: NDArray[np.bool_]) -> NDArray[np.float64]:
    """Each chain's draws where ``on``, in order, cut to a common length (chains with < 4 such draws dropped)."""
    runs = [row[m] for row, m in zip(x, on)]
    runs = [r for r in runs if r.size >= 4]
    if len(runs) == 0:
        return np.zeros((0, 0))
    n = min(r.size for r in runs)
    return np.stack([r[:n] for r in runs])


def reported_quantities(indicators: NDArray, penalty_weights: NDArray, log_likelihood: NDArray,
                        feature_names: Sequence[str], parameters: NDArray | None = None,
                        parameter_names: Sequence[str] | None = None,
                        skip: Sequence[str] = ()) -> dict[str, NDArray[np.float64] | list[NDArray[np.float64]]]:
    """The draws behind every reported quantity (see the module docstring), by name.

    Parameters
    ----------
    indicators, penalty_weights : ndarray (chains, draws, d)
    log_likelihood : ndarray (chains, draws)
    feature_names : sequence of str (d,)
    parameters : ndarray (chains, draws, P), optional
        NaN where the constraint is inactive.
    skip : names of features whose summaries are not reported (not identifiable from the data).

    Returns
    -------
    dict
        Name -> (chains, draws) array, or a list of such arrays whose worst statistic counts (the conditional
        quantile indicators of one feature).
    """
    c = np.asarray(indicators).astype(bool)
    w = np.asarray(penalty_weights, dtype=np.float64)
    out: dict[str, Any] = {}
    for j, name in enumerate(feature_names):
        if name in skip:
            continue
        cj = c[:, :, j]
        out[f"P(c=1) {name}"] = cj.astype(np.float64)
        frac = cj.mean()
        if frac == 0.0:
            continue
        wj = w[:, :, j]
        mag = np.where(cj, np.log(np.maximum(np.abs(wj), np.finfo(float).tiny)), np.nan)
        active_vals = mag[cj]
        qs = np.quantile(active_vals, [0.05, 0.5, 0.95])
        out[f"{name} | c=1"] = [(cj & (mag <= q)).astype(np.float64) for q in qs]
        if frac >= 0.5:
            act = _active(mag, cj)
            if act.size:
                out[f"log|w| {name} | c=1"] = act
    if parameters is not None and np.size(parameters):
        p = np.asarray(parameters, dtype=np.float64)
        if p.ndim == 2:
            p = p[:, :, None]
        pnames = list(parameter_names or [f"theta{k}" for k in range(p.shape[2])])
        for k, name in enumerate(pnames):
            act = _active(p[:, :, k], np.isfinite(p[:, :, k]))
            if act.size:
                out[f"parameter {name}"] = act
    out["log-likelihood"] = np.asarray(log_likelihood, dtype=np.float64)
    return out


def _stats(x: NDArray[np.float64]) -> tuple[float | None, float | None, float | None]:
    if x.ndim != 2 or x.shape[1] < 4 or np.all(x == x.flat[0]):
        return None, None, None
    s = _split(x)
    z = _rank_normalise(s)  # shared by rhat and ess_bulk
    r = math.inf if np.all(s.var(axis=1) == 0) else _rhat_split(s, z)
    b = _ess(z)
    t = ess_tail(x)
    return (None if math.isnan(r) else r, None if math.isnan(b) else b, None if math.isnan(t) else t)


def check_convergence(quantities: Mapping[str, Any], *, target_ess: float = TARGET_ESS,
                      target_rhat: float = TARGET_RHAT) -> Convergence:
    """Apply the stopping rule to :func:`reported_quantities` output.

    A quantity given as a list of arrays takes the largest :math:`\\hat R` and the smallest ESS among them.
    Arrays are thinned to at most 20,000 draws per chain first (ESS is rate-like; the statistics cost
    O(draws log draws)).
    """
    checks = []
    for name, x in quantities.items():
        arrays = x if isinstance(x, list) else [x]
        rs, bs, ts = [], [], []
        for a in arrays:
            a = np.asarray(a, dtype=np.float64)
            if a.ndim == 2 and a.shape[1] > 20_000:
                a = a[:, ::-(-a.shape[1] // 20_000)]
            r, b, t = _stats(a)
            if r is not None:
                rs.append(r)
            if b is not None:
                bs.append(b)
            if t is not None:
                ts.append(t)
        r = max(rs) if rs else None
        b = min(bs) if bs else None
        t = min(ts) if ts else None
        ok = (r is None or r < target_rhat) and (b is None or b >= target_ess) and (t is None or t >= target_ess)
        checks.append(QuantityCheck(name, r, b, t, bool(ok)))
    return Convergence(all(c.ok for c in checks), tuple(checks), float(target_ess), float(target_rhat))
