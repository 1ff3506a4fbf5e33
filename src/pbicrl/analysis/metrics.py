"""Constraint error metrics, named apart because the literature uses "CMSE" for two different things.

* :func:`cmse_location` - squared error between the inferred and the true constraint *location*
  (e.g. the wall position :math:`\\vartheta`); this is the quantity in the PBICRL paper's Table I,
  reported there as mean +- std over seeds (:func:`mean_std`).
* :func:`cmse_grid` - mean squared difference between the true and the inferred constraint *indicator*
  over a grid of positions, the definition used by the ICL authors (Gaurav et al. 2022); with 0/1
  indicators it is the fraction of grid points classified wrongly, and it also accepts soft indicators in
  [0, 1] (e.g. a learned constraint function's output).
"""

from __future__ import annotations

from typing import Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["cmse_location", "cmse_grid", "mean_std", "halfspace_indicator"]


def cmse_location(inferred: ArrayLike, true: ArrayLike) -> float:
    """:math:`\\lVert \\hat\\vartheta - \\vartheta \\rVert^2` (a scalar location gives the squared difference)."""
    a = np.asarray(inferred, dtype=np.float64)
    b = np.asarray(true, dtype=np.float64)
    if a.shape != b.shape:
        raise ValueError(f"cmse_location: inferred shape {a.shape} differs from true shape {b.shape}")
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
        raise ValueError("cmse_location: locations must be finite (was the constraint inferred as inactive?)")
    return float(np.sum((a - b) ** 2))


def cmse_grid(true_indicator: Callable[[NDArray], NDArray] | ArrayLike,
              inferred_indicator: Callable[[NDArray], NDArray] | ArrayLike,
              grid: ArrayLike | None = None) -> float:
    """:math:`\\frac{1}{|G|}\\sum_{x\\in G} (I_{true}(x) - I_{inf}(x))^2` over grid positions ``grid`` (rows).

    Either indicator may be a callable evaluated on ``grid`` or an array already evaluated on it.
    """
    g = None if grid is None else np.asarray(grid, dtype=np.float64)
    t = np.asarray(true_indicator(g) if callable(true_indicator) else true_indicator, dtype=np.float64).reshape(-1)
    i = np.asarray(inferred_indicator(g) if callable(inferred_indicator) else inferred_indicator, dtype=np.float64).reshape(-1)
    if t.shape != i.shape or t.size == 0:
        raise ValueError(f"cmse_grid: indicator arrays must be non-empty and of equal length, got {t.size} and {i.size}")
    return float(np.mean((t - i) ** 2))


def halfspace_indicator(threshold: float, direction: str = ">=") -> Callable[[NDArray], NDArray]:
    """Indicator of :math:`x \\ge \\vartheta` (or ``<=``) for 1-D grids."""
    if direction == ">=":
        return lambda x: (np.asarray(x).reshape(-1) >= threshold).astype(float)
    if direction == "<=":
        return lambda x: (np.asarray(x).reshape(-1) <= threshold).astype(float)
    raise ValueError(f"direction: expected '>=' or '<=', got {direction!r}")


def mean_std(values: ArrayLike) -> tuple[float, float]:
    """Mean and (population) standard deviation over seeds, as the paper's tables report."""
    v = np.asarray(values, dtype=np.float64).reshape(-1)
    return float(v.mean()), float(v.std())
