"""The environments ICL runs on (:class:`ICLEnv`: factory with the nominal reward, constrained coordinate, true
constraint for evaluation) and the expert demonstrations it learns from."""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from pbicrl.baselines.icl.presets import ENVS

__all__ = ["ICLEnv", "icl_env", "point_mass_expert_demos", "expert_coordinates"]


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
    """

    name: str
    make: Callable[[], Any]
    coord: Callable[[Any, dict], NDArray]
    true_indicator: Callable[[NDArray], NDArray]
    grid: NDArray[np.float64]
    location_grid: NDArray[np.float64] | None
    true_location: float | None


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


def _wall_coord(obs: Any, info: dict) -> NDArray[np.float64]:
    return np.array([float(info["x_position"])])


def _obs_coord(obs: Any, info: dict) -> NDArray[np.float64]:
    return np.asarray(obs, dtype=np.float64).reshape(-1)[:2]


def icl_env(name: str) -> ICLEnv:
    """The :class:`ICLEnv` of ``"halfcheetah"``, ``"ant"`` (walls at x = 8 and 10) or ``"point_mass"``.

    The CMSE grid spans ``[0, 2 * wall]`` on x (so that an all-0 or all-1 constraint scores 0.5), 401 points;
    the location is scanned up to ``5 * wall`` (from the lowest expert x, see :func:`run_icl`). For the point mass the grid is 43 x 43 over
    ``[-1, 20]^2`` and the truth is the union of the two discs.
    """
    if name in ("halfcheetah", "ant"):
        from pbicrl.envs.mujoco_wall import WALL_SPECS

        wall = WALL_SPECS[name].wall_x
        return ICLEnv(name, _WallFactory(name), _wall_coord,
                      lambda x, w=wall: (np.asarray(x, dtype=np.float64).reshape(-1) >= w).astype(float),
                      np.linspace(0.0, 2 * wall, 401)[:, None], np.linspace(-10.0, 5 * wall, 2001), float(wall))
    if name == "point_mass":
        from pbicrl.envs.point_mass import HIGH, LOW, POINT_MASS_TASK

        g = np.linspace(LOW, HIGH, 43)
        grid = np.stack(np.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)

        def truth(s: NDArray) -> NDArray:
            s = np.asarray(s, dtype=np.float64).reshape(-1, 2)
            return (POINT_MASS_TASK.orange.contains(s) | POINT_MASS_TASK.red.contains(s)).astype(float)

        return ICLEnv(name, _PointMassFactory(), _obs_coord, truth, grid, None, None)
    raise ValueError(f"env: unknown ICL environment {name!r}; choose one of {ENVS}")


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
