"""Posterior predictive check: do the inferred constraints order demonstrations they were not fitted to?

For held-out demonstrations in groups :math:`\\mathcal{G}_1 \\succ \\dots \\succ \\mathcal{G}_K`, each posterior
draw :math:`(c, w_p, \\vartheta)` defines a reward :math:`r = (w_n + c \\circ w_p)^\\top \\phi_\\vartheta` and so
length-normalised returns :math:`\\bar r_i`. The *pair accuracy* of a draw is the fraction of cross-group
pairs :math:`(\\tau_i \\in \\mathcal{G}_k, \\tau_j \\in \\mathcal{G}_\\ell)`, :math:`k < \\ell`, with
:math:`\\bar r_i > \\bar r_j` (ties count one half). It is compared with the accuracy of the nominal reward
alone (:math:`w_p = 0`): if the constraints explain the ranking, the posterior's accuracy is clearly higher.
Counting uses sorted returns, :math:`O(N \\log N)` per draw, so 10^5 held-out trajectories are cheap.

``pbicrl check RUN_DIR --data HELDOUT.npz`` evaluates a finished run; ``pbicrl infer ... --check K`` runs a
stratified K-fold cross-validation (K fits, each scored on its held-out fold).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from pbicrl.inference.data import Dataset
from pbicrl.runs import constraint_set_of

__all__ = ["PredictiveCheck", "cross_validate", "kfold_split", "merge_folds", "pair_accuracy", "predictive_check"]


def pair_accuracy(returns: NDArray[np.float64], group: NDArray[np.int64]) -> float:
    """Fraction of cross-group pairs ordered correctly by ``returns`` (higher = better group; ties = 1/2).

    Parameters
    ----------
    returns : ndarray (N,)
    group : ndarray (N,) int
        1 = most preferred.

    Returns
    -------
    float
        In [0, 1]; NaN when there is no cross-group pair.
    """
    r = np.asarray(returns, dtype=np.float64)
    g = np.asarray(group)
    labels = np.unique(g)
    good = 0.0
    total = 0
    # walk from the worst group up: every trajectory of a better group is compared with all worse ones
    worse = np.zeros(0)
    for lab in labels[::-1]:
        ri = r[g == lab]
        if worse.size:
            worse_sorted = np.sort(worse)
            below = np.searchsorted(worse_sorted, ri, side="left")
            ties = np.searchsorted(worse_sorted, ri, side="right") - below
            good += float(below.sum() + 0.5 * ties.sum())
            total += ri.size * worse.size
        worse = np.concatenate([worse, ri])
    return good / total if total else float("nan")


@dataclass(frozen=True)
class PredictiveCheck:
    """Result of a posterior predictive check on held-out demonstrations.

    Attributes
    ----------
    accuracy_draws : ndarray (S,)
        Pair accuracy of each of ``S`` posterior draws.
    accuracy_nominal : float
        Pair accuracy of the nominal reward :math:`w_n` alone.
    accuracy_posterior_mean_return : float
        Accuracy of the posterior-mean return (returns averaged over the draws, then compared).
    n_trajectories, n_pairs : int
        Held-out trajectories and cross-group pairs.
    folds : list of dict
        Per-fold results of a K-fold check (empty for a single held-out set).
    """

    accuracy_draws: NDArray[np.float64]
    accuracy_nominal: float
    accuracy_posterior_mean_return: float
    n_trajectories: int
    n_pairs: int
    folds: list[dict[str, Any]] = field(default_factory=list)

    @property
    def accuracy_mean(self) -> float:
        return float(np.mean(self.accuracy_draws))

    @property
    def accuracy_interval(self) -> tuple[float, float]:
        """Central 90% interval of the per-draw accuracy."""
        lo, hi = np.quantile(self.accuracy_draws, [0.05, 0.95])
        return float(lo), float(hi)

    @property
    def p_better_than_nominal(self) -> float:
        """Share of draws that order more held-out pairs correctly than the nominal reward."""
        return float(np.mean(self.accuracy_draws > self.accuracy_nominal))

    def to_dict(self) -> dict[str, Any]:
        lo, hi = self.accuracy_interval
        return {"n_trajectories": self.n_trajectories, "n_pairs": self.n_pairs,
                "pair_accuracy": {"mean": self.accuracy_mean, "ci90": [lo, hi],
                                  "posterior_mean_return": self.accuracy_posterior_mean_return},
                "nominal_pair_accuracy": self.accuracy_nominal,
                "p_better_than_nominal": self.p_better_than_nominal, "draws": int(self.accuracy_draws.size),
                "folds": self.folds}

    def table(self) -> str:
        lo, hi = self.accuracy_interval
        lines = [f"held-out: {self.n_trajectories} trajectories, {self.n_pairs} cross-group pairs"
                 + (f", {len(self.folds)} folds" if self.folds else ""),
                 f"pair accuracy, posterior:        {self.accuracy_mean:.3f}  (90% of draws in [{lo:.3f}, {hi:.3f}])",
                 f"pair accuracy, posterior-mean return: {self.accuracy_posterior_mean_return:.3f}",
                 f"pair accuracy, nominal reward:   {self.accuracy_nominal:.3f}",
                 f"draws better than nominal:       {self.p_better_than_nominal:.1%}"]
        if self.accuracy_mean <= self.accuracy_nominal + 1e-12:
            lines.append("the inferred constraints do not order the held-out demonstrations better than the nominal "
                         "reward alone")
        return "\n".join(lines)


def _n_pairs(group: NDArray[np.int64]) -> int:
    counts = np.unique(group, return_counts=True)[1]
    return int((counts.sum() ** 2 - np.sum(counts ** 2)) // 2)


def _posterior_draws(post: Any, n_draws: int, rng: np.random.Generator) -> tuple[NDArray, NDArray]:
    d = post.n_features
    eff = post.effective_penalty.reshape(-1, d)
    P = len(post.parameter_names)
    theta = post.parameters.reshape(-1, P) if P else np.zeros((eff.shape[0], 0))
    take = rng.choice(eff.shape[0], size=min(int(n_draws), eff.shape[0]), replace=False)
    return eff[np.sort(take)], theta[np.sort(take)]


def predictive_check(post: Any, heldout: Dataset, *, n_draws: int = 400, seed: int = 0) -> PredictiveCheck:
    """Score posterior draws on held-out grouped demonstrations.

    Parameters
    ----------
    post : Posterior or RunRecord
        A finished run (its nominal weights and constraint specifications are used).
    heldout : Dataset
        Demonstrations with the same features (and ``states`` for parametric constraints).
    n_draws : int
        Posterior draws to score (evenly random over all chains).
    seed : int

    Returns
    -------
    PredictiveCheck

    Raises
    ------
    ValueError
        If the held-out data do not match the run (feature count or names) or have fewer than two groups.
    """
    d_known = heldout.n_features
    names = tuple(post.feature_names)
    n_param_features = len({*getattr(post, "parameter_owner", ())})
    if len(names) - n_param_features != d_known:
        raise ValueError(f"data: the held-out set has {d_known} features, the run was fitted on "
                         f"{len(names) - n_param_features}")
    if tuple(heldout.feature_names) != names[:d_known]:
        raise ValueError(f"data: feature names differ from the run's ({list(heldout.feature_names)} vs "
                         f"{list(names[:d_known])})")
    if heldout.n_groups < 2:
        raise ValueError("data: the held-out set needs at least two groups to compare")
    if int(np.min(heldout.group)) < 1:
        raise ValueError("data: the held-out set has unlabelled trajectories (group 0); label them first")
    if int(n_draws) < 1:
        raise ValueError(f"n_draws: must be >= 1, got {n_draws}")
    wn = np.asarray(post.settings.get("nominal_weights") or np.zeros(d_known), dtype=np.float64)
    rng = np.random.default_rng(seed)
    eff, theta = _posterior_draws(post, n_draws, rng)
    cs = constraint_set_of(post, heldout)
    F = heldout.mean_features
    base = F @ wn
    g = heldout.group
    acc = np.empty(eff.shape[0])
    mean_ret = np.zeros(F.shape[0])
    for s in range(eff.shape[0]):
        r = base + F @ eff[s, :d_known]
        if cs is not None:
            for m in range(cs.n_constraints):
                w = eff[s, d_known + m]
                if w != 0.0:
                    r = r + w * cs.mean_feature(m, np.nan_to_num(cs.theta_of(theta[s], m)))
        acc[s] = pair_accuracy(r, g)
        mean_ret += r
    mean_ret /= eff.shape[0]
    return PredictiveCheck(acc, pair_accuracy(base, g), pair_accuracy(mean_ret, g), heldout.n_trajectories,
                           _n_pairs(g))


def kfold_split(group: NDArray[np.int64], k: int, seed: int = 0) -> list[NDArray[np.int64]]:
    """Stratified folds: each group's trajectories are shuffled and dealt round-robin into ``k`` folds.

    Returns
    -------
    list of ndarray
        Indices of the held-out trajectories of each fold.

    Raises
    ------
    ValueError
        If ``k < 2`` or some group has fewer than ``k`` trajectories.
    """
    k = int(k)
    if k < 2:
        raise ValueError(f"check: the number of folds must be >= 2, got {k}")
    group = np.asarray(group)
    rng = np.random.default_rng(seed)
    folds: list[list[int]] = [[] for _ in range(k)]
    for lab in np.unique(group):
        idx = np.flatnonzero(group == lab)
        if idx.size < k:
            raise ValueError(f"check: group {int(lab)} has {idx.size} trajectories, fewer than the {k} folds")
        rng.shuffle(idx)
        for f in range(k):
            folds[f].extend(idx[f::k].tolist())
    return [np.sort(np.array(f, dtype=np.int64)) for f in folds]


def merge_folds(results: list[PredictiveCheck]) -> PredictiveCheck:
    """Pool K fold results: draws concatenated, accuracies weighted by each fold's number of pairs."""
    w = np.array([r.n_pairs for r in results], dtype=np.float64)
    w /= w.sum()
    # each fold scores its own draws; pool per-draw accuracies fold-weighted via equal draw counts
    n = min(r.accuracy_draws.size for r in results)
    draws = sum(wi * r.accuracy_draws[:n] for wi, r in zip(w, results))
    return PredictiveCheck(np.asarray(draws), float(sum(wi * r.accuracy_nominal for wi, r in zip(w, results))),
                           float(sum(wi * r.accuracy_posterior_mean_return for wi, r in zip(w, results))),
                           int(sum(r.n_trajectories for r in results)), int(sum(r.n_pairs for r in results)),
                           folds=[r.to_dict() | {"fold": i} for i, r in enumerate(results)])


def cross_validate(dataset: Dataset, k: int, fit: Any, *, n_draws: int = 400, seed: int = 0) -> PredictiveCheck:
    """Stratified K-fold posterior predictive check.

    Parameters
    ----------
    dataset : Dataset
    k : int
        Number of folds (each group needs at least ``k`` trajectories).
    fit : callable
        ``fit(train_dataset) -> Posterior`` (e.g. ``lambda d: pbicrl.infer(d, **settings)``).
    n_draws, seed
        As :func:`predictive_check`.

    Returns
    -------
    PredictiveCheck
        Fold results pooled by :func:`merge_folds`; per-fold numbers in ``folds``.
    """
    folds = kfold_split(dataset.group, k, seed=seed)
    everyone = np.arange(dataset.n_trajectories)
    results = []
    for f, held in enumerate(folds):
        post = fit(dataset.subset(np.setdiff1d(everyone, held)))
        results.append(predictive_check(post, dataset.subset(held), n_draws=n_draws, seed=seed + f))
    return merge_folds(results)
