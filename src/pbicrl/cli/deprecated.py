"""Names of command-line code that moved into :mod:`pbicrl.cli` and stay reachable at their old module for
one release (until pbicrl 0.3), with a :class:`~pbicrl.errors.PbicrlWarning` on each use.

A module whose ``main`` or ``add_subcommands`` moved sets its module-level ``__getattr__`` (PEP 562) with
:func:`moved_to_cli`::

    __getattr__ = moved_to_cli(__name__, {"add_subcommands": "pbicrl.cli.sweep"})
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from importlib import import_module
from typing import Any

from pbicrl.errors import warn

__all__ = ["moved_to_cli"]


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
        warn(f"{module}.{name} is deprecated and will be removed in pbicrl 0.3: use {new}.{name}")
        return getattr(import_module(new), name)

    return __getattr__
