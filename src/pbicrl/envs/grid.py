"""The 3x3 grid of paper Fig. 1 and its three ranked trajectories.

Cells are indexed ``(row, col)`` with row 0 at the bottom; the start is ``(0, 0)`` and the
goal ``(2, 2)``.  Every cell has a one-hot feature ``(grey, orange, red)``; the layout is ::

    row 2:  grey    grey    grey(goal)
    row 1:  grey    orange  grey
    row 0:  grey    grey    red
            (start)

Three start-to-goal paths of five cells each (the paper's Fig. 1 is not reproduced
cell for cell; this layout realises its description):

* ``tau_1`` up the left column and along the top row -- grey cells only;
* ``tau_2`` through the centre -- one orange cell;
* ``tau_3`` along the bottom row and up the right column -- one red cell;

ranked ``tau_1 > tau_2 > tau_3`` (groups 1, 2, 3).  :func:`grid_dataset` builds them as a
:class:`pbicrl.inference.data.Dataset`; :class:`GridEnv` is the matching Gymnasium environment
(needs the ``envs`` extra; the dataset does not).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from pbicrl.inference.data import Dataset

__all__ = [
    "GRID_COLOURS",
    "GRID_FEATURE_NAMES",
    "GRID_GOAL",
    "GRID_PATHS",
    "GRID_START",
    "GridEnv",
    "cell_features",
    "grid_dataset",
    "grid_path_actions",
    "make_grid_env",
]

GRID_FEATURE_NAMES: tuple[str, ...] = ("grey", "orange", "red")
# GRID_COLOURS[row][col]; row 0 is the bottom row.
GRID_COLOURS: tuple[tuple[str, ...], ...] = (
    ("grey", "grey", "red"),
    ("grey", "orange", "grey"),
    ("grey", "grey", "grey"),
)
GRID_START = (0, 0)
GRID_GOAL = (2, 2)
GRID_PATHS: dict[str, tuple[tuple[int, int], ...]] = {
    "tau_1": ((0, 0), (1, 0), (2, 0), (2, 1), (2, 2)),
    "tau_2": ((0, 0), (0, 1), (1, 1), (1, 2), (2, 2)),
    "tau_3": ((0, 0), (0, 1), (0, 2), (1, 2), (2, 2)),
}
# Moves: up, right, down, left as (d_row, d_col).
_MOVES = ((1, 0), (0, 1), (-1, 0), (0, -1))


def cell_features(row: int, col: int) -> NDArray[np.float64]:
    """One-hot ``(grey, orange, red)`` feature of cell ``(row, col)``."""
    if not (0 <= row < 3 and 0 <= col < 3):
        raise ValueError(f"cell: (row, col) must lie in the 3x3 grid, got ({row}, {col})")
    out = np.zeros(3)
    out[GRID_FEATURE_NAMES.index(GRID_COLOURS[row][col])] = 1.0
    return out


def grid_dataset() -> Dataset:
    """The paper's three ranked grid trajectories as a dataset.

    Returns
    -------
    Dataset
        3 trajectories (``tau_1, tau_2, tau_3``, groups 1, 2, 3) of 5 cells each, per-cell
        one-hot features ``(grey, orange, red)`` and states ``(row, col)``.  No actions
        (there are only 4 per 5 cells) and no nominal weights (the example has none).
    """
    feats = [np.array([cell_features(r, c) for r, c in cells]) for cells in GRID_PATHS.values()]
    states = [np.array(cells, dtype=np.float64) for cells in GRID_PATHS.values()]
    return Dataset.from_trajectories(feats, group=[1, 2, 3], states=states, feature_names=GRID_FEATURE_NAMES)


def grid_path_actions(name: str) -> list[int]:
    """Action indices (0..3 = up, right, down, left) that walk path ``name`` of :data:`GRID_PATHS`."""
    if name not in GRID_PATHS:
        raise ValueError(f"name: expected one of {sorted(GRID_PATHS)}, got {name!r}")
    cells = GRID_PATHS[name]
    return [_MOVES.index((b[0] - a[0], b[1] - a[1])) for a, b in zip(cells[:-1], cells[1:])]


def make_grid_env(**kwargs: Any) -> GridEnv:
    """Build :class:`GridEnv` (needs gymnasium)."""
    return GridEnv(**kwargs)


try:  # the environment needs gymnasium; the dataset above does not
    import gymnasium as _gym
    from gymnasium import spaces as _spaces
except ImportError:  # pragma: no cover
    _gym = None


if _gym is not None:

    class GridEnv(_gym.Env):
        """3x3 grid world: observation = cell index ``3*row + col``; actions up/right/down/left.

        Moves off the grid leave the agent in place.  The episode terminates at the goal
        and is truncated after ``max_steps``.  Reward ``w . phi(cell)`` of the new cell with
        ``reward_weights`` (default ``(0, -1, -2)``: grey free, orange bad, red worse).
        ``info["features"]`` holds the one-hot feature of the new cell.
        """

        metadata = {"render_modes": []}

        def __init__(self, reward_weights: Any = (0.0, -1.0, -2.0), max_steps: int = 20) -> None:
            w = np.asarray(reward_weights, dtype=np.float64).reshape(-1)
            if w.shape != (3,):
                raise ValueError(f"reward_weights: expected 3 numbers (grey, orange, red), got {reward_weights!r}")
            if int(max_steps) < 1:
                raise ValueError(f"max_steps: must be >= 1, got {max_steps}")
            self.w, self.max_steps = w, int(max_steps)
            self.observation_space = _spaces.Discrete(9)
            self.action_space = _spaces.Discrete(4)
            self._cell, self._t = GRID_START, 0

        def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
            """Start at the bottom-left cell."""
            super().reset(seed=seed)
            self._cell, self._t = GRID_START, 0
            return 3 * self._cell[0] + self._cell[1], {"features": cell_features(*self._cell)}

        def step(self, action: int):
            """Move one cell (staying put at the border)."""
            if not self.action_space.contains(int(action)):
                raise ValueError(f"action: expected an integer in 0..3, got {action!r}")
            dr, dc = _MOVES[int(action)]
            r, c = self._cell
            self._cell = (min(max(r + dr, 0), 2), min(max(c + dc, 0), 2))
            self._t += 1
            phi = cell_features(*self._cell)
            terminated = self._cell == GRID_GOAL
            truncated = (not terminated) and self._t >= self.max_steps
            return (3 * self._cell[0] + self._cell[1], float(self.w @ phi), terminated, truncated,
                    {"features": phi})
else:  # pragma: no cover

    class GridEnv:  # type: ignore[no-redef]
        """Placeholder raising an ImportError that names the extra."""

        def __init__(self, *args: Any, **kwargs: Any) -> None:
            raise ImportError('GridEnv needs gymnasium: pip install "pbicrl[envs]"')
