"""MuJoCo HalfCheetah and Ant with an unobserved forward wall (paper Section V-C).

The paper places an invisible constraint on the forward coordinate :math:`x`
(``info["x_position"]``, i.e. ``qpos[0]``): HalfCheetah is penalised by -50 at
every step whose resulting state has :math:`x \\ge 8`, Ant by -100 at every step
with :math:`x \\ge 10`. The inference side only sees the *known* per-step
features

``forward_displacement``
    :math:`x_{t+1} - x_t` (metres per control step, ``dt = 0.05`` s for both robots),
``action_sq_norm``
    :math:`\\lVert a_t \\rVert_2^2`,

with nominal weights :math:`w_n = [20, -0.1]` as stated in the paper. Since
``dt = 0.05``, :math:`20\\,\\Delta x` equals the forward velocity, so the nominal
reward coincides with Gymnasium's HalfCheetah reward (velocity weight 1,
control-cost weight 0.1). The authors' code used velocity with weight 1 and a
control cost of 0.5; we follow the paper text so that the shipped
``nominal_weights`` are exactly the ones the inference is told about.

The per-step *state* exposed for parametric (axis-halfspace) constraints is the
x-position reached after the step, :math:`x_{t+1}`; the penalty applies to a
step iff that value is ``>= wall_x``.

Observation choice: the demonstrators observe their own x-position
(``exclude_current_positions_from_observation=False``); otherwise a policy
trained with the wall penalty could not know where to stop. The constraint
itself (location and penalty) is never part of the observation.

Ant specifics: the policy is trained with Gymnasium's healthy (survival) bonus
of 1 per step and its termination on falling over, because without them Ant
learns far more slowly; the contact cost is disabled and the control cost is set
to 0.1 so that, apart from the survival bonus, the training reward equals
:math:`w_n^\\top \\phi`. The external contact forces are dropped from the
observation (``include_cfrc_ext_in_observation=False``, 29-D observation) to
speed learning. None of this changes the features shipped for inference.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

try:
    import gymnasium as gym
except ImportError as exc:  # pragma: no cover - exercised only without the extra
    raise ImportError(
        "pbicrl.envs.mujoco_wall needs Gymnasium and MuJoCo: pip install \"pbicrl[envs]\""
    ) from exc

__all__ = [
    "FEATURE_NAMES",
    "NOMINAL_WEIGHTS",
    "REACH_MARGIN",
    "WALL_SPECS",
    "WallPenaltyWrapper",
    "WallSpec",
    "make_wall_env",
    "rollout_wall_env",
    "wall_spec",
]

FEATURE_NAMES: tuple[str, str] = ("forward_displacement", "action_sq_norm")
NOMINAL_WEIGHTS: tuple[float, float] = (20.0, -0.1)
#: A good demonstration "reaches the wall" when its furthest x is within this distance of it (issue 13's target).
REACH_MARGIN: float = 0.5


@dataclass(frozen=True)
class WallSpec:
    """Definition of one wall environment.

    Parameters
    ----------
    env_id : str
        Gymnasium id of the base MuJoCo environment.
    wall_x : float
        Constraint threshold: a step is constrained iff the reached x-position is ``>= wall_x``.
    penalty : float
        Reward added (negative) at every constrained step in ``"constrained"`` mode.
    alive_bonus : float
        Per-step survival bonus added to the training reward (Ant only).
    make_kwargs : dict
        Keyword arguments passed to :func:`gymnasium.make`.
    """

    env_id: str
    wall_x: float
    penalty: float
    alive_bonus: float = 0.0
    make_kwargs: dict[str, Any] = field(default_factory=dict)


WALL_SPECS: dict[str, WallSpec] = {
    "halfcheetah": WallSpec(
        env_id="HalfCheetah-v5", wall_x=8.0, penalty=-50.0, alive_bonus=0.0,
        make_kwargs={"exclude_current_positions_from_observation": False},
    ),
    "ant": WallSpec(
        env_id="Ant-v5", wall_x=10.0, penalty=-100.0, alive_bonus=1.0,
        make_kwargs={
            "exclude_current_positions_from_observation": False,
            "include_cfrc_ext_in_observation": False,
            "ctrl_cost_weight": 0.1,
            "contact_cost_weight": 0.0,
            "healthy_reward": 1.0,
        },
    ),
}


def wall_spec(name: str) -> WallSpec:
    """The :class:`WallSpec` of a wall environment by name (``halfcheetah``, ``ant``; any case)."""
    try:
        return WALL_SPECS[name.lower()]
    except KeyError:
        raise ValueError(f"env: unknown wall environment {name!r}; choose one of {sorted(WALL_SPECS)}") from None


class WallPenaltyWrapper(gym.Wrapper):
    """Replace the reward by the nominal reward (+ optional wall penalty) and expose features.

    Parameters
    ----------
    env : gymnasium.Env
        A HalfCheetah-v5 or Ant-v5 environment (``qpos[0]`` is the forward coordinate).
    wall_x : float
        Wall location on x.
    penalty : float
        Penalty (negative) per step whose reached x-position is ``>= wall_x``.
    constrained : bool
        If true the penalty is added to the reward ("good" demonstrator); if false
        the reward is purely nominal ("violating" demonstrator).
    alive_bonus : float
        Added to the reward at every step that does not terminate the episode.
    position_bonus : float
        Training-only shaping of the good demonstrator (``constrained`` mode only): adds
        ``position_bonus * min(x, wall_x)`` per step, so that staying close to the wall pays
        for the rest of the episode (with ``20 * dx`` alone, the return only depends on the
        final x and an exploring policy learns to stop early). 0 (default) is the paper's reward.
        The features (and so the demonstrations' data) do not depend on it.
    reach_bonus : float
        Training-only shaping of the good demonstrator (``constrained`` mode only): adds
        ``reach_bonus`` per step whose reached x lies in ``[wall_x - REACH_MARGIN, wall_x)``,
        the band just short of the wall. With the linear position bonus alone the last half
        metre pays little against the risk of a crossing, and the policy stands still short of
        it. 0 (default) is the paper's reward; the features do not depend on it.
    start_spread : float
        Training-only ("exploring starts"): each reset moves the robot forward by a uniform
        draw from ``[0, start_spread]`` (the environment's own generator, so seeded resets
        repeat), so that every stretch of the track, the last metre before the wall included,
        is practised from a fresh start. 0 (default): Gymnasium's start near x = 0, as the
        demonstrations use.
    terminate_when_flipped : bool
        Training-only: end the episode (as Gymnasium ends it on a fall) when the torso turns
        upside down, i.e. the z-component of its up axis drops below 0. Gymnasium's Ant
        only checks the torso height, and an ant on its back (height about 0.27) stays
        "healthy" for the rest of the episode without being able to walk. Needs a robot
        whose ``qpos[3:7]`` is the torso's quaternion (Ant).
    nominal_weights : sequence of float, length 2
        Weights of ``[forward_displacement, action_sq_norm]``.

    Notes
    -----
    ``step`` adds to ``info``: ``features`` (shape (2,)), ``x_position`` (after the step),
    ``x_position_before``, ``in_wall`` (bool), ``wall_penalty``, ``nominal_reward``
    (:math:`w_n^\\top\\phi`) and ``base_reward`` (Gymnasium's original reward).
    """

    def __init__(self, env: gym.Env, wall_x: float, penalty: float, *, constrained: bool,
                 alive_bonus: float = 0.0, position_bonus: float = 0.0, reach_bonus: float = 0.0,
                 start_spread: float = 0.0, terminate_when_flipped: bool = False,
                 nominal_weights=NOMINAL_WEIGHTS) -> None:
        super().__init__(env)
        for name, value in (("position_bonus", position_bonus), ("reach_bonus", reach_bonus),
                            ("start_spread", start_spread)):
            if not (np.isfinite(value) and value >= 0):
                raise ValueError(f"{name}: must be a finite value >= 0, got {value}")
        if not np.isfinite(wall_x):
            raise ValueError(f"wall_x: must be finite, got {wall_x}")
        if not (np.isfinite(penalty) and penalty <= 0):
            raise ValueError(f"penalty: must be a finite value <= 0, got {penalty}")
        w = np.asarray(nominal_weights, dtype=np.float64).reshape(-1)
        if w.shape != (2,):
            raise ValueError(f"nominal_weights: expected 2 values, got shape {w.shape}")
        self.wall_x = float(wall_x)
        self.penalty = float(penalty)
        self.constrained = bool(constrained)
        self.alive_bonus = float(alive_bonus)
        self.position_bonus = float(position_bonus)
        self.reach_bonus = float(reach_bonus)
        self.start_spread = float(start_spread)
        self.terminate_when_flipped = bool(terminate_when_flipped)
        # a free joint (MuJoCo type 0) first: qpos[3:7] is then the torso's quaternion
        self._free_torso = int(self.env.unwrapped.model.jnt_type[0]) == 0
        if self.terminate_when_flipped and not self._free_torso:
            raise ValueError("terminate_when_flipped: needs a free-floating torso (qpos[3:7] a quaternion), "
                             "as in Ant")
        self.nominal_weights = w
        self._x = 0.0

    def _qpos_x(self) -> float:
        return float(self.env.unwrapped.data.qpos[0])

    def torso_up_z(self) -> float:
        """z-component of the torso's up axis in the world frame (1 upright, -1 on its back; Ant only)."""
        if not self._free_torso:
            raise ValueError("torso_up_z: this robot's torso is not free-floating (qpos[3:7] is not a quaternion)")
        _, qx, qy, _ = (float(v) for v in self.env.unwrapped.data.qpos[3:7])
        return 1.0 - 2.0 * (qx * qx + qy * qy)

    def reset(self, **kwargs):
        obs, info = self.env.reset(**kwargs)
        if self.start_spread:
            u = self.env.unwrapped
            qpos, qvel = u.data.qpos.copy(), u.data.qvel.copy()
            qpos[0] += u.np_random.uniform(0.0, self.start_spread)
            u.set_state(qpos, qvel)
            obs = u._get_obs()
        self._x = self._qpos_x()
        info = dict(info)
        info["x_position"] = self._x
        return obs, info

    def step(self, action):
        x_before = self._x
        obs, base_reward, terminated, truncated, info = self.env.step(action)
        x_after = self._qpos_x()
        self._x = x_after
        flipped = self.terminate_when_flipped and self.torso_up_z() < 0.0
        terminated = bool(terminated or flipped)
        a = np.asarray(action, dtype=np.float64).reshape(-1)
        # features use the action actually applied (MuJoCo clips to ctrlrange = action space)
        a = np.clip(a, self.env.action_space.low, self.env.action_space.high)
        phi = np.array([x_after - x_before, float(a @ a)])
        nominal = float(self.nominal_weights @ phi)
        in_wall = x_after >= self.wall_x
        pen = self.penalty if in_wall else 0.0
        reward = nominal + (pen if self.constrained else 0.0)
        if not terminated:
            reward += self.alive_bonus
        if self.constrained and self.position_bonus:
            reward += self.position_bonus * min(x_after, self.wall_x)
        if self.constrained and self.reach_bonus and self.wall_x - REACH_MARGIN <= x_after < self.wall_x:
            reward += self.reach_bonus
        info = dict(info)
        info.update(features=phi, x_position=x_after, x_position_before=x_before, in_wall=bool(in_wall),
                    wall_penalty=pen, nominal_reward=nominal, base_reward=float(base_reward), flipped=flipped)
        return obs, reward, terminated, truncated, info


def make_wall_env(name: str, *, constrained: bool, max_episode_steps: int = 500,
                  render_mode: str | None = None, position_bonus: float = 0.0, reach_bonus: float = 0.0,
                  start_spread: float = 0.0, terminate_when_flipped: bool = False, **overrides: Any) -> gym.Env:
    """Create a wall environment.

    Parameters
    ----------
    name : {"halfcheetah", "ant"}
        Which robot.
    constrained : bool
        Add the wall penalty to the reward (good demonstrator) or not (violating one).
    max_episode_steps : int
        Episode length (the paper's demonstrations have 500 steps).
    render_mode : str, optional
        Passed to :func:`gymnasium.make`.
    position_bonus : float
        Training-only shaping of the good demonstrator, see :class:`WallPenaltyWrapper`.
    reach_bonus : float
        Training-only: a bonus per step just short of the wall, see :class:`WallPenaltyWrapper`.
    start_spread : float
        Training-only: starts spread uniformly over ``[0, start_spread]`` ahead of Gymnasium's,
        see :class:`WallPenaltyWrapper`.
    terminate_when_flipped : bool
        Training-only: end the episode when the torso is upside down (Ant), see
        :class:`WallPenaltyWrapper`.
    **overrides
        Extra keyword arguments for :func:`gymnasium.make` (override the spec's).

    Returns
    -------
    gymnasium.Env
        ``TimeLimit(WallPenaltyWrapper(base_env))``.
    """
    spec = wall_spec(name)
    if int(max_episode_steps) < 1:
        raise ValueError(f"max_episode_steps: must be >= 1, got {max_episode_steps}")
    kwargs = {**spec.make_kwargs, **overrides}
    # the base env gets a longer limit; our TimeLimit below decides the episode length
    from pbicrl.envs._mujoco_compat import quiet_mujoco_warnings

    quiet_mujoco_warnings()  # no MUJOCO_LOG.TXT in the working directory, no settotalmass notice per env
    base = gym.make(spec.env_id, render_mode=render_mode, max_episode_steps=10**9, **kwargs)
    env = WallPenaltyWrapper(base, spec.wall_x, spec.penalty, constrained=constrained,
                             alive_bonus=spec.alive_bonus, position_bonus=position_bonus,
                             reach_bonus=reach_bonus, start_spread=start_spread,
                             terminate_when_flipped=terminate_when_flipped)
    return gym.wrappers.TimeLimit(env, max_episode_steps=int(max_episode_steps))


def rollout_wall_env(env: gym.Env, policy: Callable[[NDArray], NDArray], *, seed: int | None,
                     n_steps: int = 500) -> dict[str, NDArray]:
    """Run one episode and record per-step features, x-positions and actions.

    Parameters
    ----------
    env : gymnasium.Env
        From :func:`make_wall_env`.
    policy : callable
        Maps an observation to an action.
    seed : int or None
        Reset seed.
    n_steps : int
        Maximum number of steps (stops earlier on termination/truncation).

    Returns
    -------
    dict
        ``features`` (T, 2), ``x`` (T,) x-position after each step, ``actions`` (T, a),
        ``rewards`` (T,), ``terminated`` (bool scalar array), ``x0`` (initial x).
    """
    obs, info = env.reset(seed=seed)
    x0 = float(info["x_position"])
    feats, xs, acts, rews = [], [], [], []
    terminated = False
    for _ in range(int(n_steps)):
        action = np.asarray(policy(obs), dtype=np.float64)
        obs, r, terminated, truncated, info = env.step(action)
        feats.append(info["features"])
        xs.append(info["x_position"])
        acts.append(np.clip(action, env.action_space.low, env.action_space.high))
        rews.append(r)
        if terminated or truncated:
            break
    return {"features": np.asarray(feats), "x": np.asarray(xs), "actions": np.asarray(acts),
            "rewards": np.asarray(rews), "terminated": np.asarray(bool(terminated)), "x0": np.asarray(x0)}
