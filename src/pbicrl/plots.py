"""Figures of a posterior: traces, posterior densities, P(constraint), penalty-vs-location pairs, MAP rewards.

Matplotlib (``pip install "pbicrl[plot]"``) is imported lazily and used without ``pyplot`` (figures render
with the Agg canvas), so plotting never changes the caller's backend. Every function takes a
:class:`~pbicrl.results.Posterior` or a run loaded with :func:`pbicrl.runs.load_run` and returns a
``matplotlib.figure.Figure``; :func:`plot_run` writes them all for a run directory.

``truth`` (optional, e.g. for synthetic data) maps feature names to the true effective penalty
:math:`c_j w_{p,j}` (0 = not a constraint) and parameter names to their true values.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

__all__ = ["plot_traces", "plot_posteriors", "plot_p_constraint", "plot_pairs", "plot_rewards", "plot_run",
           "map_returns", "parse_truth", "FORMATS"]

FORMATS = ("png", "pdf", "svg")
_MAX_TRACE_POINTS = 1500


def _mpl() -> Any:
    try:
        from matplotlib.figure import Figure
    except ImportError as exc:
        raise ImportError(f"plots need matplotlib ({exc}): pip install \"pbicrl[plot]\"") from exc
    return Figure


def _colors(n: int) -> list:
    from matplotlib import colormaps

    cmap = colormaps["tab10"]
    return [cmap(k % 10) for k in range(n)]


def _params(post: Any) -> tuple[NDArray[np.float64] | None, list[str]]:
    p = getattr(post, "parameters", None)
    if p is None or not np.size(p):
        return None, []
    p = np.asarray(p, dtype=np.float64)
    if p.ndim == 2:
        p = p[:, :, None]
    names = list(getattr(post, "parameter_names", None) or [f"theta{k}" for k in range(p.shape[2])])
    return p, names


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


def _truth_value(truth: Mapping[str, float] | None, name: str) -> float | None:
    if not truth or name not in truth or truth[name] is None:
        return None
    return float(truth[name])


def plot_traces(post: Any, *, truth: Mapping[str, float] | None = None) -> Any:
    """Trace (left) and per-chain histogram (right) of every penalty :math:`c_j w_{p,j}`, parameter and the
    log-likelihood; the true value is a dashed line where known."""
    Figure = _mpl()
    names = list(post.feature_names)
    eff = np.asarray(post.indicators) * np.asarray(post.penalty_weights, dtype=np.float64)
    rows: list[tuple[str, NDArray[np.float64], float | None]] = [
        (f"c*w_p  {n}", eff[:, :, j], _truth_value(truth, n)) for j, n in enumerate(names)]
    params, pnames = _params(post)
    if params is not None:
        rows += [(f"{n}", params[:, :, k], _truth_value(truth, n)) for k, n in enumerate(pnames)]
    rows.append(("log-likelihood", np.asarray(post.log_likelihood, dtype=np.float64), None))
    C, D = rows[0][1].shape
    step = max(1, D // _MAX_TRACE_POINTS)
    cols = _colors(C)
    fig = Figure(figsize=(10, 1.7 * len(rows) + 0.6), layout="constrained")
    axes = fig.subplots(len(rows), 2, squeeze=False, gridspec_kw={"width_ratios": [3, 1]})
    x = np.arange(0, D, step)
    for r, (label, draws, tv) in enumerate(rows):
        ax, hx = axes[r]
        for c in range(C):
            ax.plot(x, draws[c, ::step], lw=0.6, color=cols[c], alpha=0.8, label=f"chain {c}")
            fin = draws[c][np.isfinite(draws[c])]
            if fin.size:
                hx.hist(fin, bins=40, histtype="step", color=cols[c], orientation="horizontal", density=True)
        if tv is not None:
            ax.axhline(tv, color="k", ls="--", lw=1)
            hx.axhline(tv, color="k", ls="--", lw=1)
        ax.set_ylabel(label, fontsize=8)
        ax.tick_params(labelsize=7)
        hx.tick_params(labelsize=7, labelleft=False)
        hx.sharey(ax)
    axes[-1, 0].set_xlabel("kept draw")
    axes[-1, 1].set_xlabel("density")
    axes[0, 0].legend(fontsize=7, ncol=min(C, 6), loc="upper right")
    shown = "" if step == 1 else f", every {step}th shown"
    fig.suptitle(f"Traces ({C} chains x {D} draws{shown}{'; dashed = truth' if truth else ''})", fontsize=10)
    return fig


def plot_posteriors(post: Any, *, truth: Mapping[str, float] | None = None) -> Any:
    """Posterior density of each penalty given its constraint is active (area = P(c=1)), and of each parameter;
    the truth is a red line (or a note "truth: not a constraint")."""
    Figure = _mpl()
    names = list(post.feature_names)
    c = np.asarray(post.indicators).reshape(-1, len(names)).astype(bool)
    w = np.asarray(post.penalty_weights, dtype=np.float64).reshape(-1, len(names))
    params, pnames = _params(post)
    panels: list[tuple[str, NDArray[np.float64], float, float | None, bool]] = []
    for j, n in enumerate(names):
        panels.append((n, w[c[:, j], j], float(c[:, j].mean()), _truth_value(truth, n), True))
    if params is not None:
        flat = params.reshape(-1, params.shape[2])
        for k, n in enumerate(pnames):
            x = flat[:, k]
            x = x[np.isfinite(x)]
            panels.append((n, x, 1.0, _truth_value(truth, n), False))
    ncol = min(4, len(panels))
    nrow = -(-len(panels) // ncol)
    fig = Figure(figsize=(3.2 * ncol, 2.6 * nrow), layout="constrained")
    axes = np.atleast_1d(fig.subplots(nrow, ncol, squeeze=False)).ravel()
    for ax, (name, x, p_on, tv, is_pen) in zip(axes, panels):
        if x.size:
            h, edges = np.histogram(x, bins=40)
            widths = np.diff(edges)
            dens = h / max(h.sum(), 1) / np.where(widths > 0, widths, 1) * p_on
            ax.stairs(dens, edges, fill=True, alpha=0.5, color="C0")
        else:
            ax.text(0.5, 0.5, "never active", ha="center", va="center", transform=ax.transAxes, fontsize=9)
        if tv is not None and (tv != 0 or not is_pen):
            ax.axvline(tv, color="C3", lw=1.5, label="truth")
            ax.legend(fontsize=7, loc="upper right")
        elif tv is not None and is_pen:
            ax.text(0.02, 0.95, "truth: not a constraint", color="C3", fontsize=7, va="top", transform=ax.transAxes)
        title = f"{name}  P(c=1)={p_on:.2f}" if is_pen else f"{name} (while active)"
        ax.set_title(title, fontsize=9)
        ax.set_xlabel("penalty w_p | c=1" if is_pen else "value", fontsize=8)
        ax.tick_params(labelsize=7)
    for ax in axes[len(panels):]:
        ax.set_visible(False)
    fig.suptitle("Posterior densities (penalty: given the constraint is active; area = P(c=1))", fontsize=10)
    return fig


def plot_p_constraint(post: Any, *, truth: Mapping[str, float] | None = None) -> Any:
    """Bar chart of :math:`P(c_j = 1 \\mid \\mathcal{D})` per feature, with per-chain estimates as dots and
    true constraints (non-zero true penalty) marked."""
    Figure = _mpl()
    names = list(post.feature_names)
    ind = np.asarray(post.indicators).astype(float)
    p = ind.reshape(-1, len(names)).mean(axis=0)
    per_chain = ind.mean(axis=1)  # (chains, d)
    fig = Figure(figsize=(max(4.0, 0.9 * len(names) + 2), 3.4), layout="constrained")
    ax = fig.subplots()
    x = np.arange(len(names))
    colors = []
    for n in names:
        tv = _truth_value(truth, n)
        colors.append("C7" if tv is None else ("C3" if tv != 0 else "C0"))
    ax.bar(x, p, color=colors, alpha=0.8)
    for c in range(per_chain.shape[0]):
        ax.plot(x, per_chain[c], "k.", ms=4, alpha=0.6, label="per chain" if c == 0 else None)
    ax.set_xticks(x, names, rotation=30, ha="right", fontsize=8)
    ax.set_ylim(0, 1.05)
    ax.set_ylabel("P(constraint | data)")
    ax.axhline(0.5, color="k", lw=0.5, ls=":")
    if truth:
        from matplotlib.patches import Patch

        handles = [Patch(color="C3", label="true constraint"), Patch(color="C0", label="not a constraint")]
        ax.legend(handles=handles + ax.get_legend_handles_labels()[0], fontsize=7, loc="upper right")
    else:
        ax.legend(fontsize=7, loc="upper right")
    ax.set_title("Posterior probability of each constraint", fontsize=10)
    return fig


def plot_pairs(post: Any, *, truth: Mapping[str, float] | None = None) -> Any | None:
    """Penalty vs location: for every parametric constraint, a scatter of its penalty :math:`w_p` against each of
    its parameters over the draws where it is active. ``None`` if the posterior has no parameters."""
    params, pnames = _params(post)
    if params is None:
        return None
    Figure = _mpl()
    owner = _owner(post, pnames)
    names = list(post.feature_names)
    c = np.asarray(post.indicators).reshape(-1, len(names)).astype(bool)
    w = np.asarray(post.penalty_weights, dtype=np.float64).reshape(-1, len(names))
    th = params.reshape(-1, params.shape[2])
    panels = [(k, j) for k, j in enumerate(owner) if j is not None]
    if not panels:
        return None
    ncol = min(3, len(panels))
    nrow = -(-len(panels) // ncol)
    fig = Figure(figsize=(3.6 * ncol, 3.2 * nrow), layout="constrained")
    axes = np.atleast_1d(fig.subplots(nrow, ncol, squeeze=False)).ravel()
    rng = np.random.default_rng(0)  # only picks which draws to show
    for ax, (k, j) in zip(axes, panels):
        sel = c[:, j] & np.isfinite(th[:, k])
        xs, ys = th[sel, k], w[sel, j]
        if xs.size > 4000:
            pick = rng.choice(xs.size, 4000, replace=False)
            xs, ys = xs[pick], ys[pick]
        ax.plot(xs, ys, ".", ms=2, alpha=0.3, color="C0")
        tx, ty = _truth_value(truth, pnames[k]), _truth_value(truth, names[j])
        if tx is not None:
            ax.axvline(tx, color="C3", lw=1)
        if ty is not None and ty != 0:
            ax.axhline(ty, color="C3", lw=1)
        if tx is not None and ty is not None and ty != 0:
            ax.plot([tx], [ty], "*", color="C3", ms=12, label="truth")
            ax.legend(fontsize=7)
        ax.set_xlabel(pnames[k], fontsize=8)
        ax.set_ylabel(f"penalty w_p of {names[j]}", fontsize=8)
        ax.set_title(f"{names[j]}: P(c=1)={c[:, j].mean():.2f}, {int(sel.sum())} active draws", fontsize=9)
        ax.tick_params(labelsize=7)
    for ax in axes[len(panels):]:
        ax.set_visible(False)
    fig.suptitle("Penalty vs location of parametric constraints", fontsize=10)
    return fig


def map_returns(post: Any, dataset: Any) -> NDArray[np.float64]:
    """Length-normalised return :math:`\\bar r(\\tau_i)` of every trajectory under the MAP, (N,).

    Uses the run's nominal weights and MAP :math:`(c, w_p)`; parametric constraint features are recomputed
    at the MAP parameters from the dataset's states.
    """
    names = list(post.feature_names)
    d_known = dataset.n_features
    settings = dict(getattr(post, "settings", {}) or {})
    wn = np.asarray(settings.get("nominal_weights") if settings.get("nominal_weights") is not None
                    else (dataset.nominal_weights if dataset.nominal_weights is not None else np.zeros(d_known)),
                    dtype=np.float64).reshape(-1)
    if list(dataset.feature_names) != names[:d_known] or wn.size != d_known:
        raise ValueError(f"data: the dataset's features {list(dataset.feature_names)} do not match the run's "
                         f"{names[:d_known]}; pass the dataset the run was inferred from (--data)")
    feats = [dataset.mean_features]
    specs = settings.get("constraints")
    if len(names) > d_known:
        if not specs:
            raise ValueError(f"data: the run has {len(names) - d_known} features beyond the dataset's "
                             f"{d_known} but no constraint settings to recompute them")
        from pbicrl.constraints import ConstraintSet, constraint_from_dict

        cons = []
        for spec in specs:
            spec = {k: v for k, v in spec.items() if k != "resolved_bounds"}
            cons.append(constraint_from_dict(spec))
        cs = ConstraintSet(tuple(cons), dataset)
        theta = np.asarray(getattr(post, "map_parameters", None), dtype=np.float64).reshape(-1)
        if theta.size != cs.n_params:
            raise ValueError(f"run: MAP parameters have {theta.size} values, the constraints need {cs.n_params}")
        cols = []
        for m in range(cs.n_constraints):
            t = cs.theta_of(theta, m)
            cols.append(cs.mean_feature(m, t) if np.all(np.isfinite(t)) else np.zeros(dataset.n_trajectories))
        feats.append(np.column_stack(cols))
        wn = np.concatenate([wn, np.zeros(len(names) - d_known)])
    F = np.hstack(feats)
    w = wn + np.asarray(post.map_indicators, dtype=np.float64) * np.asarray(post.map_penalty_weights, dtype=np.float64)
    return F @ w


def plot_rewards(post: Any, dataset: Any) -> Any:
    """Distribution of the MAP length-normalised return per group (box plot with every trajectory as a dot).

    A good posterior orders the groups: group 1 (best) highest."""
    Figure = _mpl()
    r = map_returns(post, dataset)
    labels = dataset.group_labels
    data = [r[dataset.group == g] for g in labels]
    fig = Figure(figsize=(max(4.0, 1.3 * len(labels) + 2), 3.6), layout="constrained")
    ax = fig.subplots()
    ax.boxplot(data, positions=np.arange(len(labels)), widths=0.5, showfliers=False)
    rng = np.random.default_rng(0)  # jitter only
    for k, x in enumerate(data):
        ax.plot(k + rng.uniform(-0.18, 0.18, x.size), x, ".", ms=4, alpha=0.6, color=f"C{k % 10}")
    ax.set_xticks(np.arange(len(labels)), [f"G{g} (n={x.size})" for g, x in zip(labels, data)], fontsize=8)
    ax.set_ylabel("MAP mean reward per step")
    ax.set_xlabel("group (1 = best)")
    ax.set_title("Reward per group under the MAP", fontsize=10)
    return fig


def parse_truth(text: str | None, feature_names: Sequence[str]) -> dict[str, float] | None:
    """``--truth``: a JSON file (``{"name": value}`` or ``{"true_penalty": [...]}``), ``name=value,...`` pairs,
    or one value per feature in order (``0,-10,-100,0``)."""
    if text is None:
        return None
    names = list(feature_names)
    p = Path(text)
    if p.suffix == ".json" or p.is_file():
        if not p.is_file():
            raise FileNotFoundError(f"--truth: {p}: no such file")
        try:
            obj = json.loads(p.read_text())
        except json.JSONDecodeError as exc:
            raise ValueError(f"--truth: {p} is not valid JSON ({exc})") from None
        if isinstance(obj, dict) and "true_penalty" in obj:
            obj = obj["true_penalty"]
        if isinstance(obj, list):
            return _truth_list(obj, names)
        if not isinstance(obj, dict):
            raise ValueError("--truth: the JSON file must hold an object {name: value} or a list of values")
        try:
            return {str(k): float(v) for k, v in obj.items()}
        except (TypeError, ValueError):
            raise ValueError("--truth: values must be numbers") from None
    if "=" in text:
        out = {}
        for item in text.split(","):
            if not item.strip():
                continue
            if "=" not in item:
                raise ValueError(f"--truth: expected name=value pairs, got {item!r}")
            k, v = item.split("=", 1)
            try:
                out[k.strip()] = float(v)
            except ValueError:
                raise ValueError(f"--truth: value of {k.strip()!r} is not a number: {v!r}") from None
        return out
    return _truth_list(text.replace(",", " ").split(), names)


def _truth_list(values: Sequence[Any], names: Sequence[str]) -> dict[str, float]:
    try:
        vals = [float(v) for v in values]
    except (TypeError, ValueError):
        raise ValueError("--truth: values must be numbers") from None
    if len(vals) != len(names):
        raise ValueError(f"--truth: expected {len(names)} values (one per feature: {', '.join(names)}), got {len(vals)}")
    return dict(zip(names, vals))


def _save(fig: Any, path: Path, dpi: int) -> None:
    fig.savefig(path, dpi=dpi)


def plot_run(run: Any, out_dir: str | os.PathLike[str] | None = None, *, dataset: Any = None,
             truth: Mapping[str, float] | None = None, fmt: str = "png", dpi: int = 110) -> list[Path]:
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
        True effective penalties / parameters by name.
    fmt : {"png", "pdf", "svg"}
    dpi : int

    Returns
    -------
    list of Path
        The files written.
    """
    from pbicrl.data import Dataset, load_dataset
    from pbicrl.runs import load_run

    if fmt not in FORMATS:
        raise ValueError(f"--format: expected one of {', '.join(FORMATS)}, got {fmt!r}")
    _mpl()
    if isinstance(run, (str, os.PathLike)):
        run = load_run(run)
    if out_dir is None:
        base = getattr(run, "path", None)
        if base is None:
            raise ValueError("out_dir: required when plotting a Posterior that was not loaded from a run directory")
        out_dir = Path(base) / "plots"
    out = Path(out_dir)
    if dataset is None:
        dp = getattr(run, "data_path", None)
        if dp is None:
            dp = (getattr(run, "extra", {}) or {}).get("data", {}).get("path")
        if dp is not None and Path(dp).is_file():
            dataset = Path(dp)
    if isinstance(dataset, (str, os.PathLike)):
        dataset = load_dataset(dataset)
    if dataset is not None and not isinstance(dataset, Dataset):
        raise TypeError(f"dataset: expected a Dataset or a path, got {type(dataset).__name__}")
    figures = {"trace": plot_traces(run, truth=truth), "posterior": plot_posteriors(run, truth=truth),
               "p_constraint": plot_p_constraint(run, truth=truth)}
    pairs = plot_pairs(run, truth=truth)
    if pairs is not None:
        figures["pairs"] = pairs
    if dataset is not None:
        figures["rewards"] = plot_rewards(run, dataset)
    out.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=".plots.tmp-", dir=out))
    written = []
    try:
        for name, fig in figures.items():
            _save(fig, tmp / f"{name}.{fmt}", dpi)
        for name in figures:
            dst = out / f"{name}.{fmt}"
            os.replace(tmp / f"{name}.{fmt}", dst)
            written.append(dst)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return written
