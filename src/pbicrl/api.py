"""High-level entry point: ``pbicrl.infer(dataset, ...)`` from a dataset to a :class:`~pbicrl.results.Posterior`."""

from __future__ import annotations

from typing import Sequence

import numpy as np
from numpy.typing import ArrayLike

from pbicrl.config import ConfigError, InferConfig
from pbicrl.constraints import Constraint, ConstraintSet, constraint_from_dict
from pbicrl.data import Dataset
from pbicrl.likelihood import PreferenceLikelihood
from pbicrl.preferences import Margins
from pbicrl.priors import IndicatorPrior, WeightPrior
from pbicrl.results import Posterior
from pbicrl.samplers import SamplerSettings, sample

__all__ = ["infer", "infer_from_config", "resolve_candidates", "weight_prior_from_config"]


def resolve_candidates(dataset: Dataset, candidates: Sequence[str | int] | None,
                       constraints: ConstraintSet | None = None) -> tuple[int, ...] | None:
    """Feature (or parametric constraint) names or indices -> indices, with a clear error for unknown ones."""
    if candidates is None:
        return None
    names = list(dataset.feature_names) + (list(constraints.names) if constraints is not None else [])
    out = []
    for c in candidates:
        if isinstance(c, (int, np.integer)) and not isinstance(c, bool):
            if not 0 <= int(c) < len(names):
                raise ConfigError(f"candidates: index {c} out of range [0, {len(names)})")
            out.append(int(c))
        elif isinstance(c, str):
            if c.isdigit():
                out.append(int(c))
                continue
            if c not in names:
                raise ConfigError(f"candidates: unknown feature '{c}'; features are {names}")
            out.append(names.index(c))
        else:
            raise ConfigError(f"candidates: expected feature names or indices, got {c!r}")
    if not out:
        raise ConfigError("candidates: empty; name at least one feature that may be a constraint")
    return tuple(out)


def infer(
    dataset: Dataset,
    *,
    method: str = "pbicrl",
    likelihood: str = "grouped",
    nominal_weights: ArrayLike | None = None,
    margins: Margins | ArrayLike | None = None,
    beta: float = 1.0,
    power: float | str | None = None,
    pairs: str | int | None = None,
    pairs_seed: int = 0,
    n_iterations: int = 400_000,
    burn_in: int | None = None,
    thin: int | None = None,
    n_chains: int = 4,
    seed: int = 0,
    n_jobs: int | None = None,
    sigma: float = 0.1,
    f_s: int = 4,
    p_flip: float = 0.5,
    init_scale: float = 1.0,
    init_range: Sequence[float] = (-30.0, -1.0),
    weight_prior: WeightPrior | None = None,
    indicator_prior: IndicatorPrior | None = None,
    candidates: Sequence[str | int] | None = None,
    constraints: Sequence[Constraint | dict] | None = None,
    sigma_theta: float = 0.5,
    p_theta: float | None = None,
    alpha: float = 0.05,
    progress: bool = True,
) -> Posterior:
    r"""Infer constraints from a grouped dataset.

    Parameters
    ----------
    dataset : Dataset
        Ranked demonstrations (group 1 = best).
    method : {"pbicrl", "paper", "authors", "bpl"}
        Sampler, see :mod:`pbicrl.samplers.kernels`.
    likelihood : {"grouped", "pairwise"}
        ``grouped`` (default): the exact grouped Plackett-Luce likelihood, calibrated for grouped rankings.
        ``pairwise``: the paper's Eq. 7 over cross-group pairs (for reproduction; overconfident on grouped
        data because each trajectory enters :math:`(K-1)n` pairs counted as independent).
    nominal_weights : array-like (d,), optional
        Known :math:`w_n`; default: the dataset's, else zeros.
    margins : Margins, K-1 gaps or K x K matrix, optional
        :math:`m_{k\ell}` (default 0).
    beta : float
        Inverse temperature :math:`\beta`.
    power : float or "pairs", optional
        ``pairwise`` only: likelihood power in (0, 1] (default 1 = the paper); ``"pairs"`` = trajectories /
        pairs (see :class:`~pbicrl.likelihood.PreferenceLikelihood`).
    pairs : "all" or int, optional
        ``pairwise`` only: every cross-group pair (default, paper Eq. 7) or ``pairs`` random pairs per group
        pair (seeded by ``pairs_seed``).
    n_iterations, burn_in, thin, n_chains, seed, n_jobs, sigma, f_s, p_flip, init_scale, init_range
        Sampler settings (:class:`~pbicrl.samplers.SamplerSettings`).
    weight_prior, indicator_prior
        Priors (default: half-Student-t with 3 degrees of freedom on (-inf, 0], scale
        :math:`2.5/(\beta\,\mathrm{sd}_j)` per feature; Bernoulli(1/2)). See :class:`~pbicrl.priors.WeightPrior`.
    candidates : names or indices, optional
        Features that may be constraints (default: all known features; with parametric ``constraints``,
        only those, as in Algorithm 2).
    constraints : sequence of Constraint (or dicts for :func:`~pbicrl.constraints.constraint_from_dict`)
        Parametric constraints over the dataset's states (axis halfspace, halfspace, box, ball).
    sigma_theta, p_theta
        Parameter random-walk step and move probability (see :class:`~pbicrl.samplers.SamplerSettings`).
    alpha : float
        Level of the identifiability analysis run before sampling (:func:`pbicrl.identify.identify`); its
        result is in ``summary.json`` under ``identified``.
    progress : bool
        Progress bar.

    Returns
    -------
    Posterior
    """
    if likelihood not in ("grouped", "pairwise"):
        raise ConfigError(f"likelihood: expected 'grouped' or 'pairwise', got {likelihood!r}")
    if likelihood == "grouped":
        if pairs is not None and pairs != "all":
            raise ConfigError("pairs: applies to likelihood='pairwise' only (the grouped likelihood uses every "
                              "trajectory once); pass likelihood='pairwise' to sample pairs")
        if power is not None and power != 1 and power != 1.0:
            raise ConfigError("power: applies to likelihood='pairwise' only (the grouped likelihood needs no "
                              "tempering); pass likelihood='pairwise' to temper Eq. 7")
    pairs = "all" if pairs is None else pairs
    power = 1.0 if power is None else power
    if pairs != "all":
        try:
            pairs = int(pairs)
        except (TypeError, ValueError):
            raise ConfigError(f"pairs: expected 'all' or a number of pairs per group pair, got {pairs!r}") from None
    _check_groups(dataset)
    lik = PreferenceLikelihood.from_dataset(dataset, margins=margins, protocol=pairs, seed=pairs_seed,
                                            nominal_weights=nominal_weights, beta=beta, power=power,
                                            likelihood=likelihood)
    cset = None
    if constraints:
        cset = ConstraintSet(tuple(c if isinstance(c, Constraint) else constraint_from_dict(c) for c in constraints),
                             dataset)
    wprior = weight_prior if weight_prior is not None else WeightPrior()
    settings = SamplerSettings(
        method=method, n_iterations=int(n_iterations), burn_in=burn_in, thin=thin, sigma=sigma, f_s=f_s,
        p_flip=p_flip, init_scale=init_scale, init_range=tuple(init_range), weight_prior=wprior,
        indicator_prior=indicator_prior if indicator_prior is not None else IndicatorPrior(),
        candidates=resolve_candidates(dataset, candidates, cset), sigma_theta=sigma_theta, p_theta=p_theta)
    from pbicrl.identify import identify

    ident = identify(dataset, nominal_weights=lik.nominal_weights, beta=beta, margins=margins, alpha=alpha,
                     candidates=candidates, penalty_sign=wprior.sign if method not in ("paper", "authors") else "any",
                     constraints=cset)
    post = sample(lik, settings, n_chains=n_chains, seed=seed, n_jobs=n_jobs, progress=progress,
                  feature_names=dataset.feature_names, constraints=cset, identified=ident)
    K = dataset.n_groups
    m = Margins.parse(margins, K)
    post.extra.update({"data": {"n_trajectories": dataset.n_trajectories, "n_features": dataset.n_features,
                                "n_states": int(dataset.lengths.sum()), "group_counts": dataset.group_counts()},
                       "margins": m.as_dict(), "likelihood": likelihood, "pairs_seed": int(pairs_seed)})
    return post


def _check_groups(dataset: Dataset) -> None:
    """Inference needs every trajectory labelled (group >= 1) and at least two groups."""
    g = np.asarray(dataset.group)
    if g.size and int(g.min()) < 1:
        raise ConfigError(f"data: {int(np.sum(g < 1))} trajectories are unlabelled (group 0); label them "
                          "(e.g. 'pbicrl label') or drop them before inference")
    if dataset.n_groups < 2:
        raise ConfigError(f"data: inference needs at least two groups, the dataset has {dataset.n_groups}")


def infer_from_config(dataset: Dataset, config: InferConfig, *, progress: bool = True) -> Posterior:
    """:func:`infer` with an :class:`~pbicrl.config.InferConfig`."""
    c = config
    return infer(
        dataset, method=c.sampler, likelihood=c.likelihood, nominal_weights=c.nominal_weights, margins=c.margins,
        beta=c.beta, power=c.power, pairs=c.pairs, pairs_seed=c.pairs_seed, n_iterations=c.iterations,
        burn_in=c.burn_in, thin=c.thin, n_chains=c.chains, seed=c.seed, n_jobs=c.jobs, sigma=c.sigma, f_s=c.f_s,
        p_flip=c.p_flip, init_scale=c.init_scale, init_range=tuple(c.init_range), weight_prior=weight_prior_from_config(c),
        indicator_prior=IndicatorPrior(c.indicator_pi), candidates=c.candidates, constraints=c.constraints,
        sigma_theta=c.sigma_theta, p_theta=c.p_theta, alpha=c.alpha, progress=progress)


def weight_prior_from_config(c: InferConfig) -> WeightPrior:
    """The :class:`~pbicrl.priors.WeightPrior` a config describes (``prior``, ``prior_*``, ``penalty_sign``)."""
    return WeightPrior(c.prior, c.prior_low, c.prior_high, mean=c.prior_mean,  # type: ignore[arg-type]
                       scale=c.prior_abs_scale, sign=c.penalty_sign, df=c.prior_df,  # type: ignore[arg-type]
                       prior_scale=c.prior_scale)
