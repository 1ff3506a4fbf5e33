"""Fetch-Reach with two box constraint regions (paper Sec. V-B).

Wraps Gymnasium-Robotics' MuJoCo ``FetchReach-v4`` (``mujoco`` bindings, no mujoco-py).
The state is the gripper position ``s in R^3``; an action ``a in [-1, 1]^3`` moves the
gripper's mocap target by ``0.05 a`` metres (the Fetch convention; the finger command is
held at 0).  The goal is the ball of radius 0.05 around ``(0.95, 0.90, 0.72)``; reaching it
ends the episode.  Orange box: ``x in [0.7, 1.1], y in [0.70, 0.85], z in [0.7, 1.4]``; red
box: ``x in [0.7, 1.1], y in [1.00, 1.10], z in [0.7, 1.4]``; the goal sits in the corridor
between them.  Features as in :mod:`pbicrl.envs.regions`; true weights
``[0.1, -20, -100, -5]``, nominal ``[0.1, 0, 0, -5]``.

Start states (a choice of this package; the paper does not state them): the gripper is
driven to a point drawn uniformly from a start box (:data:`START_BOXES`):

* ``"wide"`` (default; the box the shipped policies were trained on):
  ``x in [1.15, 1.30], y in [0.50, 1.30], z in [0.70, 0.90]`` (in front of both boxes, at
  their height), so that a direct reach crosses orange from low ``y``, red from high ``y``
  and neither from the middle.
* ``"equidistant"`` (the demonstrations shipped until 2026-11-29): the sub-box
  ``x in [1.25, 1.30], y in [0.60, 1.20], z in [0.70, 0.90]``.  Every start is then
  ``0.30-0.35`` m from the goal centre along ``x`` and at most ``0.30`` m along ``y`` and
  ``z``, so its Chebyshev distance to the goal (which sets the fewest steps, each axis
  moving at most ``0.05`` m) is ``0.30-0.35`` m wherever it lies in ``y``: whether a reach
  crosses a region no longer decides how far it has to go.  The point mass's edge starts
  have the same property (Chebyshev distance 19-20).  In the wide box, starts in the
  middle band of ``y`` (whose direct reaches avoid both regions) are nearer the goal than
  the oblique ones, so region-free trajectories are shorter.
* ``"balanced"`` (the shipped demonstrations): ``x in [1.20, 1.30], y in [0.60, 1.25],
  z in [0.70, 0.80]``, chosen from pilot rollouts of the shipped policies so that the groups'
  nominal-feature means agree better than from ``"equidistant"`` (expected largest
  standardised mean difference 0.20 against 0.32 there; docs/envs.md).

Compatibility: gymnasium-robotics <= 1.4.2 fails inside ``gym.make("FetchReach-v4")`` with a
bare ``AssertionError`` under mujoco >= 3.12; :mod:`pbicrl.envs._mujoco_compat` patches
its joint helpers before the environment is built (see there).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from pbicrl.envs.regions import Box, Disc, NavigationTask

try:
    import gymnasium as gym
    from gymnasium import spaces
except ImportError as exc:  # pragma: no cover
    raise ImportError('pbicrl.envs.fetch_reach needs gymnasium: pip install "pbicrl[envs]"') from exc

__all__ = [
    "FETCH_REACH_TASK",
    "MAX_STEPS",
    "START_BOXES",
    "START_HIGH",
    "START_LOW",
    "FetchReachConstrainedEnv",
    "make_fetch_reach_base",
]

MAX_STEPS = 50
START_LOW = (1.15, 0.50, 0.70)
START_HIGH = (1.30, 1.30, 0.90)
#: Named start boxes ``(low, high)``; see the module docstring.
START_BOXES: dict[str, tuple[tuple[float, float, float], tuple[float, float, float]]] = {
    "wide": (START_LOW, START_HIGH),
    "equidistant": ((1.25, 0.60, 0.70), (1.30, 1.20, 0.90)),
    "balanced": ((1.20, 0.60, 0.70), (1.30, 1.25, 0.80)),
}
# Mocap settling at reset: sim steps (each ``n_substeps`` MuJoCo steps) and tolerance (m).
_SETTLE_STEPS = 8
_SETTLE_ROUNDS = 4
_SETTLE_TOL = 0.005

FETCH_REACH_TASK = NavigationTask(
    goal=Disc((0.95, 0.90, 0.72), 0.05, closed=True),
    orange=Box((0.7, 0.70, 0.7), (1.1, 0.85, 1.4)),
    red=Box((0.7, 1.00, 0.7), (1.1, 1.10, 1.4)),
    true_weights=(0.1, -20.0, -100.0, -5.0),
    nominal_weights=(0.1, 0.0, 0.0, -5.0),
)


def make_fetch_reach_base(render_mode: str | None = None) -> Any:
    """Build Gymnasium-Robotics' ``FetchReach-v4`` (unwrapped), applying the mujoco shim.

    Raises
    ------
    ImportError
        If gymnasium-robotics or mujoco is missing (names the pip command).
    """
    try:
        import gymnasium_robotics
        import mujoco  # noqa: F401
    except ImportError as exc:
        raise ImportError('Fetch-Reach needs gymnasium-robotics and mujoco: pip install "pbicrl[envs]"') from exc
    from pbicrl.envs._mujoco_compat import patch_gymnasium_robotics

    patch_gymnasium_robotics()
    gym.register_envs(gymnasium_robotics)
    return gym.make("FetchReach-v4", render_mode=render_mode).unwrapped


class FetchReachConstrainedEnv(gym.Env):
    """Fetch-Reach to a fixed target past two box constraints; observation = gripper position.

    Parameters
    ----------
    reward_weights : {"true", "nominal"} or array-like of 4 floats
        Weights of the per-state reward ``w . phi(s')``.
    max_steps : int
        Steps before truncation (default 50, as FetchReach).
    render_mode : str, optional
        Passed to the underlying FetchReach (``"rgb_array"`` or ``"human"``).
    start : {"wide", "equidistant", "balanced"}
        Start box (:data:`START_BOXES`); starts are uniform in it.

    Notes
    -----
    ``reset(options={"position": xyz})`` starts from a given gripper position.
    ``info`` holds ``"features"`` of the new state, ``"reached"`` and ``"start"``.
    """

    metadata = {"render_modes": ["human", "rgb_array"]}

    def __init__(self, reward_weights: str | ArrayLike = "true", max_steps: int = MAX_STEPS,
                 render_mode: str | None = None, start: str = "wide") -> None:
        self.task = FETCH_REACH_TASK
        self.w = self.task.weights(reward_weights)
        if int(max_steps) < 1:
            raise ValueError(f"max_steps: must be >= 1, got {max_steps}")
        if start not in START_BOXES:
            raise ValueError(f"start: expected one of {sorted(START_BOXES)}, got {start!r}")
        self.start = start
        self.start_low, self.start_high = (np.asarray(b, dtype=np.float64) for b in START_BOXES[start])
        self.max_steps = int(max_steps)
        self.render_mode = render_mode
        self._base = make_fetch_reach_base(render_mode)
        # The wrapped env's own goal only drives its (unused) reward and the target marker.
        self._base.goal = np.asarray(self.task.goal.centre, dtype=np.float64)
        self.observation_space = spaces.Box(-np.inf, np.inf, shape=(3,), dtype=np.float32)
        self.action_space = spaces.Box(-1.0, 1.0, shape=(3,), dtype=np.float32)
        self._t = 0
        self._start = np.zeros(3)

    @property
    def position(self) -> NDArray[np.float64]:
        """Current gripper position (copy)."""
        return self._base._utils.get_site_xpos(self._base.model, self._base.data, "robot0:grip").copy()

    def sample_start(self, rng: np.random.Generator) -> NDArray[np.float64]:
        """Draw a start position uniformly from the start box."""
        return rng.uniform(self.start_low, self.start_high)

    def _move_gripper_to(self, target: NDArray[np.float64]) -> None:
        import mujoco

        base = self._base
        # The mocap is welded to the gripper link, which sits at a fixed offset from the grip
        # site; correct the mocap target by the remaining error until the site is on target.
        mocap = np.asarray(target, dtype=np.float64).copy()
        for _ in range(_SETTLE_ROUNDS):
            base._utils.set_mocap_pos(base.model, base.data, "robot0:mocap", mocap)
            for _ in range(_SETTLE_STEPS):
                mujoco.mj_step(base.model, base.data, nstep=base.n_substeps)
            err = target - self.position
            if np.linalg.norm(err) < _SETTLE_TOL:
                break
            mocap = mocap + err

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        """Reset the robot and drive the gripper to a (random or given) start position."""
        super().reset(seed=seed)
        options = options or {}
        self._base.reset(seed=int(self.np_random.integers(2**31)))
        self._base.goal = np.asarray(self.task.goal.centre, dtype=np.float64)
        if "position" in options:
            start = np.asarray(options["position"], dtype=np.float64).reshape(-1)
            if start.shape != (3,):
                raise ValueError(f"options['position']: expected 3 numbers, got {options['position']!r}")
        else:
            start = self.sample_start(self.np_random)
        self._move_gripper_to(start)
        self._t = 0
        pos = self.position
        self._start = pos
        return pos.astype(np.float32), {"features": self.task.features(pos)[0], "reached": False, "start": pos}

    def step(self, action: ArrayLike):
        """Move the gripper target by ``0.05 * action`` and score the new gripper position."""
        a = np.clip(np.asarray(action, dtype=np.float64).reshape(-1), -1.0, 1.0)
        if a.shape != (3,):
            raise ValueError(f"action: expected 3 numbers, got shape {np.shape(action)}")
        self._base.step(np.append(a, 0.0))
        self._t += 1
        pos = self.position
        phi = self.task.features(pos)[0]
        reached = bool(phi[3] == 0.0)
        truncated = (not reached) and self._t >= self.max_steps
        info = {"features": phi, "reached": reached, "start": self._start}
        return pos.astype(np.float32), float(self.w @ phi), reached, truncated, info

    def render(self):
        """Render the underlying FetchReach scene (target marker at the goal centre)."""
        return self._base.render()

    def close(self) -> None:
        """Release the MuJoCo renderer, if any."""
        self._base.close()
