"""Numba's on-disk cache, invalidated when a compiled function's callees in other files change.

``@njit(cache=True)`` keys a cached function on its own source file only (its modification time and size),
while the cached machine code also holds every compiled callee and every global constant it read. After an edit
of :mod:`pbicrl.inference.likelihood_kernels` (or ``_parametric``, ``_priorkern``, ``bundles``,
:mod:`pbicrl.inference.codes`), the cached sampler loop would keep running the old callees.

:func:`flush_stale` fixes that: it hashes the source files a dispatcher depends on and keeps the hash in a stamp
file beside Numba's index of that dispatcher (``<index>.nbi.deps``); when the hash differs it empties the index
(``Cache.flush``: the next call compiles again and refills it) and writes the new stamp. It must run before the
dispatcher's first call in a process; :mod:`pbicrl.inference.samplers._mcmc` runs it at import.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path
from typing import Any, Iterable

from pbicrl._atomic import write_text

__all__ = ["source_digest", "flush_stale", "stamp_path"]


def source_digest(paths: Iterable[str | os.PathLike[str]]) -> str:
    """SHA-256 over the Numba version and the bytes of ``paths`` (sorted by path, so the order given does not
    matter)."""
    import numba

    h = hashlib.sha256(f"numba {numba.__version__}\n".encode())
    for p in sorted({os.fspath(Path(p).resolve()) for p in paths}):
        h.update(p.encode() + b"\n")
        h.update(Path(p).read_bytes())
    return h.hexdigest()


def stamp_path(dispatcher: Any) -> Path | None:
    """The stamp file of a cached dispatcher, or None when it is not cached on disk (``cache=False``)."""
    index = getattr(getattr(getattr(dispatcher, "_cache", None), "_cache_file", None), "_index_path", None)
    return None if index is None else Path(index + ".deps")


def flush_stale(dispatchers: Iterable[Any], sources: Iterable[str | os.PathLike[str]]) -> list[str]:
    """Empty the on-disk cache of each dispatcher whose ``sources`` changed since its stamp; returns the names of
    the dispatchers flushed.

    Quiet on file-system errors (a read-only installation: Numba then cannot write its cache either) and on
    Numba versions without these internals: housekeeping must never stop an import.
    """
    flushed: list[str] = []
    try:
        digest = source_digest(sources)
    except OSError:
        return flushed
    for d in dispatchers:
        stamp = stamp_path(d)
        if stamp is None:
            continue
        try:
            if stamp.is_file() and stamp.read_text() == digest:
                continue
            if Path(d._cache._cache_file._index_path).exists():
                d._cache.flush()  # an empty index with the current source stamp: every signature recompiles
                flushed.append(d.__name__)
            write_text(stamp, digest)  # atomic: a concurrent import reads the old stamp or the new one
        except (OSError, AttributeError):
            continue
    return flushed
