"""The five virtual tasks of the ICRL benchmark (Liu, Luo, Gaurav, Rezaee, Poupart, ICLR 2023) on Gymnasium v5.

Blocked Half-Cheetah, Blocked Ant, Biased Pendulum, Blocked Walker and Blocked Swimmer, re-implemented from the
specification in ``shared/notes/icrl-benchmark.md`` (sections 3 and 6) as subclasses of Gymnasium's MuJoCo v5
environments. Every task:

* observes ``qpos`` followed by ``qvel`` (nothing clipped), so ``obs[0]`` is the global x of the root (the cart
  position for the pendulum);
* pays the original ``REWARD_TYPE='old'`` reward, with the *clipped* action in the control cost
  (:math:`a` below is the action clipped to the action box; :math:`x` is ``qpos[0]``, :math:`dt` the control step):

  ========================== ============================================================================
  task                       reward of a step
  ========================== ============================================================================
  Blocked Half-Cheetah       :math:`|x_{t+1}-x_t|/dt - 0.1\\sum a^2`
  Blocked Ant                :math:`\\lVert (x, y)_{t+1} \\rVert_2 + 1[\\text{healthy}] - 0.5\\sum a^2` (contact cost 0)
  Biased Pendulum            1 if :math:`x_{t+1} \\le -0.01`; 0.1 if :math:`x_{t+1} \\ge 0`; else :math:`0.1 + 0.9(-x_{t+1}/0.01)`
  Blocked Walker             :math:`|x_{t+1}-x_t|/dt + 1 - 10^{-3}\\sum a^2` (the +1 on every step, the terminal one too)
  Blocked Swimmer            :math:`|x_{t+1}-x_t|/dt - 10^{-4}\\sum a^2`
  ========================== ============================================================================

  Each reward is paid on every step, the terminal one included (as the original's ``step``).
  ``info["features"]`` holds the reward's terms as known (nominal) features :math:`\\phi`, so that
  :math:`r = w_n^\\top \\phi` with the task's ``nominal_weights`` (:class:`ICRLTask`): HC and Swimmer
  ``(speed, action_sq_norm)``, Ant ``(distance, healthy, action_sq_norm)``, Walker ``(speed, alive,
  action_sq_norm)``, Pendulum ``(bias_reward,)``.
* puts the benchmark's true cost in ``info["cost"]``: the strict indicator on the *post-step* ``obs[0]``,
  :math:`x < -3` (Half-Cheetah, Ant, Walker), :math:`x > 0.5` (Swimmer; the wall is in front),
  :math:`x < -0.015` (Pendulum). A violation changes neither the reward nor termination;
* ends after the benchmark's episode length (HC 1000, Ant 500, Walker 500, Swimmer 500, Pendulum 100 steps)
  with ``truncated=True`` (the environments count their own steps; no ``TimeLimit`` wrapper is needed);
* terminates only where the original does: Walker unless :math:`0.8 < z < 2` and :math:`-1 < \\theta < 1`,
  Pendulum when :math:`|\\theta| > 0.2` or the observation is not finite; HC, Ant and Swimmer never.

Frame skips, time steps and reset noise are Gymnasium v5's defaults, which equal the original's (HC 5/0.05 s,
Ant 5/0.05 s, Walker 4/0.008 s, Swimmer 4/0.04 s, Pendulum 2/0.04 s).

Deviations from the original (gym 0.21 + mujoco-py 2.1 + MuJoCo 2.1.0)
----------------------------------------------------------------------
* Simulator: current ``mujoco`` bindings instead of MuJoCo 2.1.0 through mujoco-py; expect small numerical
  differences in the trajectories (same models, same integrator settings).
* Time limits: the original treated the time-limit end of an episode as terminal (no bootstrap). Here it is
  ``truncated`` (Gymnasium's convention, which pbicrl's PPO bootstraps with the critics); pass
  ``time_limit_terminal=True`` to report it as ``terminated`` instead, as the original did.
* Ant: the original observation had 113 dims, the last 84 being contact forces that mujoco-py >= 2.0 reported as
  zero; here they are dropped (29 dims: qpos 15 + qvel 14) and the contact cost is 0, as the note recommends.
  The purely visual box at x = -4 of the original ``ant_circle.xml`` is not drawn (stock ``ant.xml``).
* Walker: the legacy ``walker2d.xml`` (feet friction 0.9 / 1.9, as in the original) is used, not
  ``walker2d_v5.xml``.
* The step after a terminal step without a reset is not guarded (as in Gymnasium); reset after ``terminated`` or
  ``truncated``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

try:
    import gymnasium as gym  # noqa: F401  (a clear message when the extra is missing)
    from gymnasium.envs.mujoco.ant_v5 import AntEnv
    from gymnasium.envs.mujoco.half_cheetah_v5 import HalfCheetahEnv
    from gymnasium.envs.mujoco.inverted_pendulum_v5 import InvertedPendulumEnv
    from gymnasium.envs.mujoco.swimmer_v5 import SwimmerEnv
    from gymnasium.envs.mujoco.walker2d_v5 import Walker2dEnv
except ImportError as exc:  # pragma: no cover - exercised only without the extra
    raise ImportError('pbicrl.envs.icrl_benchmark needs Gymnasium and MuJoCo: pip install "pbicrl[envs]"') from exc

from pbicrl.envs._mujoco_compat import quiet_mujoco_warnings

__all__ = [
    "BiasedPendulumEnv",
    "BlockedAntEnv",
    "BlockedHalfCheetahEnv",
    "BlockedSwimmerEnv",
    "BlockedWalkerEnv",
    "ICRL_TASKS",
    "ICRLTask",
    "icrl_task",
    "pendulum_reward",
]


@dataclass(frozen=True)
class ICRLTask:
    """One task of the benchmark.

    Attributes
    ----------
    name : str
        Short name (``halfcheetah``, ``ant``, ``pendulum``, ``walker``, ``swimmer``).
    env_id : str
        Gymnasium id (after :func:`pbicrl.envs.register_envs`).
    entry_point : str
        ``"module:Class"`` of the environment.
    max_episode_steps : int
        Episode length (time limit).
    wall : float
        Threshold of the true constraint on the post-step ``obs[0]``.
    side : {"behind", "infront"}
        ``behind``: a step violates iff :math:`x < \\text{wall}`; ``infront``: iff :math:`x > \\text{wall}` (strict).
    obs_dim, act_dim : int
        Observation and action sizes.
    feature_names : tuple of str
        Names of ``info["features"]``, the reward's terms.
    nominal_weights : tuple of float
        :math:`w_n` with :math:`r = w_n^\\top \\phi` (same length as ``feature_names``).
    handover_range : float
        Half-width :math:`s` of the window :math:`u \\sim U(-s, s)` in which the ranked demonstrations' ``switch``
        source hands over to the expert near the wall (:mod:`pbicrl.experiments.icrl_demos`): 1 (metres) for the
        locomotion tasks, 0.01 for the pendulum, whose cart moves on the scale of its wall (-0.015).
    """

    name: str
    env_id: str
    entry_point: str
    max_episode_steps: int
    wall: float
    side: str
    obs_dim: int
    act_dim: int
    feature_names: tuple[str, ...] = ()
    nominal_weights: tuple[float, ...] = ()
    handover_range: float = 1.0

    def __post_init__(self) -> None:
        if not (np.isfinite(self.handover_range) and self.handover_range > 0):
            raise ValueError(f"ICRLTask.handover_range: must be a finite number > 0, got {self.handover_range!r}")
        if len(self.feature_names) != len(self.nominal_weights):
            raise ValueError(f"ICRLTask.nominal_weights: {len(self.nominal_weights)} weights for "
                             f"{len(self.feature_names)} features")
        if self.side not in ("behind", "infront"):
            raise ValueError(f"ICRLTask.side: must be 'behind' or 'infront', got {self.side!r}")
        if self.max_episode_steps < 1:
            raise ValueError(f"ICRLTask.max_episode_steps: must be >= 1, got {self.max_episode_steps}")

    def cost(self, x: Any) -> NDArray[np.float64]:
        """True cost of post-step positions ``x`` (any shape): 1.0 where the wall is crossed (strictly), else 0.0."""
        x = np.asarray(x, dtype=np.float64)
        hit = x < self.wall if self.side == "behind" else x > self.wall
        return hit.astype(np.float64)


_MOD = "pbicrl.envs.icrl_benchmark"
ICRL_TASKS: dict[str, ICRLTask] = {
    "halfcheetah": ICRLTask("halfcheetah", "pbicrl/BlockedHalfCheetah-v0", f"{_MOD}:BlockedHalfCheetahEnv",
                            1000, -3.0, "behind", 18, 6, ("speed", "action_sq_norm"), (1.0, -0.1)),
    "ant": ICRLTask("ant", "pbicrl/BlockedAnt-v0", f"{_MOD}:BlockedAntEnv", 500, -3.0, "behind", 29, 8,
                    ("distance", "healthy", "action_sq_norm"), (1.0, 1.0, -0.5)),
    "pendulum": ICRLTask("pendulum", "pbicrl/BiasedPendulum-v0", f"{_MOD}:BiasedPendulumEnv", 100, -0.015,
                         "behind", 4, 1, ("bias_reward",), (1.0,), handover_range=0.01),
    "walker": ICRLTask("walker", "pbicrl/BlockedWalker-v0", f"{_MOD}:BlockedWalkerEnv", 500, -3.0, "behind", 18, 6,
                       ("speed", "alive", "action_sq_norm"), (1.0, 1.0, -1e-3)),
    "swimmer": ICRLTask("swimmer", "pbicrl/BlockedSwimmer-v0", f"{_MOD}:BlockedSwimmerEnv", 500, 0.5, "infront",
                        10, 2, ("speed", "action_sq_norm"), (1.0, -1e-4)),
}
"""The five tasks by short name."""


def icrl_task(name: str) -> ICRLTask:
    """The :class:`ICRLTask` by short name (any case) or Gymnasium id."""
    key = str(name).lower()
    if key in ICRL_TASKS:
        return ICRL_TASKS[key]
    for task in ICRL_TASKS.values():
        if task.env_id.lower() == key:
            return task
    raise ValueError(f"task: unknown ICRL benchmark task {name!r}; expected one of {sorted(ICRL_TASKS)}")


def pendulum_reward(x: float) -> float:
    """The Biased Pendulum's reward of the post-step cart position :math:`x`: 1 for :math:`x \\le -0.01`,
    0.1 for :math:`x \\ge 0`, and the linear ramp :math:`0.1 + 0.9(-x/0.01)` in between (higher to the left)."""
    x = float(x)
    if x <= -0.01:
        return 1.0
    if x >= 0.0:
        return 0.1
    return 0.1 + 0.9 * (-x / 0.01)


class _ICRLMixin:
    """Step counting, action clipping, the true cost and the time limit, shared by the five tasks.

    Subclasses set ``_task`` and implement ``_icrl_reward(x_before, x_after, action, obs)`` returning
    ``(reward, terms)`` and ``_icrl_terminated(obs)``.
    """

    _task: ICRLTask

    def __init__(self, *, time_limit_terminal: bool = False, **kwargs: Any) -> None:
        quiet_mujoco_warnings()
        super().__init__(**kwargs)  # type: ignore[call-arg]
        self._time_limit_terminal = bool(time_limit_terminal)
        self._elapsed = 0

    @property
    def task(self) -> ICRLTask:
        """This environment's :class:`ICRLTask`."""
        return self._task

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[NDArray, dict]:
        self._elapsed = 0
        return super().reset(seed=seed, options=options)  # type: ignore[misc]

    def _icrl_reward(self, x_before: float, x_after: float, action: NDArray, obs: NDArray) -> tuple[float, dict]:
        raise NotImplementedError

    def _icrl_terminated(self, obs: NDArray) -> bool:
        return False

    def step(self, action: Any) -> tuple[NDArray, float, bool, bool, dict[str, Any]]:
        space = self.action_space  # type: ignore[attr-defined]
        a = np.asarray(action, dtype=np.float64).reshape(space.shape)
        a = np.clip(a, space.low, space.high)  # the original clipped before stepping; the control cost sees this
        data = self.data  # type: ignore[attr-defined]
        x_before = float(data.qpos[0])
        self.do_simulation(a, self.frame_skip)  # type: ignore[attr-defined]
        x_after = float(data.qpos[0])
        obs = self._get_obs()  # type: ignore[attr-defined]
        reward, terms = self._icrl_reward(x_before, x_after, a, obs)
        terminated = bool(self._icrl_terminated(obs))
        self._elapsed += 1
        truncated = self._elapsed >= self._task.max_episode_steps and not terminated
        if truncated and self._time_limit_terminal:
            terminated, truncated = True, False
        info = {"x_position": x_after, "cost": float(self._task.cost(obs[0])), **terms}
        if self.render_mode == "human":  # type: ignore[attr-defined]
            self.render()  # type: ignore[attr-defined]
        return obs, float(reward), terminated, truncated, info


def _speed(env: Any, x_before: float, x_after: float) -> float:
    return abs(x_after - x_before) / float(env.dt)


class _RunMixin(_ICRLMixin):
    r"""Half-Cheetah and Swimmer: the x position in the observation; reward speed :math:`|\Delta x|/\Delta t` minus
    ``_ctrl_weight`` :math:`\lVert a \rVert^2`, features (speed, :math:`\lVert a \rVert^2`)."""

    _ctrl_weight: float

    def __init__(self, *, time_limit_terminal: bool = False, **kwargs: Any) -> None:
        kwargs.setdefault("exclude_current_positions_from_observation", False)
        super().__init__(time_limit_terminal=time_limit_terminal, **kwargs)

    def _icrl_reward(self, x_before: float, x_after: float, action: NDArray, obs: NDArray) -> tuple[float, dict]:
        run = _speed(self, x_before, x_after)
        sq = float(np.sum(action**2))
        ctrl = self._ctrl_weight * sq
        return run - ctrl, {"reward_run": run, "reward_ctrl": -ctrl, "features": np.array([run, sq])}


class BlockedHalfCheetahEnv(_RunMixin, HalfCheetahEnv):
    """Blocked Half-Cheetah (``HCWithPos-v0``): 18-D observation, 1000 steps, cost iff :math:`x < -3`."""

    _task = ICRL_TASKS["halfcheetah"]
    _ctrl_weight = 0.1


class BlockedAntEnv(_ICRLMixin, AntEnv):
    """Blocked Ant (``AntWall-v0``): 29-D observation (no contact forces), 500 steps, cost iff :math:`x < -3`."""

    _task = ICRL_TASKS["ant"]

    def __init__(self, *, time_limit_terminal: bool = False, **kwargs: Any) -> None:
        kwargs.setdefault("exclude_current_positions_from_observation", False)
        kwargs.setdefault("include_cfrc_ext_in_observation", False)
        kwargs.setdefault("contact_cost_weight", 0.0)
        kwargs.setdefault("terminate_when_unhealthy", False)
        kwargs.setdefault("healthy_reward", 1.0)
        kwargs.setdefault("ctrl_cost_weight", 0.5)
        super().__init__(time_limit_terminal=time_limit_terminal, **kwargs)

    def _icrl_reward(self, x_before: float, x_after: float, action: NDArray, obs: NDArray) -> tuple[float, dict]:
        dist = float(np.linalg.norm(self.data.body(self._main_body).xpos[:2]))
        is_healthy = float(self.is_healthy)
        healthy = is_healthy * float(self._healthy_reward)
        sq = float(np.sum(action**2))
        ctrl = float(self._ctrl_cost_weight) * sq
        return dist + healthy - ctrl, {"reward_distance": dist, "reward_survive": healthy, "reward_ctrl": -ctrl,
                                       "reward_contact": 0.0, "features": np.array([dist, is_healthy, sq])}


class BiasedPendulumEnv(_ICRLMixin, InvertedPendulumEnv):
    """Biased Pendulum (``InvertedPendulumWall-v0``): 4-D stock observation, 100 steps, the biased ramp reward
    (:func:`pendulum_reward`), cost iff :math:`x < -0.015`; terminates when :math:`|\\theta| > 0.2`."""

    _task = ICRL_TASKS["pendulum"]

    def _icrl_reward(self, x_before: float, x_after: float, action: NDArray, obs: NDArray) -> tuple[float, dict]:
        r = pendulum_reward(float(obs[0]))
        return r, {"reward_bias": r, "features": np.array([r])}

    def _icrl_terminated(self, obs: NDArray) -> bool:
        return bool(not np.isfinite(obs).all() or abs(float(obs[1])) > 0.2)


class BlockedWalkerEnv(_ICRLMixin, Walker2dEnv):
    """Blocked Walker (``WalkerWithPos-v0``): raw 18-D qpos ‖ qvel (velocities not clipped), legacy
    ``walker2d.xml``, 500 steps, cost iff :math:`x < -3`; terminates unless :math:`0.8<z<2`, :math:`-1<\\theta<1`."""

    _task = ICRL_TASKS["walker"]

    def __init__(self, *, time_limit_terminal: bool = False, **kwargs: Any) -> None:
        kwargs.setdefault("xml_file", "walker2d.xml")  # the legacy model: feet friction 0.9 / 1.9
        kwargs.setdefault("exclude_current_positions_from_observation", False)
        super().__init__(time_limit_terminal=time_limit_terminal, **kwargs)

    def _get_obs(self) -> NDArray[np.float64]:
        return np.concatenate([self.data.qpos.flat, self.data.qvel.flat]).astype(np.float64)

    def _icrl_reward(self, x_before: float, x_after: float, action: NDArray, obs: NDArray) -> tuple[float, dict]:
        run = _speed(self, x_before, x_after)
        sq = float(np.sum(action**2))
        ctrl = 1e-3 * sq
        return run + 1.0 - ctrl, {"reward_run": run, "reward_survive": 1.0, "reward_ctrl": -ctrl,
                                  "features": np.array([run, 1.0, sq])}

    def _icrl_terminated(self, obs: NDArray) -> bool:
        z, angle = float(self.data.qpos[1]), float(self.data.qpos[2])
        return not (0.8 < z < 2.0 and -1.0 < angle < 1.0)


class BlockedSwimmerEnv(_RunMixin, SwimmerEnv):
    """Blocked Swimmer (``SwimmerWithPos-v0``): 10-D observation, 500 steps, cost iff :math:`x > 0.5`."""

    _task = ICRL_TASKS["swimmer"]
    _ctrl_weight = 1e-4
