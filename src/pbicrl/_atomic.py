"""Atomic files and directories: one way to write output that is either complete or absent.

Every writer works in a temporary beside its target, named by :func:`temporary_prefix`
(``.<name>.tmp-<host>.<pid>.<random>``), flushes it to disk (``fsync``), gives it the permissions a plain
``open``/``mkdir`` would under the process's umask (``0o666``/``0o777`` less :func:`umask`; ``mkstemp`` and
``mkdtemp`` create ``0o600``/``0o700``), and renames it into place with :func:`os.replace`, then syncs the
parent directory so that the rename survives a crash. A writer killed half-way leaves a temporary whose
process is gone; :func:`clean_stale_temporaries` removes those (and puts back a previous content a replace
moved aside).

:func:`read_json` and :func:`read_toml` are the matching readers of a small input document (a truth file, a
``--groups`` mapping, a sweep or config file): one set of checks and messages for every caller.

This module uses the standard library only, so that every other module can import it at module level.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import socket
import tempfile
import time
import tomllib
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import IO, Any

__all__ = [
    "FILE_MODE", "DIR_MODE", "OutputExistsError", "OutputBusyError", "umask", "host_tag", "pid_alive",
    "temporary_prefix", "clean_stale_temporaries", "atomic_path", "atomic_file", "write_bytes", "write_text",
    "write_json", "copy_file", "atomic_dir", "fsync_tree", "apply_mode", "OUTPUT_MARKER", "mark_output",
    "read_marker", "inputs_inside", "check_replaceable", "check_file_output", "read_json", "read_toml",
]

FILE_MODE = 0o666
"""Permissions of a new file before the umask (what ``open(..., "w")`` asks for)."""
DIR_MODE = 0o777
"""Permissions of a new directory before the umask (what ``mkdir`` asks for)."""


class OutputExistsError(FileExistsError):
    """An output exists and may not be replaced without ``overwrite=True``.

    The message is worded for Python callers; a command line rewords it for its own flag from the attributes.

    Attributes
    ----------
    field : str
        The argument that names the output (``"out"``, ``"path"``).
    path : Path
    kind : str
        ``"directory"`` or ``"file"``.
    """

    def __init__(self, field: str, path: str | os.PathLike[str], kind: str = "directory") -> None:
        self.field, self.path, self.kind = field, Path(path), kind
        super().__init__(f"{field}: {self.path} already exists; choose another {kind} or pass overwrite=True")


class OutputBusyError(FileExistsError):
    """Another process is writing the same output (it holds the output's claim)."""


# ---------------------------------------------------------------------------------------------- process facts
def umask() -> int:
    """The process's file-creation mask, read without changing it where the platform allows.

    On Linux it is read from ``/proc/self/status`` (setting and restoring it, the portable way, is not
    thread-safe: another thread creating a file in between would get mask 0).
    """
    try:
        with open("/proc/self/status", encoding="ascii", errors="replace") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    mask = os.umask(0)
    os.umask(mask)
    return mask


def apply_mode(path: str | os.PathLike[str], *, directory: bool = False) -> None:
    """Give ``path`` the permissions a new file (or directory) gets under the umask."""
    os.chmod(path, (DIR_MODE if directory else FILE_MODE) & ~umask())


def host_tag() -> str:
    """This machine's name as it appears in temporary names (letters, digits, ``-`` and ``_``)."""
    name = "".join(ch if ch.isalnum() or ch in "-_" else "_" for ch in socket.gethostname())
    return name[:40] or "host"


def pid_alive(pid: int) -> bool:
    """Whether process ``pid`` of this host is running (a zombie counts as dead)."""
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # PermissionError included: it exists, owned by someone else
        return True
    try:  # a killed process stays a zombie until its new parent reaps it
        text = Path(f"/proc/{pid}/stat").read_text()
        return text[text.rindex(")") + 2] not in "ZX"
    except (OSError, ValueError, IndexError):
        return True


def temporary_prefix(target: str | os.PathLike[str], kind: str = "tmp") -> str:
    """Name prefix of a temporary for ``target``: ``.<name>.<kind>-<host>.<pid>.``.

    ``kind`` is ``"tmp"`` (the new content, before its rename) or ``"old"`` (the previous content, moved
    aside while the new one takes its place). :func:`clean_stale_temporaries` recognises these names.
    """
    if kind not in ("tmp", "old"):
        raise ValueError(f"kind: expected 'tmp' or 'old', got {kind!r}")
    return f".{Path(target).name}.{kind}-{host_tag()}.{os.getpid()}."


def clean_stale_temporaries(target: str | os.PathLike[str], *, legacy_age_s: float = 3600.0) -> list[Path]:
    """Remove the temporaries that killed writers left beside ``target``; returns what was removed.

    Temporaries named by :func:`temporary_prefix` are stale when their process (on this host) is gone;
    older names without a process id are stale after ``legacy_age_s`` seconds. Temporaries of running
    writers and of other hosts are kept. If ``target`` is missing but a stale ``.old-*`` still holds the
    previous content (the writer died between its two renames), that content is put back: a killed write
    never loses the earlier results.
    """
    target = Path(target)
    parent = target.parent if str(target.parent) else Path(".")
    prefix = f".{target.name}."
    try:
        names = sorted(e.name for e in os.scandir(parent) if e.name.startswith(prefix))
    except OSError:
        return []
    host, now = host_tag(), time.time()
    stale: list[tuple[str, Path]] = []
    for name in names:
        kind, sep, rest = name[len(prefix):].partition("-")
        if not sep or kind not in ("tmp", "old"):
            continue
        path = parent / name
        parts = rest.split(".")
        if len(parts) >= 3 and parts[1].isdigit():  # .<name>.<kind>-<host>.<pid>.<random>
            if parts[0] != host or pid_alive(int(parts[1])):
                continue
        else:  # written before temporaries carried their process id: only age tells
            try:
                if now - path.lstat().st_mtime < legacy_age_s:
                    continue
            except OSError:
                continue
        stale.append((kind, path))
    removed: list[Path] = []
    for kind, path in sorted(stale, key=lambda kp: kp[0] != "old"):  # restore before deleting anything
        if kind == "old" and not (target.exists() or target.is_symlink()):
            inner = path / "old" if path.is_dir() and (path / "old").exists() else None
            if inner is not None:
                try:
                    os.replace(inner, target)
                except OSError:
                    continue  # could not restore: keep the copy rather than delete it
        try:
            if path.is_dir() and not path.is_symlink():
                shutil.rmtree(path)
            else:
                path.unlink()
        except FileNotFoundError:
            pass
        except OSError:
            continue
        removed.append(path)
    return removed


# ---------------------------------------------------------------------------------------------- files
def _fsync_dir(directory: Path) -> None:
    """Make a rename in ``directory`` durable (a no-op where directories cannot be opened)."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _fsync_file(path: Path) -> None:
    with open(path, "rb") as fh:
        os.fsync(fh.fileno())


def _place(tmp: Path, path: Path, *, overwrite: bool, field: str) -> None:
    """Rename the finished temporary onto ``path`` (refusing an existing one unless ``overwrite``)."""
    if overwrite:
        os.replace(tmp, path)
        return
    try:
        os.link(tmp, path)  # fails if path exists, even if it appeared a moment ago
    except FileExistsError:
        raise OutputExistsError(field, path, "file") from None
    except OSError:  # no hard links on this file system: check, then rename
        if path.exists():
            raise OutputExistsError(field, path, "file") from None
        os.replace(tmp, path)


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike[str], *, overwrite: bool = True, field: str = "path") -> Iterator[Path]:
    """A temporary path (same suffix as ``path``) to write; renamed onto ``path`` if the block succeeds.

    For writers that take a file name (``fig.savefig``, ``np.savez``, ``torch.save``). The parent directory
    is created. On an exception the temporary is removed and ``path`` is untouched.

    Raises
    ------
    OutputExistsError
        ``path`` exists and ``overwrite`` is false (``field`` names the argument in the message).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, name = tempfile.mkstemp(prefix=temporary_prefix(path), suffix=path.suffix, dir=path.parent)
    os.close(fd)
    tmp = Path(name)
    try:
        yield tmp
        _fsync_file(tmp)
        apply_mode(tmp)
        _place(tmp, path, overwrite=overwrite, field=field)
        _fsync_dir(path.parent)
    finally:
        tmp.unlink(missing_ok=True)


@contextlib.contextmanager
def atomic_file(path: str | os.PathLike[str], mode: str = "w", *, overwrite: bool = True, field: str = "path",
                encoding: str | None = "utf-8") -> Iterator[IO[Any]]:
    """An open temporary file (``mode`` ``"w"`` or ``"wb"``) that becomes ``path`` when the block succeeds."""
    if mode not in ("w", "wb"):
        raise ValueError(f"mode: expected 'w' or 'wb', got {mode!r}")
    with atomic_path(path, overwrite=overwrite, field=field) as tmp:
        with open(tmp, mode, encoding=None if "b" in mode else encoding) as fh:
            yield fh


def write_bytes(path: str | os.PathLike[str], data: bytes, *, overwrite: bool = True, field: str = "path") -> Path:
    """Write ``data`` to ``path`` atomically; returns ``path``."""
    with atomic_file(path, "wb", overwrite=overwrite, field=field) as fh:
        fh.write(data)
    return Path(path)


def write_text(path: str | os.PathLike[str], text: str, *, overwrite: bool = True, field: str = "path") -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically; returns ``path``."""
    with atomic_file(path, "w", overwrite=overwrite, field=field) as fh:
        fh.write(text)
    return Path(path)


def write_json(path: str | os.PathLike[str], obj: Any, *, indent: int | None = 2,
               default: Callable[[Any], Any] | None = None, allow_nan: bool = True, overwrite: bool = True) -> Path:
    """Write ``obj`` as JSON (and a final newline) to ``path`` atomically; returns ``path``.

    The text is made before anything is created, so an object JSON cannot hold leaves no trace.
    """
    text = json.dumps(obj, indent=indent, default=default, allow_nan=allow_nan) + "\n"
    return write_text(path, text, overwrite=overwrite)


def copy_file(src: str | os.PathLike[str], dst: str | os.PathLike[str], *, overwrite: bool = True) -> Path:
    """Copy ``src`` onto ``dst`` atomically (contents only; permissions follow the umask)."""
    with atomic_path(dst, overwrite=overwrite) as tmp:
        shutil.copyfile(src, tmp)
    return Path(dst)


# ---------------------------------------------------------------------------------------------- input documents
def _read_document(path: str | os.PathLike[str], what: str, kind: str, parse: Callable[[str], Any],
                   error: type[Exception], missing: type[Exception]) -> Any:
    path = Path(path)
    if not path.exists():
        raise missing(f"{what}: {path}: no such file")
    if not path.is_file():
        raise error(f"{what}: {path} is {'a directory' if path.is_dir() else 'not a regular file'}, "
                    f"not a {kind} file")
    try:
        return parse(path.read_text(encoding="utf-8"))
    except UnicodeDecodeError:  # before ValueError, which it is
        raise error(f"{what}: {path} is not UTF-8 text (not a {kind} file)") from None
    except OSError as exc:
        raise error(f"{what}: {path} cannot be read ({exc.strerror or exc})") from None
    except (ValueError, RecursionError) as exc:  # JSONDecodeError, TOMLDecodeError; absurd nesting recurses
        raise error(f"{what}: {path} is not valid {kind} ({exc})") from None


def read_json(path: str | os.PathLike[str], what: str, *, error: type[Exception] = ValueError,
              missing: type[Exception] = FileNotFoundError) -> Any:
    """The JSON document in the UTF-8 file ``path``; every message starts with ``what`` (the field that named it).

    Parameters
    ----------
    path : path-like
    what : str
        The option or field the path came from (``"truth"``, ``"--groups"``).
    error : exception class
        Raised when ``path`` is not a regular file, cannot be read or is not valid JSON.
    missing : exception class
        Raised when ``path`` does not exist.

    Returns
    -------
    Any
        What ``json.loads`` makes of the text.
    """
    return _read_document(path, what, "JSON", json.loads, error, missing)


def read_toml(path: str | os.PathLike[str], what: str, *, error: type[Exception] = ValueError,
              missing: type[Exception] = FileNotFoundError) -> dict[str, Any]:
    """The TOML document in the UTF-8 file ``path`` as a dict; the checks and messages of :func:`read_json`."""
    return _read_document(path, what, "TOML", tomllib.loads, error, missing)


# ---------------------------------------------------------------------------------------------- directories
def fsync_tree(root: str | os.PathLike[str]) -> None:
    """Flush every regular file under ``root``, then the directories, to disk."""
    root = Path(root)
    dirs = [root]
    for p in sorted(root.rglob("*")):
        if p.is_symlink():
            continue
        if p.is_file():
            _fsync_file(p)
        elif p.is_dir():
            dirs.append(p)
    for d in reversed(dirs):
        _fsync_dir(d)


@contextlib.contextmanager
def atomic_dir(target: str | os.PathLike[str], *, replace: bool = False) -> Iterator[Path]:
    """A temporary directory beside ``target`` to fill; it becomes ``target`` when the block succeeds.

    The directory gets the permissions ``mkdir`` would give; its files are synced before the rename. With
    ``replace`` an existing ``target`` is first moved aside (into a ``.old-`` temporary, removed afterwards,
    or put back by :func:`clean_stale_temporaries` if this process dies in between); without it the
    rename fails on an existing non-empty ``target``. Checking whether ``target`` may be replaced is the
    caller's policy. On an exception nothing is left behind.
    """
    target = Path(target)
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=temporary_prefix(target, "tmp"), dir=target.parent))
    try:
        apply_mode(tmp, directory=True)
        yield tmp
        fsync_tree(tmp)
        if replace and (target.exists() or target.is_symlink()):
            backup = Path(tempfile.mkdtemp(prefix=temporary_prefix(target, "old"), dir=target.parent))
            os.replace(target, backup / "old")
            os.replace(tmp, target)
            shutil.rmtree(backup, ignore_errors=True)
        else:
            os.replace(tmp, target)
        _fsync_dir(target.parent)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


# ------------------------------------------------------------------------------------------ owned outputs
OUTPUT_MARKER = ".pbicrl-output.json"
"""File a directory pbicrl writes as one output holds: its kind and the entries pbicrl put there."""


def mark_output(directory: str | os.PathLike[str], kind: str, entries: Any = None) -> Path:
    """Record (or extend) ``directory``'s marker: it is a pbicrl output of ``kind`` holding ``entries``.

    ``entries`` (names directly inside ``directory``) defaults to everything there now; an existing marker of
    the same kind keeps its entries. The marker is what lets ``overwrite`` replace the directory later
    (:func:`check_replaceable`).
    """
    d = Path(directory)
    names = set(e.name for e in d.iterdir()) if entries is None else {str(e) for e in entries}
    old = read_marker(d)
    if old is not None and old[0] == kind:
        names |= old[1]
    names.discard(OUTPUT_MARKER)
    return write_json(d / OUTPUT_MARKER, {"kind": kind, "entries": sorted(names)})


def read_marker(directory: str | os.PathLike[str]) -> tuple[str, set[str]] | None:
    """``(kind, entries)`` of ``directory``'s marker, or ``None`` without a readable one."""
    p = Path(directory) / OUTPUT_MARKER
    try:
        if p.is_symlink() or not p.is_file() or p.stat().st_size > 1 << 20:
            return None
        obj = json.loads(p.read_text(encoding="utf-8"))
    except (OSError, ValueError, UnicodeDecodeError, RecursionError):
        return None
    if (not isinstance(obj, dict) or not isinstance(obj.get("kind"), str) or not isinstance(obj.get("entries"), list)
            or not all(isinstance(e, str) for e in obj["entries"])):
        return None
    return obj["kind"], set(obj["entries"])


def inputs_inside(out: str | os.PathLike[str], inputs: Any) -> list[Path]:
    """The ``inputs`` (paths; ``None`` skipped) that are ``out`` itself or lie inside it (links resolved)."""
    root = Path(os.path.realpath(out))
    found = []
    for p in inputs or ():
        if p is None:
            continue
        real = Path(os.path.realpath(p))
        if real == root or root in real.parents:
            found.append(Path(p))
    return found


def check_replaceable(out: str | os.PathLike[str], kind: str, *, field: str = "out_dir", inputs: Any = (),
                      legacy: Callable[[Path], set[str] | None] | None = None) -> None:
    """Refuse to replace ``out`` unless pbicrl wrote it as output of ``kind`` and it holds only what pbicrl wrote.

    ``out`` may be replaced when its marker (:func:`mark_output`) has this ``kind`` and every entry in it is
    listed there, or, for a directory written before markers existed, when ``legacy(out)`` returns the set of
    entries an earlier pbicrl wrote there and nothing else is present. An ``input`` inside ``out`` is never
    replaced.

    Raises
    ------
    FileExistsError
        Naming ``field``, the directory and what stops the replacement.
    """
    out = Path(out)
    inside = inputs_inside(out, inputs)
    if inside:
        raise FileExistsError(f"{field}: {out} holds this command's input {inside[0]}; replacing the directory "
                              "would delete it: choose another directory")
    if out.is_symlink() or not out.is_dir():
        raise FileExistsError(f"{field}: {out} is a file, not a directory pbicrl wrote; overwrite replaces only those")
    marker = read_marker(out)
    if marker is not None:
        if marker[0] != kind:
            raise FileExistsError(f"{field}: {out} is a pbicrl {marker[0]} directory, not a {kind} directory; "
                                  "overwrite replaces only output of the same kind")
        allowed = marker[1] | {OUTPUT_MARKER}
    else:
        known = legacy(out) if legacy is not None else None
        if known is None:
            raise FileExistsError(f"{field}: {out} is a directory pbicrl did not write as a {kind} directory; "
                                  "overwrite replaces only those: choose another directory")
        allowed = known
    foreign = sorted(e.name for e in out.iterdir() if e.name not in allowed)
    if foreign:
        listed = ", ".join(foreign[:5]) + (", ..." if len(foreign) > 5 else "")
        raise FileExistsError(f"{field}: {out} also holds {listed}, which pbicrl did not write; overwrite never "
                              "removes those: move them out or choose another directory")


def check_file_output(path: str | os.PathLike[str], *, overwrite: bool = False, inputs: Any = (),
                      field: str = "out") -> Path:
    """The one rule for a file output: an existing file is replaced only with ``overwrite``, an input never.

    Call it before any work, then write with ``atomic_path(path, overwrite=overwrite)`` (which re-checks).

    Raises
    ------
    OutputExistsError
        ``path`` exists and ``overwrite`` is false.
    FileExistsError
        ``path`` is one of ``inputs`` (the same file, links resolved), a directory or a symbolic link.
    """
    p = Path(path)
    real = os.path.realpath(p)
    for i in inputs or ():
        if i is not None and (os.path.realpath(i) == real or (p.exists() and Path(i).exists()
                                                               and os.path.samefile(p, i))):
            raise FileExistsError(f"{field}: {p} is this command's input {i}; an input is never overwritten: "
                                  "choose another file")
    if p.is_symlink() or p.is_dir():
        raise FileExistsError(f"{field}: {p} is a {'symbolic link' if p.is_symlink() else 'directory'}; "
                              "give a file path")
    if p.exists() and not overwrite:
        raise OutputExistsError(field, p, "file")
    return p
