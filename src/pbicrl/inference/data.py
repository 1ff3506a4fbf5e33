"""Ranked demonstration datasets.

A :class:`Dataset` holds ``N`` ragged trajectories, each a sequence of per-state
feature vectors :math:`\\phi(s) \\in \\mathbb{R}^d`, and a group label per trajectory
(1 = most preferred group :math:`\\mathcal{G}_1`, larger labels are worse).

On disk a dataset is one ``.npz`` archive (always read with ``allow_pickle=False``):

=================== ============ ==========================================================
field               shape        meaning
=================== ============ ==========================================================
``features``        (S, d) float per-state features, all trajectories stacked
``offsets``         (N+1,) int   trajectory ``i`` is rows ``offsets[i]:offsets[i+1]``
``group``           (N,) int     group label, 1 = most preferred
``states``          (S, k) float optional per-state states (for parametric constraints)
``actions``         (S, a) float optional per-state actions
``feature_names``   (d,) str     optional feature names
``nominal_weights`` (d,) float   optional known nominal weights :math:`w_n`
``group_names``     (K,) str     optional names of the groups, best first (e.g. good, bad, very bad)
``gap_relation``    (K-1,) float optional relative sizes of the gaps between consecutive groups
``skipped``         (N,) bool    optional: trajectories the labeller chose not to rank (group 0)
``env_id``          () str       optional environment the demonstrations come from (``point_mass``, ...)
=================== ============ ==========================================================

Group 0 means *unlabelled*: a pool of demonstrations still to be ranked, or a labelling session in
progress (``pbicrl label``). Such files load only with ``load_dataset(path, allow_unlabelled=True)``;
inference refuses them until every trajectory is labelled, and :meth:`Dataset.labelled` keeps the
labelled ones. ``gap_relation`` is what ``pbicrl tune-margins --relation`` takes (``[1, 4]``: the gap
between groups 2 and 3 is about four times the gap between groups 1 and 2).

Reading is defensive: only regular files are opened (a device or a named pipe is refused, never read),
every array header is checked before any data is read (an array larger than the archive holds, or than
this process may allocate, is an error naming the field), and complex values or objects are refused
rather than converted. Datasets shipped with pbicrl are found by name: ``load_dataset("point_mass")``
(see :func:`list_shipped_datasets` and :func:`resolve_dataset_path`).

Files are written atomically through temporaries named ``.<target>.tmp-<host>.<pid>.<random>``, so that
:func:`clean_stale_temporaries` can tell those of killed writers from those of running ones.
"""

from __future__ import annotations

import dataclasses
import math
import os
import stat
import zipfile
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import IO, Any, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

# one implementation of temporary names, their clean-up and the umask, shared with every atomic writer
from pbicrl._atomic import OutputExistsError, atomic_path, clean_stale_temporaries, temporary_prefix

__all__ = [
    "Dataset", "DatasetError", "DatasetNotFoundError", "load_dataset", "resolve_dataset_path",
    "list_shipped_datasets", "ArrayHeader", "inspect_npz", "memory_limit_bytes", "clean_stale_temporaries",
    "temporary_prefix", "MAX_GROUPS", "file_kind", "format_bytes", "shipped_dir", "SHIPPED_ENV_IDS",
]

MAX_GROUPS = 1000
"""Most groups a dataset may have. The default likelihoods, ``identify`` and ``export`` hold additive margins
as K offsets (nothing K x K) and run on 20,000 single-trajectory groups; what still grows with K^2 is the
pairwise likelihood with sampled pairs (``pairs=n``: n pairs for each of the K(K-1)/2 group pairs, drawn in a
loop over them), a general K x K margin matrix, and ``suggest`` (O(M K^2) time per draw for M candidates). The
cap stays until those check their own sizes."""

SHIPPED_ENV_IDS = {"point_mass": "point_mass", "fetch_reach": "fetch_reach", "grid": "grid",
                   "halfcheetah": "halfcheetah", "ant": "ant"}
"""The environment of each shipped dataset (``example`` is synthetic: none); :meth:`Dataset.load` sets it, so a
shipped dataset and a pool made from it (:meth:`Dataset.as_pool`) are drawn with their goal and regions."""

_FIELDS = ("features", "offsets", "group", "states", "actions", "feature_names", "nominal_weights", "group_names",
           "gap_relation", "skipped", "env_id")
_REQUIRED = ("features", "offsets", "group")
_MAX_ENV_ID = 200  # characters: an environment id, not a document
_MAX_HEADER = 10_000  # bytes of an .npy header, as numpy's own default: a larger one is hostile or corrupt


class DatasetError(ValueError):
    """Invalid dataset content; the message names the offending field."""


class DatasetNotFoundError(DatasetError, FileNotFoundError):
    """No dataset file (and no shipped dataset) of that name; both a :class:`DatasetError` and a
    :class:`FileNotFoundError`."""


# ---------------------------------------------------------------------------------------------- shipped data
def shipped_dir() -> Path:
    """The folder of the datasets shipped with pbicrl (``pbicrl/data``)."""
    from importlib import resources

    return Path(str(resources.files("pbicrl") / "data"))


def list_shipped_datasets() -> list[str]:
    """Names of the datasets shipped with pbicrl, e.g. ``["ant", "example", ..., "point_mass"]``.

    Each name works wherever a dataset path does: ``load_dataset(name)``, ``pbicrl infer NAME``,
    ``data = "NAME"`` in a sweep file.
    """
    d = shipped_dir()
    if not d.is_dir():
        return []
    return sorted(p.stem for p in d.glob("*.npz") if p.is_file())


def resolve_dataset_path(name_or_path: str | os.PathLike[str]) -> Path:
    """The file a dataset argument refers to: an existing file, else a shipped dataset of that name.

    Parameters
    ----------
    name_or_path : str or path
        A path (``demos.npz``, ``~/data/demos.npz``) or the name of a shipped dataset, with or without
        ``.npz`` (``point_mass``). An existing file of exactly that name wins over a shipped dataset; a
        directory does not, and neither does ``point_mass.npz`` when the argument is ``point_mass``.

    Returns
    -------
    pathlib.Path
        The file (not checked further: :meth:`Dataset.load` refuses devices, pipes and directories).

    Raises
    ------
    DatasetNotFoundError
        Neither a file nor a shipped dataset; the message lists the shipped names.
    """
    text = os.fspath(name_or_path)
    if not isinstance(text, str) or not text.strip():
        raise DatasetNotFoundError(f"data: expected a dataset file or the name of a shipped dataset, got {text!r}")
    p = Path(text).expanduser()
    try:
        if p.is_file():
            return p
        if not p.is_absolute() and len(Path(text).parts) == 1:  # a bare name may be a shipped dataset
            stem = p.stem if p.suffix == ".npz" else p.name
            shipped = shipped_dir() / f"{stem}.npz"
            if shipped.is_file():
                return shipped
        if p.exists() or p.is_symlink():
            return p  # a directory, device, pipe or dangling link: loading says what is wrong with it
    except OSError as exc:  # a name longer than the file system allows, a loop of links, ...
        shown = text if len(text) <= 80 else text[:60] + f"... ({len(text):,} characters)"
        raise DatasetNotFoundError(f"data: {shown}: cannot be looked up ({exc.strerror or exc})") from None
    names = ", ".join(list_shipped_datasets()) or "none"
    raise DatasetNotFoundError(f"data: {text}: no such file, and no shipped dataset of that name "
                               f"(shipped datasets: {names})")


# ---------------------------------------------------------------------------------------------- memory
def format_bytes(n: float) -> str:
    """``n`` bytes for people: ``"512 bytes"``, ``"1.5 MiB"``."""
    for unit in ("bytes", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if abs(n) < 1024 or unit == "PiB":
            return f"{n:.0f} {unit}" if unit == "bytes" else f"{n:.1f} {unit}"
        n /= 1024
    return f"{n:.1f} EiB"  # pragma: no cover - unreachable


def memory_limit_bytes() -> int:
    """Bytes this process can still allocate, at most: the least of physical memory, the remaining
    address space under ``RLIMIT_AS`` and the remaining memory of a cgroup (container) limit.

    An upper bound used to refuse allocations that cannot succeed (a corrupt header, a typo in a size)
    with a clear error instead of an out-of-memory kill; not a promise that smaller ones will.
    """
    limits: list[int] = []
    try:
        limits.append(int(os.sysconf("SC_PAGE_SIZE")) * int(os.sysconf("SC_PHYS_PAGES")))
    except (AttributeError, ValueError, OSError):
        pass
    try:
        import resource

        soft, _ = resource.getrlimit(resource.RLIMIT_AS)
        if soft != resource.RLIM_INFINITY and soft > 0:
            used = 0
            try:  # address space already mapped (libraries, numba, ...) counts against the limit
                used = int(Path("/proc/self/statm").read_text().split()[0]) * int(os.sysconf("SC_PAGE_SIZE"))
            except (OSError, ValueError, IndexError):
                pass
            limits.append(max(0, int(soft) - used))
    except (ImportError, ValueError, OSError):
        pass
    for limit_file, usage_file in (("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory.current"),
                                   ("/sys/fs/cgroup/memory/memory.limit_in_bytes",
                                    "/sys/fs/cgroup/memory/memory.usage_in_bytes")):
        try:
            text = Path(limit_file).read_text().strip()
        except OSError:
            continue
        if text.isdigit() and int(text) < 1 << 60:  # "max" or a huge number: no limit
            try:
                usage = int(Path(usage_file).read_text().strip())
            except (OSError, ValueError):
                usage = 0
            limits.append(max(0, int(text) - usage))
        break
    return min(limits) if limits else 1 << 62


# ---------------------------------------------------------------------------------------------- safe reading
def _open_regular(path: Path, what: str) -> IO[bytes]:
    """Open ``path`` for reading if (and only if) it is a non-empty regular file.

    ``O_NONBLOCK`` makes opening a named pipe return at once instead of waiting for a writer; the type is
    then checked on the open descriptor, so a file swapped for a pipe after a check cannot slip through.
    """
    flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0) | getattr(os, "O_BINARY", 0)
    try:
        fd = os.open(path, flags)
    except FileNotFoundError:
        raise DatasetNotFoundError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise DatasetError(f"{path}: is a directory, not a {what} file") from None
    except PermissionError:
        raise DatasetError(f"{path}: permission denied") from None
    except OSError as exc:
        raise DatasetError(f"{path}: cannot be opened ({exc.strerror or exc})") from None
    try:
        st = os.fstat(fd)
        kind = file_kind(st.st_mode)
        if kind is not None:
            raise DatasetError(f"{path}: is a {kind}, not a regular file; pbicrl reads a {what} only from a "
                               "regular file")
        if st.st_size == 0:
            raise DatasetError(f"{path}: empty file (0 bytes), not a {what} (.npz archive)")
        return os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise


def file_kind(mode: int) -> str | None:
    """``None`` for a regular file's ``st_mode``, else what it is (``"directory"``, ``"FIFO"``, ...) for messages."""
    if stat.S_ISREG(mode):
        return None
    for test, name in ((stat.S_ISDIR, "directory"), (stat.S_ISCHR, "character device"),
                       (stat.S_ISBLK, "block device"), (stat.S_ISFIFO, "named pipe (FIFO)"),
                       (stat.S_ISSOCK, "socket")):
        if test(mode):
            return name
    return "special file"


@dataclass(frozen=True)
class ArrayHeader:
    """What the header of one array of a ``.npz`` declares (read without loading the data).

    Attributes
    ----------
    shape : tuple of int
    dtype : numpy.dtype
    fortran_order : bool
    data_bytes : int
        Bytes of array data the member holds after its header (from the archive's directory).
    """

    shape: tuple[int, ...]
    dtype: np.dtype
    fortran_order: bool
    data_bytes: int

    @property
    def nbytes(self) -> int:
        """Bytes the array occupies in memory once loaded."""
        return math.prod(self.shape) * int(self.dtype.itemsize)


def _read_header(zf: zipfile.ZipFile, info: zipfile.ZipInfo, where: str) -> ArrayHeader:
    fmt = np.lib.format
    try:
        with zf.open(info) as member:
            version = fmt.read_magic(member)
            if version == (1, 0):
                shape, fortran, dtype = fmt.read_array_header_1_0(member, max_header_size=_MAX_HEADER)
            elif version == (2, 0):
                shape, fortran, dtype = fmt.read_array_header_2_0(member, max_header_size=_MAX_HEADER)
            else:
                raise ValueError(f"unsupported .npy format version {version[0]}.{version[1]}")
            header_len = member.tell()
    except Exception as exc:  # anything a hostile or corrupt member raises, zipfile's and numpy's alike
        msg = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise DatasetError(f"{where}: not a readable array ({msg})") from None
    if any((not isinstance(n, int)) or n < 0 for n in shape):
        raise DatasetError(f"{where}: invalid shape {shape} in the array header")
    return ArrayHeader(tuple(int(n) for n in shape), np.dtype(dtype), bool(fortran), int(info.file_size) - header_len)


def _check_header(h: ArrayHeader, where: str, *, what: str, allow_objects: bool = False) -> None:
    if h.dtype.hasobject and not allow_objects:
        raise DatasetError(f"{where}: contains Python objects (pickles), which are not read for safety; "
                           "store text as a string array (np.array(names, dtype=str))")
    if h.nbytes > h.data_bytes:
        raise DatasetError(f"{where}: the header declares shape {h.shape} ({h.dtype}, {format_bytes(h.nbytes)}) "
                           f"but the {what} holds only {format_bytes(max(h.data_bytes, 0))} of data (truncated "
                           "or corrupt file)")


def inspect_npz(path: str | os.PathLike[str], *, what: str = "dataset") -> dict[str, ArrayHeader]:
    """Check a ``.npz`` archive without loading its arrays; returns each array's header by name.

    Refuses (with :class:`DatasetError` naming the file and the array) anything but a non-empty regular
    file, a file that is not a zip archive, an unreadable or oversized (> 10,000 bytes) array header, an
    array of Python objects, an array larger than the data its member holds, and arrays that together
    exceed :func:`memory_limit_bytes`.

    Parameters
    ----------
    path : path
    what : str
        What the file is, for messages ("dataset", "chains file", ...).
    """
    path = Path(path)
    with _open_regular(path, what) as fh:
        return _inspect_open(fh, path, what)[1]


def _inspect_open(fh: IO[bytes], path: Path, what: str, fields: Sequence[str] | None = None
                  ) -> tuple[zipfile.ZipFile, dict[str, ArrayHeader]]:
    try:
        zf = zipfile.ZipFile(fh)
    except zipfile.BadZipFile:
        raise DatasetError(f"{path}: not a readable .npz archive (not a zip file)") from None
    except Exception as exc:  # truncated central directory, bad offsets, ...
        raise DatasetError(f"{path}: not a readable .npz archive ({exc})") from None
    headers: dict[str, ArrayHeader] = {}
    for info in zf.infolist():
        if info.is_dir():
            continue
        name = info.filename[:-4] if info.filename.endswith(".npy") else info.filename
        headers[name] = _read_header(zf, info, f"{path}: field '{name}'")
    for name, h in headers.items():
        _check_header(h, f"{path}: field '{name}'", what="archive", allow_objects=True)
    loaded = [k for k in headers if fields is None or k in fields]  # only what will be read counts
    total = sum(headers[k].nbytes for k in loaded)
    limit = memory_limit_bytes()
    if total > limit:
        big = max(loaded, key=lambda k: headers[k].nbytes)
        h = headers[big]
        raise DatasetError(f"{path}: field '{big}' has shape {h.shape} ({h.dtype}, {format_bytes(h.nbytes)}); the "
                           f"arrays of this {what} need {format_bytes(total)}, more than the {format_bytes(limit)} "
                           "this process can allocate")
    return zf, headers


def _read_npz(path: Path, fields: Sequence[str], *, what: str) -> tuple[dict[str, NDArray], list[str]]:
    """Load ``fields`` (those present) of a checked archive; returns them and the names of the others."""
    with _open_regular(path, what) as fh:
        zf, headers = _inspect_open(fh, path, what, fields)
        out: dict[str, NDArray] = {}
        for name in fields:
            if name not in headers:
                continue
            where = f"{path}: field '{name}'"
            _check_header(headers[name], where, what="archive")
            member = f"{name}.npy" if f"{name}.npy" in zf.NameToInfo else name
            try:
                with zf.open(member) as fp:
                    out[name] = np.lib.format.read_array(fp, allow_pickle=False, max_header_size=_MAX_HEADER)
            except Exception as exc:  # CRC error, truncated deflate stream, ...
                msg = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
                raise DatasetError(f"{where}: not readable ({msg})") from None
        return out, [k for k in headers if k not in fields]


# ---------------------------------------------------------------------------------------------- temporaries


# ---------------------------------------------------------------------------------------------- validation
def _real_float64(raw: NDArray, what: str) -> NDArray[np.float64]:
    """``raw`` as float64; complex values are an error (a float cast would drop the imaginary part silently).

    ``what`` starts the message, e.g. ``"features:"`` or ``"features: trajectory 3 has"``.
    """
    if raw.dtype.kind == "c":
        raise DatasetError(f"{what} complex values (dtype {raw.dtype}) are not supported; store the real and "
                           "imaginary parts as separate columns")
    return np.asarray(raw, dtype=np.float64)


def _as_float_2d(name: str, value: ArrayLike) -> NDArray[np.float64]:
    raw = value if isinstance(value, np.ndarray) else None
    try:
        arr = _real_float64(np.asarray(value) if raw is None else raw, f"{name}:")
    except DatasetError:
        raise
    except (TypeError, ValueError) as exc:
        raise DatasetError(f"{name}: values must be numeric ({exc})") from None
    if arr.ndim == 1:
        arr = arr[:, None]
    if arr.ndim != 2:
        raise DatasetError(f"{name}: expected a 2-D array (rows, columns), got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        bad = np.argwhere(~np.isfinite(arr))[0]
        raise DatasetError(f"{name}: contains NaN or inf (first at row {bad[0]}, column {bad[1]})")
    return np.ascontiguousarray(arr)


def _as_names(name: str, value: Any) -> tuple[str, ...]:
    """Text labels from a sequence of str or bytes (UTF-8); anything else is an error naming ``name``."""
    if isinstance(value, (str, bytes)):
        raise DatasetError(f"{name}: expected a sequence of names, got the single string {value!r}")
    if isinstance(value, np.ndarray):
        if value.ndim != 1:
            raise DatasetError(f"{name}: expected a 1-D array of names, got shape {value.shape}")
        items = value.tolist()
    else:
        try:
            items = list(value)
        except TypeError:
            raise DatasetError(f"{name}: expected a sequence of names, got {type(value).__name__}") from None
    out = []
    for i, item in enumerate(items):
        if isinstance(item, bytes):  # e.g. an 'S' array: str() would give "b'speed'"
            try:
                item = item.decode("utf-8")
            except UnicodeDecodeError:
                raise DatasetError(f"{name}: name {i} ({item!r}) is not UTF-8 text") from None
        if not isinstance(item, str):
            raise DatasetError(f"{name}: name {i} is {type(item).__name__} {item!r}, expected text")
        if not item.strip():
            raise DatasetError(f"{name}: name {i} is empty")
        out.append(str(item))
    return tuple(out)


def _as_vector(name: str, value: ArrayLike, d: int) -> NDArray[np.float64]:
    try:
        raw = np.asarray(value)
        if raw.dtype.kind == "c":
            raise DatasetError(f"{name}: complex values (dtype {raw.dtype}) are not supported")
        vec = np.asarray(raw, dtype=np.float64).reshape(-1)
    except DatasetError:
        raise
    except (TypeError, ValueError):
        raise DatasetError(f"{name}: values must be numeric") from None
    if vec.shape != (d,):
        raise DatasetError(f"{name}: expected {d} values (one per feature), got {vec.size}")
    if not np.all(np.isfinite(vec)):
        raise DatasetError(f"{name}: contains NaN or inf")
    return vec


def _as_gap_relation(value: ArrayLike, n_groups: int) -> NDArray[np.float64] | None:
    """``K - 1`` positive finite relative gap sizes (``None`` for an empty array)."""
    try:
        raw = np.asarray(value)
        if raw.dtype.kind == "c":
            raise DatasetError(f"gap_relation: complex values (dtype {raw.dtype}) are not supported")
        rel = np.asarray(raw, dtype=np.float64)
    except DatasetError:
        raise
    except (TypeError, ValueError):
        raise DatasetError("gap_relation: values must be numbers (relative sizes of the gaps between "
                           "consecutive groups, e.g. [1, 4])") from None
    if rel.ndim > 1:
        raise DatasetError(f"gap_relation: expected a 1-D array of K-1 numbers, got shape {rel.shape}")
    rel = rel.reshape(-1)
    if rel.size == 0:
        return None
    if n_groups < 2:
        raise DatasetError(f"gap_relation: relates the gaps between consecutive groups, but the dataset defines "
                           f"{n_groups} group{'s' if n_groups != 1 else ''}")
    if rel.size != n_groups - 1:
        raise DatasetError(f"gap_relation: {n_groups} groups need {n_groups - 1} relative gap sizes (one per pair "
                           f"of consecutive groups), got {rel.size}")
    if not np.all(np.isfinite(rel)) or np.any(rel <= 0):
        raise DatasetError(f"gap_relation: relative gap sizes must be positive finite numbers, got {rel.tolist()}")
    return rel


def _as_skipped(value: ArrayLike, n: int) -> NDArray[np.bool_]:
    """One flag per trajectory; booleans, or integers that are 0 or 1."""
    raw = np.asarray(value)
    if raw.shape != (n,):
        raise DatasetError(f"skipped: expected shape ({n},) (one flag per trajectory), got {raw.shape}")
    if raw.dtype == np.bool_:
        return raw.copy()
    if raw.dtype.kind in "iu" or (raw.dtype.kind == "f" and np.all(np.isfinite(raw))):
        if np.all((raw == 0) | (raw == 1)):
            return raw.astype(np.bool_)
    raise DatasetError(f"skipped: expected booleans (or 0/1), got dtype {raw.dtype}"
                       + (f" with values {np.unique(raw)[:5].tolist()}" if raw.dtype.kind in "iuf" else ""))


def _as_env_id(value: Any) -> str | None:
    """The environment id as text: a str, UTF-8 bytes, or a string array with one element."""
    if isinstance(value, np.ndarray):
        if value.size != 1 or value.ndim > 1 or value.dtype.kind not in "US":
            raise DatasetError(f"env_id: expected one string, got an array of dtype {value.dtype} and shape "
                               f"{value.shape}")
        value = value.reshape(-1)[0].item()
    if isinstance(value, bytes):
        try:
            value = value.decode("utf-8")
        except UnicodeDecodeError:
            raise DatasetError("env_id: not UTF-8 text") from None
    if not isinstance(value, str):
        raise DatasetError(f"env_id: expected a string such as 'point_mass', got {type(value).__name__}")
    text = value.strip()
    if not text:
        raise DatasetError("env_id: empty; leave the field out when the environment is unknown")
    if len(text) > _MAX_ENV_ID:
        raise DatasetError(f"env_id: {len(text)} characters; an environment id has at most {_MAX_ENV_ID}")
    if not text.isprintable():
        raise DatasetError(f"env_id: contains control characters: {text[:40]!r}")
    return text


# ---------------------------------------------------------------------------------------------- the dataset
@dataclass(frozen=True, eq=False)
class Dataset:
    """Grouped demonstrations with per-state features.

    Parameters
    ----------
    features : ndarray, shape (S, d)
        Per-state features :math:`\\phi(s)` of all trajectories, stacked. Real numbers (complex values are
        refused, not truncated).
    offsets : ndarray, shape (N + 1,)
        Trajectory boundaries: trajectory ``i`` is ``features[offsets[i]:offsets[i+1]]``.
        Must start at 0, be strictly increasing (no empty trajectory) and end at ``S``.
    group : ndarray, shape (N,)
        Positive integer group labels; 1 is the most preferred group. Any labels
        ``K >= 2`` distinct values (at most :data:`MAX_GROUPS`); ranking follows their numeric order.
        With ``allow_unlabelled`` also 0 (unlabelled), and fewer than two groups.
    states : ndarray, shape (S, k), optional
        Per-state states (e.g. positions), needed by parametric constraints.
    actions : ndarray, shape (S, a), optional
        Per-state actions.
    feature_names : sequence of str, length d, optional
        Defaults to ``("f0", "f1", ...)``. Bytes are decoded as UTF-8.
    nominal_weights : ndarray, shape (d,), optional
        Known nominal weights :math:`w_n`.
    group_names : sequence of str, length K, optional
        Names of the groups in preference order (best first): ``group_names[k]`` names the ``k``-th
        smallest label. Empty (the default) means unnamed. With ``allow_unlabelled`` a labelling file may
        also name groups that are still empty: when there are more names than non-empty groups, label ``k``
        is named ``group_names[k-1]`` and every label must be at most ``len(group_names)``.
    gap_relation : array-like, shape (K-1,), optional
        Relative sizes of the gaps between consecutive groups, as ``pbicrl tune-margins --relation`` takes
        them: ``[1, 4]`` says the gap between groups 2 and 3 is about four times the one between groups 1
        and 2. ``K`` is the number of groups the dataset defines (:attr:`defined_groups`).
    skipped : array-like of bool, shape (N,), optional
        Trajectories the labeller chose not to rank; each has group 0. Default: none.
    env_id : str, optional
        Environment of the demonstrations (``"point_mass"``, ``"fetch_reach"``, ``"grid"``,
        ``"halfcheetah"``, ``"ant"`` or one of your own), so that tools can draw them without extra flags.
    allow_unlabelled : bool
        Accept group 0 (unlabelled) and fewer than two groups: a pool of demonstrations to rank, or a
        labelling session in progress. Inference refuses such a dataset; :meth:`labelled` keeps the
        labelled trajectories.

    Raises
    ------
    DatasetError
        With a message naming the field, for any inconsistent or non-finite input.
    """

    features: NDArray[np.float64]
    offsets: NDArray[np.int64]
    group: NDArray[np.int64]
    states: NDArray[np.float64] | None = None
    actions: NDArray[np.float64] | None = None
    feature_names: tuple[str, ...] = field(default=())
    nominal_weights: NDArray[np.float64] | None = None
    group_names: tuple[str, ...] = field(default=())
    gap_relation: NDArray[np.float64] | None = None
    skipped: NDArray[np.bool_] | None = None
    env_id: str | None = None
    allow_unlabelled: bool = False

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        feats = _as_float_2d("features", self.features)
        S, d = feats.shape
        if S == 0 or d == 0:
            raise DatasetError(f"features: must have at least one row and one column, got shape {feats.shape}")
        offsets = np.asarray(self.offsets)
        if offsets.ndim != 1 or offsets.size < 2:
            raise DatasetError(f"offsets: expected a 1-D array of length N+1 >= 2, got shape {offsets.shape}")
        if not np.issubdtype(offsets.dtype, np.integer):
            if not np.issubdtype(offsets.dtype, np.floating) or not np.all(offsets == np.round(offsets)):
                raise DatasetError(f"offsets: must be integers, got dtype {offsets.dtype}")
            if not np.all(np.abs(offsets) < 2**53):
                raise DatasetError("offsets: values too large to be row numbers")
        offsets = offsets.astype(np.int64)
        if offsets[0] != 0:
            raise DatasetError(f"offsets: must start at 0, starts at {offsets[0]}")
        steps = np.diff(offsets)
        if np.any(steps <= 0):
            i = int(np.argmax(steps <= 0))
            kind = "empty" if steps[i] == 0 else "decreasing"
            raise DatasetError(f"offsets: must be strictly increasing; trajectory {i} is {kind} "
                               f"(offsets[{i}]={offsets[i]}, offsets[{i + 1}]={offsets[i + 1]})")
        if offsets[-1] != S:
            raise DatasetError(f"offsets: must end at the number of feature rows S={S}, ends at {offsets[-1]}")
        N = offsets.size - 1

        group = np.asarray(self.group)
        if group.shape != (N,):
            raise DatasetError(f"group: expected shape ({N},) (one label per trajectory), got {group.shape}")
        if not np.issubdtype(group.dtype, np.integer):
            whole = np.issubdtype(group.dtype, np.floating) and np.all(np.isfinite(group)) \
                and np.all(group == np.round(group)) and np.all(np.abs(group) < 2**53)
            if whole:
                group = group.astype(np.int64)
            else:
                raise DatasetError(f"group: labels must be positive integers, got dtype {group.dtype}")
        group = group.astype(np.int64)
        allow = bool(self.allow_unlabelled)
        skipped = np.zeros(N, dtype=np.bool_) if self.skipped is None else _as_skipped(self.skipped, N)
        if np.any(group < 0):
            allowed = "0 (unlabelled) or positive integers" if allow else "positive integers (1 = most preferred)"
            raise DatasetError(f"group: labels must be {allowed}, got {int(group.min())}")
        n0 = int(np.sum(group == 0))
        if n0 and not allow:
            skip = f", {int(skipped.sum())} of them marked skipped" if skipped.any() else ""
            raise DatasetError(
                f"group: labels must be positive integers (1 = most preferred); {n0} of {N} trajectories have "
                f"group 0 (unlabelled{skip}). Label them ('pbicrl label'), keep only the labelled ones "
                "(load_dataset(path, allow_unlabelled=True).labelled()), or load the file as a pool with "
                "allow_unlabelled=True")
        labels = np.unique(group[group > 0])
        if labels.size < 2 and not allow:
            raise DatasetError("group: need at least two non-empty groups to rank, found "
                               f"{labels.size} ({labels.tolist()})")
        if labels.size > MAX_GROUPS:
            K = int(labels.size)
            raise DatasetError(
                f"group: {K:,} distinct groups; at most {MAX_GROUPS:,} are supported (sampled pairs and active "
                f"query selection visit every pair of groups: {K * (K - 1) // 2:,} of them here). Merge the labels "
                "into a few ranked groups (e.g. by quantiles of your score)")

        states = None if self.states is None else _as_float_2d("states", self.states)
        if states is not None and states.shape[0] != S:
            raise DatasetError(f"states: expected {S} rows (one per feature row), got {states.shape[0]}")
        actions = None if self.actions is None else _as_float_2d("actions", self.actions)
        if actions is not None and actions.shape[0] != S:
            raise DatasetError(f"actions: expected {S} rows (one per feature row), got {actions.shape[0]}")

        given = self.feature_names if self.feature_names is not None else ()
        names = _as_names("feature_names", given)
        names = names if names else tuple(f"f{j}" for j in range(d))
        if len(names) != d:
            raise DatasetError(f"feature_names: expected {d} names (one per feature column), got {len(names)}")
        if len(set(names)) != d:
            raise DatasetError(f"feature_names: names must be unique, got {list(names)}")

        wn = None if self.nominal_weights is None else _as_vector("nominal_weights", self.nominal_weights, d)

        gnames = _as_names("group_names", self.group_names if self.group_names is not None else ())
        defined = tuple(int(k) for k in labels)
        if gnames:
            if len(set(gnames)) != len(gnames):
                raise DatasetError(f"group_names: names must be unique, got {list(gnames)}")
            if len(gnames) != labels.size:
                if not allow or len(gnames) < labels.size:
                    raise DatasetError(f"group_names: expected {labels.size} names (one per group, best first), "
                                       f"got {len(gnames)}")
                if len(gnames) > MAX_GROUPS:
                    raise DatasetError(f"group_names: {len(gnames):,} groups; at most {MAX_GROUPS:,} are supported")
                if labels.size and int(labels.max()) > len(gnames):
                    raise DatasetError(
                        f"group_names: {len(gnames)} names, but a trajectory has group {int(labels.max())}; in a "
                        "labelling file with empty groups, group k is named group_names[k-1]")
                defined = tuple(range(1, len(gnames) + 1))  # names by rank: empty groups keep their place
        bad = np.flatnonzero(skipped & (group != 0))
        if bad.size:
            i = int(bad[0])
            raise DatasetError(f"skipped: trajectory {i} is marked skipped but has group {int(group[i])}; a "
                               "skipped trajectory is unlabelled (group 0)")
        rel = None if self.gap_relation is None else _as_gap_relation(self.gap_relation, len(defined))
        env = None if self.env_id is None else _as_env_id(self.env_id)

        checked = dict(features=feats, offsets=offsets, group=group, states=states, actions=actions,
                       feature_names=names, nominal_weights=wn, group_names=gnames, gap_relation=rel,
                       skipped=skipped, env_id=env, allow_unlabelled=allow, _defined=defined)
        for key, value in checked.items():  # the checked, normalised values replace what was given
            set_(self, key, value)

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_trajectories(
        cls,
        features: Sequence[ArrayLike],
        group: ArrayLike,
        *,
        states: Sequence[ArrayLike] | None = None,
        actions: Sequence[ArrayLike] | None = None,
        feature_names: Sequence[str] | None = None,
        nominal_weights: ArrayLike | None = None,
        group_names: Sequence[str] | None = None,
        gap_relation: ArrayLike | None = None,
        skipped: ArrayLike | None = None,
        env_id: str | None = None,
        allow_unlabelled: bool = False,
    ) -> "Dataset":
        """Build from a list of per-trajectory arrays.

        Parameters
        ----------
        features : sequence of arrays, each (T_i, d)
        group : array-like, (N,)
        states, actions : sequence of arrays, each (T_i, k), optional
        feature_names : sequence of str, optional
        nominal_weights : array-like, (d,), optional
        group_names : sequence of str, optional
            One per group, best first.
        gap_relation, skipped, env_id, allow_unlabelled
            As for :class:`Dataset`.
        """
        if len(features) == 0:
            raise DatasetError("features: no trajectories given")
        blocks = []
        for i, f in enumerate(features):
            a = _as_float_2d(f"features: trajectory {i}", f)  # (T_i, d)
            if a.shape[0] == 0:
                raise DatasetError(f"features: trajectory {i} is empty")
            if blocks and a.shape[1] != blocks[0].shape[1]:
                raise DatasetError(f"features: trajectory {i} has {a.shape[1]} features, trajectory 0 has {blocks[0].shape[1]}")
            blocks.append(a)
        lengths = np.array([b.shape[0] for b in blocks], dtype=np.int64)
        offsets = np.concatenate([[0], np.cumsum(lengths)])

        def stack(name: str, seq: Sequence[ArrayLike] | None) -> NDArray[np.float64] | None:
            if seq is None:
                return None
            if len(seq) != len(blocks):
                raise DatasetError(f"{name}: expected {len(blocks)} trajectories, got {len(seq)}")
            parts = []
            for i, s in enumerate(seq):
                a = _as_float_2d(f"{name}: trajectory {i}", s)
                if a.shape[0] != lengths[i]:
                    raise DatasetError(f"{name}: trajectory {i} must have {lengths[i]} rows, got shape {a.shape}")
                parts.append(a)
            return np.concatenate(parts, axis=0)

        return cls(
            features=np.concatenate(blocks, axis=0),
            offsets=offsets,
            group=np.asarray(group),
            states=stack("states", states),
            actions=stack("actions", actions),
            feature_names=feature_names if feature_names is not None else (),
            nominal_weights=nominal_weights,
            group_names=group_names if group_names is not None else (),
            gap_relation=gap_relation,
            skipped=skipped,
            env_id=env_id,
            allow_unlabelled=allow_unlabelled,
        )

    # ------------------------------------------------------------------ properties
    @property
    def n_trajectories(self) -> int:
        """Number of trajectories ``N``."""
        return int(self.offsets.size - 1)

    @property
    def n_features(self) -> int:
        """Number of features ``d``."""
        return int(self.features.shape[1])

    @property
    def lengths(self) -> NDArray[np.int64]:
        """Trajectory lengths ``T_i``, shape (N,)."""
        return np.diff(self.offsets)

    @property
    def group_labels(self) -> NDArray[np.int64]:
        """Distinct labels of the non-empty groups in preference order (best first), shape (K,); never 0."""
        return np.unique(self.group[self.group > 0])

    @property
    def n_groups(self) -> int:
        """Number of non-empty groups ``K``."""
        return int(self.group_labels.size)

    @property
    def defined_groups(self) -> tuple[int, ...]:
        """Labels of the groups the dataset defines, best first: the non-empty ones, and in a labelling file
        whose :attr:`group_names` name empty groups too, ``1 .. len(group_names)``. :attr:`gap_relation` has
        one value per consecutive pair of them."""
        return self._defined  # type: ignore[attr-defined]

    @property
    def n_unlabelled(self) -> int:
        """Trajectories with group 0 (skipped ones included)."""
        return int(np.sum(self.group == 0))

    def group_name(self, label: int) -> str:
        """The name of group ``label`` (from :attr:`group_names`), else ``"G<label>"``; 0 is ``"unlabelled"``."""
        if int(label) == 0 and self.allow_unlabelled:
            return "unlabelled"
        labels = list(self.defined_groups)
        if int(label) not in labels:
            raise DatasetError(f"group: no group with label {label}; labels are {labels}")
        return self.group_names[labels.index(int(label))] if self.group_names else f"G{int(label)}"

    @cached_property
    def mean_features(self) -> NDArray[np.float64]:
        """Length-normalised feature sums :math:`\\frac{1}{T_i}\\sum_{s\\in\\tau_i}\\phi(s)`, shape (N, d)."""
        sums = np.add.reduceat(self.features, self.offsets[:-1], axis=0)
        return sums / self.lengths[:, None]

    def trajectory(self, i: int) -> NDArray[np.float64]:
        """Features of trajectory ``i``, shape (T_i, d)."""
        return self.features[self.offsets[i]:self.offsets[i + 1]]

    def trajectory_states(self, i: int) -> NDArray[np.float64]:
        """States of trajectory ``i``, shape (T_i, k)."""
        if self.states is None:
            raise DatasetError("states: this dataset has no states")
        return self.states[self.offsets[i]:self.offsets[i + 1]]

    def group_counts(self) -> dict[int, int]:
        """Number of trajectories per group label (0 = unlabelled, when there are any)."""
        labels, counts = np.unique(self.group, return_counts=True)
        return {int(k): int(c) for k, c in zip(labels, counts)}

    # ------------------------------------------------------------------ selection
    def subset(self, indices: ArrayLike) -> "Dataset":
        """Dataset of the trajectories ``indices`` (in that order)."""
        idx = np.asarray(indices, dtype=np.int64).reshape(-1)
        if idx.size == 0:
            raise DatasetError("subset: no trajectories selected")
        if idx.min() < 0 or idx.max() >= self.n_trajectories:
            raise DatasetError(f"subset: indices must lie in [0, {self.n_trajectories})")
        return self._take(idx, strict=False)

    def labelled(self) -> "Dataset":
        """The labelled trajectories (group >= 1) as a dataset that inference accepts.

        Skipped and unlabelled trajectories are dropped, so are empty groups: their names go, and
        :attr:`gap_relation` is merged over them (gaps add up: the gap between groups 1 and 3 is the sum of
        the two gaps between them).

        Raises
        ------
        DatasetError
            Fewer than two non-empty groups.
        """
        idx = np.flatnonzero(self.group > 0)
        if self.n_groups < 2:
            names = ", ".join(self.group_name(k) for k in self.group_labels.tolist()) or "none"
            raise DatasetError(f"group: inference needs at least two non-empty groups; {idx.size} labelled "
                               f"trajectories in {self.n_groups} group(s) ({names})")
        return self._take(idx, strict=True)

    def _take(self, idx: NDArray[np.int64], *, strict: bool) -> "Dataset":
        """Trajectories ``idx``; ``strict`` drops the allowance for unlabelled ones (and empty groups)."""
        rows = np.concatenate([np.arange(self.offsets[i], self.offsets[i + 1]) for i in idx])
        lengths = self.lengths[idx]
        group = self.group[idx]
        defined = list(self.defined_groups)
        keep_all = self.allow_unlabelled and not strict and len(defined) > self.n_groups
        kept = defined if keep_all else [k for k in np.unique(group[group > 0]).tolist()]
        names = tuple(self.group_name(k) for k in kept) if self.group_names else ()
        rel = None
        if self.gap_relation is not None and len(kept) >= 2:
            cum = np.concatenate([[0.0], np.cumsum(self.gap_relation)])
            rel = np.diff(cum[[defined.index(k) for k in kept]])
        return Dataset(
            features=self.features[rows],
            offsets=np.concatenate([[0], np.cumsum(lengths)]),
            group=group,
            states=None if self.states is None else self.states[rows],
            actions=None if self.actions is None else self.actions[rows],
            feature_names=self.feature_names,
            nominal_weights=self.nominal_weights,
            group_names=names,
            gap_relation=rel,
            skipped=None if strict else self.skipped[idx],
            env_id=self.env_id,
            allow_unlabelled=self.allow_unlabelled and not strict,
        )

    def as_pool(self, n: int | None = None, *, seed: int | np.random.Generator = 0) -> "Dataset":
        """An unlabelled pool for ``pbicrl label``: ``n`` trajectories drawn without replacement (all of them when
        ``n`` is None or at least the number of trajectories), every group set to 0 (unlabelled).

        States, actions, features, nominal weights and ``env_id`` are kept (so the labelling page draws the
        environment: goal, regions, walls); group names, the gap relation and skips are not. ``pbicrl pool DATA
        --n 40 --out pool.npz`` on the command line.

        Raises
        ------
        DatasetError
            ``n`` is not a positive integer.
        """
        N = self.n_trajectories
        if n is not None and (isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1):
            raise DatasetError(f"n: expected a positive number of trajectories, got {n!r}")
        rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
        idx = np.arange(N) if n is None or n >= N else np.sort(rng.choice(N, size=int(n), replace=False))
        part = self._take(idx, strict=True)
        return Dataset(part.features, part.offsets, np.zeros(idx.size, dtype=np.int64), part.states, part.actions,
                       part.feature_names, part.nominal_weights, env_id=part.env_id, allow_unlabelled=True)

    def sample_per_group(self, n: int, seed: int | np.random.Generator | None = 0) -> "Dataset":
        """Draw ``n`` trajectories from every group without replacement (all if a group has fewer)."""
        if n < 1:
            raise DatasetError(f"sample_per_group: n must be >= 1, got {n}")
        rng = np.random.default_rng(seed)
        picks = []
        for k in self.group_labels:
            members = np.flatnonzero(self.group == k)
            take = members if members.size <= n else np.sort(rng.choice(members, size=n, replace=False))
            picks.append(take)
        return self.subset(np.concatenate(picks))

    def with_nominal_weights(self, nominal_weights: ArrayLike) -> "Dataset":
        """Copy with other nominal weights :math:`w_n`."""
        return dataclasses.replace(self, nominal_weights=np.asarray(nominal_weights, dtype=np.float64))

    # ------------------------------------------------------------------ I/O
    def save(self, path: str | os.PathLike[str], *, compress: bool = True, overwrite: bool = True) -> Path:
        """Write the dataset to ``path`` (``.npz``) atomically: a crash never leaves a partial file.

        Parameters
        ----------
        path : path
            ``.npz`` is appended if the name has another suffix or none.
        compress : bool
        overwrite : bool
            Replace an existing file. With False an existing file is an error, also one that appears
            while this one is being written (the final step cannot replace it).

        Raises
        ------
        OutputExistsError
            ``path`` exists and ``overwrite`` is false (a :class:`FileExistsError`).
        DatasetError
            ``path`` is a directory.
        """
        path = Path(path)
        if path.suffix != ".npz":
            path = path.with_suffix(path.suffix + ".npz") if path.suffix else path.with_suffix(".npz")
        if path.is_dir():
            raise DatasetError(f"path: {path} is a directory; give a file name such as {path / 'demos.npz'}")
        if path.exists() and not overwrite:
            raise OutputExistsError("path", path, "file")
        arrays = self.to_arrays()
        path.parent.mkdir(parents=True, exist_ok=True)
        clean_stale_temporaries(path)
        with atomic_path(path, overwrite=overwrite, field="path") as tmp:
            (np.savez_compressed if compress else np.savez)(tmp, **arrays)
        return path

    def to_arrays(self) -> dict[str, NDArray]:
        """The fields :meth:`save` writes, by name (the ``.npz`` layout of the module docstring)."""
        arrays: dict[str, NDArray] = {
            "features": self.features, "offsets": self.offsets, "group": self.group,
            "feature_names": np.array(self.feature_names, dtype=np.str_),
        }
        if self.states is not None:
            arrays["states"] = self.states
        if self.actions is not None:
            arrays["actions"] = self.actions
        if self.nominal_weights is not None:
            arrays["nominal_weights"] = self.nominal_weights
        if self.group_names:
            arrays["group_names"] = np.array(self.group_names, dtype=np.str_)
        if self.gap_relation is not None:
            arrays["gap_relation"] = self.gap_relation
        if self.skipped is not None and self.skipped.any():
            arrays["skipped"] = self.skipped
        if self.env_id is not None:
            arrays["env_id"] = np.array(self.env_id, dtype=np.str_)
        return arrays

    def content_hash(self) -> str:
        """SHA-256 (hex) of what the likelihood reads: features, offsets, groups, states, feature names and
        nominal weights (not group names, ``env_id`` or the labelling fields).

        A run records it (``extra.data.sha256``) so that an export can tell the run's dataset from another one.
        """
        import hashlib

        h = hashlib.sha256()
        for key in ("features", "offsets", "group", "states", "nominal_weights"):
            v = getattr(self, key)
            if v is None:
                h.update(f"{key}:none;".encode())
                continue
            a = np.ascontiguousarray(v, dtype=np.float64 if v.dtype.kind == "f" else np.int64)
            h.update(f"{key}:{a.dtype.str}:{a.shape};".encode())
            h.update(a.tobytes())
        h.update(("feature_names:" + "\x1f".join(self.feature_names)).encode("utf-8"))
        return h.hexdigest()

    @property
    def source(self) -> Path | None:
        """The file this dataset was read from (:meth:`load`, :func:`load_dataset`), or None if built in memory."""
        return getattr(self, "_source", None)

    @classmethod
    def load(cls, path: str | os.PathLike[str], *, allow_unlabelled: bool = False) -> "Dataset":
        """Read and validate a dataset file written by :meth:`save` (or by hand, see module docs).

        Only a path: :func:`load_dataset` also takes the names of shipped datasets. ``allow_unlabelled``
        accepts group 0 (a pool, or a labelling session in progress; see :class:`Dataset`).

        Raises
        ------
        DatasetNotFoundError
            No such file.
        DatasetError
            Not a regular file, not an ``.npz`` archive, an array header that declares more data than the
            file holds or than fits in memory, pickled objects, a missing or invalid field.
        """
        path = Path(path)
        content, unknown = _read_npz(path, _FIELDS, what="dataset")
        missing = [k for k in _REQUIRED if k not in content]
        if missing:
            raise DatasetError(f"{path}: missing required field(s) {', '.join(missing)}")
        if unknown:
            from pbicrl.errors import warn

            warn(f"{path}: ignored unknown field(s) {', '.join(repr(k) for k in unknown)}; the fields of a dataset "
                 f"are {', '.join(_FIELDS)}")
        try:
            ds = cls(
                features=content["features"],
                offsets=content["offsets"],
                group=content["group"],
                states=content.get("states"),
                actions=content.get("actions"),
                feature_names=content.get("feature_names", ()),
                nominal_weights=content.get("nominal_weights"),
                group_names=content.get("group_names", ()),
                gap_relation=content.get("gap_relation"),
                skipped=content.get("skipped"),
                env_id=content.get("env_id"),
                allow_unlabelled=allow_unlabelled,
            )
        except DatasetError as exc:
            raise DatasetError(f"{path}: {exc}") from None
        if ds.env_id is None and path.stem in SHIPPED_ENV_IDS and path.resolve().parent == shipped_dir().resolve():
            # shipped files predate the env_id field; rewriting them would change every shipped-data tag
            ds = dataclasses.replace(ds, env_id=SHIPPED_ENV_IDS[path.stem])
        object.__setattr__(ds, "_source", path.resolve())  # runs record it (not a field: copies are other data)
        return ds

    def __repr__(self) -> str:
        counts = ", ".join(("unlabelled" if k == 0 else f"G{k}{' ' + repr(self.group_name(k)) if self.group_names else ''}")
                           + f": {c}" for k, c in self.group_counts().items())
        more = ""
        if self.skipped is not None and self.skipped.any():
            more += f", skipped={int(self.skipped.sum())}"
        if self.gap_relation is not None:
            more += f", gap_relation={self.gap_relation.tolist()}"
        if self.env_id is not None:
            more += f", env_id={self.env_id!r}"
        return (f"Dataset(N={self.n_trajectories}, d={self.n_features}, states={self.lengths.sum()}, "
                f"groups={{{counts}}}, features={list(self.feature_names)}{more})")


def load_dataset(name_or_path: str | os.PathLike[str], *, allow_unlabelled: bool = False) -> Dataset:
    """Read a dataset: a ``.npz`` file (see :class:`Dataset`) or the name of a shipped one.

    Parameters
    ----------
    name_or_path : str or path
        ``"demos.npz"``, or a shipped dataset such as ``"point_mass"`` (:func:`list_shipped_datasets`);
        see :func:`resolve_dataset_path`.
    allow_unlabelled : bool
        Accept trajectories with group 0 (unlabelled) and fewer than two groups: a pool of demonstrations
        to rank or a labelling file in progress (``pbicrl label``). Inference refuses them; keep the labelled
        trajectories with :meth:`Dataset.labelled`.
    """
    return Dataset.load(resolve_dataset_path(name_or_path), allow_unlabelled=allow_unlabelled)
