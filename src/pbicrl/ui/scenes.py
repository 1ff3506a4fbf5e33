"""What the labelling page draws for each demonstration, as JSON-ready dicts.

A *scene* says how to draw a dataset's trajectories, from its ``env_id`` (or, for shipped datasets, their
name) and its ``states``:

``navigation``
    Top-down path over the environment's regions (point mass; Fetch-Reach projected on its x-y plane).
    Region geometry comes from the tasks of :mod:`pbicrl.envs` (``pbicrl.envs.regions``).
``grid``
    The 3x3 grid of paper Fig. 1 (``pbicrl.envs.grid``), states ``(row, col)``.
``wall``
    Forward position x(t) against the wall (HalfCheetah, Ant; ``pbicrl.envs.mujoco_wall``).
``path2d``
    Unknown environment with at least two state columns: the path in the first two.
``features``
    Anything else: every feature over time, one strip per feature.

The environment modules need Gymnasium (the ``envs`` extra); without it the regions or the wall are left
out and the scene says why (``note``).
"""

from __future__ import annotations

import re
from typing import Any

import numpy as np
from numpy.typing import NDArray

from pbicrl.analysis import style as _style
from pbicrl.inference.data import Dataset

__all__ = ["KNOWN_ENVS", "normalise_env_id", "scene_for", "trajectory_payload", "thumbnail_payload",
           "MAX_THUMBNAIL_POINTS"]

KNOWN_ENVS = ("point_mass", "fetch_reach", "grid", "halfcheetah", "ant")
MAX_THUMBNAIL_POINTS = 80
"""Points per trajectory in the list's small pictures (the detail view gets every state)."""

_COLOURS = _style.REGION_COLOURS  # the figures' colours (pbicrl.analysis.style), so page and figures agree
_ALIASES = {"pointmass": "point_mass", "fetchreach": "fetch_reach", "fetchreachconstrained": "fetch_reach",
            "grid": "grid", "grid3x3": "grid", "halfcheetah": "halfcheetah", "ant": "ant"}


def normalise_env_id(env_id: str | None) -> str | None:
    """A known environment name for ``env_id`` (``"pbicrl/PointMass-v0"`` -> ``"point_mass"``), else ``None``."""
    if not env_id:
        return None
    text = env_id.strip().lower()
    text = text.split("/")[-1]
    text = re.sub(r"-v\d+$", "", text)
    key = re.sub(r"[^a-z0-9]", "", text)
    return _ALIASES.get(key)


def _region_json(name: str, region: Any, axes: tuple[int, int]) -> dict[str, Any]:
    """A Disc or Box projected on ``axes`` (a ball stays a disc of the same radius: its widest section)."""
    if hasattr(region, "radius"):
        c = region.centre
        return {"name": name, "shape": "disc", "centre": [float(c[axes[0]]), float(c[axes[1]])],
                "radius": float(region.radius), "color": _COLOURS.get(name, "#888")}
    lo, hi = region.low, region.high
    return {"name": name, "shape": "box", "low": [float(lo[axes[0]]), float(lo[axes[1]])],
            "high": [float(hi[axes[0]]), float(hi[axes[1]])], "color": _COLOURS.get(name, "#888")}


def _extent(states: NDArray[np.float64], axes: tuple[int, int]) -> list[float]:
    xy = states[:, list(axes)]
    return [float(xy[:, 0].min()), float(xy[:, 0].max()), float(xy[:, 1].min()), float(xy[:, 1].max())]


def _union(a: list[float], regions: list[dict[str, Any]]) -> list[float]:
    x0, x1, y0, y1 = a
    for r in regions:
        if r["shape"] == "disc":
            (cx, cy), rad = r["centre"], r["radius"]
            x0, x1, y0, y1 = min(x0, cx - rad), max(x1, cx + rad), min(y0, cy - rad), max(y1, cy + rad)
        else:
            x0, x1 = min(x0, r["low"][0]), max(x1, r["high"][0])
            y0, y1 = min(y0, r["low"][1]), max(y1, r["high"][1])
    pad = 0.04 * max(x1 - x0, y1 - y0, 1e-9)
    return [x0 - pad, x1 + pad, y0 - pad, y1 + pad]


def _navigation(dataset: Dataset, env: str) -> dict[str, Any]:
    axes = (0, 1)
    note = None
    regions: list[dict[str, Any]] = []
    try:
        if env == "point_mass":
            from pbicrl.envs.point_mass import POINT_MASS_TASK as task
        else:
            from pbicrl.envs.fetch_reach import FETCH_REACH_TASK as task
        regions = [_region_json(n, getattr(task, n), axes) for n in ("orange", "red", "goal")]
    except ImportError as exc:
        note = f"regions not drawn: {exc}"
    assert dataset.states is not None
    return {"kind": "navigation", "env_id": env, "axes": list(axes),
            "axis_labels": ["x", "y"], "projection": "top-down (x, y)" if dataset.states.shape[1] > 2 else None,
            "regions": regions, "bounds": _union(_extent(dataset.states, axes), regions), "note": note}


def _grid() -> dict[str, Any]:
    from pbicrl.envs.grid import GRID_COLOURS, GRID_GOAL, GRID_START

    cells = [[{"color": _COLOURS.get(c, "#888"), "name": c} for c in row] for row in GRID_COLOURS]
    return {"kind": "grid", "env_id": "grid", "rows": len(GRID_COLOURS), "cols": len(GRID_COLOURS[0]),
            "cells": cells, "start": list(GRID_START), "goal": list(GRID_GOAL), "note": None}


def _wall(dataset: Dataset, env: str) -> dict[str, Any]:
    assert dataset.states is not None
    wall, note = None, None
    try:
        from pbicrl.envs.mujoco_wall import WALL_SPECS

        wall = float(WALL_SPECS[env].wall_x)
    except ImportError as exc:
        note = f"wall not drawn: {exc}"
    x = dataset.states[:, 0]
    hi = max(float(x.max()), wall if wall is not None else -np.inf)
    lo = min(float(x.min()), 0.0)
    return {"kind": "wall", "env_id": env, "wall_x": wall, "x_range": [lo, hi + 0.04 * (hi - lo + 1e-9)],
            "max_length": int(dataset.lengths.max()), "note": note}


def _features(dataset: Dataset, note: str | None = None) -> dict[str, Any]:
    lo = dataset.features.min(axis=0)
    hi = dataset.features.max(axis=0)
    return {"kind": "features", "env_id": dataset.env_id, "feature_names": list(dataset.feature_names),
            "ranges": [[float(a), float(b)] for a, b in zip(lo, hi)], "max_length": int(dataset.lengths.max()),
            "note": note}


def scene_for(dataset: Dataset, env_id: str | None = None) -> dict[str, Any]:
    """How to draw ``dataset`` (module docstring); ``env_id`` overrides the dataset's."""
    raw = env_id if env_id is not None else dataset.env_id
    env = normalise_env_id(raw)
    states = dataset.states
    k = 0 if states is None else states.shape[1]
    if env in ("point_mass", "fetch_reach") and k >= 2:
        return _navigation(dataset, env)
    if env == "grid" and k == 2:
        return _grid()
    if env in ("halfcheetah", "ant") and k >= 1:
        return _wall(dataset, env)
    note = None
    if not raw:
        # say so, and how to fix it: a pool made without its environment is drawn without goal or regions
        note = ("no environment recorded (env_id), so no goal or regions are drawn: start with --env ENV "
                f"({', '.join(KNOWN_ENVS)}), or make the pool with 'pbicrl pool DATA --n 40 --out pool.npz', which "
                "keeps the data's env_id")
    elif raw and env is None:
        note = f"environment {raw!r} is not one pbicrl knows how to draw ({', '.join(KNOWN_ENVS)})"
    elif env is not None:
        note = f"the states ({k} columns) do not fit the {env} picture"
    if k >= 2 and env is None:
        sc = {"kind": "path2d", "env_id": raw, "axes": [0, 1], "axis_labels": ["state 0", "state 1"],
              "regions": [], "bounds": _union(_extent(states, (0, 1)), []), "note": note}  # type: ignore[arg-type]
        return sc
    return _features(dataset, note)


def _series(dataset: Dataset, scene: dict[str, Any], i: int) -> list[list[float]]:
    """The numbers the scene draws for trajectory ``i``, one row per time step."""
    kind = scene["kind"]
    if kind in ("navigation", "path2d"):
        return dataset.trajectory_states(i)[:, :2].tolist()
    if kind == "grid":
        return dataset.trajectory_states(i)[:, :2].tolist()
    if kind == "wall":
        return dataset.trajectory_states(i)[:, :1].tolist()
    return dataset.trajectory(i).tolist()


def trajectory_payload(dataset: Dataset, scene: dict[str, Any], i: int) -> dict[str, Any]:
    """Everything the detail view needs for trajectory ``i``: its series, features and length."""
    return {"id": int(i), "length": int(dataset.lengths[i]), "series": _series(dataset, scene, i),
            "features": dataset.trajectory(i).tolist(), "feature_names": list(dataset.feature_names),
            "mean_features": dataset.mean_features[i].tolist()}


def thumbnail_payload(dataset: Dataset, scene: dict[str, Any]) -> list[list[list[float]]]:
    """Per trajectory, its series thinned to at most :data:`MAX_THUMBNAIL_POINTS` time steps (ends kept)."""
    out = []
    for i in range(dataset.n_trajectories):
        s = _series(dataset, scene, i)
        if len(s) > MAX_THUMBNAIL_POINTS:
            keep = np.unique(np.linspace(0, len(s) - 1, MAX_THUMBNAIL_POINTS).round().astype(int))
            s = [s[j] for j in keep]
        out.append(s)
    return out
