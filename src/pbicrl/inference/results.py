"""Deprecated: what this module held now lives where it belongs (ArviZ's split of data, statistics and files).

* the posterior and its summaries: :mod:`pbicrl.inference.posterior` (:class:`~pbicrl.inference.posterior.Posterior`),
  :mod:`pbicrl.inference.summary` (``summary.json``, :func:`~pbicrl.inference.summary.json_safe`),
  :mod:`pbicrl.inference.draws` (:func:`~pbicrl.inference.draws.split_rhat`);
* run directories: :mod:`pbicrl.io.runs` (``load_run``, ``save_run``, ``write_run_dir``, ``check_out_dir``,
  ``claim_out_dir``, ``release_out_dir``, ``is_run_dir``);
* the table, HTML and data frame: :mod:`pbicrl.analysis.report`.

Every old name still imports from here, with a :class:`~pbicrl.errors.PbicrlWarning`; the aliases go in pbicrl 0.3.
"""

from __future__ import annotations

import importlib
from typing import Any

__all__: list[str] = []  # nothing new is defined here; the old names resolve through __getattr__

#: old name -> module that defines it now
MOVED_NAMES: dict[str, str] = {
    "Posterior": "pbicrl.inference.posterior",
    "AUTHORS_LAST_ITERATIONS": "pbicrl.inference.posterior",
    "DrawsView": "pbicrl.inference.draws",
    "ESTIMATORS": "pbicrl.inference.draws",
    "SELECTION_THRESHOLD": "pbicrl.inference.draws",
    "split_rhat": "pbicrl.inference.draws",
    "SCHEMA_VERSION": "pbicrl.inference.summary",
    "MAP_DEFINITION": "pbicrl.inference.summary",
    "json_safe": "pbicrl.inference.summary",
    "write_run_dir": "pbicrl.io.outdir",
    "check_out_dir": "pbicrl.io.outdir",
    "claim_out_dir": "pbicrl.io.outdir",
    "release_out_dir": "pbicrl.io.outdir",
    "is_run_dir": "pbicrl.io.outdir",
    "OutputExistsError": "pbicrl._atomic",
    "OutputBusyError": "pbicrl._atomic",
}


def __getattr__(name: str) -> Any:
    where = MOVED_NAMES.get(name)
    if where is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    from pbicrl.errors import warn

    warn(f"pbicrl.inference.results.{name} moved to {where}.{name}; the old path is deprecated and will be removed "
         "in pbicrl 0.3", stacklevel=2)
    return getattr(importlib.import_module(where), name)


def __dir__() -> list[str]:
    return sorted(MOVED_NAMES)
