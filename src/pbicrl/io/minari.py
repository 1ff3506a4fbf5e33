"""Import trajectories from a local Minari dataset with a user-supplied feature function.

Minari (``pip install "minari[hdf5]"``; recording new datasets with ``minari.DataCollector`` also needs
``pip install "minari[create]"``, both in ``pip install "pbicrl[minari]"``) stores episodes (observations,
actions, rewards, infos) but no
preference labels and no features, so the user supplies both:

* ``feature_fn(episode) -> array (T_i, d)``: per-state features :math:`\\phi(s)` of one episode (a Minari
  ``EpisodeData`` with ``observations``, ``actions``, ``rewards``, ``infos``, ``id``);
* ``groups``: a callable ``episode -> int``, a mapping ``{episode id: group}``, or a sequence with one label per
  episode (1 = best).

Datasets written by pbicrl itself (:func:`pbicrl.envs.minari_io.episodes_to_minari`) carry
``infos["features"]`` and ``infos["group"]``; both are used when ``feature_fn`` / ``groups`` are not given.
Nothing is downloaded: datasets are read from ``root`` (or Minari's default directory). Observations are kept as
states and actions as actions, aligned with the feature rows (see :func:`from_minari`).
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np
from numpy.typing import ArrayLike

from pbicrl.inference.data import Dataset, DatasetError

__all__ = ["from_minari", "load_feature_function", "load_minari", "require_minari", "datasets_root", "MINARI_HINT",
           "MINARI_CREATE_HINT"]

MINARI_HINT = 'pip install "minari[hdf5]"'
"""Reading and writing Minari datasets (HDF5 storage)."""
MINARI_CREATE_HINT = 'pip install "minari[create]"'
"""Recording datasets with ``minari.DataCollector`` (it needs JAX)."""


def require_minari() -> Any:
    """Import minari (with its HDF5 storage) or raise an ImportError naming the pip command.

    Cheap and side-effect free: call it before running any user code that only makes sense with minari.
    """
    try:
        import minari
    except ImportError as exc:
        raise ImportError(f"Minari datasets need minari ({exc}): {MINARI_HINT} (or pip install \"pbicrl[minari]\"; "
                          f"recording new datasets with minari.DataCollector also needs {MINARI_CREATE_HINT})") from exc
    try:
        import h5py  # noqa: F401  (minari's default storage; without it every read fails deep inside minari)
    except ImportError as exc:
        raise ImportError(f"Minari datasets are stored in HDF5, which needs h5py ({exc}): {MINARI_HINT}") from exc
    return minari


@contextlib.contextmanager
def datasets_root(root: str | os.PathLike | None) -> Iterator[None]:
    """Point Minari at ``root`` for the duration of the block."""
    if root is None:
        yield
        return
    old = os.environ.get("MINARI_DATASETS_PATH")
    os.environ["MINARI_DATASETS_PATH"] = str(Path(root).resolve())
    try:
        yield
    finally:
        if old is None:
            os.environ.pop("MINARI_DATASETS_PATH", None)
        else:
            os.environ["MINARI_DATASETS_PATH"] = old


def load_minari(dataset_id: str, root: str | os.PathLike | None = None) -> Any:
    """Load a local Minari dataset (never downloads).

    Raises
    ------
    FileNotFoundError
        ``root`` is not a directory, or there is no dataset ``dataset_id`` in it; the message lists the local
        datasets (Minari's own would suggest ``download=True``, which pbicrl never does).
    ValueError
        A malformed id or an unreadable dataset.
    """
    minari = require_minari()
    if root is not None and not Path(root).is_dir():
        # Minari would create the directory; a typo must not leave an empty tree behind
        raise FileNotFoundError(f"root: {root}: no such directory (the directory holding Minari datasets)")
    if not isinstance(dataset_id, str) or not dataset_id.strip():
        raise ValueError(f"dataset_id: expected a Minari dataset id such as 'namespace/name-v0', got {dataset_id!r}")
    with datasets_root(root):
        from minari.storage import get_dataset_path

        where = Path(get_dataset_path(""))
        path = Path(get_dataset_path(dataset_id))
        if not (path / "data").is_dir():
            local = _local_ids(minari)
            listed = (", ".join(local[:10]) + (", ..." if len(local) > 10 else "")) if local else "none"
            raise FileNotFoundError(
                f"dataset_id: no Minari dataset {dataset_id!r} in {where} (local datasets: {listed}); pbicrl reads "
                "local datasets only: pass --root DIR (root=) or set MINARI_DATASETS_PATH, or download it "
                "first with Minari itself (minari download ID)")
        try:
            return minari.load_dataset(dataset_id, download=False)
        except FileNotFoundError as exc:
            raise FileNotFoundError(f"dataset_id: {dataset_id!r} in {where} is incomplete ({exc})") from None
        except (ValueError, KeyError, OSError) as exc:
            raise ValueError(f"dataset_id: {dataset_id!r} in {where} cannot be read "
                             f"({type(exc).__name__}: {exc})") from None


def _local_ids(minari: Any) -> list[str]:
    try:
        return sorted(minari.list_local_datasets())
    except Exception:  # a damaged dataset elsewhere in the directory must not hide the real message
        return []


FeatureFn = Callable[[Any], ArrayLike]


def _episode_group(ep: Any, k: int, groups: Any) -> int:
    if groups is None:
        infos = getattr(ep, "infos", None) or {}
        if "group" not in infos:
            raise DatasetError(f"groups: episode {ep.id} has no infos['group']; pass groups= (a function of the "
                               "episode, a mapping {episode id: group} or one label per episode)")
        g = np.asarray(infos["group"]).reshape(-1)[0]
    elif callable(groups):
        g = groups(ep)
    elif isinstance(groups, Mapping):
        if ep.id not in groups and str(ep.id) not in groups:
            raise DatasetError(f"groups: no label for episode {ep.id}")
        g = groups[ep.id] if ep.id in groups else groups[str(ep.id)]
    else:
        if k >= len(groups):
            raise DatasetError(f"groups: {len(groups)} labels for more episodes (episode index {k})")
        g = groups[k]
    try:
        gi = int(g)
    except (TypeError, ValueError):
        raise DatasetError(f"groups: episode {ep.id}: label {g!r} is not an integer") from None
    if gi != g or gi < 1:
        raise DatasetError(f"groups: episode {ep.id}: labels must be positive integers (1 = best), got {g!r}")
    return gi


def _episode_features(ep: Any, feature_fn: FeatureFn | None) -> np.ndarray:
    if feature_fn is None:
        infos = getattr(ep, "infos", None) or {}
        if "features" not in infos:
            raise DatasetError(f"feature_fn: episode {ep.id} has no infos['features']; pass a feature function "
                               "feature_fn(episode) -> array (T, d)")
        raw = infos["features"]
    else:
        raw = feature_fn(ep)
    try:
        f = np.asarray(raw, dtype=np.float64)
    except (TypeError, ValueError):
        raise DatasetError(f"feature_fn: episode {ep.id}: features are not numeric") from None
    if f.ndim == 1:
        f = f[:, None]
    if f.ndim != 2 or f.shape[0] == 0:
        raise DatasetError(f"feature_fn: episode {ep.id}: expected an array (T, d) with T >= 1, got shape {f.shape}")
    if not np.all(np.isfinite(f)):
        raise DatasetError(f"feature_fn: episode {ep.id}: features contain NaN or inf")
    return f


def _episode_states(ep: Any, T: int) -> np.ndarray | None:
    obs = getattr(ep, "observations", None)
    if obs is None or isinstance(obs, (dict, tuple)):
        return None  # structured observations: no flat state vector
    s = np.asarray(obs, dtype=np.float64)
    s = s.reshape(s.shape[0], -1) if s.ndim != 2 else s
    if s.shape[0] == T:
        return s
    if s.shape[0] == T + 1:
        return s[:-1]  # features per step, observations include the final state
    raise DatasetError(f"feature_fn: episode {ep.id}: {T} feature rows but {s.shape[0]} observations; return one "
                       "row per observation (or per step), or pass states=False")


def _episode_actions(ep: Any, T: int) -> np.ndarray | None:
    act = getattr(ep, "actions", None)
    if act is None or isinstance(act, (dict, tuple)):
        return None  # structured action spaces: no flat action vector
    try:
        a = np.asarray(act, dtype=np.float64)
    except (TypeError, ValueError):
        return None
    if a.ndim == 0 or a.shape[0] == 0:
        return None
    a = a.reshape(a.shape[0], -1)
    if a.shape[0] == T:
        return a
    if a.shape[0] == T - 1:
        # one feature row per observation: the final observation follows the last action, so it has none
        return np.concatenate([a, np.zeros((1, a.shape[1]))], axis=0)
    raise DatasetError(f"feature_fn: episode {ep.id}: {T} feature rows but {a.shape[0]} actions; return one row per "
                       "step or per observation, or pass actions=False")


def from_minari(
    dataset: Any,
    feature_fn: FeatureFn | None = None,
    *,
    groups: Callable[[Any], int] | Mapping[Any, int] | Sequence[int] | None = None,
    root: str | os.PathLike[str] | None = None,
    feature_names: Sequence[str] | None = None,
    nominal_weights: ArrayLike | None = None,
    states: bool = True,
    actions: bool = True,
    episode_indices: Sequence[int] | None = None,
) -> Dataset:
    """Convert a Minari dataset into a :class:`Dataset`.

    Parameters
    ----------
    dataset : MinariDataset or str
        A loaded dataset or its id (read from ``root``; never downloaded).
    feature_fn : callable, optional
        ``feature_fn(episode) -> (T_i, d)`` per-state features; default ``episode.infos["features"]``.
    groups : callable, mapping or sequence, optional
        Group label per episode; default ``episode.infos["group"]``.
    root : path, optional
        Directory holding Minari datasets (default: Minari's).
    feature_names, nominal_weights : optional
        Stored in the dataset.
    states : bool
        Keep the (flat) observations as states, aligned with the feature rows.
    actions : bool
        Keep the (flat) actions, aligned with the feature rows: with one feature row per step they match
        one to one; with one per observation (T+1 rows) the final observation, which no action follows,
        gets a row of zeros.
    episode_indices : sequence of int, optional
        Only these episodes (Minari indices).

    Raises
    ------
    ImportError
        Without minari (the message names the pip command).
    DatasetError
        With the episode id, for missing labels or features, bad shapes or a single group.
    """
    require_minari()
    if isinstance(dataset, (str, os.PathLike)):
        dataset = load_minari(str(dataset), root)
    if feature_fn is not None and not callable(feature_fn):
        raise TypeError(f"feature_fn: expected a callable episode -> (T, d) array, got {type(feature_fn).__name__}")
    episodes = dataset.iterate_episodes(episode_indices) if episode_indices is not None else dataset.iterate_episodes()
    feats, labels, st, acts = [], [], [], []
    for k, ep in enumerate(episodes):
        f = _episode_features(ep, feature_fn)
        if feats and f.shape[1] != feats[0].shape[1]:
            raise DatasetError(f"feature_fn: episode {ep.id} has {f.shape[1]} features, the first episode has "
                               f"{feats[0].shape[1]}")
        feats.append(f)
        labels.append(_episode_group(ep, k, groups))
        if states:
            st.append(_episode_states(ep, f.shape[0]))
        if actions:
            acts.append(_episode_actions(ep, f.shape[0]))
    if not feats:
        raise DatasetError("dataset: no episodes")
    keep_states = states and all(s is not None for s in st)
    keep_actions = actions and all(a is not None for a in acts) and len({a.shape[1] for a in acts}) == 1
    return Dataset.from_trajectories(feats, np.asarray(labels), states=st if keep_states else None,
                                     actions=acts if keep_actions else None,
                                     feature_names=feature_names, nominal_weights=nominal_weights)


def load_feature_function(spec: str, *, option: str = "--features") -> FeatureFn:
    """``"package.module:function"`` or ``"path/to/file.py:function"`` -> the function (for the CLI).

    A module is looked up in the working directory first, then among installed packages, as
    ``python -m`` would: ``--features feats:features`` finds ``./feats.py``.

    Parameters
    ----------
    spec : str
    option : str
        The command-line option the spec came from, for messages.

    Raises
    ------
    ValueError, FileNotFoundError, ImportError
        Naming ``option``: a malformed spec, a missing file or module, no such function.
    """
    import importlib
    import importlib.util
    import sys
    from pathlib import Path

    if not isinstance(spec, str) or ":" not in spec:
        raise ValueError(f"{option}: expected 'module:function' or 'file.py:function', got {spec!r}")
    mod_name, _, fn_name = spec.rpartition(":")
    if not mod_name or not fn_name.isidentifier():
        raise ValueError(f"{option}: expected 'module:function' or 'file.py:function', got {spec!r}")
    if mod_name.endswith(".py"):
        path = Path(mod_name)
        if not path.is_file():
            raise FileNotFoundError(f"{option}: {path}: no such file")
        module_spec = importlib.util.spec_from_file_location(path.stem, path)
        if module_spec is None or module_spec.loader is None:
            raise ValueError(f"{option}: cannot import {path}")
        module = importlib.util.module_from_spec(module_spec)
        module_spec.loader.exec_module(module)
    else:
        # The `pbicrl` console script runs with its own directory on sys.path, not the working directory
        # that `python -m` or `python -c` would put first; add it for this import only.
        cwd = os.getcwd()
        added = cwd not in sys.path
        if added:
            sys.path.insert(0, cwd)
        try:
            module = importlib.import_module(mod_name)
        except ImportError as exc:
            raise ImportError(f"{option}: cannot import module {mod_name!r} ({exc}); give a module in the working "
                              f"directory ({cwd}) or an installed one, or a file: {option} path/to/file.py:{fn_name}"
                              ) from exc
        finally:
            if added:
                try:
                    sys.path.remove(cwd)
                except ValueError:
                    pass
    fn = getattr(module, fn_name, None)
    if not callable(fn):
        raise ValueError(f"{option}: {mod_name} has no function {fn_name!r}")
    return fn
