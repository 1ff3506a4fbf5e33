"""Figures of a posterior: traces, posterior densities, P(constraint), penalty-vs-location pairs, rewards per group.

Matplotlib (``pip install "pbicrl[plot]"``) is imported lazily and used without ``pyplot`` (figures render
with the Agg canvas), so plotting never changes the caller's backend. Every function takes a
:class:`~pbicrl.inference.posterior.Posterior` or a run loaded with :func:`pbicrl.io.runs.read_run` and returns a
``matplotlib.figure.Figure``; :func:`plot_run` writes them all for a run directory (200 dpi by default).

Conventions shared by the figures:

* A penalty's posterior under the reversible-jump sampler is a mixture of an atom at 0 (:math:`c_j = 0`) and a
  density (:math:`c_j = 1`). Densities show :math:`w_{p,j} \\mid c_j = 1`; :math:`P(c_j = 1)` is a separate bar
  and stated in the panel.
* Axis ranges follow the draws. A true value a little outside is taken in; one far outside is written at
  the edge of the axis with an arrow, so it cannot squash the draws into a line.
* Prior bounds that fall inside the plotted range are drawn as dotted lines (a posterior piling up at a
  bound is the sign of separable groups, see :mod:`pbicrl.inference.priors`).
* Penalties are in "reward units per unit feature", parameters in "state units", unless ``units`` says
  otherwise (``{"reward": ..., "<feature>": ..., "state": ..., "<parameter>": ...}``).

``truth`` (optional, e.g. for synthetic data) maps feature names to the true effective penalty
:math:`c_j w_{p,j}` (0 = not a constraint) and parameter names to their true values; unknown names are an
error (:func:`check_truth`).
"""

from __future__ import annotations

import contextlib
import functools
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence, TypeVar

import numpy as np
from numpy.typing import NDArray

from pbicrl._atomic import atomic_path, read_json
from pbicrl.analysis import style as _style
from pbicrl.inference.draws import parameter_draws

__all__ = ["plot_traces", "plot_posteriors", "plot_p_constraint", "plot_pairs", "plot_rewards", "plot_run",
           "map_returns", "estimate_returns", "true_returns", "parse_truth", "check_truth", "FORMATS", "DEFAULT_DPI",
           "PENALTY_UNIT", "STATE_UNIT", "REWARD_UNIT"]

FORMATS = ("png", "pdf", "svg")
DEFAULT_DPI = 200
"""Resolution of raster figures: sharp when a figure is shrunk to one column of a paper."""
REWARD_UNIT = "reward units"
PENALTY_UNIT = "reward units per unit feature"
STATE_UNIT = "state units"

_MAX_TRACE_POINTS = 1500  # per chain: more points than pixels only slows rendering
_MAX_SCATTER_POINTS = 4000
_SLACK = 0.25  # a true value within 25% of the data span outside the range is taken into the axis
_PAD = 0.05

# Fonts and colours of every pbicrl figure: pbicrl.analysis.style (one module for plot, reproduce and the page).
_RC = _style.RC
_TRUTH = _style.TRUTH
_BOUND = _style.BOUND
_ACTIVE = _style.ACTIVE
_ATOM = _style.ATOM
_MINPEN = "0.15"

_F = TypeVar("_F", bound=Callable[..., Any])


def _mpl() -> Any:
    try:
        from matplotlib.figure import Figure
    except ImportError as exc:
        raise ImportError(f"plots need matplotlib ({exc}): pip install \"pbicrl[plot]\"") from exc
    return Figure


def _styled(fn: _F) -> _F:
    """Run a figure function under :data:`_RC` (artists read the font sizes when they are created)."""

    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        _mpl()
        import matplotlib

        with matplotlib.rc_context(_RC):
            return fn(*args, **kwargs)

    return wrapper  # type: ignore[return-value]


def _colors(n: int) -> list:
    """Chain colours (:func:`pbicrl.analysis.style.chain_colours`)."""
    return _style.chain_colours(n)


# --------------------------------------------------------------------------------------------- run views
def _owner(post: Any, pnames: Sequence[str]) -> list[int | None]:
    """Feature index of the constraint each parameter belongs to (``name.param`` convention as fallback)."""
    own = getattr(post, "parameter_owner", None)
    if own is not None and len(own) == len(pnames):
        return [int(j) for j in own]
    feats = list(post.feature_names)
    out: list[int | None] = []
    for n in pnames:
        head = n.rsplit(".", 1)[0]
        out.append(feats.index(head) if head in feats else None)
    return out


def _settings(post: Any) -> dict[str, Any]:
    return dict(getattr(post, "settings", {}) or {})


def _prior_source(post: Any) -> Mapping[str, Any] | None:
    """The weight prior as recorded: the posterior's prior summary (``Posterior.prior`` or ``summary.json``'s
    ``prior``), else the sampler settings' ``weight_prior``."""
    summary = getattr(post, "summary", None)  # a RunRecord's dict; a Posterior's is a method
    for src in (getattr(post, "prior", None), summary.get("prior") if isinstance(summary, Mapping) else None,
                _settings(post).get("weight_prior")):
        if isinstance(src, Mapping):
            return src
    return None


def _weight_bounds(post: Any) -> list[tuple[float, ...]]:
    """Finite bounds of each feature's penalty prior (empty where unbounded or no prior was applied).

    Reads both layouts: ``{"kind", "low", "high"}`` and ``{"kind", "support": [lo, hi], "features":
    {name or index: {"support": ...}}, "applied"}`` (a bound recorded as None is infinite)."""
    names = [str(n) for n in post.feature_names]
    src = _prior_source(post)
    s = _settings(post)
    method = str(getattr(post, "sampler", s.get("sampler", s.get("method", ""))))
    base = None
    if src is not None:
        base = src if "kind" in src else next((src[k] for k in ("weight_prior", "weight")
                                               if isinstance(src.get(k), Mapping)), None)
    # the paper's Algorithm 1 samples with an improper prior whatever the settings say (samplers.kernels)
    if base is None or base.get("applied") is False or method == "paper" or base.get("kind") == "improper":
        return [()] * len(names)
    feats = base.get("features", src.get("features") if src is not None else None)
    out: list[tuple[float, ...]] = []
    for j, n in enumerate(names):
        entry = feats.get(n, feats.get(str(j))) if isinstance(feats, Mapping) else None
        spec = dict(base) | (dict(entry) if isinstance(entry, Mapping) else {})
        lo_hi = spec.get("support") or [spec.get("low"), spec.get("high")]
        try:
            vals = tuple(float(v) for v in lo_hi if v is not None)
        except (TypeError, ValueError):
            vals = ()
        out.append(tuple(v for v in vals if np.isfinite(v)))
    return out


def _param_bounds(post: Any, pnames: Sequence[str]) -> dict[str, tuple[float, float]]:
    """Uniform prior bounds of every parameter (``resolved_bounds`` of the run's constraints)."""
    specs = _settings(post).get("constraints") or []
    b: list[tuple[float, float]] = []
    for spec in specs:
        for lo_hi in spec.get("resolved_bounds") or spec.get("bounds") or []:
            b.append((float(lo_hi[0]), float(lo_hi[1])))
    return dict(zip(pnames, b)) if len(b) == len(pnames) else {}


@dataclass(frozen=True)
class _Units:
    """Axis units: defaults, overridden by a mapping (from the caller or the dataset)."""

    mapping: Mapping[str, str] = field(default_factory=dict)

    @property
    def reward(self) -> str:
        return str(self.mapping.get("reward", REWARD_UNIT))

    def penalty(self, feature: str) -> str:
        fu = self.mapping.get(feature)
        if fu is None:
            return PENALTY_UNIT if self.reward == REWARD_UNIT else f"{self.reward} per unit feature"
        return f"{self.reward} per {fu}"

    def param(self, name: str) -> str:
        return str(self.mapping.get(name) or self.mapping.get("state") or STATE_UNIT)

    def penalty_label(self, feature: str) -> str:
        return f"penalty w_p ({self.penalty(feature)})"

    def param_label(self, name: str) -> str:
        return f"{name} ({self.param(name)})"


def _units(post: Any, units: Mapping[str, str] | None) -> _Units:
    u = units if units is not None else getattr(post, "units", None)
    return _Units(dict(u) if isinstance(u, Mapping) else {})


def _truth_value(truth: Mapping[str, float] | None, name: str) -> float | None:
    if not truth or name not in truth or truth[name] is None:
        return None
    return float(truth[name])


# --------------------------------------------------------------------------------------------- axis helpers
def _limits(values: NDArray[np.float64]) -> tuple[float, float]:
    """Data range with a small margin; a constant gets a unit-sized window around it."""
    v = np.asarray(values, dtype=np.float64)
    v = v[np.isfinite(v)]
    if not v.size:
        return 0.0, 1.0
    lo, hi = float(v.min()), float(v.max())
    span = hi - lo
    if span <= 0:
        half = max(abs(lo) * 0.05, 0.5)
        return lo - half, hi + half
    return lo - _PAD * span, hi + _PAD * span


def _take_in(lim: tuple[float, float], values: Sequence[float | None]) -> tuple[float, float]:
    """Widen ``lim`` to include values lying within :data:`_SLACK` of its span outside it (not further)."""
    lo, hi = lim
    span = hi - lo
    for v in values:
        if v is None or not np.isfinite(v):
            continue
        if lo - _SLACK * span <= v < lo + _PAD * span:  # outside, or inside on the frame: room on that side
            lo = min(lo, v - _PAD * span)
        elif hi - _PAD * span < v <= hi + _SLACK * span:
            hi = max(hi, v + _PAD * span)
    return lo, hi


def _mark(ax: Any, value: float, lim: tuple[float, float], *, axis: str, text: str, color: str = _TRUTH,
          ls: str = "--", lw: float = 1.5, row: int = 0) -> bool:
    """A line at ``value`` if it lies in ``lim``, else an arrow and the value at the nearer edge.

    ``row`` moves an x-axis edge label down by one text line (two labels in one corner of a scatter).
    Returns whether a line was drawn."""
    lo, hi = lim
    if lo <= value <= hi:
        (ax.axvline if axis == "x" else ax.axhline)(value, color=color, ls=ls, lw=lw, zorder=3)
        return True
    box = {"boxstyle": "round,pad=0.2", "fc": "white", "ec": "none", "alpha": 0.8}
    label = f"{text} {value:.4g}"
    if axis == "x":
        left = value < lo
        ax.text(0.01 if left else 0.99, 0.97 - 0.08 * row, f"\u2190 {label}" if left else f"{label} \u2192",
                color=color, ha="left" if left else "right", va="top", transform=ax.transAxes, fontsize=8.5,
                bbox=box, zorder=4)
    else:
        below = value < lo
        ax.text(0.995, 0.03 if below else 0.97, f"{label} \u2193" if below else f"{label} \u2191", color=color,
                ha="right", va="bottom" if below else "top", transform=ax.transAxes, fontsize=8.5, bbox=box,
                zorder=4)
    return False


def _mark_bounds(ax: Any, bounds: Sequence[float] | None, lim: tuple[float, float], *, axis: str) -> bool:
    """Dotted lines at prior bounds inside ``lim``; returns whether any was drawn.

    The figure legend names the dotted style: a text label next to the line sat on the draws it bounds."""
    if not bounds:
        return False
    drawn = False
    for b in bounds:
        if lim[0] <= b <= lim[1]:
            (ax.axvline if axis == "x" else ax.axhline)(b, color=_BOUND, ls=":", lw=1.5, zorder=3)
            drawn = True
    return drawn


def _identified_edge(post: Any, name: str) -> float | None:
    r"""The penalty at the identified end of a feature's range: :math:`\pm` ``min_penalty`` on the side the data
    bound (``identified.features[name].penalty_range``, the other end open); None when not one-sided."""
    ident = getattr(post, "identified", None)
    if callable(ident):
        ident = ident()
    e = ((ident or {}).get("features") or {}).get(name) if isinstance(ident, Mapping) else None
    if not isinstance(e, Mapping):
        return None
    pr = e.get("penalty_range")
    if not isinstance(pr, (list, tuple)) or len(pr) != 2:
        return None
    lo, hi = (None if v is None or not np.isfinite(v) else float(v) for v in pr)
    if (lo is None) == (hi is None):
        return None
    return hi if lo is None else lo


def _blank(ax: Any, text: str) -> None:
    """An axis that only says why it is empty."""
    ax.set_xticks([])
    ax.set_yticks([])
    ax.text(0.5, 0.5, text, ha="center", va="center", transform=ax.transAxes, fontsize=10, color="0.3")


def _legend_handles(items: Sequence[tuple[str, str]]) -> list:
    """Legend entries by kind: ("patch", ...) boxes for densities, lines for marks."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    style = {"active": lambda lab: Patch(color=_ACTIVE, alpha=0.5, label=lab),
             "atom": lambda lab: Patch(color=_ATOM, label=lab),
             "truth": lambda lab: Line2D([], [], color=_TRUTH, ls="--", lw=1.5, label=lab),
             "bound": lambda lab: Line2D([], [], color=_BOUND, ls=":", lw=1.3, label=lab),
             "minpen": lambda lab: Line2D([], [], color=_MINPEN, ls="-.", lw=1.5, label=lab)}
    return [style[kind](label) for kind, label in items]


# --------------------------------------------------------------------------------------------- traces
_TraceRow = tuple[str, NDArray[np.float64], "NDArray[np.bool_] | None", "float | None", "Sequence[float] | None", float]
"""(title, draws (chains, draws), active mask or None, truth, prior bounds, P(active))."""


@_styled
def plot_traces(post: Any, *, truth: Mapping[str, float] | None = None,
                units: Mapping[str, str] | None = None) -> Any:
    """Trace (left) and per-chain histogram of the active draws (right) of every effective penalty
    :math:`c_j w_{p,j}`, parameter and the log-likelihood.

    Features that are never active get a short row saying so. True values are dashed lines (or an arrow at
    the edge when far outside the draws), prior bounds inside the range dotted lines.

    Parameters
    ----------
    post : Posterior or RunRecord
    truth : mapping, optional
        True effective penalties and parameter values by name (see the module docstring).
    units : mapping, optional
        Axis units by name: ``"reward"``, a feature, ``"state"``, a parameter.

    Returns
    -------
    matplotlib.figure.Figure
    """
    Figure = _mpl()
    U = _units(post, units)
    names = list(post.feature_names)
    ind = np.asarray(post.indicators).astype(bool)
    eff = ind * np.asarray(post.penalty_weights, dtype=np.float64)
    wb = _weight_bounds(post)
    params, pnames = parameter_draws(post)
    owner = _owner(post, pnames) if params is not None else []
    pb = _param_bounds(post, pnames)
    rows: list[_TraceRow] = []
    for j, n in enumerate(names):
        rows.append((f"c\u00b7w_p  {n}  ({U.penalty(n)})", eff[:, :, j], ind[:, :, j], _truth_value(truth, n),
                     wb[j], float(ind[:, :, j].mean())))
    if params is not None:
        for k, n in enumerate(pnames):
            act = np.isfinite(params[:, :, k])
            if owner[k] is not None:
                act &= ind[:, :, owner[k]]
            rows.append((f"{n}  ({U.param(n)})", params[:, :, k], act, _truth_value(truth, n), pb.get(n),
                         float(act.mean())))
    rows.append(("log-likelihood (nats)", np.asarray(post.log_likelihood, dtype=np.float64), None, None, None, 1.0))
    C, D = rows[0][1].shape
    step = max(1, D // _MAX_TRACE_POINTS)
    cols = _colors(C)
    heights = [0.45 if p == 0 else 1.0 for (*_, p) in rows]  # a never-active row only carries a sentence
    fig = Figure(figsize=(11, 2.1 * sum(heights) + 1.1), layout="constrained")
    axes = fig.subplots(len(rows), 2, squeeze=False, gridspec_kw={"width_ratios": [4, 1], "height_ratios": heights})
    x = np.arange(0, D, step)
    any_truth = any_bound = False
    for r, (title, draws, active, tv, bounds, p_on) in enumerate(rows):
        ax, hx = axes[r]
        ax.set_title(title, loc="left", fontsize=10)
        if p_on == 0:
            _blank(ax, f"never active ({_p_label(_meaning(post), True)}=0)")
            hx.set_visible(False)
            continue
        ax.set_ylabel(title.split("  ")[0] if r < len(rows) - 1 else "nats")
        for c in range(C):
            ax.plot(x, draws[c, ::step], lw=0.6, color=cols[c], alpha=0.85)
            sel = draws[c][np.isfinite(draws[c]) & (True if active is None else active[c])]
            if sel.size:
                hx.hist(sel, bins=40, histtype="step", color=cols[c], orientation="horizontal", density=True)
        lim = _take_in(_limits(draws), [tv])
        ax.set_ylim(lim)
        hx.set_ylim(lim)
        if tv is not None:
            any_truth |= _mark(ax, tv, lim, axis="y", text="truth")
            if lim[0] <= tv <= lim[1]:
                hx.axhline(tv, color=_TRUTH, ls="--", lw=1.5)
        any_bound |= _mark_bounds(ax, bounds, lim, axis="y")
        ax.margins(x=0.01)
        from matplotlib.ticker import MaxNLocator

        hx.xaxis.set_major_locator(MaxNLocator(2))
        hx.tick_params(labelleft=False)
        if active is not None:  # also at 1.00: the label said nothing when every draw was active
            hx.set_title(f"{_p_label(_meaning(post), True)} = {p_on:.2f}", fontsize=9)
    shown = [r for r in range(len(rows)) if rows[r][5] > 0]
    for r in shown[:-1]:  # one draw axis for the traces, labelled once at the bottom
        axes[r, 0].sharex(axes[shown[-1], 0])
        axes[r, 0].tick_params(labelbottom=False)
    axes[shown[-1], 0].set_xlabel(_draw_axis_label(post))
    for r in shown:  # each density has its own scale: ticks and a label on every row
        axes[r, 1].set_xlabel("density" if r != shown[-1] else "density\n(active draws)", fontsize=8.5)
        axes[r, 1].tick_params(labelsize=8)
    from matplotlib.lines import Line2D

    handles = [Line2D([], [], color=cols[c], lw=1.5, label=f"chain {c}") for c in range(C)]
    marks = ([("truth", "truth")] if any_truth else []) + ([("bound", "prior bound")] if any_bound else [])
    # outside the axes (a legend inside covered the first trace), below them (above, it met the title)
    fig.legend(handles=handles + _legend_handles(marks), loc="outside lower center",
               ncol=min(len(handles) + len(marks), 8), frameon=False)
    shown_txt = "" if step == 1 else f"; 1 in {step} shown"
    fig.suptitle(f"Traces: {C} chains \u00d7 {D} kept draws{shown_txt}")
    return fig


def _draw_axis_label(post: Any) -> str:
    s = _settings(post)
    thin, burn = s.get("thin"), s.get("burn_in")
    if thin is None or burn is None:
        return "kept draw"
    every = "every iteration" if int(thin) == 1 else f"1 in {int(thin)} iterations"
    return f"kept draw ({every} after {int(burn):,} burn-in iterations)"


# --------------------------------------------------------------------------------------------- densities
@dataclass
class _Panel:
    name: str
    draws: NDArray[np.float64]  # the conditional draws (given active)
    p_on: float
    truth: float | None
    bounds: Sequence[float] | None
    xlabel: str
    is_penalty: bool
    true_on: int | None = None  # the true indicator, where known


def _grid(n: int) -> tuple[int, int]:
    ncol = n if n <= 3 else (2 if n == 4 else 3)
    return -(-n // ncol), ncol


@_styled
def plot_posteriors(post: Any, *, truth: Mapping[str, float] | None = None,
                    units: Mapping[str, str] | None = None) -> Any:
    """Posterior of every penalty and parameter, one panel each.

    A penalty panel has a bar with :math:`P(c_j = 1)` (grey: the atom at 0, :math:`c_j = 0`) and the density of
    :math:`w_{p,j}` given :math:`c_j = 1`, which integrates to 1. A parameter panel likewise shows the probability
    that its constraint is active and its density while active. True values in red (the true indicator as a
    red tick on the bar), prior bounds inside the range dotted.

    Parameters
    ----------
    post : Posterior or RunRecord
    truth : mapping, optional
        True effective penalties and parameter values by name (see the module docstring).
    units : mapping, optional
        Axis units by name: ``"reward"``, a feature, ``"state"``, a parameter.

    Returns
    -------
    matplotlib.figure.Figure
    """
    Figure = _mpl()
    U = _units(post, units)
    names = list(post.feature_names)
    c = np.asarray(post.indicators).reshape(-1, len(names)).astype(bool)
    w = np.asarray(post.penalty_weights, dtype=np.float64).reshape(-1, len(names))
    wb = _weight_bounds(post)
    params, pnames = parameter_draws(post)
    meaning = _meaning(post)
    model = _in_model(post, len(names))
    c = c & model  # bpl: a non-candidate is not in the model (no draws to show)
    panels: list[_Panel] = []
    for j, n in enumerate(names):
        tv = _truth_value(truth, n)
        panels.append(_Panel(n, w[c[:, j], j], float(c[:, j].mean()), tv if tv != 0 else None, wb[j],
                             U.penalty_label(n), True, None if tv is None else int(tv != 0)))
    if params is not None:
        flat = params.reshape(-1, params.shape[2])
        owner = _owner(post, pnames)
        pb = _param_bounds(post, pnames)
        for k, n in enumerate(pnames):
            act = np.isfinite(flat[:, k])
            if owner[k] is not None:
                act &= c[:, owner[k]]
            panels.append(_Panel(n, flat[act, k], float(act.mean()), _truth_value(truth, n), pb.get(n),
                                 U.param_label(n), False))
    nrow, ncol = _grid(len(panels))
    fig = Figure(figsize=(5.0 * ncol, 3.7 * nrow + 0.8), layout="constrained")
    subs = np.asarray(fig.subfigures(nrow, ncol, squeeze=False)).ravel()
    used = {"active": False, "atom": False, "truth": False, "bound": False, "minpen": False}
    for sf, pn in zip(subs, panels):
        axb, axd = sf.subplots(1, 2, gridspec_kw={"width_ratios": [1, 7]})
        on_word = "c=1" if pn.is_penalty else "active"
        note = "" if pn.true_on is None or pn.true_on else ";  truth: not a constraint"
        p_word = f"P({on_word})" if meaning == "posterior" else "freq on" if meaning == "chain_frequency" else (
            "in the model" if pn.p_on > 0 else "not in the model")
        # name and numbers on two lines: on one, a long name with the note ran past the panel
        sf.suptitle(f"{pn.name}\n{p_word}" + (f" = {pn.p_on:.2f}" if meaning != "fixed" else "") + note, fontsize=11)
        # the probability bar: blue P(active), grey the rest (for a penalty: the atom at w_p = 0)
        axb.bar([0], [pn.p_on], width=0.8, color=_ACTIVE, alpha=0.7)
        axb.bar([0], [1 - pn.p_on], bottom=[pn.p_on], width=0.8, color=_ATOM)
        used["atom"] |= pn.p_on < 1
        axb.set_xlim(-0.6, 0.6)
        axb.set_ylim(0, 1)
        axb.set_xticks([])
        axb.set_yticks([0, 0.5, 1])
        axb.set_ylabel(_p_label(meaning, pn.is_penalty))
        if pn.true_on is not None:
            axb.plot([-0.55, 0.55], [pn.true_on, pn.true_on], color=_TRUTH, lw=3, clip_on=False, zorder=5)
            used["truth"] = True
        if pn.draws.size == 0:
            _blank(axd, "not in the model" if meaning == "fixed" else f"never active ({_p_label(meaning, True)}=0)")
            axd.set_xlabel(pn.xlabel)
            continue
        used["active"] = True
        lim = _take_in(_limits(pn.draws), [pn.truth])
        edges = np.linspace(lim[0], lim[1], 51)
        h, _ = np.histogram(pn.draws, bins=edges)
        dens = h / max(h.sum(), 1) / np.diff(edges)
        axd.stairs(dens, edges, fill=True, alpha=0.5, color=_ACTIVE)
        axd.stairs(dens, edges, color=_ACTIVE, lw=1)
        axd.set_xlim(lim)
        axd.set_ylim(0, dens.max() * 1.15 if dens.max() > 0 else 1)  # headroom for edge labels
        if pn.truth is not None:
            _mark(axd, pn.truth, lim, axis="x", text="truth")
            used["truth"] = True
        used["bound"] |= _mark_bounds(axd, pn.bounds, lim, axis="x")
        edge = _identified_edge(post, pn.name) if pn.is_penalty else None
        if edge is not None and lim[0] <= edge <= lim[1]:
            axd.axvline(edge, color=_MINPEN, ls="-.", lw=1.5, zorder=3)
            used["minpen"] = True
        elif edge is not None:
            _mark(axd, edge, lim, axis="x", text="min|w_p|", color=_MINPEN, row=1)
            used["minpen"] = True
        axd.set_xlabel(pn.xlabel)
        axd.set_ylabel("density | c=1" if pn.is_penalty else "density | active")
        from matplotlib.ticker import MaxNLocator

        axd.xaxis.set_major_locator(MaxNLocator(6))
    for sf in subs[len(panels):]:
        sf.set_visible(False)
    labels = {"active": ("active", "posterior density given active (integrates to 1)"),
              "atom": ("atom", "P(c=0): no penalty (atom at 0)"),
              "truth": ("truth", "truth"), "bound": ("bound", "prior bound"),
              "minpen": ("minpen", "min|w_p|: smallest penalty the rankings require (identified)")}
    fig.legend(handles=_legend_handles([labels[k] for k, v in used.items() if v]), loc="outside lower center",
               ncol=4, frameon=False)
    fig.suptitle("Posterior: each penalty given its constraint is active, with "
                 + {"posterior": "P(c=1)", "chain_frequency": "the frequency on in the chain (not a posterior "
                    "probability)", "fixed": "no indicators (bpl)"}[meaning] + "; each parameter while active")
    return fig


# --------------------------------------------------------------------------------------------- P(constraint)
@_styled
def plot_p_constraint(post: Any, *, truth: Mapping[str, float] | None = None,
                      units: Mapping[str, str] | None = None) -> Any:
    """Bar chart of :math:`P(c_j = 1 \\mid \\mathcal{D})` per feature with its value, per-chain estimates as
    dots, and bars coloured by the truth where it is known (non-zero true penalty = constraint). For the
    ``paper`` / ``authors`` samplers the bars are the frequency on in the chain and are named so (not a
    posterior probability, :data:`pbicrl.inference.draws.INDICATOR_MEANINGS`); a ``bpl`` run has no
    indicators (``ValueError``).

    ``units`` is accepted for a common signature; this figure has no axis in units.

    Parameters
    ----------
    post : Posterior or RunRecord
    truth : mapping, optional
        True effective penalties and parameter values by name (see the module docstring).
    units : mapping, optional
        Axis units by name: ``"reward"``, a feature, ``"state"``, a parameter.

    Returns
    -------
    matplotlib.figure.Figure
    """
    Figure = _mpl()
    names = list(post.feature_names)
    meaning = _meaning(post)
    if meaning == "fixed":
        raise ValueError("post: a bpl run has no indicators (every candidate is in the model): no P(c=1) to plot")
    ind = np.asarray(post.indicators).astype(float)
    p = ind.reshape(-1, len(names)).mean(axis=0)
    per_chain = ind.mean(axis=1)  # (chains, d)
    fig = Figure(figsize=(max(5.0, 1.0 * len(names) + 2.5), 4.2), layout="constrained")
    ax = fig.subplots()
    x = np.arange(len(names))
    kinds = []
    for n in names:
        tv = _truth_value(truth, n)
        kinds.append("unknown" if tv is None else ("true" if tv != 0 else "false"))
    color = {"true": "C3", "false": "C0", "unknown": "C7"}
    ax.bar(x, p, color=[color[k] for k in kinds], alpha=0.8, width=0.7)
    for k in range(len(names)):
        # one row of values above 1, where neither bars nor per-chain dots (at most 1) can be
        ax.text(x[k], 1.015, f"{p[k]:.2f}", ha="center", va="bottom", fontsize=9)
    for c in range(per_chain.shape[0]):
        ax.plot(x, per_chain[c], "k.", ms=5, alpha=0.6)
    ax.set_xticks(x, names, rotation=30 if max(len(n) for n in names) > 8 else 0, ha="right"
                  if max(len(n) for n in names) > 8 else "center")
    ax.set_ylim(0, 1.12)
    ax.set_yticks([0, 0.25, 0.5, 0.75, 1])
    ax.set_ylabel("P(constraint | data)" if meaning == "posterior" else "frequency on in the chain")
    ax.set_xlabel("feature")
    if meaning == "posterior":  # the selection threshold; a chain frequency selects nothing
        ax.axhline(0.5, color="k", lw=0.5, ls=":")
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    label = {"true": "true constraint", "false": "not a constraint", "unknown": "truth unknown"}
    handles = [Patch(color=color[k], alpha=0.8, label=label[k]) for k in ("true", "false", "unknown")
               if k in kinds and (truth or k != "unknown")]
    handles.append(Line2D([], [], color="k", marker=".", ls="none", ms=6, label="per chain"))
    fig.legend(handles=handles, loc="outside lower center", ncol=len(handles), frameon=False)
    fig.suptitle("Posterior probability that each feature is a constraint" if meaning == "posterior" else
                 f"Frequency on in the chain ({post.sampler} sampler: not a posterior probability)")
    return fig


# --------------------------------------------------------------------------------------------- pairs
@_styled
def plot_pairs(post: Any, *, truth: Mapping[str, float] | None = None,
               units: Mapping[str, str] | None = None) -> Any | None:
    """Penalty vs location: for every parametric constraint, a scatter of its penalty :math:`w_p` against each of
    its parameters over the draws where it is active, with true values and prior bounds.

    Returns ``None`` if the posterior has no parameters.

    Parameters
    ----------
    post : Posterior or RunRecord
    truth : mapping, optional
        True effective penalties and parameter values by name (see the module docstring).
    units : mapping, optional
        Axis units by name: ``"reward"``, a feature, ``"state"``, a parameter.

    Returns
    -------
    matplotlib.figure.Figure
    """
    params, pnames = parameter_draws(post)
    if params is None:
        return None
    Figure = _mpl()
    U = _units(post, units)
    owner = _owner(post, pnames)
    names = list(post.feature_names)
    c = np.asarray(post.indicators).reshape(-1, len(names)).astype(bool)
    w = np.asarray(post.penalty_weights, dtype=np.float64).reshape(-1, len(names))
    th = params.reshape(-1, params.shape[2])
    wb = _weight_bounds(post)
    pb = _param_bounds(post, pnames)
    panels = [(k, j) for k, j in enumerate(owner) if j is not None]
    if not panels:
        return None
    nrow, ncol = _grid(len(panels))
    fig = Figure(figsize=(max(6.0, 5.0 * ncol), 4.2 * nrow + 0.6), layout="constrained")
    axes = np.atleast_1d(fig.subplots(nrow, ncol, squeeze=False)).ravel()
    rng = np.random.default_rng(0)  # only picks which draws to show
    any_truth = any_bound = False
    for ax, (k, j) in zip(axes, panels):
        sel = c[:, j] & np.isfinite(th[:, k])
        xs, ys = th[sel, k], w[sel, j]
        ax.set_title(f"{names[j]}: {_p_label(_meaning(post), True)}={c[:, j].mean():.2f}, "
                     f"{int(sel.sum())} active draws")
        ax.set_xlabel(U.param_label(pnames[k]))
        ax.set_ylabel(f"penalty w_p of {names[j]}\n({U.penalty(names[j])})")
        if not xs.size:
            _blank(ax, f"never active ({_p_label(_meaning(post), True)}=0)")
            continue
        if xs.size > _MAX_SCATTER_POINTS:
            pick = rng.choice(xs.size, _MAX_SCATTER_POINTS, replace=False)
            xs, ys = xs[pick], ys[pick]
        ax.plot(xs, ys, ".", ms=2.5, alpha=0.35, color=_ACTIVE, rasterized=True)
        tx, ty = _truth_value(truth, pnames[k]), _truth_value(truth, names[j])
        ty = None if ty == 0 else ty
        xl, yl = _take_in(_limits(xs), [tx]), _take_in(_limits(ys), [ty])
        ax.set_xlim(xl)
        ax.set_ylim(yl)
        for value, lim, axis in ((tx, xl, "x"), (ty, yl, "y")):
            if value is not None:
                _mark(ax, value, lim, axis=axis, text="truth", row=1)  # below a y-axis label in the corner
                any_truth = True
        if tx is not None and ty is not None and xl[0] <= tx <= xl[1] and yl[0] <= ty <= yl[1]:
            ax.plot([tx], [ty], "*", color=_TRUTH, ms=14, zorder=5)
        any_bound |= _mark_bounds(ax, pb.get(pnames[k]), xl, axis="x")
        any_bound |= _mark_bounds(ax, wb[j], yl, axis="y")
    for ax in axes[len(panels):]:
        ax.set_visible(False)
    marks = [("active", "active draws")] + ([("truth", "truth")] if any_truth else []) + \
        ([("bound", "prior bound")] if any_bound else [])
    fig.legend(handles=_legend_handles(marks), loc="outside lower center", ncol=len(marks), frameon=False)
    fig.suptitle("Penalty vs location of each parametric constraint")
    return fig


# --------------------------------------------------------------------------------------------- rewards
def _weights_known(post: Any, dataset: Any) -> NDArray[np.float64]:
    names = list(post.feature_names)
    d_known = dataset.n_features
    settings = _settings(post)
    wn = np.asarray(settings.get("nominal_weights") if settings.get("nominal_weights") is not None
                    else (dataset.nominal_weights if dataset.nominal_weights is not None else np.zeros(d_known)),
                    dtype=np.float64).reshape(-1)
    if list(dataset.feature_names) != names[:d_known] or wn.size != d_known:
        raise ValueError(f"data: the dataset's features {list(dataset.feature_names)} do not match the run's "
                         f"{names[:d_known]}; pass the dataset the run was inferred from (--data)")
    return wn


def _returns(post: Any, dataset: Any, effective: NDArray[np.float64],
             theta: NDArray[np.float64] | None) -> NDArray[np.float64]:
    """Length-normalised returns under nominal weights + ``effective`` penalties, constraint features at ``theta``."""
    names = list(post.feature_names)
    d_known = dataset.n_features
    wn = _weights_known(post, dataset)
    feats = [dataset.mean_features]
    if len(names) > d_known:
        from pbicrl.inference.constraints import constraint_set_of

        cs = constraint_set_of(post, dataset)
        if cs is None:
            raise ValueError(f"data: the run has {len(names) - d_known} features beyond the dataset's "
                             f"{d_known} but no constraint settings to recompute them")
        th = np.asarray(theta if theta is not None else [], dtype=np.float64).reshape(-1)
        if th.size != cs.n_params:
            raise ValueError(f"run: parameters have {th.size} values, the constraints need {cs.n_params}")
        cols = []
        for m in range(cs.n_constraints):
            t = cs.theta_of(th, m)
            # an inactive constraint has NaN parameters and weight 0: its feature does not matter
            cols.append(cs.mean_feature(m, t) if np.all(np.isfinite(t)) else np.zeros(dataset.n_trajectories))
        feats.append(np.column_stack(cols))
        wn = np.concatenate([wn, np.zeros(len(names) - d_known)])
    return np.hstack(feats) @ (wn + np.asarray(effective, dtype=np.float64))


def estimate_returns(post: Any, dataset: Any, estimator: str = "selected") -> NDArray[np.float64]:
    """Length-normalised return of every trajectory, (N,), under a point estimate
    (:meth:`~pbicrl.inference.draws.DrawsView.point_estimate`; default the selected set at its conditional
    medians, the estimate the labelling page and the reports use)."""
    eff, theta = post.point_estimate(estimator)
    if theta is not None and np.size(theta) and not np.all(np.isfinite(theta)):
        theta = np.where(np.isfinite(theta), theta, 0.0)  # parameters of constraints that are off: weight 0
    return _returns(post, dataset, np.nan_to_num(np.asarray(eff, dtype=np.float64)), theta)


def map_returns(post: Any, dataset: Any) -> NDArray[np.float64]:
    """Length-normalised return :math:`\\bar r(\\tau_i)` of every trajectory under the MAP, (N,).

    Uses the run's nominal weights and MAP :math:`(c, w_p)`; parametric constraint features are recomputed
    at the MAP parameters from the dataset's states.
    """
    eff = np.asarray(post.map_indicators, dtype=np.float64) * np.asarray(post.map_penalty_weights, dtype=np.float64)
    return _returns(post, dataset, eff, getattr(post, "map_parameters", None))


def true_returns(post: Any, dataset: Any,
                 truth: Mapping[str, float] | None) -> tuple[NDArray[np.float64] | None, list[str]]:
    """Length-normalised returns under the true reward (nominal weights + true effective penalties).

    Returns
    -------
    returns : ndarray (N,) or None
        None when ``truth`` lacks a value the reward needs.
    missing : list of str
        The names it lacks: every feature, and the parameters of constraints with a non-zero true penalty.
    """
    names = list(post.feature_names)
    if not truth:
        return None, names
    missing = [n for n in names if _truth_value(truth, n) is None]
    params, pnames = parameter_draws(post)
    theta = None
    if pnames:
        owner = _owner(post, pnames)
        theta = np.full(len(pnames), np.nan)
        for k, n in enumerate(pnames):
            tv = _truth_value(truth, n)
            j = owner[k]
            needed = j is None or (_truth_value(truth, names[j]) or 0.0) != 0.0
            if tv is None and needed:
                missing.append(n)
            elif tv is not None:
                theta[k] = tv
    if missing:
        return None, missing
    eff = np.array([_truth_value(truth, n) for n in names], dtype=np.float64)
    return _returns(post, dataset, eff, theta), []


def _rankdata(x: NDArray[np.float64]) -> NDArray[np.float64]:
    """Ranks with ties averaged (many trajectories share a return when features are indicators)."""
    order = np.argsort(x, kind="mergesort")
    ranks = np.empty(x.size)
    ranks[order] = np.arange(x.size, dtype=np.float64)
    _, inv, counts = np.unique(x, return_inverse=True, return_counts=True)
    sums = np.bincount(inv, weights=ranks)
    return sums[inv] / counts[inv]


def _spearman(x: NDArray[np.float64], y: NDArray[np.float64]) -> float:
    rx, ry = _rankdata(x), _rankdata(y)
    if np.ptp(rx) == 0 or np.ptp(ry) == 0:
        return float("nan")
    return float(np.corrcoef(rx, ry)[0, 1])


def _strip(ax: Any, data: Sequence[NDArray[np.float64]], positions: Sequence[float], rng: np.random.Generator,
           colors: Sequence[Any]) -> None:
    """Box (quartiles, whiskers to 1.5 IQR) over every trajectory as a jittered dot."""
    ax.boxplot(list(data), positions=list(positions), widths=0.55, showfliers=False, zorder=3,
               medianprops={"color": "k", "lw": 1.5}, boxprops={"lw": 1}, whiskerprops={"lw": 1})
    for pos, x, col in zip(positions, data, colors):
        ax.plot(pos + rng.uniform(-0.2, 0.2, x.size), x, ".", ms=3.5, alpha=0.5, color=col, zorder=2,
                rasterized=True)


@_styled
def plot_rewards(post: Any, dataset: Any, *, truth: Mapping[str, float] | None = None,
                 units: Mapping[str, str] | None = None) -> Any:
    """Distribution of the length-normalised return per group under the selected-set estimate (the selected
    constraints at their conditional medians, as on the labelling page; :func:`estimate_returns`).

    Left: all groups on one scale (a good posterior orders them, group 1 highest). Right: each group on its own
    scale, so a tight group is a distribution and not a line. With a complete ``truth``, a bottom panel plots
    the estimated return against the true return of every trajectory with Spearman's rank correlation: the true
    reward's ordering against the inferred one (an incomplete ``truth`` is named in the title instead).

    Parameters
    ----------
    post : Posterior or RunRecord
    dataset : Dataset
        The dataset the run was inferred from.
    truth, units : mapping, optional
        As for the other figures.

    Returns
    -------
    matplotlib.figure.Figure
    """
    Figure = _mpl()
    U = _units(post, units)
    r = estimate_returns(post, dataset, "selected")
    labels = list(dataset.group_labels)
    K = len(labels)
    data = [r[dataset.group == g] for g in labels]
    cols = _style.group_colours(K)  # best green ... worst red, as on the labelling page
    gname = {g: (dataset.group_name(g) if dataset.group_names else f"G{g}") for g in labels}
    rt, missing = true_returns(post, dataset, truth) if truth else (None, [])
    fig = Figure(figsize=(max(8.0, 2.0 * K + 5.0), 4.4 + (4.0 if rt is not None else 0.0)), layout="constrained")
    gs = fig.add_gridspec(2 if rt is not None else 1, K + 2)
    rng = np.random.default_rng(0)  # jitter only
    ax = fig.add_subplot(gs[0, :2])
    _strip(ax, data, np.arange(K), rng, cols)
    ax.set_xticks(np.arange(K), [f"{gname[g]}\n(n={x.size})" for g, x in zip(labels, data)])
    ax.set_ylabel(f"reward per step ({U.reward})")
    ax.set_xlabel("group (best first)")
    ax.set_title("all groups, one scale")
    for k, (g, x) in enumerate(zip(labels, data)):
        zx = fig.add_subplot(gs[0, 2 + k])
        _strip(zx, [x], [0], rng, [cols[k]])
        zx.set_xticks([0], [gname[g]])
        zx.set_xlabel("group")
        zx.set_title(f"{gname[g]} (n={x.size}),\nown scale", fontsize=9.5)
        zx.set_ylabel("reward per step", fontsize=8.5)
        if x.size and np.ptp(x) == 0:
            zx.text(0.5, 0.02, "all equal", ha="center", va="bottom", transform=zx.transAxes, fontsize=8.5)
        from matplotlib.ticker import MaxNLocator

        zx.yaxis.set_major_locator(MaxNLocator(5))
    if rt is not None:
        sx = fig.add_subplot(gs[1, :])
        for k, g in enumerate(labels):
            m = dataset.group == g
            sx.plot(rt[m], r[m], ".", ms=4, alpha=0.5, color=cols[k], label=gname[g], rasterized=True)
            # open diamonds: a filled one hid a tight group's trajectories under it
            sx.plot([rt[m].mean()], [r[m].mean()], "D", ms=10, mfc="none", mec="k", mew=1.8, zorder=5)
        sx.set_xlabel(f"true reward per step ({U.reward})")
        sx.set_ylabel(f"estimated reward per step ({U.reward})")
        means = " > ".join(gname[g] for g in sorted(labels, key=lambda g: -rt[dataset.group == g].mean()))
        sx.set_title(f"estimated vs true reward per trajectory (open diamonds: group means): Spearman \u03c1 = "
                     f"{_spearman(rt, r):.3f}; true order of group means {means}")
        sx.legend(loc="upper left", bbox_to_anchor=(1.0, 1.0), frameon=False, markerscale=2)  # off the data
    title = ("Reward per step of each trajectory by group (best first), under the selected set at its "
             "conditional medians")
    if truth and rt is None:
        title += f"\n(true reward not drawn: --truth lacks {', '.join(missing)})"
    fig.suptitle(title)
    return fig


# --------------------------------------------------------------------------------------------- truth
def check_truth(truth: Mapping[str, float] | None, feature_names: Sequence[str],
                parameter_names: Sequence[str] = ()) -> dict[str, float] | None:
    """Validate ``truth`` against a run's names.

    Raises
    ------
    ValueError
        Naming every unknown name and listing the known ones, or a value that is not a finite number.
    """
    if truth is None:
        return None
    known = [str(n) for n in feature_names] + [str(n) for n in parameter_names]
    unknown = [str(k) for k in truth if str(k) not in known]
    if unknown:
        raise ValueError(f"truth: unknown name{'s' if len(unknown) > 1 else ''} "
                         f"{', '.join(repr(u) for u in unknown)}; known names: {', '.join(known)}")
    out = {}
    for k, v in truth.items():
        try:
            x = float(v)
        except (TypeError, ValueError):
            raise ValueError(f"truth: value of {k!r} is not a number: {v!r}") from None
        if not np.isfinite(x):
            raise ValueError(f"truth: value of {k!r} is not finite: {v!r}")
        out[str(k)] = x
    return out


def parse_truth(text: str | None, feature_names: Sequence[str],
                parameter_names: Sequence[str] | None = None) -> dict[str, float] | None:
    """Parse a ``truth`` specification: a JSON file (``{"name": value}`` or ``{"true_penalty": [...]}``), ``name=value,...`` pairs,
    or one value per feature in order (``0,-10,-100,0``).

    Names are checked (:func:`check_truth`) when ``parameter_names`` is given (``()`` for a run without
    parameters); :func:`plot_run` checks them in any case.
    """
    if text is None:
        return None
    names = list(feature_names)
    out = _parse_truth(text, names)
    if parameter_names is not None:
        out = check_truth(out, names, parameter_names)
    return out


def _parse_truth(text: str, names: list[str]) -> dict[str, float]:
    p = Path(text)
    if p.suffix == ".json" or p.is_file():
        obj = read_json(p, "truth")
        if isinstance(obj, dict) and "true_penalty" in obj:
            obj = obj["true_penalty"]
        if isinstance(obj, list):
            return _truth_list(obj, names)
        if not isinstance(obj, dict):
            raise ValueError("truth: the JSON file must hold an object {name: value} or a list of values")
        try:
            return {str(k): float(v) for k, v in obj.items()}
        except (TypeError, ValueError):
            raise ValueError("truth: values must be numbers") from None
    if "=" in text:
        out = {}
        for item in text.split(","):
            if not item.strip():
                continue
            if "=" not in item:
                raise ValueError(f"truth: expected name=value pairs, got {item!r}")
            k, v = item.split("=", 1)
            try:
                out[k.strip()] = float(v)
            except ValueError:
                raise ValueError(f"truth: value of {k.strip()!r} is not a number: {v!r}") from None
        return out
    return _truth_list(text.replace(",", " ").split(), names)


def _truth_list(values: Sequence[Any], names: Sequence[str]) -> dict[str, float]:
    try:
        vals = [float(v) for v in values]
    except (TypeError, ValueError):
        raise ValueError("truth: values must be numbers") from None
    if len(vals) != len(names):
        raise ValueError(f"truth: expected {len(names)} values (one per feature: {', '.join(names)}), "
                         f"got {len(vals)}")
    return dict(zip(names, vals))


# --------------------------------------------------------------------------------------------- all figures
def _meaning(post: Any) -> str:
    from pbicrl.inference.draws import indicator_meaning
    return indicator_meaning(getattr(post, "sampler", None))


def _in_model(post: Any, d: int) -> NDArray[np.bool_]:
    f = getattr(post, "in_model", None)
    return np.asarray(f(), dtype=bool) if callable(f) else np.ones(d, dtype=bool)


def _p_label(meaning: str, is_penalty: bool) -> str:
    """What the share of draws with the constraint on is called (:data:`pbicrl.inference.draws.INDICATOR_MEANINGS`)."""
    if meaning == "posterior":
        return "P(c=1)" if is_penalty else "P(active)"
    return "freq on" if meaning == "chain_frequency" else "in the model"


def _save(fig: Any, path: Path, dpi: int) -> None:
    fig.savefig(path, dpi=dpi)


def plot_run(run: Any, out_dir: str | os.PathLike[str] | None = None, *, dataset: Any = None,
             truth: Mapping[str, float] | None = None, fmt: str = "png", dpi: int | None = None,
             units: Mapping[str, str] | None = None, overwrite: bool = False) -> list[Path]:
    """Write every figure of a run: ``trace``, ``posterior``, ``p_constraint``, ``pairs`` (parametric constraints
    only) and ``rewards`` (when the dataset is known).

    Parameters
    ----------
    run : path, RunRecord or Posterior
        A run directory (``summary.json`` + ``chains.npz``) or a posterior.
    out_dir : path, optional
        Default ``RUN_DIR/plots``. Files are rendered in a temporary directory and moved in when all succeeded.
    dataset : Dataset or path, optional
        For the rewards plot; default: the dataset recorded in the run (``extra.data.path``) if it exists.
    truth : mapping, optional
        True effective penalties / parameters by name; checked with :func:`check_truth` before anything is drawn.
    fmt : {"png", "pdf", "svg"}
    dpi : int, optional
        Default :data:`DEFAULT_DPI`.
    units : mapping, optional
        Axis units by name (``"reward"``, a feature, ``"state"``, a parameter); default: the dataset's
        ``units`` attribute when it has one.
    overwrite : bool
        Replace figures of the same names already in ``out_dir`` (otherwise an existing one is an error,
        raised before anything is drawn).

    Returns
    -------
    list of Path
        The files written.

    Raises
    ------
    ValueError
        For an unknown format, a non-positive dpi, or a ``truth`` with an unknown name.
    OutputExistsError
        A figure file exists and ``overwrite`` is false.
    """
    from pbicrl.inference.data import Dataset, load_dataset
    from pbicrl.io.runs import read_run

    if fmt not in FORMATS:
        raise ValueError(f"fmt: expected one of {', '.join(FORMATS)}, got {fmt!r}")
    dpi = DEFAULT_DPI if dpi is None else int(dpi)
    if dpi < 1:
        raise ValueError(f"dpi: expected a positive number, got {dpi}")
    _mpl()
    if isinstance(run, (str, os.PathLike)):
        run = read_run(run)
    truth = check_truth(truth, run.feature_names, tuple(getattr(run, "parameter_names", None) or ()))
    default_out = out_dir is None
    if out_dir is None:
        base = getattr(run, "path", None)
        if base is None:
            raise ValueError("out_dir: required when plotting a Posterior that was not loaded from a run directory")
        out_dir = Path(base) / "plots"
    out = Path(out_dir)
    from pbicrl._atomic import check_file_output, mark_output, read_marker

    will_have_rewards = dataset is not None or _recorded_dataset(run) is not None
    parametric = bool(tuple(getattr(run, "parameter_names", None) or ()))
    for name in ("trace", "posterior", "p_constraint", *(("pairs",) if parametric else ()),
                 *(("rewards",) if will_have_rewards else ())):
        check_file_output(out / f"{name}.{fmt}", overwrite=overwrite, field="out_dir")
    if dataset is None:
        dataset = _recorded_dataset(run)
    if isinstance(dataset, (str, os.PathLike)):
        dataset = load_dataset(dataset)
    if dataset is not None and not isinstance(dataset, Dataset):
        raise TypeError(f"dataset: expected a Dataset or a path, got {type(dataset).__name__}")
    if units is None and dataset is not None and isinstance(getattr(dataset, "units", None), Mapping):
        units = dataset.units
    kw = {"truth": truth, "units": units}
    figures = {"trace": plot_traces(run, **kw), "posterior": plot_posteriors(run, **kw)}
    if _meaning(run) != "fixed":  # bpl: no indicators
        figures["p_constraint"] = plot_p_constraint(run, **kw)
    pairs = plot_pairs(run, **kw)
    if pairs is not None:
        figures["pairs"] = pairs
    if dataset is not None:
        figures["rewards"] = plot_rewards(run, dataset, **kw)
    # every figure is rendered before any file is replaced: a failing figure leaves the old set untouched
    with contextlib.ExitStack() as stack:
        temps = {name: stack.enter_context(atomic_path(out / f"{name}.{fmt}", overwrite=overwrite, field="out_dir"))
                 for name in figures}
        for name, fig in figures.items():
            _save(fig, temps[name], dpi)
    marker = read_marker(out.parent) if default_out else None
    if marker is not None and marker[0] == "run":  # RUN/plots belongs to the run: a later overwrite may replace it
        mark_output(out.parent, "run", [out.name])
    return [out / f"{name}.{fmt}" for name in figures]


def _recorded_dataset(run: Any) -> Path | None:
    dp = getattr(run, "data_path", None)
    if dp is None:
        dp = (getattr(run, "extra", {}) or {}).get("data", {}).get("path")
    return Path(dp) if dp is not None and Path(dp).is_file() else None
