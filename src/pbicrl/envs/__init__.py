"""Simulation environments for pbicrl demonstrations (optional extra ``envs``).

Submodules are imported lazily so that ``import pbicrl.envs`` costs nothing and
does not require Gymnasium or MuJoCo. Attribute access (e.g.
``pbicrl.envs.make_wall_env``) imports the owning submodule on first use; a
missing optional dependency raises an :class:`ImportError` that names
``pip install "pbicrl[envs]"``.

To add an environment module, add its public names to ``_LAZY`` below
(name -> submodule); never remove other modules' entries.
"""

from __future__ import annotations

import importlib
from typing import Any

# public name -> submodule (relative to this package) that defines it
_LAZY: dict[str, str] = {
    # MuJoCo HalfCheetah / Ant with an unobserved forward wall (paper Section V-C)
    "WallSpec": "mujoco_wall",
    "WALL_SPECS": "mujoco_wall",
    "WallPenaltyWrapper": "mujoco_wall",
    "make_wall_env": "mujoco_wall",
    "rollout_wall_env": "mujoco_wall",
    # 3x3 grid, 2-D point mass and Fetch-Reach with constraint regions (paper Fig. 1, Section V-A/V-B)
    "GridEnv": "grid",
    "grid_dataset": "grid",
    "PointMassEnv": "point_mass",
    "POINT_MASS_TASK": "point_mass",
    "FetchReachConstrainedEnv": "fetch_reach",
    "FETCH_REACH_TASK": "fetch_reach",
    "NavigationTask": "regions",
    "register_envs": "registration",
    "patch_gymnasium_robotics": "_mujoco_compat",
    # a per-step cost (info["cost"]) from an inferred constraint, for constrained RL
    "InferredConstraintCost": "inferred_cost",
}

__all__ = sorted(_LAZY)


def __getattr__(name: str) -> Any:
    try:
        module_name = _LAZY[name]
    except KeyError:
        raise AttributeError(f"module 'pbicrl.envs' has no attribute {name!r}") from None
    module = importlib.import_module(f".{module_name}", __name__)
    value = getattr(module, name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))
