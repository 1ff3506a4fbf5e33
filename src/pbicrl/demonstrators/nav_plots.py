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
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    from pbicrl.analysis import style

    with style.rc():  # the house fonts for this figure only, not the caller's rcParams
        region_handles = []
        if env == "point_mass":
            from pbicrl.envs.point_mass import HIGH, LOW
            from pbicrl.envs.point_mass import POINT_MASS_TASK as task

            fig, ax = plt.subplots(figsize=(7.2, 5), layout="constrained")
            axes = [(ax, 0, 1)]
            ax.set_xlim(LOW, HIGH)
            ax.set_ylim(LOW, HIGH)
            for name, reg in (("goal", task.goal), ("orange", task.orange), ("red", task.red)):
                col = style.REGION_COLOURS[name]
                ax.add_patch(Circle(reg.centre, reg.radius, facecolor=col, edgecolor=col, alpha=0.3, lw=1.5))
                region_handles.append(Patch(facecolor=col, edgecolor=col, alpha=0.45, label=f"{name} region"))
        else:
            from pbicrl.envs.fetch_reach import FETCH_REACH_TASK as task

            fig, (a1, a2) = plt.subplots(1, 2, figsize=(12, 4.8), layout="constrained")
            axes = [(a1, 0, 1), (a2, 0, 2)]
            # outlines and hatching keep the two boxes apart where one hides the other (the side view)
            for name, box, hatch in (("orange", task.orange, "//"), ("red", task.red, "\\\\")):
                col = style.REGION_COLOURS[name]
                for ax, i, j in axes:
                    ax.add_patch(Rectangle((box.low[i], box.low[j]), box.high[i] - box.low[i], box.high[j] - box.low[j],
                                           facecolor=col, edgecolor=col, alpha=0.25, lw=1.8, hatch=hatch))
                    ax.add_patch(Rectangle((box.low[i], box.low[j]), box.high[i] - box.low[i], box.high[j] - box.low[j],
                                           fill=False, edgecolor=col, lw=1.8))
                region_handles.append(Patch(facecolor=col, edgecolor=col, alpha=0.45, hatch=hatch, label=f"{name} box"))
            goal = style.REGION_COLOURS["goal"]
            for ax, i, j in axes:
                ax.add_patch(Circle((task.goal.centre[i], task.goal.centre[j]), task.goal.radius, facecolor=goal,
                                    edgecolor=goal, alpha=0.4, lw=1.5))
            region_handles.append(Patch(facecolor=goal, edgecolor=goal, alpha=0.45, label="goal ball"))
            a1.set_title("top view (x-y)")
            a2.set_title("side view (x-z)")
            a2.set_ylim(0.4, 1.0)
            if all(np.allclose([task.orange.low[i], task.orange.high[i]], [task.red.low[i], task.red.high[i]])
                   for i in (0, 2)):
                a2.text(0.02, 0.03, "the orange and red boxes coincide in this view\n(they differ in y: top view)",
                        transform=a2.transAxes, fontsize=8.5, color="0.25", va="bottom")
        names = "xyz"
        colours = dict(zip(ds.group_labels.tolist(), style.group_colours(len(ds.group_labels))))
        group_handles = []
        for k in ds.group_labels:
            idx = np.flatnonzero(ds.group == k)
            n_good = 0 if letters is None else int((letters[idx] == "g").sum())
            label = (f"{ds.group_name(int(k)) if ds.group_names else f'G{k}'} ({idx.size} shown"
                     + (f", {n_good} good policy, dashed)" if n_good else ")"))
            group_handles.append(Line2D([], [], color=colours[int(k)], lw=1.5, label=label))
            for i in idx:
                s = ds.trajectory_states(int(i))
                good = letters is not None and letters[i] == "g"
                for ax, a, b in axes:
                    ax.plot(s[:, a], s[:, b], color=colours[int(k)], lw=1.2 if good else 0.8,
                            alpha=0.9 if good else 0.6, ls="--" if good else "-")
                    ax.plot(s[0, a], s[0, b], ".", color="black", ms=2)
        group_handles.append(Line2D([], [], color="black", marker=".", ls="none", ms=5, label="start"))
        unit = " (m)" if env == "fetch_reach" else " (arena units)"
        for ax, a, b in axes:
            ax.set_xlabel(names[a] + unit)
            ax.set_ylabel(names[b] + unit)
            ax.set_aspect("equal", adjustable="box")
        # beside the data, never on it: groups (best first), then the regions
        style.legend_outside(fig, group_handles + region_handles, where="right")
        fig.suptitle(title or f"{env} demonstrations by group")
        out = Path(out)
        with atomic_path(out) as tmp:
            fig.savefig(tmp, dpi=120)
        plt.close(fig)
    return out
