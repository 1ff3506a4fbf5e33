"""matplotlib for the reports (imported only when a figure is drawn: ``pip install "pbicrl[plot]"``)."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

import numpy as np

__all__ = ["pyplot", "sensitivity_figure", "weights_figure", "sensitivity_panels_figure", "reward_distributions_figure",
           "redraw", "WEIGHTS_YLABEL"]


def pyplot() -> Any:
    try:
        import matplotlib
    except ImportError:
        raise ImportError('figures need matplotlib: pip install "pbicrl[plot]"') from None
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _tab(n: int) -> list[Any]:
    from matplotlib import colormaps

    cmap = colormaps["tab10"]
    return [cmap(k % 10) for k in range(n)]


def sensitivity_figure(d: Path, fname: str, sizes: Sequence[int], ours: dict[str, list[tuple[float, float]]],
                        paper: dict[int, tuple[float, float]], title: str, *, unit: str = "m") -> str:
    """CMSE of the wall location (mean ± std over seeds) per number of demonstrations, ours and the paper's.

    Points with error bars on a log axis (bars on a log axis start from an arbitrary floor); the lower arm of an
    error bar that would reach 0 or below is cut at the axis. Legend beside the data."""
    from pbicrl.analysis import style

    plt = pyplot()
    with style.rc():
        fig, ax = plt.subplots(figsize=(8.0, 3.8), layout="constrained")
        x = np.arange(len(sizes))
        series = {**ours, "paper (their Table)": [paper[n] for n in sizes]}
        w = 0.7 / len(series)
        for k, ((label, vals), col) in enumerate(zip(series.items(), _tab(len(series) - 1) + ["black"])):
            m = np.array([v[0] for v in vals], float)
            sd = np.array([v[1] for v in vals], float)
            ok = np.isfinite(m) & (m > 0)
            lower = np.minimum(np.nan_to_num(sd[ok]), m[ok] * (1 - 1e-3))  # a log axis has no 0
            ax.errorbar(x[ok] - 0.35 + w * (k + 0.5), m[ok], yerr=[lower, np.nan_to_num(sd[ok])], fmt="o", ms=6,
                        capsize=3, color=col, label=label)
        ax.set_yscale("log")
        ax.set_xticks(x, [str(n) for n in sizes])
        ax.set_xlabel("demonstrations per group")
        ax.set_ylabel(f"CMSE of the wall location ({unit}\u00b2)")
        ax.set_title(title)
        style.legend_outside(ax, title="mean \u00b1 1 std over seeds")
        fig.savefig(d / fname, dpi=200)
        plt.close(fig)
    return fname


def weights_figure(d: Path, fname: str, feats: Sequence[str], true_pen: Sequence[float] | None,
                   rows: dict[str, dict[str, Any]], *, seeds: int, ylabel: str, title: str) -> str:
    """Effective penalty per feature for each method: mean over seeds with ± 1 std error bars, the truth in black,
    a symlog axis (linear within ±1, stated on the axis), the legend beside the data."""
    from pbicrl.analysis import style

    plt = pyplot()
    with style.rc():
        fig, ax = plt.subplots(figsize=(10.5, 4.2), layout="constrained")
        x = np.arange(len(feats))
        n = len(rows) + (true_pen is not None)
        wdt = 0.8 / n
        k0 = 0
        if true_pen is not None:
            ax.bar(x - 0.4 + wdt / 2, true_pen, wdt, color="black", label="truth")
            k0 = 1
        for k, ((label, row), col) in enumerate(zip(rows.items(), _tab(len(rows)))):
            ax.bar(x - 0.4 + wdt * (k + k0 + 0.5), row["mean"], wdt, yerr=row.get("std"), color=col, label=label,
                   error_kw={"lw": 0.8, "capsize": 1.5})
        ax.set_xticks(x, feats, rotation=15 if max(len(f) for f in feats) > 10 else 0)
        ax.set_xlabel("feature")
        ax.set_yscale("symlog", linthresh=1.0)
        ax.set_ylabel(ylabel + "\n(symlog axis: linear within \u00b11)")
        ax.axhline(0, color="0.5", lw=0.6)
        ax.set_title(title)
        style.legend_outside(ax, title=f"mean \u00b1 1 std over {seeds} seeds")
        fig.savefig(d / fname, dpi=150)
        plt.close(fig)
    return fname


def sensitivity_panels_figure(d: Path, panels: Sequence[tuple[str, Sequence[str], Any, dict[str, Any]]],
                              models: Sequence[tuple[str, str]], sizes: Sequence[int], *, seeds: int) -> str:
    """The appendix's sensitivity bars: per dataset and model, the effective penalty per feature for 20/60/100
    demonstrations per group. A feature no seed selects (estimate exactly 0) gets an ``x`` at 0 rather than an
    empty slot, which read as "not computed"."""
    from pbicrl.analysis import style

    plt = pyplot()
    with style.rc():
        fig, axes = plt.subplots(len(models), len(panels), figsize=(5.6 * len(panels) + 2.2, 3.3 * len(models)),
                                 squeeze=False, layout="constrained")
        cols = _tab(len(sizes))
        for j, (name, feats, true_pen, res_n) in enumerate(panels):
            x = np.arange(len(feats))
            for i, (label, model) in enumerate(models):
                ax = axes[i, j]
                w = 0.8 / (len(sizes) + 1)
                ax.bar(x - 0.4 + w / 2, true_pen, w, color="black", label="truth")
                for k, n in enumerate(sizes):
                    e = res_n[model][n] if n in res_n[model] else res_n[model][str(n)]
                    mean, sd = np.asarray(e["mean"], float), np.asarray(e["std"], float)
                    pos = x - 0.4 + w * (k + 1.5)
                    ax.bar(pos, mean, w, yerr=sd, color=cols[k], label=f"{n} per group", error_kw={"lw": 0.8})
                    zero = (mean == 0) & (sd == 0)
                    ax.plot(pos[zero], np.zeros(zero.sum()), "x", color=cols[k], ms=6, mew=1.5)
                ax.set_xticks(x, feats, fontsize=8, rotation=15)
                ax.set_yscale("symlog", linthresh=1.0)
                ax.set_title(f"{name}: {label}")
                ax.axhline(0, color="0.5", lw=0.5)
                ax.set_ylabel("c\u00b7w_p (symlog)")
                ax.set_xlabel("feature")
        from matplotlib.lines import Line2D

        handles, labels = axes[0, 0].get_legend_handles_labels()
        handles.append(Line2D([], [], color="0.3", marker="x", ls="none", ms=6, mew=1.5))
        labels.append("0: not selected in any seed")
        fig.legend(handles, labels, loc="outside right center", frameon=False,
                   title=f"mean \u00b1 1 std over {seeds} seeds")
        fig.savefig(d / "sensitivity.png", dpi=150)
        plt.close(fig)
    return "sensitivity.png"


def reward_distributions_figure(d: Path, sub: Any, true_w: Any, wn: Any, rows: dict[str, dict[str, Any]]) -> str:
    """Appendix figure: every demonstration's mean reward per group (dots; mean ± 1 std in the group's colour)
    under the true weights, PBICRL with m = 0 and with tuned margins (seed 0's MAP), on seed 0's subsample."""
    from pbicrl.analysis import style

    plt = pyplot()
    with style.rc():
        fig, axes = plt.subplots(1, 3, figsize=(12.5, 3.6), layout="constrained")
        rng = np.random.default_rng(0)  # jitter only
        F = sub.mean_features
        cols = style.group_colours(len(sub.group_labels))
        panels = [("true weights", np.asarray(true_w, float))]
        for label in ("PBICRL, m = 0", "PBICRL, tuned margins"):
            panels.append((f"{label} (seed 0, MAP)", np.asarray(wn, float) + np.array(rows[label]["per_seed"][0])))
        for ax, (label, w) in zip(axes, panels):
            r = F @ w
            for k, g in enumerate(sub.group_labels):
                v = r[sub.group == g]
                ax.scatter(k + 0.15 * rng.standard_normal(v.size), v, s=6, color="0.55", alpha=0.6)
                ax.errorbar(k, v.mean(), yerr=v.std(), fmt="o", color=cols[k], ms=7, capsize=4, lw=2)
            ax.set_xticks(range(len(sub.group_labels)), [f"G{g}" for g in sub.group_labels])
            ax.set_xlabel("group (best first)")
            ax.set_ylabel("mean reward per step")
            ax.set_title(label)
        from matplotlib.lines import Line2D

        fig.legend(handles=[Line2D([], [], color="0.55", marker="o", ls="none", ms=3, label="one demonstration"),
                            Line2D([], [], color="0.2", marker="o", ls="-", ms=6, label="group mean \u00b1 1 std")],
                   loc="outside right center", frameon=False)
        fig.savefig(d / "reward_distributions.png", dpi=150)
        plt.close(fig)
    return "reward_distributions.png"


def redraw(report_dir: str | Path) -> list[str]:
    """Draw a report's figures again from its ``results.json`` (after a change of style; no sampling).

    Knows the point-mass, fetch-reach, grid, halfcheetah, ant and sensitivity reports; returns the files."""
    import json

    from pbicrl.experiments.reproduce.paper import PAPER

    d = Path(report_dir)
    res = json.loads((d / "results.json").read_text())
    name = d.name
    if name in ("point-mass", "fetch-reach"):
        from pbicrl.inference.data import load_dataset

        feats = list(load_dataset(name.replace("-", "_")).feature_names)
        paper = res.get("paper") or PAPER[name]
        true_pen = np.array(paper["true_weights"], float) - np.array(paper["nominal_weights"], float)
        out = [weights_figure(d, "weights.png", feats, true_pen, res["methods"], seeds=int(res["seeds"]),
                              ylabel=WEIGHTS_YLABEL, title=f"{name}: effective penalties by method")]
        sub = load_dataset(name.replace("-", "_")).sample_per_group(int(paper["demos_per_group"]), seed=0)
        out.append(reward_distributions_figure(d, sub, paper["true_weights"], paper["nominal_weights"],
                                               res["methods"]))
        return out
    if name == "grid":
        feats = ["grey", "orange", "red"]
        rows = {k: v for k, v in res["weights"].items()}
        return [weights_figure(d, "weights.png", feats, None, rows, seeds=int(res["runs"]),
                               ylabel="inferred weight (MAP)", title="grid: BPL with and without margins")]
    if name in ("halfcheetah", "ant"):
        sizes = [int(n) for n in res["sizes"]]
        pp, dd = res["sizes"], res["default"]
        paper = res["paper"]
        return [sensitivity_figure(d, f"{name}_cmse.png", sizes,
                                   {"paper Alg. 2, MAP": [pp[str(n)]["cmse"] for n in sizes],
                                    "default, MAP": [dd[str(n)]["cmse"] for n in sizes],
                                    "default, posterior median": [dd[str(n)]["cmse_selected"] for n in sizes]},
                                   {int(k): v for k, v in paper["sensitivity"].items()},
                                   f"{name}: CMSE of the wall location")]
    if name == "sensitivity":
        from pbicrl.inference.data import load_dataset

        models = (("PBICRL, m = 0 (MAP)", "paper"), ("pbicrl default (selected)", "default"))
        panels = []
        for key, r in res.items():
            feats = list(load_dataset(key.replace("-", "_")).feature_names)
            paper = PAPER[key]
            true_pen = np.array(paper["true_weights"], float) - np.array(paper["nominal_weights"], float)
            panels.append((key, feats, true_pen, r))
        seeds = len(next(iter(next(iter(res.values()))["paper"].values()))["per_seed"])
        return [sensitivity_panels_figure(d, panels, models, (20, 60, 100), seeds=seeds)]
    raise ValueError(f"redraw: no figures known for a report named {name!r}")


WEIGHTS_YLABEL = "c\u00b7w_p: MAP, or the conditional\nmedian (pbicrl default)"
"""What the weights figures plot: the paper's algorithms by their MAP draw, pbicrl's default by the selected set
at its conditional medians."""
