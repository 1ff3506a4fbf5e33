"""High-level entry points: ``pbicrl.infer(dataset, ...)`` from a dataset to a :class:`~pbicrl.inference.posterior.Posterior`,
and ``pbicrl.load_run(run_dir)`` (:func:`pbicrl.io.runs.load_run`) from a saved run back to one."""

from __future__ import annotations

import os
from dataclasses import replace
from typing import Any, Sequence

import numpy as np

from pbicrl.config import ConfigError, InferConfig, canonical_names, check_setting
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


_OBJECT_SETTINGS = frozenset({"nominal_weights", "margins", "init_range", "candidates", "constraints"})
"""Settings that Python callers may give as objects (arrays, :class:`Margins`, :class:`Constraint`, tuples) rather
than the lists a TOML file holds; they are checked where they are used."""


def infer(dataset: Dataset | str | os.PathLike[str], config: InferConfig | None = None, *,
          weight_prior: WeightPrior | None = None, indicator_prior: IndicatorPrior | None = None,
          log_moves: bool | None = None, progress: bool = True, **overrides: Any) -> Posterior:
    r"""Infer constraints from a grouped dataset.

    The settings are those of :class:`~pbicrl.config.InferConfig` (the command line's options and the TOML keys
    of the same names, with their meanings and defaults): ``config`` gives a whole record, and each keyword
    overrides one of its fields, e.g. ``infer(ds, sampler="bpl", iterations=20_000, chains=4, margins=[0, 2.9])``.
    A keyword is checked as a TOML value is (name, type, range; the message names it), except that
    ``nominal_weights``, ``margins``, ``init_range``, ``candidates`` and ``constraints`` may also be Python objects
    (arrays, a :class:`~pbicrl.inference.preferences.Margins`, :class:`~pbicrl.inference.constraints.Constraint`
    objects).

    Parameters
    ----------
    dataset : Dataset, path or name of a shipped dataset
        Ranked demonstrations (group 1 = best): a :class:`~pbicrl.inference.data.Dataset`, a ``.npz`` file or
        a shipped dataset's name (``"example"``), as ``pbicrl infer DATA`` takes them
        (:func:`~pbicrl.inference.data.load_dataset`). The run records the file (when there is one) and the
        dataset's :meth:`~pbicrl.inference.data.Dataset.content_hash` in ``extra["data"]``, and the posterior
        keeps the dataset, so that :meth:`~pbicrl.inference.posterior.Posterior.to_arviz` can build the pointwise
        log-likelihood and :meth:`~pbicrl.inference.posterior.Posterior.save` can store it with the run.
    config : InferConfig, optional
        Every setting (default: ``InferConfig()``, the defaults).
    weight_prior, indicator_prior
        The priors as objects instead of the ``prior*`` / ``penalty_sign`` and ``indicator_pi`` settings (giving
        both is an error).
    log_moves : bool, optional
        ``pbicrl`` sampler: move sign-constrained penalties on ``log|w|`` (default); ``False``: the moves on ``w`` of
        earlier releases (:class:`~pbicrl.inference.samplers.SamplerSettings`; Python only, not a file setting).
    progress : bool
        Progress bar.
    **overrides
        Fields of :class:`~pbicrl.config.InferConfig` by name. ``iterations="auto"`` (default) runs until every
        reported quantity has split R-hat < ``target_rhat`` and bulk and tail ESS >= ``target_ess``, or
        ``max_time`` seconds are spent (the posterior's ``converged`` and ``convergence`` say which). The old names
        ``method``, ``n_iterations``, ``n_chains``, ``n_jobs`` (of ``sampler``, ``iterations``, ``chains``, ``jobs``)
        are accepted until pbicrl 0.3 with a :class:`~pbicrl.errors.PbicrlWarning`.

    Returns
    -------
    Posterior

    Raises
    ------
    TypeError
        A keyword that is no setting, or ``config`` that is not an :class:`~pbicrl.config.InferConfig`.
    ConfigError
        A setting of the wrong type or out of range; the message names it.
    """
    c = _settings(config, overrides)
    dataset = _as_dataset(dataset)
    margins = Margins.parse(c.margins, dataset.n_groups)  # parsed once; the likelihood and identify take it as is
    sampler, iterations = c.sampler, c.iterations
    if c.likelihood not in ("grouped", "pairwise"):
        raise ConfigError(f"likelihood: expected 'grouped' or 'pairwise', got {c.likelihood!r}")
    if c.likelihood == "grouped":
        if c.pairs is not None and c.pairs != "all":
            raise ConfigError("pairs: applies to likelihood='pairwise' only (the grouped likelihood uses every "
                              "trajectory once); pass likelihood='pairwise' to sample pairs")
        if c.power is not None and c.power != 1 and c.power != 1.0:
            raise ConfigError("power: applies to likelihood='pairwise' only (the grouped likelihood needs no "
                              "tempering); pass likelihood='pairwise' to temper Eq. 7")
    pairs: str | int = "all" if c.pairs is None else c.pairs
    power = 1.0 if c.power is None else c.power
    if pairs != "all":
        try:
            pairs = int(pairs)
        except (TypeError, ValueError):
            raise ConfigError(f"pairs: expected 'all' or a number of pairs per group pair, got {pairs!r}") from None
    prior_settings = {k: getattr(c, k) for k in _PRIOR_SETTINGS}
    if weight_prior is not None:
        changed = [k for k, v in prior_settings.items() if v != getattr(_D, k)]
        if changed:
            raise ConfigError(f"weight_prior: given together with {', '.join(changed)}; give the prior either as a "
                              "WeightPrior or as settings")
    if indicator_prior is not None and c.indicator_pi != _D.indicator_pi:
        raise ConfigError("indicator_prior: given together with indicator_pi; give one of them")
    auto = iterations == "auto"
    # a run until converged moves the penalties more often; fixed-length runs keep the moves of earlier releases
    p_joint = (0.3 if sampler == "pbicrl" and auto else 0.0) if c.p_joint is None else c.p_joint
    p_flip = (0.3 if sampler == "pbicrl" and auto else 0.5) if c.p_flip is None else c.p_flip
    _check_p_joint(p_joint, sampler)
    _check_groups(dataset)
    lik = PreferenceLikelihood.from_dataset(dataset, margins=margins, protocol=pairs, seed=c.pairs_seed,
                                            nominal_weights=c.nominal_weights, beta=c.beta, power=power,
                                            likelihood=c.likelihood, distinct_pairs=sampler == "authors")
    cset = None
    if c.constraints:
        cset = ConstraintSet(tuple(k if isinstance(k, Constraint) else constraint_from_dict(k) for k in c.constraints),
                             dataset)
    wprior = weight_prior if weight_prior is not None else _weight_prior(**prior_settings)
    settings = SamplerSettings(
        sampler=sampler, iterations=2 if auto else int(iterations), burn_in=None if auto else c.burn_in,
        thin=None if auto else c.thin, sigma=c.sigma, f_s=c.f_s,
        p_flip=p_flip, init_scale=c.init_scale, init_range=tuple(c.init_range), weight_prior=wprior,
        indicator_prior=indicator_prior if indicator_prior is not None else IndicatorPrior(c.indicator_pi),
        candidates=resolve_candidates(dataset, c.candidates, cset), sigma_theta=c.sigma_theta, p_theta=c.p_theta,
        p_joint=float(p_joint), log_moves=log_moves)
    if settings.n_draws < MIN_DRAWS:  # before identification and sampling: one draw is no posterior
        raise ConfigError(f"iterations: {int(iterations):,} iterations with burn_in {settings.burn_in_:,} and thin "
                          f"{settings.thin_:,} keep {settings.n_draws} draw(s) per chain; at least {MIN_DRAWS} are "
                          "needed for a posterior and its convergence checks (more iterations or a smaller thin)")
    from pbicrl.analysis.identify import identify

    ident = identify(dataset, nominal_weights=lik.nominal_weights, beta=c.beta, margins=margins, alpha=c.alpha,
                     candidates=c.candidates,
                     penalty_sign=wprior.sign if sampler not in ("paper", "authors") else "any",
                     constraints=cset, preferences=lik.preferences, pairs_seed=int(c.pairs_seed),  # the pairs it uses
                     progress=bool(progress))
    stopping = None
    if auto:
        stopping = StoppingRule(target_ess=float(c.target_ess), target_rhat=float(c.target_rhat),
                                max_time=float(c.max_time), **({} if c.burn_in is None else {"warmup": int(c.burn_in)}))
    post = sample(lik, settings, chains=c.chains, seed=c.seed, jobs=c.jobs, progress=progress,
                  feature_names=dataset.feature_names, constraints=cset, identified=ident, stopping=stopping)
    post.extra.update({"data": {"n_trajectories": dataset.n_trajectories, "n_features": dataset.n_features,
                                "n_states": int(dataset.lengths.sum()), "group_counts": dataset.group_counts(),
                                "sha256": dataset.content_hash()},
                       "margins": margins.as_dict(), "likelihood": c.likelihood, "pairs_seed": int(c.pairs_seed)})
    if dataset.source is not None:
        post.extra["data"]["path"] = str(dataset.source)
    post.keep_dataset(dataset)
    return post


def _settings(config: InferConfig | None, overrides: dict[str, Any]) -> InferConfig:
    """``config`` (default: the defaults) with ``overrides``, each checked as :class:`InferConfig` checks a file's
    value (old names renamed with a warning); ``None`` keeps the config's value."""
    if config is None:
        config = InferConfig()
    elif not isinstance(config, InferConfig):
        raise TypeError(f"config: expected an InferConfig (pbicrl.InferConfig or pbicrl.config.load_config), got "
                        f"{type(config).__name__}; pass single settings as keywords")
    values = canonical_names(overrides, where="infer() argument", stacklevel=4)
    known = InferConfig.setting_types()
    for key, value in values.items():
        if key not in known:
            raise TypeError(f"infer() got an unexpected keyword argument {key!r}")
        if key not in _OBJECT_SETTINGS:
            value = value.item() if isinstance(value, np.generic) else value  # NumPy scalars are numbers too
            values[key] = value
            check_setting(key, value, where="infer")
    return replace(config, **{k: v for k, v in values.items() if v is not None})


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
    """``infer(dataset, config)``: :func:`infer` with an :class:`~pbicrl.config.InferConfig`."""
    return infer(dataset, config, progress=progress)


def weight_prior_from_config(c: InferConfig) -> WeightPrior:
    """The :class:`~pbicrl.inference.priors.WeightPrior` a config describes (``prior``, ``prior_*``, ``penalty_sign``)."""
    return _weight_prior(**{k: getattr(c, k) for k in _PRIOR_SETTINGS})


def _weight_prior(*, prior: str, prior_low: float | None, prior_high: float | None, prior_mean: float,
                  prior_scale: float, prior_abs_scale: float | None, prior_df: float, penalty_sign: str) -> WeightPrior:
    return WeightPrior(prior, prior_low, prior_high, mean=prior_mean,  # type: ignore[arg-type]
                       scale=prior_abs_scale, sign=penalty_sign, df=prior_df,  # type: ignore[arg-type]
                       prior_scale=prior_scale)
