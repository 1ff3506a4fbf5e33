"""The datasets and policies shipped with pbicrl (package data; ``importlib.resources.files("pbicrl.data")``).

Read them by name with :func:`pbicrl.load_dataset` (``pbicrl.load_dataset("point_mass")``);
:func:`pbicrl.inference.data.shipped_dir` is this folder and :func:`pbicrl.list_shipped_datasets` lists it.

In pbicrl 0.1 ``pbicrl.data`` was the dataset module, now :mod:`pbicrl.inference.data`: its names still resolve
here (the same objects) with a :class:`~pbicrl.errors.PbicrlWarning` until pbicrl 0.3, so ``pbicrl.data`` has
one meaning, this folder, with no module hiding it.
"""

from __future__ import annotations

from typing import Any

__all__: list[str] = []  # package data only; the 0.1 names resolve through __getattr__


def __getattr__(name: str) -> Any:
    if name.startswith("__"):
        raise AttributeError(name)
    from pbicrl.inference import data

    if not hasattr(data, name):
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    from pbicrl.errors import warn

    warn(f"pbicrl.data.{name}: the dataset module moved to pbicrl.inference.data ({name} is "
         f"pbicrl.inference.data.{name}); pbicrl.data is the folder of shipped datasets, and the old names there "
         "are deprecated and will be removed in pbicrl 0.3", stacklevel=2)
    return getattr(data, name)
