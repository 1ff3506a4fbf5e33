"""The environments ICL runs on (:class:`ICLEnv`: factory with the nominal reward, constrained coordinate, true
constraint for evaluation) and the expert demonstrations it learns from.

Two families: the project's wall tasks (``"halfcheetah"``, ``"ant"``: a wall in front at x = 8 / 10, and
``"point_mass"``), and the five tasks of the ICRL benchmark (:mod:`pbicrl.envs.icrl_benchmark`;
``"icrl_halfcheetah"``, ``"icrl_ant"``, ``"icrl_walker"``: the wall *behind* the start, a step violates iff its
post-step x < -3; ``"icrl_pendulum"``: the cart's x < -0.015; ``"icrl_swimmer"``: a wall in front, x > 0.5), whose
expert coordinates are the good group of the shipped datasets of the same names.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from pbicrl.baselines.icl.presets import ENVS

__all__ = ["ICLEnv", "ICRLFactory", "ICRL_ICL_ENVS", "expert_coordinates", "hide_true_cost", "icl_env", "icrl_coord",
           "point_mass_expert_demos"]

ICRL_ICL_ENVS: dict[str, str] = {"icrl_halfcheetah": "halfcheetah", "icrl_ant": "ant", "icrl_walker": "walker",
                                  "icrl_pendulum": "pendulum", "icrl_swimmer": "swimmer"}
"""ICL environment name -> ICRL benchmark task (:data:`pbicrl.envs.icrl_benchmark.ICRL_TASKS`); the shipped
dataset with the task's ranked demonstrations has the same name as the ICL environment."""


@dataclass(frozen=True)
class ICLEnv:
    """What ICL needs to know about an environment.

    Attributes
    ----------
    name : str
    make : callable
        Zero-argument factory of the environment with the *nominal* reward (no constraint penalty).
    coord : callable
        ``coord(next_obs, info) -> (k,)`` constrained coordinate of the reached state.
    true_indicator : callable
        Indicator of the true constraint on rows of coordinates (evaluation only, never used for learning).
    grid : ndarray, shape (G, k)
        Positions for :func:`pbicrl.analysis.metrics.cmse_grid`.
    location_grid : ndarray, shape (L,), or None
        1-D positions scanned for the constraint location (None: no scalar location, e.g. the point mass).
    true_location : float or None
        The true wall position.
    side : {"infront", "behind"}
        Where the wall is: ``"infront"`` (a halfspace ``x >= theta``: the location is scanned upward, see
        ``scan_from``) or ``"behind"`` (``x < theta``: scanned downward from the lowest expert coordinate).
    scan_from : {"lowest", "nearest"}
        Where the upward scan for a wall in front starts: the lowest expert coordinate (the project's wall tasks,
        whose demonstrations start there) or the highest, their nearest approach to the wall (the ICRL swimmer,
        whose demonstrations swim both ways). Walls behind are always scanned from their nearest approach.
    make_eval : callable or None
        Factory of the environment for ICL's own rollouts (each round's policy sample, the final evaluation);
        None: ``make``. Lets a caller record the training environments' episodes without ICL's rollouts.
    """

    name: str
    make: Callable[[], Any]
    coord: Callable[[Any, dict], NDArray]
    true_indicator: Callable[[NDArray], NDArray]
    grid: NDArray[np.float64]
    location_grid: NDArray[np.float64] | None
    true_location: float | None
    side: str = "infront"
    make_eval: Callable[[], Any] | None = None
    scan_from: str = "lowest"

    def __post_init__(self) -> None:
        if self.side not in ("infront", "behind"):
            raise ValueError(f"ICLEnv.side: must be 'infront' or 'behind', got {self.side!r}")
        if self.scan_from not in ("lowest", "nearest"):
            raise ValueError(f"ICLEnv.scan_from: must be 'lowest' or 'nearest', got {self.scan_from!r}")


class _WallFactory:
    def __init__(self, name: str) -> None:
        self.name = name

    def __call__(self) -> Any:
        from pbicrl.envs.mujoco_wall import make_wall_env

        # the nominal reward only: the constraint is what ICL must learn
        return make_wall_env(self.name, constrained=False, max_episode_steps=500)


class _PointMassFactory:
    def __call__(self) -> Any:
        from pbicrl.envs.point_mass import PointMassEnv

        return PointMassEnv(reward_weights="nominal")


def _hide_cost_class() -> type:
    import gymnasium as gym

    class HideTrueCost(gym.Wrapper):
        """Drops ``info["cost"]`` (the benchmark's true cost) from every step, so that nothing downstream (ICL's
        learner) can read it; rewards, observations and termination are the environment's."""

        def step(self, action: Any) -> Any:
            obs, r, term, trunc, info = self.env.step(action)
            info = dict(info)
            info.pop("cost", None)
            return obs, r, term, trunc, info

    return HideTrueCost


_HIDE: type | None = None


def hide_true_cost(env: Any) -> Any:
    """Wrap ``env`` so that its steps' ``info`` has no ``"cost"`` (:func:`_hide_cost_class`)."""
    global _HIDE
    if _HIDE is None:
        _HIDE = _hide_cost_class()
    return _HIDE(env)


class ICRLFactory:
    """Factory of an ICRL benchmark task's environment for ICL: its nominal reward (the benchmark's reward has no
    constraint term), the true cost removed from ``info`` (:func:`hide_true_cost`).

    Parameters
    ----------
    task : str
        ICRL task (``"halfcheetah"``, ``"ant"``).
    wrap : callable, optional
        Applied to the task's environment *before* the cost is hidden (e.g. a recorder of the true per-episode
        metrics, which the learner then still cannot see).
    """

    def __init__(self, task: str, wrap: Callable[[Any], Any] | None = None) -> None:
        self.task = task
        self.wrap = wrap

    def __call__(self) -> Any:
        import gymnasium as gym

        from pbicrl.envs import register_envs
        from pbicrl.envs.icrl_benchmark import icrl_task

        register_envs()
        env = gym.make(icrl_task(self.task).env_id)
        if self.wrap is not None:
            env = self.wrap(env)
        return hide_true_cost(env)


def icrl_coord(obs: Any, info: dict) -> NDArray[np.float64]:
    """The constrained coordinate of an ICRL task's reached state: the post-step ``obs[0]`` (the root's x, what
    the benchmark's wall constrains)."""
    return np.array([float(np.asarray(obs, dtype=np.float64).reshape(-1)[0])])


def _wall_coord(obs: Any, info: dict) -> NDArray[np.float64]:
    return np.array([float(info["x_position"])])


def _obs_coord(obs: Any, info: dict) -> NDArray[np.float64]:
    return np.asarray(obs, dtype=np.float64).reshape(-1)[:2]


def icl_env(name: str) -> ICLEnv:
    """The :class:`ICLEnv` of ``"halfcheetah"``, ``"ant"`` (walls at x = 8 and 10), ``"point_mass"``, or of one of
    the ICRL benchmark's tasks (:data:`ICRL_ICL_ENVS`: ``"icrl_halfcheetah"``, ``"icrl_ant"``, ``"icrl_walker"``
    with x < -3 violating, ``"icrl_pendulum"`` x < -0.015, ``"icrl_swimmer"`` x > 0.5).

    The CMSE grid spans ``[0, 2 * wall]`` on x (so that an all-0 or all-1 constraint scores 0.5), 401 points;
    the location is scanned up to ``5 * wall`` (from the lowest expert x, see :func:`run_icl`). For the point mass the grid is 43 x 43 over
    ``[-1, 20]^2`` and the truth is the union of the two discs. For the ICRL tasks: the environment is the
    benchmark's (:class:`ICRLFactory`: nominal reward, ``info["cost"]`` removed), the coordinate the post-step
    ``obs[0]`` (:func:`icrl_coord`), the truth the benchmark's strict indicator (x < wall behind the start, x > wall
    in front), the CMSE grid from 0 (the start) to ``2 * wall`` (401 points, the wall in the middle), and the
    location is scanned over ``[-5 |wall|, 5 |wall|]`` (2,001 points) from the demonstrations' nearest approach
    (``scan_from="nearest"``): downward from their lowest x for a wall behind (x < -3: [-15, 15]), upward from their
    highest x for one in front.
    """
    if name in ("halfcheetah", "ant"):
        from pbicrl.envs.mujoco_wall import WALL_SPECS

        wall = WALL_SPECS[name].wall_x
        return ICLEnv(name, _WallFactory(name), _wall_coord,
                      lambda x, w=wall: (np.asarray(x, dtype=np.float64).reshape(-1) >= w).astype(float),
                      np.linspace(0.0, 2 * wall, 401)[:, None], np.linspace(-10.0, 5 * wall, 2001), float(wall))
    if name in ICRL_ICL_ENVS:
        from pbicrl.envs.icrl_benchmark import icrl_task

        task = icrl_task(ICRL_ICL_ENVS[name])
        w = float(task.wall)
        if (task.side == "behind") != (w < 0):  # the start (x = 0) must be on the allowed side
            raise ValueError(f"env: {name!r} expects its start on the allowed side, got {task.side} {w}")
        lo, hi = sorted((2 * w, 0.0))
        return ICLEnv(name, ICRLFactory(task.name), icrl_coord, _ICRLTruth(task.name),
                      np.linspace(lo, hi, 401)[:, None], np.linspace(-5 * abs(w), 5 * abs(w), 2001), w,
                      side=task.side, scan_from="nearest")
    if name == "point_mass":
        from pbicrl.envs.point_mass import HIGH, LOW, POINT_MASS_TASK

        g = np.linspace(LOW, HIGH, 43)
        grid = np.stack(np.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)

        def truth(s: NDArray) -> NDArray:
            s = np.asarray(s, dtype=np.float64).reshape(-1, 2)
            return (POINT_MASS_TASK.orange.contains(s) | POINT_MASS_TASK.red.contains(s)).astype(float)

        return ICLEnv(name, _PointMassFactory(), _obs_coord, truth, grid, None, None)
    raise ValueError(f"env: unknown ICL environment {name!r}; choose one of {ENVS}")


class _ICRLTruth:
    """The true constraint of an ICRL task on rows of coordinates (x): its strict wall indicator."""

    def __init__(self, task: str) -> None:
        self.task = task

    def __call__(self, x: Any) -> NDArray[np.float64]:
        from pbicrl.envs.icrl_benchmark import icrl_task

        return icrl_task(self.task).cost(np.asarray(x, dtype=np.float64).reshape(-1))


def point_mass_expert_demos(n: int, seed: int = 0) -> list[NDArray[np.float64]]:
    """Scripted constraint-respecting point-mass trajectories (positions after each step), for smoke runs.

    From the left edge the expert first climbs to y = 19.5 and then goes right; from the bottom edge it first
    goes right to x = 19.5 and then up: both paths stay clear of the two discs.
    """
    from pbicrl.envs.point_mass import POINT_MASS_TASK, PointMassEnv

    env = PointMassEnv(reward_weights="nominal")
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(int(n)):
        pos, edge = env.sample_start(rng)
        states = []
        for _t in range(env.max_steps):
            if edge == "left":
                a = np.array([0.0, 1.0]) if pos[1] < 19.5 else np.array([1.0, 0.0])
            else:
                a = np.array([1.0, 0.0]) if pos[0] < 19.5 else np.array([0.0, 1.0])
            pos = env.dynamics(pos, a)
            states.append(pos.copy())
            if POINT_MASS_TASK.reached(pos)[0]:
                break
        out.append(np.asarray(states))
    return out


def expert_coordinates(dataset: Any, *, group: int = 1, n: int | None = 200, seed: int = 0,
                       dims: Sequence[int] | None = None) -> list[NDArray[np.float64]]:
    """Constrained coordinates of the expert trajectories of a :class:`pbicrl.inference.data.Dataset`.

    Parameters
    ----------
    dataset : Dataset or path
    group : int
        Label of the expert group (1 = good demonstrations).
    n : int or None
        Use at most ``n`` expert trajectories (a seeded random subset if there are more); None: all.
    seed : int
        Seed of that subset.
    dims : sequence of int, optional
        Columns of ``states`` to use (default: all).
    """
    from pbicrl.inference.data import load_dataset

    ds = dataset if not isinstance(dataset, (str, os.PathLike)) else load_dataset(dataset)
    if ds.states is None:
        raise ValueError("dataset: has no states; ICL needs the constrained coordinate of each state")
    idx = np.flatnonzero(ds.group == int(group))
    if idx.size == 0:
        raise ValueError(f"dataset: no trajectories in group {group} (groups: {ds.group_counts()})")
    if n is not None and idx.size > int(n):
        idx = np.sort(np.random.default_rng(seed).choice(idx, int(n), replace=False))
    cols = slice(None) if dims is None else list(dims)
    return [np.asarray(ds.trajectory_states(int(i)), dtype=np.float64)[:, cols] for i in idx]
