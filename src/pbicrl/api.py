"""High-level entry points: ``pbicrl.infer(dataset, ...)`` from a dataset to a :class:`~pbicrl.inference.posterior.Posterior`,
and ``pbicrl.load_run(run_dir)`` (:func:`pbicrl.io.runs.load_run`) from a saved run back to one."""

from __future__ import annotations

import os
from typing import Any, Sequence

import numpy as np
from numpy.typing import ArrayLike

from pbicrl.config import DEPRECATED_NAMES, ConfigError, InferConfig, canonical_names, check_setting
from pbicrl.inference.constraints import Constraint, ConstraintSet, constraint_from_dict
from pbicrl.inference.data import Dataset
from pbicrl.inference.likelihood import PreferenceLikelihood
from pbicrl.inference.preferences import Margins
from pbicrl.inference.priors import IndicatorPrior, WeightPrior
from pbicrl.inference.posterior import Posterior
from pbicrl.inference.samplers import SamplerSettings, sample
from pbicrl.inference.samplers.driver import StoppingRule
from pbicrl.io.runs import load_run  # pbicrl.load_run: the one reader of a run directory into a Posterior

__all__ = ["infer", "infer_from_config", "load_run", "resolve_candidates", "weight_prior_from_config", "MIN_DRAWS"]


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


_D = InferConfig()  # the defaults of every setting (InferConfig is their one source)
MIN_DRAWS = 2
"""Fewest kept draws per chain :func:`infer` accepts: one draw gives P(c=1) of 0 or 1 and no convergence check."""
_PRIOR_SETTINGS = ("prior", "prior_low", "prior_high", "prior_mean", "prior_scale", "prior_abs_scale", "prior_df",
                   "penalty_sign")


def infer(
    dataset: Dataset | str | os.PathLike[str],
    *,
    sampler: str = _D.sampler,
    likelihood: str = _D.likelihood,
    nominal_weights: ArrayLike | None = None,
    margins: Margins | ArrayLike | None = None,
    beta: float = _D.beta,
    power: float | str | None = None,
    pairs: str | int | None = None,
    pairs_seed: int = _D.pairs_seed,
    iterations: int | str = _D.iterations,
    burn_in: int | None = None,
    thin: int | None = None,
    chains: int = _D.chains,
    seed: int = _D.seed,
    jobs: int | None = None,
    sigma: float = _D.sigma,
    f_s: int = _D.f_s,
    p_flip: float | None = _D.p_flip,
    init_scale: float = _D.init_scale,
    init_range: Sequence[float] = tuple(_D.init_range),
    prior: str = _D.prior,
    prior_low: float | None = None,
    prior_high: float | None = None,
    prior_mean: float = _D.prior_mean,
    prior_scale: float = _D.prior_scale,
    prior_abs_scale: float | None = None,
    prior_df: float = _D.prior_df,
    penalty_sign: str = _D.penalty_sign,
    indicator_pi: float = _D.indicator_pi,
    weight_prior: WeightPrior | None = None,
    indicator_prior: IndicatorPrior | None = None,
    candidates: Sequence[str | int] | None = None,
    constraints: Sequence[Constraint | dict] | None = None,
    sigma_theta: float = _D.sigma_theta,
    p_theta: float | None = None,
    p_joint: float | None = _D.p_joint,
    target_ess: float = _D.target_ess,
    target_rhat: float = _D.target_rhat,
    max_time: float = _D.max_time,
    log_moves: bool | None = None,
    alpha: float = _D.alpha,
    progress: bool = True,
    **deprecated: Any,
) -> Posterior:
    r"""Infer constraints from a grouped dataset.

    Every setting has the name, meaning and default of the :class:`~pbicrl.config.InferConfig` field (the
    command line's option and the TOML key of the same name); :func:`infer_from_config` takes the record.

    Parameters
    ----------
    dataset : Dataset, path or name of a shipped dataset
        Ranked demonstrations (group 1 = best): a :class:`~pbicrl.inference.data.Dataset`, a ``.npz`` file or
        a shipped dataset's name (``"example"``), as ``pbicrl infer DATA`` takes them
        (:func:`~pbicrl.inference.data.load_dataset`). The run records the file (when there is one) and the
        dataset's :meth:`~pbicrl.inference.data.Dataset.content_hash` in ``extra["data"]``, and the posterior
        keeps the dataset, so that :meth:`~pbicrl.inference.posterior.Posterior.to_arviz` can build the pointwise
        log-likelihood and :meth:`~pbicrl.inference.posterior.Posterior.save` can store it with the run.
    sampler : {"pbicrl", "paper", "authors", "bpl"}
        MCMC sampler, see :mod:`pbicrl.inference.samplers.kernels` (formerly ``method``).
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
        pairs (see :class:`~pbicrl.inference.likelihood.PreferenceLikelihood`).
    pairs : "all" or int, optional
        ``pairwise`` only: every cross-group pair (default, paper Eq. 7) or ``pairs`` random pairs per group
        pair (seeded by ``pairs_seed``).
    iterations, burn_in, thin, chains, seed, jobs, sigma, f_s, p_flip, init_scale, init_range
        Sampler settings (:class:`~pbicrl.inference.samplers.SamplerSettings`); ``iterations`` per chain (formerly
        ``n_iterations``), or ``"auto"`` (default): run until converged (below); ``chains`` independent chains
        (formerly ``n_chains``), ``jobs`` worker processes (formerly ``n_jobs``; the draws do not depend on it).
        With ``"auto"``, ``burn_in`` is the warm-up (default 2,000) and ``thin`` does not apply.
    target_ess, target_rhat, max_time : float
        ``iterations="auto"``: sample in rounds until every reported quantity has split R-hat < ``target_rhat``
        and bulk and tail ESS >= ``target_ess`` (defaults 1.01 and 400), or ``max_time`` seconds (default 600) are
        spent. The posterior's ``converged`` and ``convergence`` say which; an unconverged run issues one
        :class:`~pbicrl.errors.PbicrlWarning` naming the quantities that fall short.
    prior, prior_low, prior_high, prior_mean, prior_scale, prior_abs_scale, prior_df, penalty_sign
        The prior on each penalty weight (default: half-Student-t with 3 degrees of freedom on (-inf, 0], scale
        :math:`2.5/(\beta\,\mathrm{sd}_j)` per feature), see :class:`~pbicrl.inference.priors.WeightPrior`.
    indicator_pi : float
        Bernoulli prior probability :math:`\pi` of each constraint (default 1/2).
    weight_prior, indicator_prior
        The priors as objects instead of the settings above (giving both is an error).
    candidates : names or indices, optional
        Features that may be constraints (default: all known features; with parametric ``constraints``,
        only those, as in Algorithm 2).
    constraints : sequence of Constraint (or dicts for :func:`~pbicrl.inference.constraints.constraint_from_dict`)
        Parametric constraints over the dataset's states (axis halfspace, halfspace, box, ball).
    sigma_theta, p_theta
        Parameter random-walk step and move probability (see :class:`~pbicrl.inference.samplers.SamplerSettings`).
    log_moves : bool, optional
        ``pbicrl`` sampler: move sign-constrained penalties on ``log|w|`` (default); ``False``: the moves on ``w`` of
        earlier releases (:class:`~pbicrl.inference.samplers.SamplerSettings`).
    p_joint : float, optional
        ``pbicrl``/``bpl`` samplers: probability of the joint step of all active weights (covariance adapted in
        warm-up), in [0, 1); default 0.3 for ``pbicrl`` run until converged, else 0; ``p_flip`` + ``p_theta`` +
        ``p_joint`` must stay below 1.
    alpha : float
        Level of the identifiability analysis run before sampling (:func:`pbicrl.analysis.identify.identify`); its
        result is in ``summary.json`` under ``identified``.
    progress : bool
        Progress bar.
    **deprecated
        ``method``, ``n_iterations``, ``n_chains``, ``n_jobs``: the old names of ``sampler``, ``iterations``,
        ``chains``, ``jobs``, accepted until pbicrl 0.3 with a :class:`~pbicrl.errors.PbicrlWarning`.

    Returns
    -------
    Posterior
    """
    if deprecated:
        unknown = sorted(k for k in deprecated if k not in DEPRECATED_NAMES)
        if unknown:
            raise TypeError(f"infer() got an unexpected keyword argument {unknown[0]!r}")
        given = {"sampler": sampler, "iterations": iterations, "chains": chains, "jobs": jobs}
        for old, new in DEPRECATED_NAMES.items():
            if old in deprecated and given[new] != getattr(_D, new):
                raise ConfigError(f"infer() argument '{old}': deprecated name of '{new}', which is given too; "
                                  f"keep only '{new}'")
        renamed = canonical_names(deprecated, where="infer() argument", stacklevel=2)
        sampler = renamed.get("sampler", sampler)
        iterations = renamed.get("iterations", iterations)
        chains = renamed.get("chains", chains)
        jobs = renamed.get("jobs", jobs)
    dataset = _as_dataset(dataset)
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
    prior_settings = {"prior": prior, "prior_low": prior_low, "prior_high": prior_high, "prior_mean": prior_mean,
                      "prior_scale": prior_scale, "prior_abs_scale": prior_abs_scale, "prior_df": prior_df,
                      "penalty_sign": penalty_sign}
    if weight_prior is not None:
        changed = [k for k, v in prior_settings.items() if v != getattr(_D, k)]
        if changed:
            raise ConfigError(f"weight_prior: given together with {', '.join(changed)}; give the prior either as a "
                              "WeightPrior or as settings")
    if indicator_prior is not None and indicator_pi != _D.indicator_pi:
        raise ConfigError("indicator_prior: given together with indicator_pi; give one of them")
    for key, value in (("iterations", iterations), ("target_ess", target_ess), ("target_rhat", target_rhat),
                       ("max_time", max_time)):
        check_setting(key, value, where="infer")
    auto = iterations == "auto"
    # a run until converged moves the penalties more often; fixed-length runs keep the moves of earlier releases
    if p_joint is None:
        p_joint = 0.3 if sampler == "pbicrl" and auto else 0.0
    if p_flip is None:
        p_flip = 0.3 if sampler == "pbicrl" and auto else 0.5
    _check_p_joint(p_joint, sampler)
    _check_groups(dataset)
    lik = PreferenceLikelihood.from_dataset(dataset, margins=margins, protocol=pairs, seed=pairs_seed,
                                            nominal_weights=nominal_weights, beta=beta, power=power,
                                            likelihood=likelihood, distinct_pairs=sampler == "authors")
    cset = None
    if constraints:
        cset = ConstraintSet(tuple(c if isinstance(c, Constraint) else constraint_from_dict(c) for c in constraints),
                             dataset)
    wprior = weight_prior if weight_prior is not None else _weight_prior(**prior_settings)
    settings = SamplerSettings(
        sampler=sampler, iterations=2 if auto else int(iterations), burn_in=None if auto else burn_in,
        thin=None if auto else thin, sigma=sigma, f_s=f_s,
        p_flip=p_flip, init_scale=init_scale, init_range=tuple(init_range), weight_prior=wprior,
        indicator_prior=indicator_prior if indicator_prior is not None else IndicatorPrior(indicator_pi),
        candidates=resolve_candidates(dataset, candidates, cset), sigma_theta=sigma_theta, p_theta=p_theta,
        p_joint=float(p_joint), log_moves=log_moves)
    if settings.n_draws < MIN_DRAWS:  # before identification and sampling: one draw is no posterior
        raise ConfigError(f"iterations: {int(iterations):,} iterations with burn_in {settings.burn_in_:,} and thin "
                          f"{settings.thin_:,} keep {settings.n_draws} draw(s) per chain; at least {MIN_DRAWS} are "
                          "needed for a posterior and its convergence checks (more iterations or a smaller thin)")
    from pbicrl.analysis.identify import identify

    ident = identify(dataset, nominal_weights=lik.nominal_weights, beta=beta, margins=margins, alpha=alpha,
                     candidates=candidates, penalty_sign=wprior.sign if sampler not in ("paper", "authors") else "any",
                     constraints=cset, preferences=lik.preferences, pairs_seed=int(pairs_seed),  # the pairs it uses
                     progress=bool(progress))
    stopping = None
    if auto:
        stopping = StoppingRule(target_ess=float(target_ess), target_rhat=float(target_rhat), max_time=float(max_time),
                                **({} if burn_in is None else {"warmup": int(burn_in)}))
    post = sample(lik, settings, chains=chains, seed=seed, jobs=jobs, progress=progress,
                  feature_names=dataset.feature_names, constraints=cset, identified=ident, stopping=stopping)
    K = dataset.n_groups
    m = Margins.parse(margins, K)
    post.extra.update({"data": {"n_trajectories": dataset.n_trajectories, "n_features": dataset.n_features,
                                "n_states": int(dataset.lengths.sum()), "group_counts": dataset.group_counts(),
                                "sha256": dataset.content_hash()},
                       "margins": m.as_dict(), "likelihood": likelihood, "pairs_seed": int(pairs_seed)})
    if dataset.source is not None:
        post.extra["data"]["path"] = str(dataset.source)
    post.keep_dataset(dataset)
    return post


def _as_dataset(dataset: Any) -> Dataset:
    """A :class:`Dataset`, or a path / shipped name read as ``pbicrl infer DATA`` reads it."""
    if isinstance(dataset, Dataset):
        return dataset
    if isinstance(dataset, (str, os.PathLike)):
        from pbicrl.inference.data import load_dataset

        return load_dataset(dataset)
    raise TypeError(f"data: expected a Dataset, a .npz path or a shipped dataset's name (e.g. 'example'), "
                      f"got {type(dataset).__name__}")


def _check_p_joint(p_joint: Any, sampler: str) -> None:
    """``p_joint`` is a number in [0, 1), and non-zero only for the samplers that have the joint move."""
    if isinstance(p_joint, (bool, np.bool_)) or not isinstance(p_joint, (int, float, np.integer, np.floating)):
        raise ConfigError(f"p_joint: expected a number in [0, 1), got {p_joint!r}")
    if not 0.0 <= float(p_joint) < 1.0:
        raise ConfigError(f"p_joint: expected a number in [0, 1), got {p_joint!r}")
    if p_joint and sampler in ("paper", "authors"):
        raise ConfigError(f"p_joint: the joint weight step belongs to the pbicrl and bpl samplers, not to "
                          f"sampler={sampler!r} (Algorithm 1 as printed); leave p_joint at 0")


def _check_groups(dataset: Dataset) -> None:
    """Inference needs every trajectory labelled (group >= 1) and at least two groups."""
    g = np.asarray(dataset.group)
    if g.size and int(g.min()) < 1:
        raise ConfigError(f"data: {int(np.sum(g < 1))} trajectories are unlabelled (group 0); label them "
                          "(e.g. 'pbicrl label') or drop them before inference")
    if dataset.n_groups < 2:
        raise ConfigError(f"data: inference needs at least two groups, the dataset has {dataset.n_groups}")


def infer_from_config(dataset: Dataset | str | os.PathLike[str], config: InferConfig, *, progress: bool = True) -> Posterior:
    """:func:`infer` with an :class:`~pbicrl.config.InferConfig` (the same names: every field is an argument)."""
    values = config.to_dict()
    values["init_range"] = tuple(values["init_range"])
    return infer(dataset, **values, progress=progress)


def weight_prior_from_config(c: InferConfig) -> WeightPrior:
    """The :class:`~pbicrl.inference.priors.WeightPrior` a config describes (``prior``, ``prior_*``, ``penalty_sign``)."""
    return _weight_prior(**{k: getattr(c, k) for k in _PRIOR_SETTINGS})


def _weight_prior(*, prior: str, prior_low: float | None, prior_high: float | None, prior_mean: float,
                  prior_scale: float, prior_abs_scale: float | None, prior_df: float, penalty_sign: str) -> WeightPrior:
    return WeightPrior(prior, prior_low, prior_high, mean=prior_mean,  # type: ignore[arg-type]
                       scale=prior_abs_scale, sign=penalty_sign, df=prior_df,  # type: ignore[arg-type]
                       prior_scale=prior_scale)
