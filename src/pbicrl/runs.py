"""Deprecated: run directories are read and written by :mod:`pbicrl.io.runs`.

``pbicrl.runs.load_run`` returned the checked record (:class:`~pbicrl.io.runs.RunRecord`); it is
:func:`pbicrl.io.runs.read_run` now, and ``pbicrl.io.runs.load_run`` (``pbicrl.load_run``) gives the full
:class:`~pbicrl.inference.posterior.Posterior`. ``constraint_set_of`` moved to :mod:`pbicrl.inference.constraints`.
Every old name still imports from here, with a :class:`~pbicrl.errors.PbicrlWarning`; the module goes in pbicrl 0.3.
"""

from __future__ import annotations

import importlib
from typing import Any

__all__: list[str] = []  # nothing new is defined here; the old names resolve through __getattr__

#: old name -> (module, name) that it is now
MOVED_NAMES: dict[str, tuple[str, str]] = {
    "load_run": ("pbicrl.io.runs", "read_run"),
    "RunRecord": ("pbicrl.io.runs", "RunRecord"),
    "RunError": ("pbicrl.io.runs", "RunError"),
    "SCHEMA_VERSION": ("pbicrl.io.runs", "SCHEMA_VERSION"),
    "DATASET_FILE": ("pbicrl.io.runs", "DATASET_FILE"),
    "check_run_dir": ("pbicrl.io.runs", "check_run_dir"),
    "recorded_dataset": ("pbicrl.io.runs", "recorded_dataset"),
    "constraint_set_of": ("pbicrl.inference.constraints", "constraint_set_of"),
}


def __getattr__(name: str) -> Any:
    moved = MOVED_NAMES.get(name)
    if moved is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    from pbicrl.errors import warn

    where, new = moved
    warn(f"pbicrl.runs.{name} moved to {where}.{new}; the old path is deprecated and will be removed in pbicrl 0.3",
         stacklevel=2)
    return getattr(importlib.import_module(where), new)


def __dir__() -> list[str]:
    return sorted(MOVED_NAMES)
