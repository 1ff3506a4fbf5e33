"""Old module paths (pbicrl 0.1) that moved into ``pbicrl.inference``, ``pbicrl.analysis`` and ``pbicrl.cli``.

Importing an old path gives the module at its new path (the same object, so ``isinstance`` and
monkeypatching keep working) with a :class:`~pbicrl.errors.PbicrlWarning`. The aliases go in pbicrl 0.3.
:func:`moved_to_cli` does the same for single names (``main``, ``add_subcommands``) whose code moved into
:mod:`pbicrl.cli`: the old module reaches the new one only when the old name is used, so no library module
imports ``pbicrl.cli``.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.machinery
import sys
import warnings
from collections.abc import Callable, Mapping
from types import ModuleType
from typing import Any

__all__ = ["MOVED", "install", "moved_to_cli"]

#: old dotted path -> new dotted path (submodules of a moved package follow it).
MOVED: dict[str, str] = {
    "pbicrl.preferences": "pbicrl.inference.preferences",
    "pbicrl.likelihood": "pbicrl.inference.likelihood",
    "pbicrl._kernels": "pbicrl.inference.likelihood_kernels",
    "pbicrl.priors": "pbicrl.inference.priors",
    "pbicrl.constraints": "pbicrl.inference.constraints",
    "pbicrl.samplers": "pbicrl.inference.samplers",
    "pbicrl.results": "pbicrl.inference.results",
    "pbicrl.draws": "pbicrl.inference.draws",
    "pbicrl.synthetic": "pbicrl.inference.synthetic",
    "pbicrl.diagnostics": "pbicrl.analysis.diagnostics",
    "pbicrl.export": "pbicrl.analysis.export",
    "pbicrl.plots": "pbicrl.analysis.plots",
    "pbicrl.calibration": "pbicrl.analysis.calibration",
    "pbicrl.margins": "pbicrl.analysis.margins",
    "pbicrl.metrics": "pbicrl.analysis.metrics",
    "pbicrl.identify": "pbicrl.analysis.identify",
    "pbicrl.suggest": "pbicrl.analysis.suggest",
    "pbicrl.check": "pbicrl.analysis.check",
    "pbicrl.cli_envs": "pbicrl.cli.envs",
    "pbicrl.cli_posterior": "pbicrl.cli.posterior",
    "pbicrl._argtypes": "pbicrl.cli.argtypes",
    "pbicrl.envs.cli": "pbicrl.cli.navigation",
    "pbicrl.demonstrators.cli": "pbicrl.cli.wall",
    "pbicrl.ui.cli": "pbicrl.cli.label",
    "pbicrl.safe_rl": "pbicrl.experiments.safe_rl",
}


def _target(name: str) -> str | None:
    if name in MOVED:
        return MOVED[name]
    head, sep, rest = name.partition(".samplers.")
    if head == "pbicrl" and sep:
        return f"pbicrl.inference.samplers.{rest}"
    return None


class _AliasLoader(importlib.abc.Loader):
    def __init__(self, old: str, new: str) -> None:
        self.old, self.new = old, new

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> ModuleType:
        from pbicrl.errors import PbicrlWarning

        warnings.warn(f"{self.old} moved to {self.new}; the old module path is deprecated and will be removed in "
                      "pbicrl 0.3", PbicrlWarning, stacklevel=2)
        return importlib.import_module(self.new)

    def exec_module(self, module: ModuleType) -> None:  # already executed under its new name
        return None


class _AliasFinder(importlib.abc.MetaPathFinder):
    def find_spec(self, fullname: str, path: object = None, target: object = None) -> importlib.machinery.ModuleSpec | None:
        new = _target(fullname)
        if new is None:
            return None
        return importlib.machinery.ModuleSpec(fullname, _AliasLoader(fullname, new))


def install() -> None:
    """Put the alias finder first on ``sys.meta_path`` (idempotent)."""
    if not any(isinstance(f, _AliasFinder) for f in sys.meta_path):
        sys.meta_path.insert(0, _AliasFinder())


# ---- names of command-line code that moved into pbicrl.cli (their old module keeps them until 0.3)
def moved_to_cli(module: str, moved: Mapping[str, str]) -> Callable[[str], Any]:
    """A module ``__getattr__`` that gives each moved name from its new module, with a deprecation warning.

    Parameters
    ----------
    module : str
        The old module's ``__name__`` (named in the warning and in ``AttributeError`` for any other name).
    moved : mapping of str to str
        Moved name -> dotted path of the module that holds it now, imported only when the name is used.

    Returns
    -------
    callable
        ``__getattr__(name)``: the moved object, or ``AttributeError`` as Python's own for any other name.
    """
    table = dict(moved)

    def __getattr__(name: str) -> Any:
        new = table.get(name)
        if new is None:
            raise AttributeError(f"module {module!r} has no attribute {name!r}")
        # warned from here, one frame below the caller, as the hand-written shims were
        from pbicrl.errors import warn

        warn(f"{module}.{name} is deprecated and will be removed in pbicrl 0.3: use {new}.{name}")
        return getattr(importlib.import_module(new), name)

    return __getattr__
