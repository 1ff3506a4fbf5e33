"""Write and read ranked navigation demonstrations as Minari datasets (offline).

Minari (``pip install "pbicrl[minari]"``, i.e. ``"minari[hdf5,create]"``) stores episodes with
observations ``s_0..s_T``,
actions, rewards, terminations and truncations.  pbicrl adds two per-step ``infos``
entries: ``"features"`` (T+1, d) and ``"group"`` (T+1,) -- the episode's group label
repeated, since Minari has no per-episode fields.  :func:`minari_to_dataset` converts a
Minari dataset back into a :class:`pbicrl.inference.data.Dataset` (deprecated: reading and converting Minari
datasets is :mod:`pbicrl.io.minari`, :func:`~pbicrl.io.minari.load_minari` and :func:`~pbicrl.io.minari.from_minari`,
re-exported here).

Everything is local: datasets live under ``root`` (or ``$MINARI_DATASETS_PATH``, else
``~/.minari/datasets``) and nothing is downloaded.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from pbicrl.errors import warn
from pbicrl.inference.data import Dataset
from pbicrl.io.minari import (MINARI_CREATE_HINT, MINARI_HINT, datasets_root, from_minari, load_minari,
                               require_minari)

__all__ = ["episodes_to_minari", "load_minari", "minari_to_dataset", "require_minari", "require_minari_create",
           "MINARI_HINT", "MINARI_CREATE_HINT"]


def require_minari_create() -> Any:
    """:func:`require_minari`, plus what ``minari.DataCollector`` needs to record episodes (``minari[create]``)."""
    minari = require_minari()
    try:
        import jax.tree_util  # noqa: F401  (DataCollector's episode buffers use it)
    except ImportError as exc:
        raise ImportError(f"recording Minari datasets (minari.DataCollector) needs JAX ({exc}): {MINARI_CREATE_HINT}"
                          ) from exc
    return minari


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
    with datasets_root(root):
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


def minari_to_dataset(dataset: Any, root: str | os.PathLike | None = None, *,
                      feature_names: Sequence[str] | None = None, nominal_weights: Any = None) -> Dataset:
    """Deprecated (until pbicrl 0.3): :func:`pbicrl.io.minari.from_minari`, the one Minari converter, with
    ``actions=False`` (what this function returned)."""
    warn("pbicrl.envs.minari_io.minari_to_dataset is deprecated and will be removed in pbicrl 0.3: use "
         "pbicrl.io.minari.from_minari (the same conversion; actions=False for the same fields)", stacklevel=2)
    return from_minari(dataset, root=root, feature_names=feature_names, nominal_weights=nominal_weights,
                       actions=False)
