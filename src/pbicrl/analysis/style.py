"""One look for every figure of pbicrl (``pbicrl plot``, ``pbicrl reproduce``, the dataset figures in ``docs/``) and
the labelling page: colours per group and per region, font sizes, legends outside the data, and a check of both.

* **Groups** run from green (group 1, best) through amber to red (the worst group), whatever their number
  (:func:`group_colours`); the page and every figure use them.
* **Regions** have one colour each (:data:`REGION_COLOURS`): the goal green, the orange region orange, the red
  region red; the labelling page (:mod:`pbicrl.ui.scenes`) reads the same table.
* **Fonts**: :data:`RC` (9-10.5 pt), applied by :func:`rc` to a figure function.
* **Legends** go outside the axes (:func:`legend_outside`), never over data.

:func:`layout_problems` draws a figure and lists what breaks these rules (a legend over an axes' data area, an
axis with tick values but no label); the figure tests require it to be empty.

Matplotlib is imported only inside the functions that need it (``pip install "pbicrl[plot]"``).
"""

from __future__ import annotations

import contextlib
from typing import Any, Iterator, Sequence

__all__ = ["REGION_COLOURS", "GROUP_GOOD", "GROUP_MID", "GROUP_BAD", "TRUTH", "BOUND", "ACTIVE", "ATOM",
           "RC", "rc", "group_colours", "region_colour", "chain_colours", "legend_outside", "layout_problems"]

REGION_COLOURS = {"goal": "#2e7d32", "orange": "#ef8a00", "red": "#c0392b", "grey": "#bdbdbd", "wall": "#c0392b"}
"""Colour of each named region (the labelling page draws with the same table)."""

GROUP_GOOD, GROUP_MID, GROUP_BAD = "#2e7d32", "#f2a900", "#c0392b"
"""Group 1 (best), a middle group, the worst group."""

TRUTH = "#7b1fa2"
"""True values (purple: apart from the group and region colours, and from the posterior's blue)."""
BOUND = "0.35"
"""Prior bounds."""
ACTIVE = "#1f5fa8"
"""Posterior draws and densities given active."""
ATOM = "0.8"
"""The atom at 0 (constraint off)."""

RC = {"font.size": 10.0, "axes.titlesize": 10.5, "axes.labelsize": 10.0, "xtick.labelsize": 9.0,
      "ytick.labelsize": 9.0, "legend.fontsize": 9.0, "figure.titlesize": 11.5, "axes.titlelocation": "center"}
"""Font sizes for a figure shown at its natural width in a paper, a report or a notebook."""


@contextlib.contextmanager
def rc() -> Iterator[None]:
    """:data:`RC` for the figures created inside (artists read font sizes when they are created)."""
    import matplotlib

    with matplotlib.rc_context(RC):
        yield


def _mix(a: str, b: str, t: float) -> str:
    from matplotlib.colors import to_hex, to_rgb

    ca, cb = to_rgb(a), to_rgb(b)
    return to_hex(tuple((1 - t) * x + t * y for x, y in zip(ca, cb)))


def group_colours(n_groups: int) -> list[str]:
    """``n_groups`` colours, best group first: green, (amber), red; more groups interpolate between them."""
    if n_groups <= 0:
        return []
    if n_groups == 1:
        return [GROUP_GOOD]
    out = []
    for k in range(n_groups):
        t = k / (n_groups - 1)
        out.append(_mix(GROUP_GOOD, GROUP_MID, 2 * t) if t <= 0.5 else _mix(GROUP_MID, GROUP_BAD, 2 * t - 1))
    return out


def region_colour(name: str) -> str:
    """A region's colour by name (``in_red`` and ``red`` alike); grey for an unknown one."""
    key = name[3:] if name.startswith("in_") else name
    return REGION_COLOURS.get(key, "#888888")


def chain_colours(n: int) -> list[Any]:
    """Colours of ``n`` chains (matplotlib's tab10; chains are not groups, so none of the group colours' meaning)."""
    from matplotlib import colormaps

    cmap = colormaps["tab10"]
    return [cmap(k % 10) for k in range(n)]


def legend_outside(target: Any, handles: Sequence[Any] | None = None, *, where: str = "right", **kwargs: Any) -> Any:
    """A legend outside the data: for an axes, to its right (``where="right"``) or under it (``"below"``); for a
    figure with a layout engine, ``"outside lower center"`` / ``"outside right center"``."""
    is_fig = hasattr(target, "legends") and hasattr(target, "axes") and not hasattr(target, "get_legend")
    kw: dict[str, Any] = {"frameon": False}
    if handles is not None:
        kw["handles"] = list(handles)
    if is_fig:
        kw["loc"] = "outside right center" if where == "right" else "outside lower center"
        if where != "right":
            kw["ncol"] = max(1, min(len(handles or target.axes[0].get_legend_handles_labels()[0]) or 1, 6))
    elif where == "right":
        kw.update(loc="upper left", bbox_to_anchor=(1.02, 1.0), borderaxespad=0.0)
    else:
        kw.update(loc="upper center", bbox_to_anchor=(0.5, -0.18), borderaxespad=0.0)
        n = len(handles) if handles is not None else len(target.get_legend_handles_labels()[0])
        kw["ncol"] = max(1, min(n, 4))
    kw.update(kwargs)
    return target.legend(**kw)


def _has_data(ax: Any) -> bool:
    return bool(ax.lines or ax.patches or ax.collections or ax.images)


def _shows_ticks(axis: Any) -> bool:
    return any(t.get_visible() and t.get_text() for t in axis.get_ticklabels())


def layout_problems(fig: Any) -> list[str]:
    """What in ``fig`` breaks the house style, as sentences (empty when nothing does).

    * a legend whose box overlaps the data area (the axes box) of an axes that shows data;
    * an axes that shows tick values on an axis with no label there (a label on another axes sharing that axis
      counts), or data with no label at all;
    * x tick labels of one axes that overlap each other (unreadable category names).

    The figure is drawn first (with its own layout engine), so positions are final.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    if fig.canvas is None or not hasattr(fig.canvas, "get_renderer"):
        FigureCanvasAgg(fig)
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    out: list[str] = []
    axes = [ax for ax in fig.get_axes() if ax.get_visible() and _has_data(ax)]
    legends = list(fig.legends) + [ax.get_legend() for ax in fig.get_axes() if ax.get_legend() is not None]
    for lg in legends:
        if not lg.get_visible():
            continue
        box = lg.get_window_extent(renderer)
        for ax in axes:
            ab = ax.get_window_extent(renderer)
            w = min(box.x1, ab.x1) - max(box.x0, ab.x0)
            h = min(box.y1, ab.y1) - max(box.y0, ab.y0)
            if w > 1 and h > 1:
                texts = ", ".join(t.get_text() for t in lg.get_texts()[:3])
                out.append(f"legend ({texts}) overlaps the data area of axes '{ax.get_title() or ax.get_label()}'")
    for ax in axes:
        name = ax.get_title() or ax.get_label() or "?"
        for which in ("x", "y"):
            axis = ax.xaxis if which == "x" else ax.yaxis
            if not _shows_ticks(axis):
                continue
            shared = (ax.get_shared_x_axes() if which == "x" else ax.get_shared_y_axes()).get_siblings(ax)
            if not any((o.get_xlabel() if which == "x" else o.get_ylabel()) for o in shared):
                out.append(f"axes '{name}': {which} axis shows values but has no label")
        boxes = sorted(((t.get_window_extent(renderer), t.get_text()) for t in ax.get_xticklabels()
                        if t.get_visible() and t.get_text()), key=lambda bt: bt[0].x0)
        for (b0, t0), (b1, t1) in zip(boxes, boxes[1:]):
            if b0.x1 - b1.x0 > 1 and min(b0.y1, b1.y1) - max(b0.y0, b1.y0) > 1:
                out.append(f"axes '{name}': x tick labels {t0!r} and {t1!r} overlap")
    return out
