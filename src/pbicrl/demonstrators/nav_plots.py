"""Figures of navigation datasets (matplotlib, imported when drawing: ``pip install "pbicrl[plot]"``)."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from pbicrl._atomic import atomic_path
from pbicrl.demonstrators.nav_envs import nav_spec
from pbicrl.inference.data import Dataset

__all__ = ["plot_navigation_demos"]


_GROUP_COLOURS = {1: "tab:green", 2: "tab:orange", 3: "tab:red"}


def plot_navigation_demos(dataset: Dataset | str | os.PathLike, env: str, out: str | os.PathLike,
                          *, max_per_group: int | None = 60, seed: int = 0, title: str | None = None,
                          policies: str | None = None) -> Path:
    """PNG of the demonstrations coloured by group (paper Fig. 3a / 4a style).

    The point mass is drawn in the plane; Fetch-Reach as a top view (x-y) and a side
    view (x-z) with the boxes and the goal ball.  ``max_per_group`` trajectories are drawn
    per group (random, seeded; ``None`` for all).  ``policies`` (one letter per trajectory,
    ``g`` good / ``v`` violating; default: ``trajectory_policy`` of the JSON report next to a
    dataset file, if any) draws the good policy's trajectories dashed.
    """
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        from matplotlib.patches import Circle, Rectangle
    except ImportError as exc:
        raise ImportError('plotting needs matplotlib: pip install "pbicrl[plot]"') from exc
    ds = dataset if isinstance(dataset, Dataset) else Dataset.load(dataset)
    if ds.states is None:
        raise ValueError("dataset: has no states to plot")
    nav_spec(env)
    if policies is None and not isinstance(dataset, Dataset):
        report = Path(dataset).with_suffix(".json")
        if report.is_file():
            policies = json.loads(report.read_text()).get("trajectory_policy")
    letters = np.array(list(policies)) if policies else None
    if letters is not None and letters.size != ds.n_trajectories:
        raise ValueError(f"policies: {letters.size} letters for {ds.n_trajectories} trajectories")
    if max_per_group is not None:
        rng = np.random.default_rng(seed)
        picks = []
        for k in ds.group_labels:
            members = np.flatnonzero(ds.group == k)
            picks.append(members if members.size <= max_per_group
                         else np.sort(rng.choice(members, size=max_per_group, replace=False)))
        keep = np.concatenate(picks)
        ds = ds.subset(keep)
        letters = None if letters is None else letters[keep]
    if env == "point_mass":
        from pbicrl.envs.point_mass import HIGH, LOW
        from pbicrl.envs.point_mass import POINT_MASS_TASK as task

        fig, ax = plt.subplots(figsize=(5, 5))
        axes = [(ax, 0, 1)]
        ax.set_xlim(LOW, HIGH)
        ax.set_ylim(LOW, HIGH)
        for reg, col in ((task.goal, "tab:blue"), (task.orange, "orange"), (task.red, "red")):
            ax.add_patch(Circle(reg.centre, reg.radius, color=col, alpha=0.3))
    else:
        from pbicrl.envs.fetch_reach import FETCH_REACH_TASK as task

        fig, (a1, a2) = plt.subplots(1, 2, figsize=(10, 4.5))
        axes = [(a1, 0, 1), (a2, 0, 2)]
        for ax, i, j in axes:
            for box, col in ((task.orange, "orange"), (task.red, "red")):
                ax.add_patch(Rectangle((box.low[i], box.low[j]), box.high[i] - box.low[i],
                                       box.high[j] - box.low[j], color=col, alpha=0.3))
            ax.add_patch(Circle((task.goal.centre[i], task.goal.centre[j]), task.goal.radius, color="tab:blue", alpha=0.4))
        a1.set_title("top view")
        a2.set_title("side view")
        a2.set_ylim(0.4, 1.0)
    names = "xyz"
    for k in ds.group_labels:
        idx = np.flatnonzero(ds.group == k)
        n_good = 0 if letters is None else int((letters[idx] == "g").sum())
        label = f"G{k} ({idx.size} shown" + (f", {n_good} good policy, dashed)" if n_good else ")")
        for n, i in enumerate(idx):
            s = ds.trajectory_states(int(i))
            good = letters is not None and letters[i] == "g"
            for ax, a, b in axes:
                ax.plot(s[:, a], s[:, b], color=_GROUP_COLOURS.get(int(k), "grey"), lw=1.2 if good else 0.8,
                        alpha=0.9 if good else 0.6, ls="--" if good else "-",
                        label=label if n == 0 and ax is axes[0][0] else None)
                ax.plot(s[0, a], s[0, b], ".", color="black", ms=2)
    for ax, a, b in axes:
        ax.set_xlabel(names[a])
        ax.set_ylabel(names[b])
        ax.set_aspect("equal", adjustable="box")
    # the point mass's middle is free of trajectories; Fetch's top view is free at low x
    axes[0][0].legend(loc="center" if env == "point_mass" else "lower left", fontsize=8)
    fig.suptitle(title or f"{env} demonstrations by group")
    fig.tight_layout()
    out = Path(out)
    with atomic_path(out) as tmp:
        fig.savefig(tmp, dpi=120)
    plt.close(fig)
    return out
