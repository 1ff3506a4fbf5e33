"""HalfCheetah / Ant wall demonstrators: training, demonstration datasets, figure.

* "good" demonstrator: SAC trained on the constrained reward (nominal reward plus
  the wall penalty), so it learns to stop before the wall;
* "violating" demonstrator: SAC trained on the nominal reward only, so it runs
  through the wall.

Demonstration datasets (:class:`pbicrl.inference.data.Dataset`) have

* ``features`` (d = 2): ``forward_displacement`` :math:`x_{t+1}-x_t` and
  ``action_sq_norm`` :math:`\\lVert a_t\\rVert^2`, ``nominal_weights`` = [20, -0.1];
* ``states`` (k = 1): the x-position reached after each step, :math:`x_{t+1}`
  (the coordinate the parametric axis-halfspace constraint acts on);
* ``actions``: the clipped actions applied;
* ``group``: 1 = good (every state below the wall), 2 = violating (crosses it).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from pbicrl._atomic import atomic_path
from pbicrl.errors import DemonstrationError

__all__ = ["MODES", "generate_wall_demos", "plot_wall_visitation", "train_wall_policy"]

MODES = ("good", "violating")


def _check_mode(mode: str) -> bool:
    if mode not in MODES:
        raise ValueError(f"mode: must be one of {MODES}, got {mode!r}")
    return mode == "good"


class _EnvFactory:
    """Picklable zero-argument env factory."""

    def __init__(self, name: str, constrained: bool, max_episode_steps: int, position_bonus: float = 0.0,
                 terminate_when_flipped: bool = False, reach_bonus: float = 0.0, start_spread: float = 0.0) -> None:
        self.name, self.constrained, self.max_episode_steps = name, constrained, max_episode_steps
        self.position_bonus = position_bonus
        self.reach_bonus = reach_bonus
        self.start_spread = start_spread
        self.terminate_when_flipped = terminate_when_flipped

    def __call__(self):
        from pbicrl.envs.mujoco_wall import make_wall_env

        return make_wall_env(self.name, constrained=self.constrained, max_episode_steps=self.max_episode_steps,
                             position_bonus=self.position_bonus, reach_bonus=self.reach_bonus,
                             start_spread=self.start_spread,
                             terminate_when_flipped=self.terminate_when_flipped)


def train_wall_policy(name: str, mode: str, total_steps: int, out_dir: str | os.PathLike, *,
                      seed: int = 0, max_episode_steps: int = 500, position_bonus: float = 0.0,
                      terminate_when_flipped: bool = False, reach_bonus: float = 0.0,
                      start_spread: float = 0.0, **sac_kwargs: Any) -> Path:
    """Train the good or violating demonstrator of a wall environment with :func:`train_sac`.

    Parameters
    ----------
    name : {"halfcheetah", "ant"}
    mode : {"good", "violating"}
    total_steps : int
    out_dir : path
        Run directory (resumable).
    seed : int
    max_episode_steps : int
        Training episode length (500, the demonstration length).
    position_bonus : float
        Training-only shaping for ``mode="good"``: ``position_bonus * min(x, wall)`` per step
        (see :class:`pbicrl.envs.mujoco_wall.WallPenaltyWrapper`); 0 is the paper's reward.
    terminate_when_flipped : bool
        Training-only: end an episode when the torso turns upside down (Ant only), as a fall
        ends it; False is the paper's (Gymnasium's) termination.
    reach_bonus : float
        Training-only shaping for ``mode="good"``: ``reach_bonus`` per step with x in
        ``[wall - 0.5, wall)``; 0 is the paper's reward.
    start_spread : float
        Training-only exploring starts: each training episode starts a uniform draw from
        ``[0, start_spread]`` further forward; 0 is Gymnasium's start (the demonstrations').
    **sac_kwargs
        Passed to :func:`pbicrl.demonstrators.sac.train_sac`.

    Returns
    -------
    pathlib.Path
        Path of the trained ``policy.zip``.
    """
    from pbicrl.demonstrators.sac import train_sac
    from pbicrl.envs.mujoco_wall import REACH_MARGIN, WALL_SPECS, wall_spec

    constrained = _check_mode(mode)
    spec = wall_spec(name)
    for opt, value in (("position_bonus", position_bonus), ("reach_bonus", reach_bonus),
                       ("start_spread", start_spread)):
        if not (np.isfinite(value) and value >= 0):
            raise ValueError(f"{opt}: must be a finite value >= 0, got {value!r}")
        if value and not constrained:
            raise ValueError(f"{opt}: only applies to mode='good' (the constrained reward)")
    if terminate_when_flipped and name.lower() != "ant":
        raise ValueError(f"terminate_when_flipped: only applies to env 'ant', got {name!r}")
    meta = {"env": name, "base_env_id": spec.env_id, "mode": mode, "constrained_reward": constrained,
            "wall_x": spec.wall_x, "penalty": spec.penalty, "alive_bonus": spec.alive_bonus,
            "make_kwargs": spec.make_kwargs, "max_episode_steps": max_episode_steps,
            "reward": "20*dx - 0.1*|a|^2" + (" + alive_bonus" if spec.alive_bonus else "")
                      + (f" + {spec.penalty} * [x >= {spec.wall_x}]" if constrained else "")
                      + (f" + {position_bonus} * min(x, {spec.wall_x})" if position_bonus else "")
                      + (f" + {reach_bonus} * [{spec.wall_x - REACH_MARGIN} <= x < {spec.wall_x}]"
                         if reach_bonus else ""),
            "position_bonus": float(position_bonus), "reach_bonus": float(reach_bonus),
            "start_spread": float(start_spread),
            "terminate_when_flipped": bool(terminate_when_flipped)}
    assert name.lower() in WALL_SPECS
    factory = _EnvFactory(name.lower(), constrained, max_episode_steps, float(position_bonus),
                          bool(terminate_when_flipped), float(reach_bonus), float(start_spread))
    return train_sac(factory, total_steps, out_dir,
                     seed=seed, metadata=meta, **sac_kwargs)


X_QUANTUM = 2.0 ** -16
ACTION_QUANTUM = 2.0 ** -10


def _quantize_rollout(ro: dict[str, Any]) -> dict[str, Any]:
    """Snap x and actions to binary grids and recompute the features from them."""
    xq = np.round(ro["x"] / X_QUANTUM) * X_QUANTUM
    x0q = float(np.round(float(ro["x0"]) / X_QUANTUM) * X_QUANTUM)
    aq = np.round(ro["actions"] / ACTION_QUANTUM) * ACTION_QUANTUM
    dx = np.diff(np.concatenate([[x0q], xq]))
    feats = np.column_stack([dx, np.sum(aq * aq, axis=1)])
    return {**ro, "x": xq, "x0": np.asarray(x0q), "actions": aq, "features": feats}


def generate_wall_demos(name: str, good_policy: str | os.PathLike, violating_policy: str | os.PathLike,
                        n_per_group: int, out_path: str | os.PathLike | None = None, *, seed: int = 0,
                        n_steps: int = 500, deterministic: bool = False, max_attempts_factor: int = 3,
                        quantize: bool = True) -> tuple[Any, dict[str, Any]]:
    """Roll out both demonstrators and build (and optionally save) a ranked dataset.

    Each rollout starts from a differently seeded reset (Gymnasium's initial-state
    noise) and, unless ``deterministic``, samples actions from the SAC policy.
    Good rollouts are kept only if every state stays below the wall and the episode
    lasts ``n_steps``; violating rollouts only if some state reaches the wall and the
    episode lasts ``n_steps``. Rejections are counted in the returned report, never hidden.

    Parameters
    ----------
    name : {"halfcheetah", "ant"}
    good_policy, violating_policy : path
        ``policy.zip`` files from :func:`train_wall_policy`.
    n_per_group : int
        Trajectories to keep per group.
    out_path : path, optional
        Where to save the dataset (compressed ``.npz``, atomic).
    seed : int
        Base seed; rollout ``j`` of group ``g`` resets with ``seed + 100000 * g + j``.
    n_steps : int
        Trajectory length.
    deterministic : bool
        Use the policy mean instead of sampling.
    max_attempts_factor : int
        Give up after ``max_attempts_factor * n_per_group`` attempts per group.
    quantize : bool
        Store x on a grid of 2**-16 m (~1.5e-5 m) and actions on a grid of 2**-10 (~1e-3),
        and recompute the features from the stored values (``forward_displacement`` =
        difference of consecutive stored x, starting from the stored initial x;
        ``action_sq_norm`` = squared norm of the stored action). The archive then
        compresses to about half the size and is exactly self-consistent; the change in
        the nominal return is below 20 * 1.5e-5 per step. The good/violating test uses
        the stored x.

    Returns
    -------
    (Dataset, dict)
        The dataset and a report (attempts, rejections, fraction of steps beyond the wall).

    Raises
    ------
    pbicrl.errors.DemonstrationError
        If a group cannot be filled within the attempt limit (with the counts).
    """
    import torch

    from pbicrl.inference.data import Dataset
    from pbicrl.demonstrators.sac import load_policy
    from pbicrl.envs.mujoco_wall import (
        FEATURE_NAMES,
        NOMINAL_WEIGHTS,
        wall_spec,
        make_wall_env,
        rollout_wall_env,
    )

    spec = wall_spec(name)
    if int(n_per_group) < 1:
        raise ValueError(f"n_per_group: must be >= 1, got {n_per_group}")
    torch.manual_seed(seed)
    feats, states, acts, groups = [], [], [], []
    report: dict[str, Any] = {"env": name, "wall_x": spec.wall_x, "n_steps": n_steps,
                              "deterministic": deterministic, "seed": seed, "quantize": quantize, "groups": {}}
    for g, (mode, pol_path) in enumerate((("good", good_policy), ("violating", violating_policy)), start=1):
        policy = load_policy(pol_path)
        env = make_wall_env(name, constrained=(mode == "good"), max_episode_steps=n_steps)

        def act(obs, _p=policy):
            a, _ = _p.predict(obs, deterministic=deterministic)
            return a

        kept = attempts = rej_len = rej_side = 0
        beyond = []
        max_x = []
        while kept < n_per_group:
            if attempts >= max_attempts_factor * n_per_group:
                env.close()
                raise DemonstrationError(
                    f"{name} {mode}: only {kept}/{n_per_group} acceptable rollouts in {attempts} attempts "
                    f"({rej_len} too short, {rej_side} on the wrong side of the wall); check that the {mode} policy "
                    f"does what its group needs, or raise --max-attempts-factor (now {max_attempts_factor:g})")
            ro = rollout_wall_env(env, act, seed=seed + 100_000 * g + attempts, n_steps=n_steps)
            attempts += 1
            if quantize:
                ro = _quantize_rollout(ro)
            if ro["x"].shape[0] != n_steps:
                rej_len += 1
                continue
            crosses = bool(np.any(ro["x"] >= spec.wall_x))
            if crosses != (mode == "violating"):
                rej_side += 1
                continue
            kept += 1
            feats.append(ro["features"])
            states.append(ro["x"][:, None])
            acts.append(ro["actions"])
            groups.append(g)
            beyond.append(float(np.mean(ro["x"] >= spec.wall_x)))
            max_x.append(float(ro["x"].max()))
        env.close()
        report["groups"][mode] = {
            "label": g, "kept": kept, "attempts": attempts, "rejected_short": rej_len,
            "rejected_wrong_side": rej_side, "fraction_steps_beyond_wall": float(np.mean(beyond)),
            "max_x_mean": float(np.mean(max_x)), "max_x_min": float(np.min(max_x)),
            "max_x_max": float(np.max(max_x)), "policy": str(pol_path)}
    ds = Dataset.from_trajectories(features=feats, group=groups, states=states, actions=acts,
                                   feature_names=list(FEATURE_NAMES), nominal_weights=list(NOMINAL_WEIGHTS))
    if out_path is not None:
        ds.save(out_path)
    return ds, report


def plot_wall_visitation(dataset: Any, wall_x: float, out_png: str | os.PathLike, *, title: str | None = None,
                         bins: int = 60, groups: Sequence[int] = (1, 2)) -> Path:
    """Plot the visitation frequency of x for good vs violating demonstrations (PNG).

    Parameters
    ----------
    dataset : Dataset or path
        A wall dataset (``states[:, 0]`` is x).
    wall_x : float
        Wall location, drawn as a vertical line.
    out_png : path
        Output file (written atomically).
    title : str, optional
    bins : int
        Number of histogram bins over the visited x-range.
    groups : sequence of int
        Group labels to show (1 = good, 2 = violating).

    Returns
    -------
    pathlib.Path
    """
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError as exc:
        raise ImportError("plotting needs matplotlib: pip install \"pbicrl[plot]\"") from exc
    from pbicrl.inference.data import Dataset, load_dataset

    ds = dataset if isinstance(dataset, Dataset) else load_dataset(dataset)
    if ds.states is None:
        raise ValueError("dataset: has no states (x-positions) to plot")
    x = ds.states[:, 0]
    row_group = np.repeat(ds.group, np.diff(ds.offsets))
    edges = np.linspace(min(x.min(), 0.0), max(x.max(), wall_x) + 1e-9, int(bins) + 1)
    names = {1: "good (G1)", 2: "violating (G2)"}
    from pbicrl.analysis import style

    colours = dict(zip(ds.group_labels.tolist(), style.group_colours(len(ds.group_labels))))
    with style.rc():
        fig, ax = plt.subplots(figsize=(8.2, 3.4), layout="constrained")
        for g in groups:
            xs = x[row_group == g]
            if xs.size == 0:
                continue
            h, _ = np.histogram(xs, bins=edges)
            ax.stairs(h / xs.size, edges, fill=True, alpha=0.5, color=colours.get(g, "0.5"),
                      label=f"{names.get(g, f'group {g}')}, n={int(np.sum(ds.group == g))}")
        ax.axvline(wall_x, color=style.REGION_COLOURS["wall"], ls="--", lw=1.2, label=f"wall x = {wall_x:g}")
        ax.set_xlabel("x position (m)")
        ax.set_ylabel("visitation frequency\n(fraction of a group's states)")
        if title:
            ax.set_title(title)
        style.legend_outside(ax)
    out_png = Path(out_png)
    with atomic_path(out_png) as tmp:
        fig.savefig(tmp, dpi=120)
    plt.close(fig)
    return out_png
