"""Posterior predictive check: how probable does the posterior make the grouping of demonstrations it was not
fitted to?

For held-out demonstrations in groups :math:`\\mathcal{G}_1 \\succ \\dots \\succ \\mathcal{G}_K`, each posterior
draw :math:`(c, w_p, \\vartheta)` defines a reward :math:`r = (w_n + c \\circ w_p)^\\top \\phi_\\vartheta` and so
length-normalised returns :math:`\\bar r_i`, and the grouped likelihood (the exact grouped Plackett-Luce
probability, :mod:`pbicrl.inference.likelihood`, with the run's :math:`\\beta` and margins) gives the probability
:math:`P(G \\mid w)` of the observed grouping :math:`G`. The check reports

* the **log score**, the log posterior predictive probability of the held-out grouping,
  :math:`\\log \\frac{1}{S}\\sum_s P(G \\mid w^{(s)})` over :math:`S` posterior draws, beside the same for the
  nominal-only model (:math:`w_p = 0`) and for the prior (draws of :math:`(c, w_p)` from the run's prior): a
  posterior that learnt something scores above both; the scores are in nats and differences are log Bayes
  factors on the held-out data;
* a **reliability table** of the predicted group probabilities: for each held-out trajectory and group
  :math:`k`, the posterior predictive probability that it belongs to :math:`\\mathcal{G}_k` given where the others
  are, :math:`P(g_i = k \\mid G_{-i}) \\propto \\frac{1}{S}\\sum_s P(G_{i \\to k} \\mid w^{(s)})`; binned by the
  predicted value against how often the trajectory is really in that group (calibrated: the two agree);
* as one line, the *pair accuracy*: the fraction of cross-group
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
from pbicrl.inference.constraints import constraint_set_of

__all__ = ["PredictiveCheck", "cross_validate", "kfold_split", "merge_folds", "pair_accuracy", "predictive_check",
           "RELIABILITY_BINS"]

RELIABILITY_BINS = (0.0, 0.05, 0.2, 0.4, 0.6, 0.8, 0.95, 1.0)
"""Edges of the predicted-probability bins of the reliability table."""
CALIBRATION_DRAWS = 50
"""Posterior draws used for the reliability table (it costs N K likelihoods per draw)."""


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
    log_score, log_score_nominal : float
        Log posterior predictive probability of the held-out grouping (nats), and the same for the nominal-only
        model (:math:`w_p = 0`).
    log_score_prior : float or None
        The same averaged over draws from the run's prior; ``None`` where the run has no proper prior to draw from
        (``paper`` / ``authors``) or parametric constraints.
    expected_log_likelihood : float
        Mean over posterior draws of the held-out grouping's log-likelihood (<= ``log_score``, Jensen).
    reliability : list of dict
        Bins of the predicted group probabilities: ``low``, ``high``, ``n`` (trajectory-group cells),
        ``mean_predicted``, ``observed`` (share of cells whose trajectory is in that group).
    calibration_draws : int
        Posterior draws behind the reliability table.
    likelihood : dict
        What was scored: ``beta``, ``margins`` (``{"m12": ...}``), ``kind`` ("grouped").
    """

    accuracy_draws: NDArray[np.float64]
    accuracy_nominal: float
    accuracy_posterior_mean_return: float
    n_trajectories: int
    n_pairs: int
    folds: list[dict[str, Any]] = field(default_factory=list)
    log_score: float = float("nan")
    log_score_nominal: float = float("nan")
    log_score_prior: float | None = None
    expected_log_likelihood: float = float("nan")
    reliability: list[dict[str, Any]] = field(default_factory=list)
    calibration_draws: int = 0
    likelihood: dict[str, Any] = field(default_factory=dict)

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

        def num(x: Any) -> float | None:
            return None if x is None or not np.isfinite(x) else float(x)

        n = max(self.n_trajectories, 1)
        return {"n_trajectories": self.n_trajectories, "n_pairs": self.n_pairs,
                "log_score": {"posterior": num(self.log_score), "nominal": num(self.log_score_nominal),
                              "prior": num(self.log_score_prior),
                              "per_trajectory": {"posterior": num(self.log_score / n),
                                                 "nominal": num(self.log_score_nominal / n),
                                                 "prior": None if self.log_score_prior is None
                                                 else num(self.log_score_prior / n)},
                              "posterior_minus_nominal": num(self.log_score - self.log_score_nominal),
                              "posterior_minus_prior": None if self.log_score_prior is None
                              else num(self.log_score - self.log_score_prior),
                              "expected_log_likelihood": num(self.expected_log_likelihood),
                              "definition": "log of the posterior predictive probability of the held-out grouping "
                                            "under the grouped likelihood, averaged over draws (nats)"},
                "likelihood": self.likelihood,
                "reliability": {"bins": self.reliability, "draws": self.calibration_draws,
                                "definition": "predicted probability that a held-out trajectory is in a group, given "
                                              "the groups of the others, against how often it is"},
                "pair_accuracy": {"mean": self.accuracy_mean, "ci90": [lo, hi],
                                  "posterior_mean_return": self.accuracy_posterior_mean_return},
                "nominal_pair_accuracy": self.accuracy_nominal,
                "p_better_than_nominal": self.p_better_than_nominal, "draws": int(self.accuracy_draws.size),
                "folds": self.folds}

    def table(self) -> str:
        lo, hi = self.accuracy_interval
        n = max(self.n_trajectories, 1)
        lines = [f"held-out: {self.n_trajectories} trajectories, {self.n_pairs} cross-group pairs"
                 + (f", {len(self.folds)} folds" if self.folds else ""),
                 "log score: log posterior predictive probability of the held-out grouping (grouped likelihood"
                 + (f", beta {self.likelihood['beta']:g}" if "beta" in self.likelihood else "") + "; nats)",
                 f"  posterior     {self.log_score:12.2f}   ({self.log_score / n:+.4f} per trajectory)",
                 f"  nominal only  {self.log_score_nominal:12.2f}   ({self.log_score_nominal / n:+.4f} per trajectory)"]
        if self.log_score_prior is not None:
            lines.append(f"  prior         {self.log_score_prior:12.2f}   ({self.log_score_prior / n:+.4f} per trajectory)")
        else:
            lines.append("  prior         -   (no proper prior to draw from)")
        d_nom = self.log_score - self.log_score_nominal
        lines.append(f"  posterior - nominal: {d_nom:+.2f} nats"
                     + ("" if self.log_score_prior is None else
                        f"; posterior - prior: {self.log_score - self.log_score_prior:+.2f} nats"))
        if self.reliability:
            lines += [f"reliability of the predicted group probabilities ({self.calibration_draws} draws; each "
                      "trajectory's group given the others'):",
                      f"  {'predicted':<11} {'cells':>7} {'mean predicted':>15} {'observed':>9}"]
            for b in self.reliability:
                if b["n"]:
                    lines.append(f"  {b['low']:.2f}-{b['high']:.2f}   {b['n']:>7} {b['mean_predicted']:>15.3f} "
                                 f"{b['observed']:>9.3f}")
        lines.append(f"pair accuracy: posterior {self.accuracy_mean:.3f} (90% of draws in [{lo:.3f}, {hi:.3f}]), "
                     f"posterior-mean return {self.accuracy_posterior_mean_return:.3f}, nominal "
                     f"{self.accuracy_nominal:.3f}; {self.p_better_than_nominal:.1%} of draws better than nominal")
        if not d_nom > 0:
            lines.append("the inferred constraints do not predict the held-out grouping better than the nominal "
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


def _prior_draws(post: Any, n: int, rng: np.random.Generator) -> NDArray[np.float64] | None:
    """``n`` draws of :math:`c \\circ w_p` from the run's prior, or ``None`` where there is none to draw from."""
    from pbicrl.inference.draws import indicator_meaning
    from pbicrl.inference.sensitivity import sample_prior, weight_prior_spec

    if indicator_meaning(getattr(post, "sampler", None)) == "chain_frequency" or post.parameter_names:
        return None
    settings = post.settings
    prior = getattr(post, "prior", None)
    if prior is None and isinstance(getattr(post, "summary", None), dict):
        prior = post.summary.get("prior")
    src = prior if isinstance(prior, dict) and prior else settings.get("weight_prior")
    d = post.n_features
    model = post.in_model()
    pi = (settings.get("indicator_prior") or {}).get("pi", 0.5) if indicator_meaning(post.sampler) == "posterior" else 1.0
    out = np.zeros((n, d))
    for j in range(d):
        if not model[j]:
            continue
        spec = weight_prior_spec(src, post.feature_names, j)
        w = None if spec is None else sample_prior(spec, rng, n)
        if w is None:
            return None
        out[:, j] = np.where(rng.random(n) < float(pi), w, 0.0)
    return out


def _margins(post: Any, labels: NDArray[np.int64]) -> Any:
    """The run's margins (``extra.margins``, ``{"m12": ...}`` or ``{"m1_2": ...}``, 1-based groups) between the
    held-out groups ``labels``; zeros where the run recorded none."""
    from pbicrl.inference.preferences import Margins

    m = (getattr(post, "extra", None) or {}).get("margins")
    given: dict[tuple[int, int], float] = {}
    if isinstance(m, dict):
        for key, v in m.items():
            try:
                k, l = (int(x) for x in key[1:].split("_")) if "_" in key else (int(key[1]), int(key[2:]))
            except (ValueError, IndexError, TypeError):
                continue
            if isinstance(v, (int, float)) and k < l:
                given[(k, l)] = float(v)
    top = max([l for _, l in given] + [int(labels.max())])
    if given and all(l == k + 1 for k, l in given) and len(given) == top - 1 and top > 2:
        off = np.concatenate([[0.0], np.cumsum([given[(k, k + 1)] for k in range(1, top)])])  # additive
        given = {(k, l): float(off[l - 1] - off[k - 1]) for k in range(1, top + 1) for l in range(k + 1, top + 1)}
    K = labels.size
    M = np.zeros((K, K))
    for a in range(K):
        for b in range(a + 1, K):
            M[a, b] = given.get((int(labels[a]), int(labels[b])), 0.0)
    return Margins(M)


def _logmeanexp(x: NDArray[np.float64]) -> float:
    x = np.asarray(x, dtype=np.float64)
    m = float(np.max(x))
    return m + float(np.log(np.mean(np.exp(x - m)))) if np.isfinite(m) else m


def predictive_check(post: Any, heldout: Dataset, *, n_draws: int = 400, seed: int = 0,
                     calibration_draws: int = CALIBRATION_DRAWS) -> PredictiveCheck:
    """Score posterior draws on held-out grouped demonstrations (module docstring).

    Parameters
    ----------
    post : Posterior or RunRecord
        A finished run (its nominal weights, :math:`\\beta`, margins, prior and constraint specifications are
        used).
    heldout : Dataset
        Demonstrations with the same features (and ``states`` for parametric constraints).
    n_draws : int
        Posterior draws to score (evenly random over all chains); as many prior draws.
    seed : int
    calibration_draws : int
        Posterior draws for the reliability table (0: no table).

    Returns
    -------
    PredictiveCheck

    Raises
    ------
    ValueError
        If the held-out data do not match the run (feature count or names) or have fewer than two groups.
    """
    from pbicrl.inference.likelihood import PreferenceLikelihood
    from pbicrl.inference.preferences import Preferences

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
    if int(calibration_draws) < 0:
        raise ValueError(f"calibration_draws: must be >= 0, got {calibration_draws}")
    wn = np.asarray(post.settings.get("nominal_weights") or np.zeros(d_known), dtype=np.float64)
    beta = float(post.settings.get("beta") or 1.0)
    rng = np.random.default_rng(seed)
    eff, theta = _posterior_draws(post, n_draws, rng)
    cs = constraint_set_of(post, heldout)
    F = heldout.mean_features
    base = F @ wn
    g = heldout.group
    labels = np.unique(g)
    K = labels.size
    rank = np.searchsorted(labels, g) + 1  # groups renumbered 1..K in order (a fold may lack none, but be safe)
    margins = _margins(post, labels)
    prefs = Preferences.from_groups(rank, margins)
    lik = PreferenceLikelihood(F, prefs, wn, beta, kind="grouped")

    def returns(e: NDArray[np.float64], th: NDArray[np.float64] | None) -> NDArray[np.float64]:
        r = base + F @ e[:d_known]
        if cs is not None and th is not None:
            for m in range(cs.n_constraints):
                w = e[d_known + m]
                if w != 0.0:
                    r = r + w * cs.mean_feature(m, np.nan_to_num(cs.theta_of(th, m)))
        return r

    S = eff.shape[0]
    R = np.empty((S, F.shape[0]))
    acc = np.empty(S)
    ll = np.empty(S)
    for s in range(S):
        R[s] = returns(eff[s], theta[s])
        acc[s] = pair_accuracy(R[s], g)
        ll[s] = lik.from_scaled_returns(beta * R[s])
    mean_ret = R.mean(axis=0)
    ll_nominal = lik.from_scaled_returns(beta * base)
    prior = _prior_draws(post, S, rng)
    ll_prior = None
    if prior is not None:
        ll_prior = _logmeanexp(np.array([lik.from_scaled_returns(beta * returns(e, None)) for e in prior]))
    reliability = _reliability(R[: int(calibration_draws)], rank, K, margins, wn, beta, F)
    m = margins.matrix
    likelihood = {"kind": "grouped", "beta": beta,
                  "margins": {f"m{k + 1}{l + 1}": float(m[k, l]) for k in range(K) for l in range(k + 1, K)}}
    return PredictiveCheck(acc, pair_accuracy(base, g), pair_accuracy(mean_ret, g), heldout.n_trajectories,
                           _n_pairs(g), log_score=_logmeanexp(ll), log_score_nominal=float(ll_nominal),
                           log_score_prior=ll_prior, expected_log_likelihood=float(np.mean(ll)),
                           reliability=reliability, calibration_draws=min(int(calibration_draws), S),
                           likelihood=likelihood)


def _reliability(R: NDArray[np.float64], rank: NDArray[np.int64], K: int, margins: Any, wn: NDArray[np.float64],
                 beta: float, F: NDArray[np.float64]) -> list[dict[str, Any]]:
    """Bins of :math:`P(g_i = k \\mid G_{-i})` (posterior predictive, over the rows of ``R``) against the truth."""
    from pbicrl.inference.likelihood import PreferenceLikelihood
    from pbicrl.inference.preferences import PreferenceError, Preferences

    S, N = R.shape
    if S == 0:
        return []
    pred = np.zeros((N, K))
    for i in range(N):
        logp = np.full(K, -np.inf)
        for k in range(1, K + 1):
            alt = rank.copy()
            alt[i] = k
            if np.unique(alt).size < K:  # moving i would empty its group: that grouping has other groups
                continue
            try:
                lik = PreferenceLikelihood(F, Preferences.from_groups(alt, margins), wn, beta, kind="grouped")
            except PreferenceError:
                continue
            logp[k - 1] = _logmeanexp(np.array([lik.from_scaled_returns(beta * R[s]) for s in range(S)]))
        if not np.isfinite(logp).any():
            pred[i] = np.nan
            continue
        logp -= logp.max()
        pred[i] = np.exp(logp) / np.exp(logp).sum()
    truth = (rank[:, None] == np.arange(1, K + 1)[None, :]).astype(float)
    ok = np.isfinite(pred).all(axis=1)
    p, t = pred[ok].ravel(), truth[ok].ravel()
    edges = np.asarray(RELIABILITY_BINS)
    idx = np.clip(np.searchsorted(edges, p, side="right") - 1, 0, edges.size - 2)
    out = []
    for b in range(edges.size - 1):
        sel = idx == b
        n = int(sel.sum())
        out.append({"low": float(edges[b]), "high": float(edges[b + 1]), "n": n,
                    "mean_predicted": float(p[sel].mean()) if n else None,
                    "observed": float(t[sel].mean()) if n else None})
    return out


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
    """Pool K fold results: log scores add (the folds are disjoint held-out sets), reliability bins pool,
    accuracies are weighted by each fold's number of pairs."""
    w = np.array([r.n_pairs for r in results], dtype=np.float64)
    w /= w.sum()
    # each fold scores its own draws; pool per-draw accuracies fold-weighted via equal draw counts
    n = min(r.accuracy_draws.size for r in results)
    draws = sum(wi * r.accuracy_draws[:n] for wi, r in zip(w, results))
    priors = [r.log_score_prior for r in results]
    bins = []
    for b in range(len(results[0].reliability)):
        cells = [r.reliability[b] for r in results if len(r.reliability) > b and r.reliability[b]["n"]]
        tot = sum(c["n"] for c in cells)
        base = results[0].reliability[b]
        bins.append({"low": base["low"], "high": base["high"], "n": int(tot),
                     "mean_predicted": sum(c["n"] * c["mean_predicted"] for c in cells) / tot if tot else None,
                     "observed": sum(c["n"] * c["observed"] for c in cells) / tot if tot else None})
    return PredictiveCheck(np.asarray(draws), float(sum(wi * r.accuracy_nominal for wi, r in zip(w, results))),
                           float(sum(wi * r.accuracy_posterior_mean_return for wi, r in zip(w, results))),
                           int(sum(r.n_trajectories for r in results)), int(sum(r.n_pairs for r in results)),
                           folds=[r.to_dict() | {"fold": i} for i, r in enumerate(results)],
                           log_score=float(sum(r.log_score for r in results)),
                           log_score_nominal=float(sum(r.log_score_nominal for r in results)),
                           log_score_prior=None if any(p is None for p in priors) else float(sum(priors)),
                           expected_log_likelihood=float(sum(r.expected_log_likelihood for r in results)),
                           reliability=bins, calibration_draws=min(r.calibration_draws for r in results),
                           likelihood=results[0].likelihood)


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
