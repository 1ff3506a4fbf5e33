"""Write and read ranked navigation demonstrations as Minari datasets (offline).

Minari (``pip install "pbicrl[minari]"``, i.e. ``"minari[hdf5,create]"``) stores episodes with
observations ``s_0..s_T``,
actions, rewards, terminations and truncations.  pbicrl adds two per-step ``infos``
entries: ``"features"`` (T+1, d) and ``"group"`` (T+1,) -- the episode's group label
repeated, since Minari has no per-episode fields.  :func:`minari_to_dataset` converts a
Minari dataset back into a :class:`pbicrl.inference.data.Dataset`.

Everything is local: datasets live under ``root`` (or ``$MINARI_DATASETS_PATH``, else
``~/.minari/datasets``) and nothing is downloaded.
"""

from __future__ import annotations

import contextlib
import os
import warnings
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from pbicrl.inference.data import Dataset

__all__ = ["episodes_to_minari", "load_minari", "minari_to_dataset", "require_minari", "require_minari_create",
           "MINARI_HINT", "MINARI_CREATE_HINT"]

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


def require_minari_create() -> Any:
    """:func:`require_minari`, plus what ``minari.DataCollector`` needs to record episodes (``minari[create]``)."""
    minari = require_minari()
    try:
        import jax.tree_util  # noqa: F401  (DataCollector's episode buffers use it)
    except ImportError as exc:
        raise ImportError(f"recording Minari datasets (minari.DataCollector) needs JAX ({exc}): {MINARI_CREATE_HINT}"
                          ) from exc
    return minari


@contextlib.contextmanager
def _datasets_root(root: str | os.PathLike | None) -> Iterator[None]:
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


def episodes_to_minari(episodes: Sequence[Any], dataset_id: str, *, env: Any, root: str | os.PathLike | None = None,
                       description: str | None = None, overwrite: bool = False) -> Path:
    """Write rollouts (:class:`pbicrl.demonstrators.navigation.Episode`) as a Minari dataset.

    Parameters
    ----------
    episodes : sequence of Episode
        Each with ``states`` (T+1, k), ``actions`` (T, a), ``rewards`` (T,), ``features``
        (T+1, d), ``reached``, ``truncated``, ``group`` and ``seed``.
    dataset_id : str
        Minari id, e.g. ``"pbicrl/point_mass/ranked-v0"``.
    env : gymnasium.Env
        The environment (its spaces and spec are recorded).
    root : path, optional
        Directory that holds Minari datasets (default: Minari's own).
    overwrite : bool
        Replace an existing dataset with this id.

    Returns
    -------
    pathlib.Path
        The dataset directory.
    """
    minari = require_minari()
    from minari.data_collector.episode_buffer import EpisodeBuffer

    if not episodes:
        raise ValueError("episodes: nothing to write")
    buffers = []
    for i, ep in enumerate(episodes):
        T = len(ep.rewards)
        if ep.states.shape[0] != T + 1 or ep.actions.shape[0] != T:
            raise ValueError(f"episodes[{i}]: need T+1 states and T actions, got {ep.states.shape[0]} and {ep.actions.shape[0]}")
        term = np.zeros(T, dtype=bool)
        trunc = np.zeros(T, dtype=bool)
        term[-1], trunc[-1] = bool(ep.reached), bool(ep.truncated)
        buffers.append(EpisodeBuffer(
            id=i, seed=int(ep.seed),
            observations=ep.states.astype(np.float32), actions=ep.actions.astype(np.float32),
            rewards=list(np.asarray(ep.rewards, dtype=np.float64)), terminations=list(term), truncations=list(trunc),
            infos={"features": np.asarray(ep.features, dtype=np.float64),
                   "group": np.full(T + 1, int(ep.group), dtype=np.int64)},
        ))
    with _datasets_root(root):
        from minari.storage import get_dataset_path

        path = Path(get_dataset_path(dataset_id))
        if path.exists():
            if not overwrite:
                raise FileExistsError(f"dataset_id: Minari dataset {dataset_id!r} already exists at {path} "
                                      "(pass overwrite=True / --overwrite)")
            minari.delete_dataset(dataset_id)
        spec = getattr(env, "spec", None)
        with warnings.catch_warnings():
            # Minari nags about optional metadata (permalink, e-mail, eval env) on every write.
            warnings.filterwarnings("ignore", message=r"`(code_permalink|author_email|eval_env)` is set to None")
            _create(minari, dataset_id, buffers, env, spec, description)
    return path


def _create(minari: Any, dataset_id: str, buffers: list, env: Any, spec: Any, description: str | None) -> None:
    minari.create_dataset_from_buffers(
        dataset_id, buffers, env=spec,
        observation_space=env.observation_space, action_space=env.action_space,
        algorithm_name="SAC (Stable-Baselines3), pbicrl demonstrators", author="pbicrl",
        description=description or "Ranked demonstrations; infos['group'] is the group label (1 = best), "
                                   "infos['features'] the per-state features.",
    )


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
    with _datasets_root(root):
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


def minari_to_dataset(dataset: Any, root: str | os.PathLike | None = None, *,
                      feature_names: Sequence[str] | None = None, nominal_weights: Any = None) -> Dataset:
    """Convert a Minari dataset written by :func:`episodes_to_minari` into a :class:`Dataset`.

    Parameters
    ----------
    dataset : MinariDataset or str
        A loaded dataset or its id (loaded from ``root``).
    feature_names, nominal_weights : optional
        Stored in the returned dataset.

    Raises
    ------
    ValueError
        If an episode lacks ``infos['features']`` or ``infos['group']``.
    """
    if isinstance(dataset, str):
        dataset = load_minari(dataset, root)
    feats, groups, states = [], [], []
    for ep in dataset.iterate_episodes():
        infos = ep.infos or {}
        if "features" not in infos or "group" not in infos:
            raise ValueError(f"episode {ep.id}: infos must hold 'features' and 'group' (written by episodes_to_minari)")
        feats.append(np.asarray(infos["features"], dtype=np.float64))
        groups.append(int(np.asarray(infos["group"]).reshape(-1)[0]))
        states.append(np.asarray(ep.observations, dtype=np.float64))
    return Dataset.from_trajectories(feats, groups, states=states, feature_names=feature_names,
                                     nominal_weights=nominal_weights)
