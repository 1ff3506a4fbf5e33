"""2-D point mass navigating to a goal disc past two constraint discs (paper Sec. V-A).

Dynamics: the state is the position ``s in [-1, 20]^2``; an action ``a in [-1, 1]^2``
is added to it and the result is clamped to the box.  The episode ends (``terminated``)
when ``||s - (20, 20)|| <= 3`` and is cut (``truncated``) after 60 steps.  Starts are drawn
uniformly on the left edge (``x in [0, 1], y in [9, 19]``) or the bottom edge
(``x in [9, 19], y in [0, 1]``), each with probability 1/2.  Every start is 19-20 from the
goal centre in Chebyshev distance (the fewest steps, as each axis moves at most 1 per step),
whichever part of an edge it is on.  ``start="balanced"`` (the shipped demonstrations) widens
both edge strips to ``[0, 2.5] x [5, 19]``: the starts that miss both regions then lie both
above and below the orange disc (and its mirror image for red), so that region-free and
region-crossing rollouts have equal nominal-feature means (docs/envs.md).

The reward of a transition is ``w . phi(s')`` with the features of
:mod:`pbicrl.envs.regions` evaluated at the next state; ``w`` is the true weight vector
``[1, -10, -100, -1]`` (penalties known), the nominal one ``[1, 0, 0, -1]`` (constraints
unknown, so a policy trained on it cuts through the regions) or any 4 numbers.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from pbicrl.envs.regions import Disc, NavigationTask

try:
    import gymnasium as gym
    from gymnasium import spaces
except ImportError as exc:  # pragma: no cover - exercised only without the extra
    raise ImportError('pbicrl.envs.point_mass needs gymnasium: pip install "pbicrl[envs]"') from exc

__all__ = ["HIGH", "LOW", "MAX_STEPS", "POINT_MASS_TASK", "START_STRIPS", "PointMassEnv"]

LOW, HIGH = -1.0, 20.0
MAX_STEPS = 60
#: ``start`` -> (along-edge range, across-edge range) of the start strips.
_EDGES = ((9.0, 19.0), (0.0, 1.0))
START_STRIPS: dict[str, tuple[tuple[float, float], tuple[float, float]]] = {
    "random": _EDGES, "left": _EDGES, "bottom": _EDGES, "balanced": ((5.0, 19.0), (0.0, 2.5)),
}

POINT_MASS_TASK = NavigationTask(
    goal=Disc((20.0, 20.0), 3.0, closed=True),
    orange=Disc((5.5, 14.5), 3.0),
    red=Disc((14.5, 5.5), 3.0),
    true_weights=(1.0, -10.0, -100.0, -1.0),
    nominal_weights=(1.0, 0.0, 0.0, -1.0),
)


class PointMassEnv(gym.Env):
    """Gymnasium environment of the constrained 2-D point mass.

    Parameters
    ----------
    reward_weights : {"true", "nominal"} or array-like of 4 floats
        Weights of the per-state reward ``w . phi(s')``.
    max_steps : int
        Steps before truncation (paper: 60).
    start : {"random", "left", "bottom", "balanced"}
        Start edge; ``"random"`` picks either with probability 1/2; ``"balanced"`` too, from the
        wider strips of :data:`START_STRIPS`.

    Notes
    -----
    Observations are the position (float32, shape (2,)); ``info`` holds the features
    of the new state (``"features"``), ``"reached"`` and the ``"start_edge"``.
    """

    metadata = {"render_modes": []}

    def __init__(self, reward_weights: str | ArrayLike = "true", max_steps: int = MAX_STEPS,
                 start: str = "random") -> None:
        self.task = POINT_MASS_TASK
        self.w = self.task.weights(reward_weights)
        if int(max_steps) < 1:
            raise ValueError(f"max_steps: must be >= 1, got {max_steps}")
        if start not in START_STRIPS:
            raise ValueError(f"start: expected one of {', '.join(map(repr, START_STRIPS))}, got {start!r}")
        self.max_steps = int(max_steps)
        self.start = start
        self.observation_space = spaces.Box(LOW, HIGH, shape=(2,), dtype=np.float32)
        self.action_space = spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)
        self._pos = np.zeros(2)
        self._t = 0
        self._edge = "left"

    # ------------------------------------------------------------------ helpers
    @staticmethod
    def dynamics(state: ArrayLike, action: ArrayLike) -> NDArray[np.float64]:
        """Next position: ``clip(s + clip(a, -1, 1), -1, 20)``."""
        a = np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0)
        return np.clip(np.asarray(state, dtype=np.float64) + a, LOW, HIGH)

    def sample_start(self, rng: np.random.Generator, edge: str | None = None) -> tuple[NDArray[np.float64], str]:
        """Draw a start position and its edge (``"left"`` or ``"bottom"``)."""
        if edge is None:
            edge = self.start if self.start in ("left", "bottom") else ("left" if rng.random() < 0.5 else "bottom")
        (a_lo, a_hi), (c_lo, c_hi) = START_STRIPS[self.start]
        along, across = rng.uniform(a_lo, a_hi), rng.uniform(c_lo, c_hi)
        pos = np.array([across, along]) if edge == "left" else np.array([along, across])
        return pos, edge

    @property
    def position(self) -> NDArray[np.float64]:
        """Current position (copy)."""
        return self._pos.copy()

    # ------------------------------------------------------------------ gym API
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        """Start an episode; ``options`` may give ``"start_edge"`` or an explicit ``"position"``."""
        super().reset(seed=seed)
        options = options or {}
        if "position" in options:
            pos = np.asarray(options["position"], dtype=np.float64).reshape(-1)
            if pos.shape != (2,):
                raise ValueError(f"options['position']: expected 2 numbers, got {options['position']!r}")
            self._pos, self._edge = np.clip(pos, LOW, HIGH), "given"
        else:
            edge = options.get("start_edge")
            if edge not in (None, "left", "bottom"):
                raise ValueError(f"options['start_edge']: expected 'left' or 'bottom', got {edge!r}")
            self._pos, self._edge = self.sample_start(self.np_random, edge)
        self._t = 0
        return self._pos.astype(np.float32), {"features": self.task.features(self._pos)[0],
                                              "start_edge": self._edge, "reached": False}

    def step(self, action: ArrayLike):
        """Move, clamp, and score the new state."""
        self._pos = self.dynamics(self._pos, action)
        self._t += 1
        phi = self.task.features(self._pos)[0]
        reached = bool(phi[3] == 0.0)
        reward = float(self.w @ phi)
        truncated = (not reached) and self._t >= self.max_steps
        info = {"features": phi, "reached": reached, "start_edge": self._edge}
        return self._pos.astype(np.float32), reward, reached, truncated, info
