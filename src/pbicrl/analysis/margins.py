"""Automated margin tuning (paper Appendix B-A, done there by hand over a candidate grid).

The user states how the gaps between consecutive groups relate, e.g. "the G2-G3 gap is about 4 times the
G1-G2 gap" -> ``relation = [1, 4]``. For each candidate set of margins :math:`m_{k\\ell}` pbicrl infers the
weights, computes the group means :math:`\\mu_k` of the length-normalised returns under the inferred weights
(MAP by default), and the gaps :math:`g_k = \\mu_k - \\mu_{k+1}`. The chosen margins minimise

.. math::
    \\sum_{k \\ge 2} \\left(\\log\\frac{g_k}{g_1} - \\log\\frac{\\rho_k}{\\rho_1}\\right)^2

over candidates whose gaps are all positive (groups in the stated order). Candidates are consecutive gaps
(:math:`m_{k\\ell} = \\sum_{k \\le r < \\ell} \\delta_r`) from a grid, or explicit margin matrices.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from pbicrl.inference.data import Dataset
from pbicrl.inference.preferences import Margins
from pbicrl.inference.posterior import Posterior
from pbicrl.inference.constraints import constraint_set_of

__all__ = ["group_mean_returns", "point_weights", "relation_error", "tune_margins", "MarginTuning", "DEFAULT_GAP_GRID"]

COMPILING_NOTE = "first run: compiling the samplers if not cached"
"""What the candidates' bar says until the first run ends (Numba compiles the samplers then, up to minutes)."""

DEFAULT_GAP_GRID = (0.0, 0.5, 1.0, 1.5, 2.0, 3.0, 4.0, 6.0)
_MATRIX_MAX_GROUPS = 64  # MarginTuning.to_dict writes the K x K matrix up to this many groups (additive margins)


def group_mean_returns(dataset: Dataset, weights: ArrayLike, extra_columns: NDArray | None = None) -> NDArray[np.float64]:
    """Mean over each group (best first) of the length-normalised returns :math:`\\bar\\phi_i^\\top w`, (K,).

    ``extra_columns`` (N, M) are mean features of parametric constraints, appended after the known features.
    """
    F = dataset.mean_features if extra_columns is None else np.c_[dataset.mean_features, extra_columns]
    r = F @ np.asarray(weights, dtype=np.float64)
    labels = dataset.group_labels
    rank = np.searchsorted(labels, dataset.group)  # one pass, not one per group (a total ranking has N groups)
    inside = (rank < labels.size) & (labels[np.minimum(rank, labels.size - 1)] == dataset.group)
    return np.bincount(rank[inside], weights=r[inside], minlength=labels.size) / np.bincount(rank[inside],
                                                                                              minlength=labels.size)


def relation_error(means: ArrayLike, relation: ArrayLike) -> tuple[float, NDArray[np.float64]]:
    """(error, achieved relation): gaps relative to the first gap vs the target ``relation`` (K-1 values)."""
    mu = np.asarray(means, dtype=np.float64)
    rel = np.asarray(relation, dtype=np.float64)
    gaps = mu[:-1] - mu[1:]
    if rel.shape != gaps.shape:
        raise ValueError(f"relation: {mu.size} groups need {gaps.size} relative gap sizes, got {rel.size}")
    achieved = gaps / gaps[0] if gaps[0] != 0 else np.full_like(gaps, np.nan)
    if np.any(gaps <= 0):
        return math.inf, achieved
    return float(np.sum((np.log(gaps / gaps[0]) - np.log(rel / rel[0])) ** 2)), achieved


@dataclass(frozen=True)
class MarginTuning:
    """Result of :func:`tune_margins`.

    Attributes
    ----------
    margins : Margins
        The chosen margins.
    relation_target, relation_achieved : ndarray (K-1,)
        Gap sizes relative to the first gap, asked for and obtained.
    error : float
    group_means : ndarray (K,)
        Group means of the returns under the chosen run's weights.
    posterior : Posterior
        The inference run with the chosen margins.
    table : list of dict
        Every candidate: margins, error, achieved relation, group means.
    """

    margins: Margins
    relation_target: NDArray[np.float64]
    relation_achieved: NDArray[np.float64]
    error: float
    group_means: NDArray[np.float64]
    posterior: Posterior
    table: list[dict[str, Any]] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        # the K x K matrix only where it is small or not additive (as_dict then lists every m_kl anyway)
        small = self.margins.n_groups <= _MATRIX_MAX_GROUPS or self.margins.offsets is None
        return {"margins": self.margins.as_dict(), "margins_matrix": self.margins.matrix.tolist() if small else None,
                "relation_target": self.relation_target.tolist(), "relation_achieved": self.relation_achieved.tolist(),
                "error": self.error, "group_means": self.group_means.tolist(), "candidates": self.table}


def point_weights(post: Any, dataset: Dataset, estimator: str = "selected",
                  nominal: ArrayLike | None = None) -> tuple[NDArray[np.float64], NDArray[np.float64] | None]:
    r"""Total weights :math:`w_n + c \circ w_p` of a point estimate, over known and parametric features.

    Parameters
    ----------
    post : Posterior or RunRecord
    dataset : Dataset
        The data the weights apply to (the parametric features are computed on its states).
    estimator : {"selected", "map", "mean"}
        See :meth:`~pbicrl.inference.draws.DrawsView.point_estimate`.
    nominal : array-like (d,), optional
        :math:`w_n` of the known features (default: the dataset's, else zeros).

    Returns
    -------
    weights : ndarray (d + M,)
    columns : ndarray (N, M) or None
        Mean features of the M parametric constraints at the estimate's locations (for
        :func:`group_mean_returns`); None without parametric constraints.
    """
    eff, theta = post.point_estimate(estimator)
    eff = np.nan_to_num(np.asarray(eff, dtype=np.float64))
    theta = np.asarray(theta, dtype=np.float64)
    d = dataset.n_features
    if nominal is None:
        nominal = dataset.nominal_weights if dataset.nominal_weights is not None else np.zeros(d)
    w = np.concatenate([np.asarray(nominal, dtype=np.float64), np.zeros(eff.size - d)]) + eff
    cols = None
    cs = constraint_set_of(post, dataset) if post.parameter_names else None
    if cs is not None:
        cols = np.stack([cs.mean_feature(m, cs.theta_of(np.nan_to_num(theta), m)) for m in range(cs.n_constraints)],
                        axis=1)
    return w, cols


def tune_margins(
    dataset: Dataset,
    relation: Sequence[float],
    *,
    gap_grid: Sequence[float] = DEFAULT_GAP_GRID,
    candidates: Sequence[ArrayLike] | None = None,
    estimator: str = "selected",
    progress: bool = True,
    run: Callable[[Margins], Posterior] | None = None,
    **infer_kwargs: Any,
) -> MarginTuning:
    """Search margins so that group-mean returns under the inferred weights show ``relation``.

    Parameters
    ----------
    dataset : Dataset
    relation : sequence of K-1 positive floats
        Relative sizes of the consecutive gaps, e.g. ``[1, 4]`` for "G2-G3 is 4 times G1-G2".
    gap_grid : sequence of float
        Values tried for each consecutive gap (all combinations), unless ``candidates`` is given.
    candidates : sequence of margin specifications, optional
        Explicit candidates (K-1 gaps or K x K matrices).
    estimator : {"selected", "map", "mean"}
        Weights used for the group means: ``selected`` (default) = the selected set (P(c=1) > 0.5) with
        conditional posterior medians; ``map`` = the highest-density draw (the paper's convention).
    run : callable, optional
        ``run(margins) -> Posterior``; default: :func:`pbicrl.infer` with ``infer_kwargs``.
    **infer_kwargs
        Passed to :func:`pbicrl.infer` (e.g. ``iterations``, ``sampler``, ``seed``, ``constraints``).
    """
    from pbicrl.api import infer

    K = dataset.n_groups
    rel = np.asarray(relation, dtype=np.float64).reshape(-1)
    if rel.size != K - 1 or np.any(~np.isfinite(rel)) or np.any(rel <= 0):
        raise ValueError(f"relation: {K} groups need {K - 1} positive relative gap sizes, got {list(relation)}")
    if candidates is None:
        grid = [float(g) for g in gap_grid]
        if not grid or any(g < 0 for g in grid):
            raise ValueError(f"gap_grid: expected non-negative values, got {list(gap_grid)}")
        cands = [Margins.from_gaps(g) for g in itertools.product(grid, repeat=K - 1)]
    else:
        cands = [Margins.parse(c, K) for c in candidates]
    nominal = dataset.nominal_weights if dataset.nominal_weights is not None else np.zeros(dataset.n_features)
    if infer_kwargs.get("nominal_weights") is not None:
        nominal = np.asarray(infer_kwargs["nominal_weights"], dtype=np.float64)
    # each run shows its own sampling bar under the candidates' (a run of the paper's settings takes ~90 s)
    infer_kwargs.setdefault("progress", bool(progress))
    runner = run or (lambda m: infer(dataset, margins=m, **infer_kwargs))
    bar = None
    if progress:
        from tqdm.auto import tqdm

        # the first run also compiles the samplers (Numba; minutes on a cold cache): say so, not a bare 0/N
        bar = tqdm(total=len(cands), desc=f"tuning margins ({COMPILING_NOTE})", unit="candidate", leave=False)
    best: tuple[float, int] | None = None
    table: list[dict[str, Any]] = []
    posts: dict[int, Posterior] = {}
    for idx, m in enumerate(cands):
        post = runner(m)
        w, cols = point_weights(post, dataset, estimator, nominal)
        mu = group_mean_returns(dataset, w, cols)
        err, achieved = relation_error(mu, rel)
        table.append({"margins": m.as_dict(), "error": err if math.isfinite(err) else None,
                      "relation_achieved": [None if not np.isfinite(x) else float(x) for x in achieved],
                      "group_means": mu.tolist()})
        if best is None or err < best[0]:
            if best is not None:
                posts.pop(best[1], None)
            best = (err, idx)
            posts[idx] = post
        if bar is not None:
            if idx == 0:
                bar.set_description("tuning margins")
            bar.update(1)
    if bar is not None:
        bar.close()
    assert best is not None
    err, idx = best
    if not math.isfinite(err):
        raise ValueError("relation: no candidate ordered the group means as ranked (every candidate has a "
                         "non-positive gap); widen the grid or check the group labels")
    row = table[idx]
    return MarginTuning(cands[idx], rel / rel[0], np.array(row["relation_achieved"], dtype=float), err,
                        np.array(row["group_means"]), posts[idx], table)
