"""Output directories of runs: claimed while written, written atomically, replaced only when they hold a run.

:func:`write_run_dir` creates a run directory in one atomic rename (a failed or interrupted write leaves no
directory behind); :func:`check_out_dir` fails early, before sampling, where it could not; a directory being
written is claimed (an advisory lock ``.<name>.lock`` beside it, :func:`claim_out_dir`), so two processes
writing the same directory cannot interleave: the second gets :class:`~pbicrl._atomic.OutputBusyError`.
Directories and files get the permissions the process's umask gives new files.
"""

from __future__ import annotations

import json
import os
import socket
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from pbicrl._atomic import (OUTPUT_MARKER, OutputBusyError, OutputExistsError, atomic_dir, check_replaceable,
                            clean_stale_temporaries, inputs_inside)
from pbicrl.inference.summary import json_safe

__all__ = ["write_run_dir", "check_out_dir", "claim_out_dir", "release_out_dir", "is_run_dir", "OutputExistsError",
           "OutputBusyError"]


def is_run_dir(path: str | os.PathLike[str]) -> bool:
    """True for a directory written by :func:`write_run_dir` (it holds ``summary.json``), empty or not."""
    p = Path(path)
    return p.is_dir() and not p.is_symlink() and (p / "summary.json").is_file()


def _check_writable(parent: Path) -> None:
    if parent.exists() and not os.access(parent, os.W_OK | os.X_OK):
        raise PermissionError(f"out_dir: cannot write into {parent} (permission denied)")


# Run directories claimed by this process: absolute path -> (descriptor of the locked file, its path).
_CLAIMS: dict[str, tuple[int, str]] = {}


def _lock_file(out: Path) -> Path:
    return out.parent / f".{out.name}.lock"


def claim_out_dir(out_dir: str | os.PathLike[str]) -> Path:
    """Claim ``out_dir`` for this process until :func:`release_out_dir` or the end of the process.

    The claim is an advisory lock (``flock``) on ``.<name>.lock`` beside ``out_dir`` (its parent directory is
    created if missing); the operating system drops it when the process ends, however it ends, so a killed
    writer never blocks later runs (the lock file it leaves is reused). :func:`write_run_dir` claims the
    directory while it writes; a command claims it before sampling (:func:`check_out_dir` with ``claim=True``)
    so that a second run writing to the same directory fails at once instead of after its sampling.
    Claiming again from the same process is a no-op. Where the platform or file system has no ``flock`` the
    claim is skipped (the writes stay atomic).

    Raises
    ------
    OutputBusyError
        Another process holds the claim; the message names it (host and process id).
    """
    out = Path(out_dir)
    key = os.path.abspath(out)
    if key in _CLAIMS:
        return out
    try:
        import fcntl
    except ImportError:  # pragma: no cover - not on POSIX
        return out
    out.parent.mkdir(parents=True, exist_ok=True)
    lock = _lock_file(out)
    for _ in range(20):
        fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o666)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 200, 0).decode("utf-8", "replace").strip() or "unknown"
            os.close(fd)
            raise OutputBusyError(f"out_dir: {out} is being written by another pbicrl process ({holder}); wait for it "
                                  "to finish or choose another directory") from None
        except OSError:  # no locks on this file system
            os.close(fd)
            return out
        # the previous holder may have removed the file between our open and flock: then retry on the new one
        try:
            current = os.stat(lock)
        except FileNotFoundError:
            current = None
        if current is not None and os.path.samestat(os.fstat(fd), current):
            os.ftruncate(fd, 0)
            os.pwrite(fd, f"host {socket.gethostname()}, pid {os.getpid()}\n".encode(), 0)
            _CLAIMS[key] = (fd, str(lock))
            return out
        os.close(fd)
    raise OutputBusyError(f"out_dir: {out}: could not claim it (its lock file keeps changing); try again")


def release_out_dir(out_dir: str | os.PathLike[str] | None = None) -> None:
    """End this process's claim on ``out_dir`` (``None``: on every directory it claimed); removes the lock file."""
    keys = list(_CLAIMS) if out_dir is None else [os.path.abspath(Path(out_dir))]
    for key in keys:
        held = _CLAIMS.pop(key, None)
        if held is None:
            continue
        fd, lock = held
        try:
            os.unlink(lock)  # while still locked, so nobody locks the file we remove
        except OSError:
            pass
        os.close(fd)


def check_out_dir(out_dir: str | os.PathLike[str], *, overwrite: bool = False, claim: bool = False,
                  inputs: Sequence[Any] = ()) -> Path:
    """Fail early (before sampling) when ``out_dir`` could not be written by :func:`write_run_dir`.

    Parameters
    ----------
    out_dir : path
    overwrite : bool
        Whether a previous run directory there may be replaced.
    claim : bool
        Also claim the directory for this process (:func:`claim_out_dir`) until :func:`write_run_dir` has
        written it (or :func:`release_out_dir`), so that a concurrent run to the same directory fails now.
    inputs : sequence of path
        The command's inputs (dataset, config): none may be ``out_dir`` or lie inside it.

    Raises
    ------
    OutputExistsError
        ``out_dir`` exists and ``overwrite`` is false.
    FileExistsError
        ``out_dir`` is a file, a symbolic link or a directory that is not a run, or names no directory.
    OutputBusyError
        Another process claims ``out_dir`` (``claim=True``).
    PermissionError
        Its parent directory is not writable.
    """
    out = Path(out_dir)
    if out.name in ("", ".", ".."):
        raise FileExistsError(f"out_dir: {out_dir!s} names no new directory; give a directory name such as runs/pm")
    if len(os.fsencode(out.name)) > 200:
        raise ValueError(f"out_dir: the directory name is {len(os.fsencode(out.name))} bytes long; at most 200")
    if out.is_symlink():
        raise FileExistsError(f"out_dir: {out} is a symbolic link; give a real directory path")
    parent = out.parent
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    if parent.exists() and not parent.is_dir():
        raise FileExistsError(f"out_dir: {parent} is a file, not a directory")
    _check_writable(parent)
    inside = inputs_inside(out, inputs)
    if inside:
        raise FileExistsError(f"out_dir: {out} holds this command's input {inside[0]}; choose another directory")
    if claim:
        claim_out_dir(out)
    try:
        _check_existing(out, overwrite, inputs)
    except BaseException:
        if claim:
            release_out_dir(out)
        raise
    return out


#: What a run directory written before markers (:data:`pbicrl._atomic.OUTPUT_MARKER`) may hold: the files
#: ``write_run_dir`` wrote, and what the labelling page added (its dataset and figures).
_LEGACY_RUN_ENTRIES = frozenset({"summary.json", "chains.npz", "check.json", "tuning.json", "data.npz", "plots"})
_FIGURE_SUFFIXES = (".png", ".pdf", ".svg")


def _legacy_run_entries(out: Path) -> set[str] | None:
    if not is_run_dir(out):
        return None
    plots = out / "plots"
    if plots.is_dir() and not plots.is_symlink() and not all(
            p.is_file() and p.suffix in _FIGURE_SUFFIXES for p in plots.iterdir()):
        return set(_LEGACY_RUN_ENTRIES - {"plots"})  # plots/ holds something else: not ours to remove
    return set(_LEGACY_RUN_ENTRIES)


def _check_existing(out: Path, overwrite: bool, inputs: Sequence[Any] = ()) -> None:
    if out.exists() and not (out.is_dir() and not any(out.iterdir())):
        if not overwrite:
            raise OutputExistsError("out_dir", out)
        # overwrite replaces a run directory pbicrl wrote and nothing else: never a data file, an unrelated
        # directory, a file pbicrl did not put there, or the command's own input
        check_replaceable(out, "run", field="out_dir", inputs=inputs, legacy=_legacy_run_entries)
    elif inputs_inside(out, inputs):
        raise FileExistsError(f"out_dir: {out} holds this command's input {inputs_inside(out, inputs)[0]}; "
                              "choose another directory")


def write_run_dir(out_dir: str | os.PathLike[str], json_files: dict[str, Any], npz_files: dict[str, dict[str, Any]],
                  *, overwrite: bool = False, inputs: Sequence[Any] = ()) -> Path:
    """Create ``out_dir`` with the given files in one atomic rename (no half-written directory).

    JSON content goes through :func:`json_safe` (non-finite numbers become ``null``) and is written with
    ``allow_nan=False``, so every file is valid JSON. The directory is claimed while it is written
    (:func:`claim_out_dir`; a claim this process took before, e.g. by :func:`check_out_dir`, ends here) and
    gets the permissions of the process's umask, as a plain ``mkdir`` would. A marker
    (:data:`pbicrl._atomic.OUTPUT_MARKER`) records the directory as a run and the files in it, so that a later
    ``overwrite`` replaces it only while it holds nothing else, and never while it holds one of ``inputs``.

    Raises
    ------
    OutputExistsError
        ``out_dir`` exists and ``overwrite`` is false.
    OutputBusyError
        Another process is writing ``out_dir``.
    FileExistsError
        ``out_dir`` is a symbolic link, a file or a directory that is not a run (``overwrite`` or not).
    """
    out = Path(out_dir)
    if out.is_symlink():
        raise FileExistsError(f"out_dir: {out} is a symbolic link; give a real directory path")
    texts = {name: json.dumps(json_safe(content), indent=2, allow_nan=False) + "\n"
             for name, content in json_files.items()}  # before creating anything: a TypeError leaves no trace
    parent = out.parent
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    _check_writable(parent)
    out.parent.mkdir(parents=True, exist_ok=True)
    claim_out_dir(out)
    try:
        clean_stale_temporaries(out)
        if out.is_symlink():
            raise FileExistsError(f"out_dir: {out} is a symbolic link; give a real directory path")
        _check_existing(out, overwrite, inputs)
        if out.is_dir() and not any(out.iterdir()):
            out.rmdir()
        with atomic_dir(out, replace=True) as tmp:
            for name, text in texts.items():
                (tmp / name).write_text(text)
            for name, arrays in npz_files.items():
                np.savez_compressed(tmp / name, **arrays)
            (tmp / OUTPUT_MARKER).write_text(json.dumps({"kind": "run", "entries": sorted([*texts, *npz_files])}) + "\n")
    finally:
        release_out_dir(out)
    return out
