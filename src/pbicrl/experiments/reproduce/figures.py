"""matplotlib for the reports (imported only when a figure is drawn: ``pip install "pbicrl[plot]"``)."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

import numpy as np

__all__ = ["pyplot", "sensitivity_figure"]


def pyplot() -> Any:
    try:
        import matplotlib
    except ImportError:
        raise ImportError('figures need matplotlib: pip install "pbicrl[plot]"') from None
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def sensitivity_figure(d: Path, fname: str, sizes: Sequence[int], ours: dict[str, list[tuple[float, float]]],
                        paper: dict[int, tuple[float, float]], title: str) -> str:
    """Grouped bars of CMSE (mean ± std over seeds) per number of demonstrations, log scale, the paper's beside."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(6.4, 3.4))
    x = np.arange(len(sizes))
    series = {**ours, "paper": [paper[n] for n in sizes]}
    w = 0.8 / len(series)
    for k, (label, vals) in enumerate(series.items()):
        m = np.array([v[0] for v in vals], float)
        sd = np.array([v[1] for v in vals], float)
        ok = np.isfinite(m)
        ax.bar(x[ok] - 0.4 + w * (k + 0.5), m[ok], w, yerr=np.minimum(sd[ok], m[ok] * 0.999) if label == "paper" else None,
               label=label, color="black" if label == "paper" else None)
    ax.set_yscale("log")
    ax.set_xticks(x, [str(n) for n in sizes])
    ax.set_xlabel("demonstrations per group")
    ax.set_ylabel("CMSE (location), mean over seeds")
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(d / fname, dpi=200)
    plt.close(fig)
    return fname
