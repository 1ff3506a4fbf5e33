"""SAC demonstrators (optional extra ``rl``).

Lazy: ``import pbicrl.demonstrators`` does not import torch or Stable-Baselines3.
``train_sac`` / ``load_policy`` live in :mod:`pbicrl.demonstrators.sac`; the
HalfCheetah/Ant wall demonstrators in :mod:`pbicrl.demonstrators.wall`; the
command-line entry (``python -m pbicrl.demonstrators``) in
:mod:`pbicrl.cli.wall`.
"""

from __future__ import annotations

import importlib
from typing import Any

_LAZY: dict[str, str] = {
    "train_sac": "sac",
    "load_policy": "sac",
    "require_rl": "sac",
    "train_wall_policy": "wall",
    "generate_wall_demos": "wall",
    "plot_wall_visitation": "wall",
}

__all__ = ["generate_wall_demos", "load_policy", "plot_wall_visitation", "require_rl", "train_sac",
           "train_wall_policy"]


def __getattr__(name: str) -> Any:
    try:
        module_name = _LAZY[name]
    except KeyError:
        raise AttributeError(f"module 'pbicrl.demonstrators' has no attribute {name!r}") from None
    value = getattr(importlib.import_module(f".{module_name}", __name__), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))
