"""Warning and error classes shared by the whole library.

Every warning pbicrl prints is also issued through Python's :mod:`warnings` module with category
:class:`PbicrlWarning`, so API users can filter or catch them::

    import warnings, pbicrl
    with warnings.catch_warnings():
        warnings.simplefilter("error", pbicrl.PbicrlWarning)
        post = pbicrl.infer(ds)
"""

from __future__ import annotations

import warnings

__all__ = ["PbicrlWarning", "DemonstrationError", "warn"]


class PbicrlWarning(UserWarning):
    """A statement about the data or the posterior that a user should read (identifiability, mixing, ...)."""


def warn(message: str, *, stacklevel: int = 2) -> None:
    """Issue ``message`` as a :class:`PbicrlWarning` (attributed to the caller's caller by default)."""
    warnings.warn(message, PbicrlWarning, stacklevel=stacklevel + 1)


class DemonstrationError(RuntimeError, ValueError):
    """The policies given to a demonstration generator did not produce the behaviour a group needs within its
    attempt limit (the message has the counts). A ``RuntimeError`` as before, and a ``ValueError`` so the command
    line reports it as a one-line error about its input (the policies), not a traceback."""
