"""Simulation-based calibration (SBC, Talts et al. 2018) of the PBICRL sampler on small synthetic problems.

One replicate: draw :math:`(c, w_p)` from the prior, simulate demonstrations and preferences, sample the
posterior, and record the rank of each true quantity among ``L`` posterior draws. If the sampler draws from
the exact posterior of the model that generated the data, every rank is uniform on ``0..L``.

Two simulators (``design``):

``"pairs"``
    Exactly the likelihood's generative model: ``n_pairs`` random pairs :math:`(i, j)` of trajectories, each
    compared independently with :math:`P(\\tau_i \\succ \\tau_j) = \\sigma(a_i - a_j)` (Bradley-Terry), the
    winner stored first (:meth:`Preferences.from_pairs`). SBC checks the sampler.
``"groups"``
    How users produce data: trajectories are ranked by their Gumbel-perturbed return (a Plackett-Luce
    ranking, the noise model behind Bradley-Terry), cut into ``n_groups`` groups, and the all-pairs composite
    likelihood of paper Eq. 7 is used. Each trajectory then enters ``(K-1) n`` pairs treated as independent,
    which is not the model that generated the ranking, so this design checks the *model* and may fail.

Quantities ranked: the effective penalty :math:`c_j w_{p,j}` and the indicator :math:`c_j` of every feature.
Both have atoms (at 0, or at 0/1); ties are broken uniformly at random, which keeps ranks uniform under
calibration. Uniformity is tested with a chi-square test on ``bins`` equal bins and a Kolmogorov-Smirnov
test on the jittered normalised ranks (scipy, imported lazily).
"""

from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass, field
from typing import Any, Literal, Sequence

import numpy as np
from numpy.typing import NDArray

from pbicrl.config import canonical_names
from pbicrl.errors import PbicrlWarning
from pbicrl.inference.likelihood import PreferenceLikelihood
from pbicrl.inference.preferences import Preferences
from pbicrl.inference.priors import IndicatorPrior, WeightPrior
from pbicrl.inference.samplers import SamplerSettings, sample

__all__ = ["SBCProblem", "SBCResult", "conditional_summary", "reliability", "simulate", "rank_statistics", "run_sbc",
           "uniformity"]


@dataclass(frozen=True)
class SBCProblem:
    """Size and priors of the synthetic problems.

    Parameters
    ----------
    n_features : int
        ``d``, all candidates.
    n_groups, per_group : int
        ``K`` groups of ``per_group`` trajectories (``N = K * per_group``).
    length : int
        States per trajectory (features are per-state normal noise around a per-trajectory mean).
    design : {"pairs", "groups"}
        See the module docstring.
    n_pairs : int or None
        ``"pairs"`` design: number of comparisons (default: as many as the all-pairs likelihood of the
        ``"groups"`` design would have, :math:`\\binom{K}{2} n^2`).
    group_pairs : "all" or int
        ``"groups"`` design: every cross-group pair (paper Eq. 7) or that many random pairs per group pair
        (the paper's sampled protocol, :meth:`Preferences.from_groups`).
    bound : float
        Flat prior on each :math:`w_{p,j}` over ``[-bound, bound]``.
    pi : float
        Bernoulli prior :math:`P(c_j = 1)`.
    nominal : float
        Nominal weight of every feature (the same known :math:`w_n` for all).
    feature_scale : float
        Standard deviation of the per-trajectory mean features.
    power : float or "pairs"
        Likelihood power used for inference (see :class:`~pbicrl.inference.likelihood.PreferenceLikelihood`).
    likelihood : {"pairwise", "grouped"}
        ``"groups"`` design: the likelihood used for inference, the paper's Eq. 7 over pairs or the exact
        grouped Plackett-Luce likelihood (the model that generated the data).
    sign : {"any", "negative"}
        Support of the flat prior: ``[-bound, bound]`` or ``[-bound, 0]``.
    """

    n_features: int = 2
    n_groups: int = 3
    per_group: int = 10
    length: int = 5
    design: Literal["pairs", "groups"] = "pairs"
    n_pairs: int | None = None
    group_pairs: str | int = "all"
    bound: float = 3.0
    pi: float = 0.5
    nominal: float = 0.0
    feature_scale: float = 1.0
    power: float | str = 1.0
    likelihood: Literal["pairwise", "grouped"] = "pairwise"
    sign: Literal["any", "negative"] = "any"

    def __post_init__(self) -> None:
        if self.design not in ("pairs", "groups"):
            raise ValueError(f"design: expected 'pairs' or 'groups', got {self.design!r}")
        for name in ("n_features", "per_group", "length"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"{name}: must be >= 1, got {getattr(self, name)}")
        if int(self.n_groups) < 2:
            raise ValueError(f"n_groups: need at least 2 groups, got {self.n_groups}")
        if self.group_pairs != "all" and not (isinstance(self.group_pairs, int) and self.group_pairs >= 1):
            raise ValueError(f"group_pairs: expected 'all' or a positive integer, got {self.group_pairs!r}")
        if not self.bound > 0:
            raise ValueError(f"bound: must be positive, got {self.bound}")
        if self.likelihood not in ("pairwise", "grouped"):
            raise ValueError(f"likelihood: expected 'pairwise' or 'grouped', got {self.likelihood!r}")
        if self.likelihood == "grouped" and self.design != "groups":
            raise ValueError("likelihood: 'grouped' needs design='groups' (grouped rankings)")

    @property
    def pairs_(self) -> int:
        K, n = int(self.n_groups), int(self.per_group)
        return int(self.n_pairs) if self.n_pairs is not None else K * (K - 1) // 2 * n * n

    @property
    def weight_prior(self) -> WeightPrior:
        return WeightPrior("flat", -float(self.bound), float(self.bound), sign=self.sign)

    @property
    def indicator_prior(self) -> IndicatorPrior:
        return IndicatorPrior(float(self.pi))

    def to_dict(self) -> dict[str, Any]:
        return {"n_features": self.n_features, "n_groups": self.n_groups, "per_group": self.per_group,
                "length": self.length, "design": self.design,
                "n_pairs": self.pairs_ if self.design == "pairs" else None,
                "group_pairs": self.group_pairs if self.design == "groups" else None, "bound": self.bound,
                "pi": self.pi, "nominal": self.nominal, "feature_scale": self.feature_scale, "power": self.power,
                "likelihood": self.likelihood, "sign": self.sign}


def simulate(problem: SBCProblem, rng: np.random.Generator) -> tuple[PreferenceLikelihood, NDArray[np.int64], NDArray[np.float64]]:
    """Draw ``(c, w_p)`` from the prior and simulate a likelihood from them.

    Returns
    -------
    likelihood : PreferenceLikelihood
    c : ndarray (d,) int
    w_p : ndarray (d,)
        The prior draw (``w_p`` of switched-off features is drawn too but has no effect).
    """
    d = int(problem.n_features)
    N = int(problem.n_groups) * int(problem.per_group)
    c = (rng.random(d) < problem.pi).astype(np.int64)
    wp = problem.weight_prior.sample(rng, d)
    centres = rng.normal(0.0, problem.feature_scale, (N, d))
    per_state = centres[:, None, :] + rng.normal(0.0, 0.5, (N, int(problem.length), d))
    mean_features = per_state.mean(axis=1)
    wn = np.full(d, float(problem.nominal))
    a = mean_features @ (wn + c * wp)  # beta = 1
    if problem.design == "pairs":
        P = problem.pairs_
        i = rng.integers(0, N, P)
        j = (i + rng.integers(1, N, P)) % N  # j != i
        win = rng.random(P) < 1.0 / (1.0 + np.exp(-(a[i] - a[j])))
        pairs = np.column_stack([np.where(win, i, j), np.where(win, j, i)]).astype(np.int64)
        prefs = Preferences.from_pairs(pairs, N)
    else:
        score = a + rng.gumbel(0.0, 1.0, N)
        order = np.argsort(-score, kind="stable")
        group = np.empty(N, dtype=np.int64)
        group[order] = np.repeat(np.arange(1, int(problem.n_groups) + 1), int(problem.per_group))
        prefs = Preferences.from_groups(group, protocol=problem.group_pairs, seed=rng)
    from pbicrl.inference.likelihood import pairwise_power

    if problem.likelihood == "grouped":
        return PreferenceLikelihood(mean_features, prefs, wn, 1.0, 1.0, kind="grouped"), c, wp
    power = pairwise_power(prefs) if problem.power == "pairs" else float(problem.power)
    return PreferenceLikelihood(mean_features, prefs, wn, 1.0, power), c, wp


def rank_statistics(truth: NDArray[np.float64], draws: NDArray[np.float64], rng: np.random.Generator) -> NDArray[np.int64]:
    """Rank of each ``truth[k]`` among ``draws[:, k]`` (0..L), ties broken uniformly at random."""
    truth = np.asarray(truth, dtype=np.float64)
    below = np.sum(draws < truth[None, :], axis=0)
    ties = np.sum(draws == truth[None, :], axis=0)
    return below + np.floor(rng.random(truth.size) * (ties + 1)).astype(np.int64)


def uniformity(ranks: NDArray[np.int64], L: int, *, bins: int = 9, seed: int = 0) -> dict[str, Any]:
    """Chi-square (``bins`` equal bins over ``0..L``) and KS tests of uniform ranks, per column of ``ranks``."""
    try:
        from scipy import stats
    except ImportError as exc:
        raise ImportError(f'the uniformity tests need scipy ({exc}): pip install "pbicrl[diag]"') from exc
    ranks = np.asarray(ranks)
    ranks = ranks[:, None] if ranks.ndim == 1 else ranks
    if (L + 1) % bins:
        raise ValueError(f"bins: {bins} must divide the L + 1 = {L + 1} possible ranks")
    rng = np.random.default_rng(seed)
    out = []
    for k in range(ranks.shape[1]):
        r = ranks[:, k]
        counts = np.bincount(r * bins // (L + 1), minlength=bins)
        chi2 = stats.chisquare(counts)
        u = (r + rng.random(r.size)) / (L + 1)
        ks = stats.kstest(u, "uniform")
        out.append({"counts": counts.tolist(), "chi2": float(chi2.statistic), "chi2_p": float(chi2.pvalue),
                    "ks": float(ks.statistic), "ks_p": float(ks.pvalue),
                    "mean_rank_normalised": float(np.mean(u))})
    return {"bins": bins, "tests": out}


def reliability(p: NDArray[np.float64], truth: NDArray[np.int64], *, edges: Sequence[float] = (0.0, 0.05, 0.2, 0.4, 0.6,
                                                                                        0.8, 0.95, 1.0)) -> list[dict]:
    """Reliability table of predicted probabilities ``p`` against binary outcomes ``truth``.

    One row per bin of ``edges`` (the last bin closed): count, mean predicted probability and observed
    frequency. Calibrated probabilities have observed close to predicted in every bin.
    """
    p = np.asarray(p, dtype=np.float64).ravel()
    t = np.asarray(truth, dtype=np.float64).ravel()
    rows = []
    for k in range(len(edges) - 1):
        lo, hi = edges[k], edges[k + 1]
        m = (p >= lo) & ((p < hi) if k < len(edges) - 2 else (p <= hi))
        rows.append({"bin": [lo, hi], "n": int(m.sum()),
                     "predicted": float(p[m].mean()) if m.any() else None,
                     "observed": float(t[m].mean()) if m.any() else None})
    return rows


def conditional_summary(cover: list[list[float]], cond_u: list[list[float]], p_c: NDArray[np.float64],
                        c_true: NDArray[np.int64], *, bins: int = 9) -> dict[str, Any]:
    """Coverage and rank uniformity of the penalties given :math:`c_j = 1`, and reliability of :math:`P(c_j=1)`."""
    from scipy import stats

    out: dict[str, Any] = {"features": {}}
    for j, (cv, u) in enumerate(zip(cover, cond_u)):
        u_arr = np.asarray(u)
        entry: dict[str, Any] = {"replicates_with_c1": len(cv),
                                 "coverage90": float(np.mean(cv)) if cv else None}
        if u_arr.size >= 10:
            counts = np.bincount(np.minimum((u_arr * bins).astype(int), bins - 1), minlength=bins)
            entry.update({"rank_counts": counts.tolist(), "rank_chi2_p": float(stats.chisquare(counts).pvalue),
                          "rank_ks_p": float(stats.kstest(u_arr, "uniform").pvalue)})
        out["features"][f"f{j}"] = entry
    out["reliability"] = reliability(p_c, c_true)
    out["brier"] = float(np.mean((p_c - c_true) ** 2))
    return out


@dataclass
class SBCResult:
    """Ranks of every replicate and their uniformity tests.

    Attributes
    ----------
    problem : SBCProblem
    names : list of str
        One per ranked quantity: ``penalty[f0]``, ..., ``indicator[f0]``, ...
    ranks : ndarray (R, Q) int
        Rank of the truth among ``L`` draws.
    L : int
    tests : dict
        :func:`uniformity` of the ranks.
    diagnostics : dict
        Worst R-hat and smallest bulk ESS per replicate (when ArviZ is available), summarised.
    conditional : dict
        Per feature, over the replicates with true :math:`c_j = 1`: coverage of the central 90% interval of
        :math:`w_{p,j}` given :math:`c_j = 1`, and uniformity tests of the truth's normalised rank among
        those conditional draws; and a reliability table of :math:`P(c_j = 1)` (see :func:`reliability`).
    """

    problem: SBCProblem
    names: list[str]
    ranks: NDArray[np.int64]
    L: int
    settings: dict
    tests: dict = field(default_factory=dict)
    diagnostics: dict = field(default_factory=dict)
    runtime_s: float = 0.0
    conditional: dict = field(default_factory=dict)

    def passed(self, alpha: float = 0.01) -> bool:
        """All chi-square and KS p-values above ``alpha`` divided by the number of tests (Bonferroni)."""
        ps = [t[k] for t in self.tests["tests"] for k in ("chi2_p", "ks_p")]
        return bool(min(ps) > alpha / len(ps))

    def to_dict(self) -> dict[str, Any]:
        return {"problem": self.problem.to_dict(), "replicates": int(self.ranks.shape[0]), "L": self.L,
                "settings": self.settings, "names": self.names,
                "tests": {n: t for n, t in zip(self.names, self.tests["tests"])}, "bins": self.tests["bins"],
                "passed_bonferroni_0.01": self.passed(0.01), "diagnostics": self.diagnostics,
                "conditional": self.conditional, "runtime_s": self.runtime_s}


def run_sbc(
    problem: SBCProblem | None = None,
    *,
    n_replicates: int = 200,
    L: int = 80,
    chains: int = 4,
    iterations: int = 20_000,
    burn_in: int | None = None,
    seed: int = 0,
    bins: int = 9,
    diagnose: bool = False,
    progress: Any = None,
    p_joint: float = 0.0,
    **deprecated: Any,
) -> SBCResult:
    """Run SBC of the ``pbicrl`` sampler.

    Parameters
    ----------
    problem : SBCProblem
    n_replicates : int
        Simulated data sets (each a fresh prior draw).
    L : int
        Posterior draws per replicate used for the rank (``L / chains`` per chain, evenly spaced after
        warm-up, so that they are close to independent). ``L + 1`` must be divisible by ``bins``.
    chains, iterations, burn_in : int
        Sampler settings per replicate (``burn_in`` default: a quarter); ``n_chains``, ``n_iterations`` (the old
        names) work until pbicrl 0.3 with a :class:`~pbicrl.errors.PbicrlWarning`.
    seed : int
        Everything (prior draws, data, chains, tie-breaking) follows from it.
    bins : int
        For the chi-square test.
    diagnose : bool
        Also record the worst R-hat and smallest bulk ESS per replicate (slower; needs ArviZ).
    p_joint : float
        Probability of the joint weight step (0.3 in runs until converged). With ``problem.sign = "negative"`` the
        sampler moves the penalties on ``log|w|`` (the default moves), so that SBC checks them.
    progress : callable, optional
        Called as ``progress(replicate_index)`` after each replicate.
    """
    if deprecated:
        unknown = sorted(set(deprecated) - {"n_chains", "n_iterations"})
        if unknown:
            raise TypeError(f"run_sbc() got an unexpected keyword argument {unknown[0]!r}")
        renamed = canonical_names(deprecated, where="run_sbc() argument", stacklevel=2)
        chains, iterations = renamed.get("chains", chains), renamed.get("iterations", iterations)
    n_chains, n_iterations = chains, iterations
    problem = SBCProblem() if problem is None else problem
    if L % n_chains:
        raise ValueError(f"L: {L} draws must split evenly over {n_chains} chains")
    if (L + 1) % bins:
        raise ValueError(f"bins: {bins} must divide the L + 1 = {L + 1} possible ranks")
    per_chain = L // n_chains
    burn = int(n_iterations) // 4 if burn_in is None else int(burn_in)
    # Keep 10x more draws than are ranked so that R-hat / ESS (diagnose=True) see the whole chains;
    # the ranked draws are every 10th of them.
    kept = int(n_iterations) - burn
    if kept < per_chain:
        raise ValueError(f"iterations: {n_iterations} iterations with {burn} warm-up keep fewer than the {per_chain} "
                         "draws per chain to rank")
    stride = min(10, kept // per_chain)
    thin = max(1, kept // (per_chain * stride))
    settings = SamplerSettings(sampler="pbicrl", iterations=int(n_iterations), burn_in=burn, thin=thin,
                               weight_prior=problem.weight_prior, indicator_prior=problem.indicator_prior,
                               p_joint=float(p_joint))
    root = np.random.SeedSequence(int(seed))
    d = int(problem.n_features)
    names = [f"penalty[f{j}]" for j in range(d)] + [f"indicator[f{j}]" for j in range(d)]
    ranks = np.zeros((int(n_replicates), 2 * d), dtype=np.int64)
    worst_rhat, min_ess = [], []
    cover: list[list[float]] = [[] for _ in range(d)]  # 1 inside the 90% interval, 0 outside (true c_j = 1)
    cond_u: list[list[float]] = [[] for _ in range(d)]  # normalised rank of the truth among w_j | c_j = 1
    p_c = np.zeros((int(n_replicates), d))
    c_true = np.zeros((int(n_replicates), d), dtype=np.int64)
    t0 = time.perf_counter()
    for r, child in enumerate(root.spawn(int(n_replicates))):
        s_data, s_chain, s_tie = child.spawn(3)
        lik, c, wp = simulate(problem, np.random.default_rng(s_data))
        with warnings.catch_warnings():  # hundreds of short replicates: their per-run warnings are noise here
            warnings.simplefilter("ignore", PbicrlWarning)
            post = sample(lik, settings, chains=n_chains, seed=int(s_chain.generate_state(1)[0]), jobs=1,
                          progress=False)
        pick = np.arange(post.n_draws - 1, -1, -stride)[:per_chain][::-1]  # evenly spaced, ending at the last
        ind = post.indicators[:, pick, :].reshape(-1, d).astype(np.float64)
        eff = ind * post.penalty_weights[:, pick, :].reshape(-1, d)
        truth = np.concatenate([c * wp, c.astype(np.float64)])
        draws = np.hstack([eff, ind])
        tie_rng = np.random.default_rng(s_tie)
        ranks[r] = rank_statistics(truth, draws, tie_rng)
        all_ind = post.indicators.reshape(-1, d).astype(bool)
        all_w = post.penalty_weights.reshape(-1, d)
        p_c[r] = all_ind.mean(axis=0)
        c_true[r] = c
        for j in range(d):
            if c[j] != 1:
                continue
            wj = all_w[all_ind[:, j], j]
            if wj.size < 20:  # the posterior says "off": the interval is empty, the truth is not covered
                cover[j].append(0.0)
                continue
            lo, hi = np.quantile(wj, [0.05, 0.95])
            cover[j].append(float(lo <= wp[j] <= hi))
            picked = ind[:, j].astype(bool)
            wpick = eff[picked, j]
            if wpick.size:
                below = np.sum(wpick < wp[j])
                cond_u[j].append(float((below + tie_rng.random()) / (wpick.size + 1)))
        if diagnose:
            from pbicrl.analysis import diagnostics
            w = diagnostics.compute(post, cache=False).worst()
            worst_rhat.append(math.nan if w["rhat"] is None else w["rhat"])
            min_ess.append(math.nan if w["ess_bulk"] is None else w["ess_bulk"])
        if progress is not None:
            progress(r)
    res = SBCResult(problem, names, ranks, L, settings.to_dict() | {"chains": n_chains, "draws_per_chain": per_chain,
                                                             "ranked_every": stride * thin},
                    runtime_s=time.perf_counter() - t0)
    res.tests = uniformity(ranks, L, bins=bins, seed=int(seed))
    res.conditional = conditional_summary(cover, cond_u, p_c, c_true, bins=bins)
    if diagnose and worst_rhat:
        wr, me = np.array(worst_rhat), np.array(min_ess)
        res.diagnostics = {"computed_on": f"{n_chains} chains x {per_chain * stride} kept draws per replicate "
                                          f"(every {thin}th iteration after warm-up)",
                           "worst_rhat_median": float(np.nanmedian(wr)), "worst_rhat_max": float(np.nanmax(wr)),
                           "share_rhat_above_1.01": float(np.nanmean(wr > 1.01)),
                           "min_ess_bulk_median": float(np.nanmedian(me)), "min_ess_bulk_min": float(np.nanmin(me))}
    return res
