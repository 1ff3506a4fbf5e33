"""Goal and constraint regions, per-state features and group labels for navigation tasks.

The point-mass and Fetch-Reach experiments share one feature map (paper Sec. V-A/V-B):

====== ============================================ ====================================
column name                                          value at state ``s``
====== ============================================ ====================================
0      ``inv_goal_distance``                        ``1 / ||s - goal centre||``
1      ``in_orange``                                1 if ``s`` is inside the orange region
2      ``in_red``                                   1 if ``s`` is inside the red region
3      ``goal_not_reached``                         1 while ``s`` is outside the goal set
====== ============================================ ====================================

A trajectory's group is decided from its states alone, as in the paper:
``G3`` if any state is inside red (even if it also entered orange), else ``G2`` if any
state is inside orange, else ``G1``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Union

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "FEATURE_NAMES",
    "Box",
    "Disc",
    "NavigationTask",
    "Region",
    "label_group",
]

FEATURE_NAMES: tuple[str, ...] = ("inv_goal_distance", "in_orange", "in_red", "goal_not_reached")

# Floor on the goal distance so that 1/d stays finite if a state lands exactly on the centre.
_MIN_DISTANCE = 1e-6


def _as_states(states: ArrayLike, dim: int) -> NDArray[np.float64]:
    s = np.asarray(states, dtype=np.float64)
    if s.ndim == 1:
        s = s[None, :]
    if s.ndim != 2 or s.shape[1] != dim:
        raise ValueError(f"states: expected shape (T, {dim}), got {np.shape(states)}")
    return s


@dataclass(frozen=True)
class Disc:
    """Ball ``||s - centre|| < radius`` (``<=`` when ``closed``).

    Parameters
    ----------
    centre : tuple of float
        Centre, one value per state dimension.
    radius : float
        Radius (> 0).
    closed : bool
        Whether the boundary belongs to the region.
    """

    centre: tuple[float, ...]
    radius: float
    closed: bool = False

    def __post_init__(self) -> None:
        if not self.radius > 0:
            raise ValueError(f"radius: must be > 0, got {self.radius}")

    @property
    def dim(self) -> int:
        """State dimension."""
        return len(self.centre)

    def distance(self, states: ArrayLike) -> NDArray[np.float64]:
        """Euclidean distance of each state to the centre, shape (T,)."""
        s = _as_states(states, self.dim)
        return np.linalg.norm(s - np.asarray(self.centre), axis=1)

    def contains(self, states: ArrayLike) -> NDArray[np.bool_]:
        """Membership of each state, shape (T,)."""
        d = self.distance(states)
        return d <= self.radius if self.closed else d < self.radius


@dataclass(frozen=True)
class Box:
    """Axis-aligned box ``low <= s <= high`` (bounds included).

    Parameters
    ----------
    low, high : tuple of float
        Lower and upper corner, one value per state dimension.
    """

    low: tuple[float, ...]
    high: tuple[float, ...]

    def __post_init__(self) -> None:
        if len(self.low) != len(self.high):
            raise ValueError(f"low/high: lengths differ ({len(self.low)} vs {len(self.high)})")
        if any(lo > hi for lo, hi in zip(self.low, self.high)):
            raise ValueError(f"low/high: need low <= high, got {self.low} and {self.high}")

    @property
    def dim(self) -> int:
        """State dimension."""
        return len(self.low)

    def contains(self, states: ArrayLike) -> NDArray[np.bool_]:
        """Membership of each state, shape (T,)."""
        s = _as_states(states, self.dim)
        return np.all((s >= np.asarray(self.low)) & (s <= np.asarray(self.high)), axis=1)


Region = Union[Disc, Box]


def label_group(in_orange: ArrayLike, in_red: ArrayLike) -> int:
    """Group of one trajectory from its per-state region indicators.

    Parameters
    ----------
    in_orange, in_red : array-like of bool, shape (T,)

    Returns
    -------
    int
        3 if any state is in red, else 2 if any is in orange, else 1.
    """
    if np.any(np.asarray(in_red, dtype=bool)):
        return 3
    if np.any(np.asarray(in_orange, dtype=bool)):
        return 2
    return 1


@dataclass(frozen=True)
class NavigationTask:
    """Goal set, two constraint regions and reward weights of a navigation task.

    Parameters
    ----------
    goal : Disc
        Goal set (closed ball); reaching it ends the episode.
    orange, red : Disc or Box
        The mild and the severe constraint region.
    true_weights, nominal_weights : tuple of float, length 4
        Weights on :data:`FEATURE_NAMES`; the reward of a state is ``w . phi(s)``.
    """

    goal: Disc
    orange: Region
    red: Region
    true_weights: tuple[float, float, float, float]
    nominal_weights: tuple[float, float, float, float]

    @property
    def dim(self) -> int:
        """State dimension."""
        return self.goal.dim

    @property
    def feature_names(self) -> tuple[str, ...]:
        """Names of the four features."""
        return FEATURE_NAMES

    def reached(self, states: ArrayLike) -> NDArray[np.bool_]:
        """Whether each state is inside the goal set, shape (T,)."""
        return self.goal.contains(states)

    def features(self, states: ArrayLike) -> NDArray[np.float64]:
        """Per-state features :math:`\\phi(s)`, shape (T, 4); see the module docstring."""
        s = _as_states(states, self.dim)
        d = np.maximum(self.goal.distance(s), _MIN_DISTANCE)
        return np.column_stack([
            1.0 / d,
            self.orange.contains(s).astype(np.float64),
            self.red.contains(s).astype(np.float64),
            (~self.goal.contains(s)).astype(np.float64),
        ])

    def weights(self, which: str | ArrayLike) -> NDArray[np.float64]:
        """Reward weights: ``"true"``, ``"nominal"`` or an explicit length-4 vector."""
        if isinstance(which, str):
            if which == "true":
                return np.asarray(self.true_weights, dtype=np.float64)
            if which == "nominal":
                return np.asarray(self.nominal_weights, dtype=np.float64)
            raise ValueError(f"reward_weights: expected 'true', 'nominal' or 4 numbers, got {which!r}")
        w = np.asarray(which, dtype=np.float64).reshape(-1)
        if w.shape != (4,) or not np.all(np.isfinite(w)):
            raise ValueError(f"reward_weights: expected 4 finite numbers, got {which!r}")
        return w

    def group(self, states: ArrayLike) -> int:
        """Group label (1, 2 or 3) of a trajectory from its states; see :func:`label_group`."""
        s = _as_states(states, self.dim)
        return label_group(self.orange.contains(s), self.red.contains(s))
