"""Priors on constraint indicators :math:`c` and penalty weights :math:`w_p`.

The paper uses flat priors. A flat prior on :math:`w_p` must be bounded for the posterior probability of a
constraint, :math:`P(c_j = 1 \\mid \\mathcal{D})`, to exist (with an improper prior the Bayes factor between
"constraint" and "no constraint" is arbitrary, Lindley's paradox). So ``flat`` here means uniform on a wide
box, ``[-1000, 1000]`` by default: keep the bounds wide compared with the penalties you expect, and note
that the width enters :math:`P(c_j = 1)` as an Occam factor.

Also note: when the groups are perfectly separated by a feature, the Bradley-Terry likelihood keeps rising
as that penalty grows, so only a lower bound on its magnitude is learned and the posterior piles up at the
prior bound. :mod:`pbicrl.results` warns when that happens; margins and the prior then set the scale.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["WeightPrior", "IndicatorPrior", "PriorError"]

_KINDS = {"flat": 0, "uniform": 0, "normal": 1, "improper": 2}


class PriorError(ValueError):
    """Invalid prior specification."""


@dataclass(frozen=True)
class WeightPrior:
    """Independent prior on each penalty weight :math:`w_{p,j}`.

    Parameters
    ----------
    kind : {"flat", "uniform", "normal", "improper"}
        ``flat``/``uniform``: uniform on ``[low, high]``. ``normal``: :math:`\\mathcal{N}(\\mu, s^2)` truncated to
        ``[low, high]`` (unnormalised truncation: the bounds should be far in the tails). ``improper``: constant
        on the real line (only for the paper's Algorithm 1 and BPL, where no indicator posterior is needed).
    low, high : float
        Bounds (default +-1000).
    mean, scale : float
        For ``normal``.
    """

    kind: Literal["flat", "uniform", "normal", "improper"] = "flat"
    low: float = -1000.0
    high: float = 1000.0
    mean: float = 0.0
    scale: float = 100.0

    def __post_init__(self) -> None:
        if self.kind not in _KINDS:
            raise PriorError(f"weight prior: unknown kind {self.kind!r}; choose one of {sorted(_KINDS)}")
        if not (np.isfinite(self.low) and np.isfinite(self.high)) and self.kind != "improper":
            raise PriorError(f"weight prior: bounds must be finite for kind {self.kind!r} (got [{self.low}, {self.high}])")
        if not self.low < self.high:
            raise PriorError(f"weight prior: need low < high, got [{self.low}, {self.high}]")
        if self.kind == "normal" and not (np.isfinite(self.scale) and self.scale > 0):
            raise PriorError(f"weight prior: normal scale must be positive, got {self.scale}")

    @property
    def code(self) -> int:
        return _KINDS[self.kind]

    def logpdf(self, w: ArrayLike) -> NDArray[np.float64]:
        """Log density (up to a constant for ``improper``), ``-inf`` outside the bounds."""
        w = np.asarray(w, dtype=np.float64)
        if self.kind == "improper":
            return np.zeros_like(w)
        inside = (w >= self.low) & (w <= self.high)
        if self.code == 0:
            val = np.full_like(w, -math.log(self.high - self.low))
        else:
            val = -0.5 * ((w - self.mean) / self.scale) ** 2 - math.log(self.scale * math.sqrt(2 * math.pi))
        return np.where(inside, val, -np.inf)

    def sample(self, rng: np.random.Generator, size: int) -> NDArray[np.float64]:
        """Draws from the prior (``improper``: not possible)."""
        if self.kind == "improper":
            raise PriorError("weight prior: cannot sample from an improper prior")
        if self.code == 0:
            return rng.uniform(self.low, self.high, size)
        return np.clip(rng.normal(self.mean, self.scale, size), self.low, self.high)

    def as_arrays(self, d: int) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
        """``(kind codes (d,), params (d, 4) = [low, high, mean, scale])`` for the compiled sampler."""
        lo = -np.inf if self.kind == "improper" else self.low
        hi = np.inf if self.kind == "improper" else self.high
        return np.full(d, self.code, dtype=np.int64), np.tile([lo, hi, self.mean, self.scale], (d, 1)).astype(np.float64)

    def to_dict(self) -> dict:
        return {"kind": self.kind, "low": self.low, "high": self.high, "mean": self.mean, "scale": self.scale}


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
