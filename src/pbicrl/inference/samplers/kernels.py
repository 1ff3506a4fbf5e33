"""Sampler kernels as pure ``init(rng) -> State`` and ``step(rng, state) -> (State, Info)`` functions.

Three methods share one compiled loop (:mod:`pbicrl.inference.samplers._mcmc`):

``"pbicrl"`` (default) - a valid reversible-jump Metropolis-Hastings sampler for the model
    :math:`c_j \\sim \\mathrm{Bernoulli}(\\pi)`, :math:`w_{p,j} \\mid c_j{=}1 \\sim p(w)`,
    likelihood paper Eq. 7. A switched-off feature has *no* penalty weight (its weight does not exist,
    stored as 0), so no stale weight is ever proposed. Moves, each chosen with a fixed probability:

    * **flip-and-draw** (probability ``p_flip``, feature :math:`j` uniform): switching :math:`j` on draws
      :math:`w_j \\sim q_j = \\mathcal{N}(\\mu_j, s_j^2)` and is accepted with
      :math:`\\min\\{1, \\frac{L(c', w')\\,\\pi\\,p(w_j)}{L(c, w)\\,(1-\\pi)\\,q_j(w_j)}\\}`; switching off is the
      reverse move, accepted with the reciprocal ratio evaluated at the current :math:`w_j`. The
      proposal :math:`q_j` does not depend on :math:`w_j`, so the pair of moves is reversible (Green 1995,
      a dimension-matching jump with unit Jacobian).
    * **weight step** (otherwise): a Gaussian random walk on one active weight chosen uniformly among the
      active ones (the identity if none is active), accepted with the usual ratio including the prior.

    * **joint weight step** (probability ``p_joint``, default 0): all active weights at once, a Gaussian step with
      a covariance adapted during warm-up (for many correlated weights and large data).

    During warm-up (``burn_in``) the random-walk scales adapt towards 30% acceptance and each :math:`q_j`
    is fitted to the active draws of :math:`w_j` (mean, twice the standard deviation), so switching a
    constraint on proposes weights where its posterior lies. Adaptation stops at the end of warm-up; the
    kept draws come from a fixed, valid kernel.

``"paper"`` - Algorithm 1 verbatim: iteration :math:`i` flips :math:`c_j` keeping the latent weight when
    :math:`i \\bmod f_s \\ne 0`, else steps :math:`w_j` by :math:`\\mathcal{N}(0, \\sigma)`; acceptance by the
    likelihood ratio alone (flat improper prior). Kept for exact reproduction; as a sampler it mixes
    poorly (a feature switched back on proposes its stale latent weight).

``"authors"`` - Algorithm 1 as the authors' public code runs it: identical to ``"paper"`` except that a
    flip to off sets the weight to zero (switching it back on starts from zero), with their initialisation:
    indicators Bernoulli(1/2) and penalties uniform on ``init_range`` (their point mass: [-30, -1];
    Fetch-Reach: [-100, -10]) for every feature, nominal ones included, kept only where the indicator starts
    on (a feature that starts off has weight 0). As in their code a weight step on a feature that is off leaves
    its weight at 0 (they propose from the effective weights), and the schedule counts iterations from 0: the
    first iteration, and every ``f_s``-th after it, steps a weight. The reset acts as shrinkage of
    :math:`c_j w_{p,j}` toward zero; judge this sampler on the effective penalty.

``"bpl"`` - Algorithm 3: every candidate feature active, random walk on :math:`w_p` (optionally with a
    prior). Features that are not candidates keep :math:`w_j = 0`: they are not part of the model.

Priors (:mod:`pbicrl.inference.priors`) are resolved against the likelihood's data once per kernel
(:attr:`Kernel.resolved_prior`): a scale-aware prior gets its per-feature scales
:math:`s_j = \\text{prior\\_scale}/(\\beta\\,\\mathrm{sd}_j)` there, and the ``pbicrl``/``bpl`` samplers measure
their random-walk steps, ``bpl``'s initial weights and the initial flip proposals in the same per-feature
unit :math:`1/(\\beta\\,\\mathrm{sd}_j)`, so rescaling a feature rescales its chain and nothing else.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, fields, replace
from functools import cached_property
from typing import Any, Literal, NamedTuple

import numpy as np
from numpy.typing import NDArray

from pbicrl.config import accept_old_names, canonical_names
from pbicrl.inference.codes import MODES, MOVE_NAMES, N_COUNTS
from pbicrl.inference.constraints import ConstraintSet
from pbicrl.inference.likelihood import PreferenceLikelihood
from pbicrl.inference.priors import IndicatorPrior, PriorError, ResolvedWeightPrior, WeightPrior, truncated_normal_ppf
from pbicrl.inference.samplers import _mcmc
from pbicrl.inference.samplers.bundles import (Adaptation, ConstraintArrays, Draws, MapTracker, Model, Moves,
                                               Position, Randoms, Schedule, Scratch)

__all__ = ["SamplerSettings", "ChainState", "StepInfo", "Kernel", "build_kernel", "METHODS"]

METHODS = ("pbicrl", "paper", "authors", "bpl")
ADAPT_EVERY = 500  # warm-up adapts the proposals every this many iterations (when adaptation is on)
_LATENT = ("paper", "authors")  # Algorithm 1's schedule and acceptance; flat improper prior


@dataclass(frozen=True)
class SamplerSettings:
    r"""Settings of a sampler (bound into a :class:`Kernel` by :func:`build_kernel`).

    Parameters
    ----------
    sampler : {"pbicrl", "paper", "authors", "bpl"}
        See module docstring (formerly ``method``).
    iterations : int
        Metropolis-Hastings iterations per chain (paper: 400,000; formerly ``n_iterations``).
    burn_in : int or None
        Warm-up iterations, not kept (adaptation happens here). Default: a quarter of ``iterations``.
    thin : int or None
        Keep every ``thin``-th draw after warm-up. Default: at most 10,000 draws per chain.
    sigma : float
        Random-walk standard deviation :math:`\\sigma` (initial value when adapting). Paper: 0.1. With a
        scale-aware weight prior, ``pbicrl`` and ``bpl`` use :math:`\\sigma / (\\beta\\,\\mathrm{sd}_j)` for
        feature :math:`j` (:math:`\\sigma` per standard deviation of the feature).
    f_s : int
        Paper mode: sampling frequency :math:`f_s` (weight step when :math:`i \\bmod f_s = 0`). Paper: 4.
    p_flip : float
        PBICRL mode: probability of a flip-and-draw move per iteration.
    adapt : bool or None
        Adapt step sizes and flip proposals during warm-up. Default: on for ``pbicrl``, off otherwise
        (the paper's algorithms use a fixed :math:`\\sigma`).
    init_scale : float
        ``paper``: initial latent weights :math:`\\mathcal{N}(0, \\text{init\\_scale}^2)` (Algorithm 1 verbatim).
        ``bpl``: the same normal (per standard deviation of the feature for a scale-aware prior) restricted to the
        prior's support, drawn exactly. ``pbicrl`` draws the initial weights from the prior instead. Initial
        indicators are Bernoulli(1/2), as the paper's random initialisation.
    weight_prior, indicator_prior
        Priors (see :mod:`pbicrl.inference.priors`); default: half-Student-t (3 degrees of freedom, scale
        2.5 / (beta sd_j)) on :math:`(-\\infty, 0]`, and Bernoulli(1/2). The paper mode ignores them (flat improper).
    candidates : sequence of int or None
        Features that may be constraints (default: all known features, or only the parametric
        constraints when there are any, as in Algorithm 2). Others keep :math:`c_j = 0`.
    sigma_theta : float
        Random-walk step :math:`\sigma_2` of the constraint parameters (paper HalfCheetah/Ant: 0.5).
    p_theta : float or None
        Probability of a parameter step. ``pbicrl``: per iteration (default 0.25 with parametric
        constraints); ``paper``/``bpl``: at iterations that would step a weight (default 0.5). Algorithm 2
        as printed never proposes :math:`\vartheta` (its ``elsif i mod f_s != 1`` branch is always taken);
        this schedule does.
    naive_counts : bool
        Recount every state on a parameter proposal even where a binary search suffices (for benchmarks).
    p_joint : float
        ``pbicrl`` and ``bpl``: probability per iteration of moving all active weights together, a Gaussian step
        whose covariance is adapted to the chain during warm-up (adaptive Metropolis within the reversible jump;
        fixed afterwards, so the kept draws come from a valid kernel). It pays when weights are correlated and
        many (large data); taken from the single-weight steps' share. Default 0: the single-site moves only.
    log_moves : bool or None
        ``pbicrl``: move every weight whose prior support is one-signed (the default half-t on
        :math:`(-\infty, 0]`, a box :math:`[a, 0]`) on the log-magnitude scale :math:`\eta = \log|w|`: random-walk
        steps on :math:`\eta` (Jacobian included) and flip-and-draw proposals that are normal mixtures on
        :math:`\eta`. A penalty the rankings bound from one side has a posterior that is the prior's heavy tail
        above the separation scale; steps proportional to the magnitude cross it in a few moves where fixed steps
        need thousands. Default: on for ``pbicrl`` (``False``: the moves on :math:`w` of earlier releases, which the
        chain reference keeps). Ignored by the other samplers.

    The names are those of :class:`pbicrl.config.InferConfig` and ``summary.json``; ``method=`` and
    ``n_iterations=`` (and the attributes of those names) work until pbicrl 0.3 with a
    :class:`~pbicrl.errors.PbicrlWarning`. :meth:`from_dict` reads :meth:`to_dict` back.
    """

    sampler: Literal["pbicrl", "paper", "authors", "bpl"] = "pbicrl"
    iterations: int = 400_000
    burn_in: int | None = None
    thin: int | None = None
    sigma: float = 0.1
    f_s: int = 4
    p_flip: float = 0.5
    adapt: bool | None = None
    init_scale: float = 1.0
    init_range: tuple[float, float] = (-30.0, -1.0)
    weight_prior: WeightPrior = field(default_factory=WeightPrior)
    indicator_prior: IndicatorPrior = field(default_factory=IndicatorPrior)
    candidates: tuple[int, ...] | None = None
    sigma_theta: float = 0.5
    p_theta: float | None = None
    naive_counts: bool = False
    p_joint: float = 0.0
    log_moves: bool | None = None

    def __post_init__(self) -> None:
        if self.sampler not in METHODS:
            raise ValueError(f"sampler: unknown sampler {self.sampler!r}; choose one of {', '.join(METHODS)}")
        if int(self.iterations) < 1:
            raise ValueError(f"iterations: must be >= 1, got {self.iterations}")
        if self.burn_in is not None and not (0 <= int(self.burn_in) < int(self.iterations)):
            raise ValueError(f"burn_in: must lie in [0, iterations), got {self.burn_in} for {self.iterations} iterations")
        if self.thin is not None and int(self.thin) < 1:
            raise ValueError(f"thin: must be >= 1, got {self.thin}")
        if not (np.isfinite(self.sigma) and self.sigma > 0):
            raise ValueError(f"sigma: the random-walk step must be positive, got {self.sigma}")
        if int(self.f_s) < 1:
            raise ValueError(f"f_s: the sampling frequency must be >= 1, got {self.f_s}")
        if not (0.0 < self.p_flip < 1.0):
            raise ValueError(f"p_flip: must lie strictly between 0 and 1, got {self.p_flip}")
        if not (np.isfinite(self.init_scale) and self.init_scale > 0):
            raise ValueError(f"init_scale: must be positive, got {self.init_scale}")
        lo_hi = tuple(float(x) for x in self.init_range)
        if len(lo_hi) != 2 or not (np.isfinite(lo_hi[0]) and np.isfinite(lo_hi[1]) and lo_hi[0] < lo_hi[1]):
            raise ValueError(f"init_range: expected two finite numbers low < high, got {self.init_range!r}")
        object.__setattr__(self, "init_range", lo_hi)
        if self.sampler == "pbicrl" and self.weight_prior.kind == "improper":
            raise PriorError("weight prior: the pbicrl sampler needs a proper prior on w_p (P(c=1) is undefined "
                             "otherwise); use 'student_t', 'normal' or 'flat' with bounds, or sampler='paper'")
        if self.candidates is not None:
            object.__setattr__(self, "candidates", tuple(int(j) for j in self.candidates))
        if not (np.isfinite(self.sigma_theta) and self.sigma_theta > 0):
            raise ValueError(f"sigma_theta: the parameter step must be positive, got {self.sigma_theta}")
        if self.p_theta is not None and not (0.0 <= self.p_theta < 1.0):
            raise ValueError(f"p_theta: must lie in [0, 1), got {self.p_theta}")
        if self.sampler == "pbicrl" and self.p_theta is not None and self.p_flip + self.p_theta >= 1.0:
            raise ValueError(f"p_flip + p_theta must be < 1 (weight steps need the rest), got {self.p_flip} + {self.p_theta}")
        if not (0.0 <= float(self.p_joint) < 1.0):
            raise ValueError(f"p_joint: must lie in [0, 1), got {self.p_joint}")
        if self.p_joint and self.sampler in ("paper", "authors"):
            raise ValueError("p_joint: joint weight moves apply to the pbicrl and bpl samplers only")
        rest = (self.p_flip if self.sampler == "pbicrl" else 0.0) + (self.p_theta or 0.0)
        if self.p_joint and rest + self.p_joint >= 1.0:
            raise ValueError(f"p_joint: the move probabilities must leave room for single-weight steps, got "
                             f"p_joint {self.p_joint} with {rest} for flips and parameter steps")

    @property
    def burn_in_(self) -> int:
        return int(self.iterations) // 4 if self.burn_in is None else int(self.burn_in)

    @property
    def thin_(self) -> int:
        if self.thin is not None:
            return int(self.thin)
        kept = int(self.iterations) - self.burn_in_
        return max(1, -(-kept // 10_000))

    @property
    def n_draws(self) -> int:
        kept = int(self.iterations) - self.burn_in_
        return -(-kept // self.thin_)

    @property
    def adapt_(self) -> bool:
        return self.sampler == "pbicrl" if self.adapt is None else bool(self.adapt)

    @property
    def log_moves_(self) -> bool:
        return self.sampler == "pbicrl" and (self.log_moves is None or bool(self.log_moves))

    def to_dict(self) -> dict:
        """Every setting, JSON-ready, under its :class:`~pbicrl.config.InferConfig` name (``summary.json``'s
        ``settings``); :meth:`from_dict` reads it back."""
        return {"sampler": self.sampler, "iterations": int(self.iterations), "burn_in": self.burn_in_,
                "thin": self.thin_, "sigma": self.sigma, "f_s": self.f_s, "p_flip": self.p_flip,
                "adapt": self.adapt_, "init_scale": self.init_scale,
                "init_range": list(self.init_range) if self.sampler == "authors" else None, "weight_prior": self.weight_prior.to_dict(),
                "indicator_prior": {"pi": self.indicator_prior.pi},
                "candidates": None if self.candidates is None else list(self.candidates),
                "sigma_theta": self.sigma_theta, "p_theta": self.p_theta, "p_joint": float(self.p_joint),
                "log_moves": self.log_moves_}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "SamplerSettings":
        """The settings :meth:`to_dict` wrote (``summary.json``'s ``settings``, any schema version).

        Keys that are not settings (``beta``, ``constraints``, ... of a run's record) are ignored; the old names
        ``method`` and ``n_iterations`` are read with a :class:`~pbicrl.errors.PbicrlWarning`, except in a record
        written by pbicrl before the rename (one that has no ``sampler``), which is read silently.

        Raises
        ------
        ValueError
            A setting out of range (the message names it), as the constructor.
        """
        d = dict(d)
        if "sampler" not in d and "method" in d and "iterations" in d:  # a record of schema 1 or 2: no warning
            d["sampler"] = d.pop("method")
        d = canonical_names(d, where="SamplerSettings.from_dict key", stacklevel=2)
        names = {f.name for f in fields(cls)}
        kw: dict[str, Any] = {k: v for k, v in d.items() if k in names}
        if isinstance(kw.get("weight_prior"), Mapping):
            wp = {f.name for f in fields(WeightPrior)}
            kw["weight_prior"] = WeightPrior(**{k: v for k, v in kw["weight_prior"].items() if k in wp})
        if isinstance(kw.get("indicator_prior"), Mapping):
            kw["indicator_prior"] = IndicatorPrior(float(kw["indicator_prior"].get("pi", 0.5)))
        if kw.get("init_range") is None:
            kw.pop("init_range", None)
        return cls(**kw)

    def replace(self, **changes: Any) -> "SamplerSettings":
        """A copy with ``changes`` (the old names ``method``, ``n_iterations`` too, with a warning)."""
        if "method" in changes or "n_iterations" in changes:
            changes = canonical_names(changes, where="SamplerSettings argument", stacklevel=2)
        return replace(self, **changes)


accept_old_names(SamplerSettings, "SamplerSettings")  # method=, n_iterations= until pbicrl 0.3


def _field(bundle: str, name: str, doc: str) -> property:
    """Read-only shortcut ``state.<name>`` for ``state.<bundle>.<name>`` (the flat names of earlier releases)."""
    return property(lambda self: getattr(getattr(self, bundle), name), doc=doc)


def _density(bundle: str, index: int, doc: str) -> property:
    """Read-only ``float(state.<bundle>.log_density[index])`` (the bundles keep their log-densities in an array)."""
    return property(lambda self: float(getattr(self, bundle).log_density[index]), doc=doc)


class ChainState(NamedTuple):
    r"""State of one chain: what the next step needs, in four parts.

    Attributes
    ----------
    position : Position
        :math:`c`, :math:`w_p`, :math:`\vartheta`, the scaled returns and feature rows they imply, and
        [log-likelihood, log-prior] (:class:`pbicrl.inference.samplers.bundles.Position`).
    iteration : int
        Iterations done (the schedule's clock: warm-up, adaptation points, thinning).
    adaptation : Adaptation
        Proposal scales and warm-up statistics (:class:`pbicrl.inference.samplers.bundles.Adaptation`); fixed
        after warm-up.
    best : MapTracker
        The highest-posterior state visited (:class:`pbicrl.inference.samplers.bundles.MapTracker`).
    counts : ndarray (N_COUNTS,) int64
        Proposals and acceptances per move type and exact likelihood evaluations, indexed by ``C_*`` of
        :mod:`pbicrl.inference.codes`.

    The flat names of earlier releases (``indicators``, ``log_likelihood``, ``sigma``, ``map_indicators``, ...)
    remain as read-only properties.
    """

    position: Position
    iteration: int
    adaptation: Adaptation
    best: MapTracker
    counts: NDArray[np.int64]

    indicators = _field("position", "indicators", ":math:`c`, (d,) int8.")
    penalty_weights = _field("position", "penalty_weights", ":math:`w_p`, (d,).")
    parameters = _field("position", "parameters", ":math:`\\vartheta`, (P,).")
    scaled_returns = _field("position", "scaled_returns", ":math:`a`, (N,).")
    features_T = _field("position", "features_T", ":math:`\\beta\\bar\\Phi^\\top`, (d, N).")
    sigma = _field("adaptation", "sigma", "Weight random-walk scales, (d,).")
    q_mean = _field("adaptation", "q_mean", "Flip-and-draw proposal means, (d,).")
    q_scale = _field("adaptation", "q_scale", "Flip-and-draw proposal scales, (d,).")
    sigma_theta = _field("adaptation", "sigma_theta", "Parameter random-walk scales, (P,).")
    q_theta_mean = _field("adaptation", "q_theta_mean", "Parameter proposal means, (P,).")
    q_theta_scale = _field("adaptation", "q_theta_scale", "Parameter proposal scales, (P,).")
    joint_cov = _field("adaptation", "joint_cov", "The joint weight move's covariance, (d, d).")
    map_indicators = _field("best", "indicators", "MAP :math:`c`.")
    map_penalty_weights = _field("best", "penalty_weights", "MAP :math:`w_p`.")
    map_parameters = _field("best", "parameters", "MAP :math:`\\vartheta`.")

    log_likelihood = _density("position", 0, "Log-likelihood at the position.")
    log_prior = _density("position", 1, "Log-prior at the position (0 for the paper's flat improper prior).")
    map_log_posterior = _density("best", 0, "Log-posterior of the MAP state.")
    map_log_likelihood = _density("best", 1, "Log-likelihood of the MAP state.")

    def __repr__(self) -> str:
        # shapes and scalars only: scaled_returns and features_T hold one entry per trajectory
        on = np.flatnonzero(np.asarray(self.indicators)).tolist()
        return (f"ChainState(iteration={self.iteration}, d={np.size(self.indicators)}, active={on}, "
                f"params={np.size(self.parameters)}, N={np.size(self.scaled_returns)}, "
                f"log_likelihood={self.log_likelihood:.6g}, log_prior={self.log_prior:.6g}, "
                f"map_log_posterior={self.map_log_posterior:.6g})")


class StepInfo(NamedTuple):
    """What one step did, as the compiled loop reports it (not reconstructed from the counters)."""

    move: str  # "flip", "weight" (single or joint), "parameter" or "none"
    accepted: bool
    log_likelihood: float


@dataclass(frozen=True, eq=False)
class Kernel:
    """A sampler with its settings bound: ``init``, ``step`` and the compiled ``run``.

    ``constraints`` adds parametric constraint features after the likelihood's known features.
    """

    likelihood: PreferenceLikelihood
    settings: SamplerSettings
    constraints: ConstraintSet | None = None
    min_penalty: tuple[float, ...] | None = None
    r"""Per feature, the separation scale :math:`|w_p| \ge m_j` the rankings require (``identify``; NaN or 0 where
    none): centres the first birth proposals of the log-magnitude moves, so a penalty the data require is proposed
    where the data put it whatever the prior says. Only affects how fast warm-up finds the posterior."""
    parameter_ranges: tuple[tuple[float, float], ...] | None = None
    r"""Per parameter :math:`\vartheta_p` (``ConstraintSet.param_names`` order), the interval ``identify`` found
    (NaN ends where none): the ``pbicrl`` sampler starts each chain's parameters uniformly in that interval widened
    by twice its width on each side (within the prior box), instead of anywhere in the box. A chain started where
    the rankings are far from ordered (a wall beyond every state the demonstrations reach: 2,000 nats below the
    identified region on Blocked Ant) never left it. Only the starting point changes, not the stationary
    distribution."""

    @property
    def d_known(self) -> int:
        return self.likelihood.n_features

    @property
    def n_features(self) -> int:
        """Known features plus parametric constraints."""
        return self.d_known + (0 if self.constraints is None else self.constraints.n_constraints)

    @property
    def n_params(self) -> int:
        return 0 if self.constraints is None else self.constraints.n_params

    @property
    def _cand(self) -> NDArray[np.int64]:
        d = self.n_features
        if self.settings.candidates is None:
            cand = np.arange(self.d_known, d) if self.constraints is not None else np.arange(d)
        else:
            cand = np.asarray(self.settings.candidates, dtype=np.int64)
        if cand.size == 0 or cand.min() < 0 or cand.max() >= d or np.unique(cand).size != cand.size:
            raise ValueError(f"candidates: expected distinct feature indices in [0, {d}), got {cand.tolist()}")
        return cand

    @property
    def p_theta_(self) -> float:
        if self.constraints is None:
            return 0.0
        if self.settings.p_theta is not None:
            return float(self.settings.p_theta)
        return 0.25 if self.settings.sampler == "pbicrl" else 0.5

    @cached_property
    def _settings_prior(self) -> ResolvedWeightPrior:
        """The settings' weight prior resolved against the likelihood's data (whatever the method)."""
        return self.settings.weight_prior.resolve(self.likelihood.mean_features, beta=self.likelihood.beta,
                                                  n_parametric=self.n_features - self.d_known)

    @cached_property
    def resolved_prior(self) -> ResolvedWeightPrior:
        """The weight prior the sampler uses, resolved per feature against the likelihood's data.

        Scale-aware priors get :math:`s_j = \\text{prior\\_scale} / (\\beta\\,\\mathrm{sd}_j)` from the likelihood's
        ``mean_features`` and ``beta``; parametric constraint features use :math:`\\mathrm{sd} = 0.5`. The paper
        mode uses the flat improper prior of Algorithm 1, whatever the settings say.
        """
        if self.settings.sampler in _LATENT:
            return WeightPrior("improper", sign="any").resolve(self.likelihood.mean_features, beta=self.likelihood.beta,
                                                               n_parametric=self.n_features - self.d_known)
        return self._settings_prior

    @cached_property
    def _prior_arrays_cached(self) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
        return self.resolved_prior.as_arrays()

    def _prior_arrays(self) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
        """``(pkind, prm)`` for the compiled loop (resolved once per kernel)."""
        return self._prior_arrays_cached

    def prior_summary(self) -> dict[str, Any]:
        """JSON-ready record of the priors as the sampler uses them (for ``summary.json``).

        Keys: the weight prior's choices (``kind``, ``sign``, ``low``/``high``/``support`` with ``None`` for
        infinite ends, ``mean``, ``scale``, ``df``, ``prior_scale``, ``scale_aware``), ``beta``, ``features``
        (by feature index as a string: resolved ``scale`` :math:`s_j`, ``feature_sd``, ``sd_source``,
        ``support``), ``sampler``, ``applied`` (False in paper mode, which ignores priors) and ``indicator_pi``.
        """
        s = self.settings
        out = self.resolved_prior.to_dict()
        out.update({"sampler": s.sampler, "applied": s.sampler not in _LATENT,
                    "indicator_pi": None if s.sampler == "bpl" else float(s.indicator_prior.pi)})
        return out

    def _step_unit(self) -> NDArray[np.float64]:
        """Per-feature unit of random-walk steps: 1 in paper mode (Algorithm 1 verbatim), else the prior's."""
        return np.ones(self.n_features) if self.settings.sampler in _LATENT else self.resolved_prior.unit

    def _param_arrays(self) -> dict[str, NDArray]:
        if self.constraints is not None:
            return self.constraints.compiled_arrays()
        N = self.likelihood.mean_features.shape[0]
        z = np.zeros(0)
        zi = np.zeros(0, np.int64)
        return {"fam": zi, "sign": zi, "poff": np.zeros(1, np.int64), "dims_off": np.zeros(1, np.int64), "dims": zi,
                "sorted_vals": np.zeros((0, 0)), "states": np.zeros((0, 0)), "offsets": np.zeros(N + 1, np.int64),
                "inv_len": np.zeros(N), "lo": z, "hi": z}

    def _log_prior(self, c: NDArray, w: NDArray, theta: NDArray) -> float:
        s = self.settings
        if s.sampler in _LATENT:
            return 0.0
        lpw = self.resolved_prior.logpdf(w)
        cs = self.constraints
        lpt = np.zeros(self.n_features)
        if cs is not None:
            width = np.log(cs.bounds[:, 1] - cs.bounds[:, 0])
            for m in range(cs.n_constraints):
                lpt[self.d_known + m] = -width[cs.param_offsets[m]:cs.param_offsets[m + 1]].sum()
        if s.sampler == "bpl":
            cand = self._cand  # non-candidates are fixed at w = 0, not parameters of the model
            return float(np.sum(lpw[cand]) + np.sum(lpt[cand]))
        on = c.astype(bool)
        return float(np.sum(lpw[on]) + np.sum(lpt[on]) + on.sum() * s.indicator_prior.log_odds)

    def _columns(self, theta: NDArray) -> NDArray[np.float64]:
        """(d, N) scaled mean features at ``theta``."""
        from pbicrl.inference.samplers._parametric import param_column

        lik = self.likelihood
        rows = [lik.scaled_features_T]
        if self.constraints is not None:
            A = self._param_arrays()
            N = lik.mean_features.shape[0]
            for m in range(self.constraints.n_constraints):
                col = np.empty(N)
                param_column(m, theta, lik.beta, A["fam"], A["sign"], A["poff"], A["dims_off"], A["dims"],
                             A["sorted_vals"], A["states"], A["offsets"], A["inv_len"], col, False)
                rows.append(col[None, :])
        return np.ascontiguousarray(np.concatenate(rows, axis=0))

    def _start_box(self, lo: NDArray[np.float64], hi: NDArray[np.float64]
                   ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Where the parameters start: the prior box, or for ``pbicrl`` the identified intervals widened by twice
        their width each side and kept inside the box (:attr:`parameter_ranges`)."""
        r = self.parameter_ranges
        if self.settings.sampler != "pbicrl" or r is None or len(r) != lo.size:
            return lo, hi
        a, b = lo.copy(), hi.copy()
        for p, (rl, rh) in enumerate(r):
            if math.isfinite(rl) and math.isfinite(rh) and rl <= rh:
                w = max(rh - rl, 1e-3 * (hi[p] - lo[p]))
                a[p], b[p] = max(lo[p], rl - 2.0 * w), min(hi[p], rh + 2.0 * w)
                if not a[p] < b[p]:
                    a[p], b[p] = lo[p], hi[p]
        return a, b

    def init(self, rng: np.random.Generator | int | None = None) -> ChainState:
        """Random initial state (paper: "randomly sample penalty weight, constraint features and theta").

        Indicators: Bernoulli(1/2) on the candidates (``bpl``: all on). Weights: ``pbicrl`` draws each active
        one from the prior; ``paper`` draws :math:`\\mathcal{N}(0, \\text{init\\_scale}^2)` latent weights for every
        feature, as Algorithm 1; ``bpl`` draws candidates from that normal (in the prior's step unit) restricted
        to the prior's support, and fixes the others at 0. Every draw is exact (nothing is clipped) and lies in
        the prior's support. Flip proposals :math:`q_j` start from the prior's scale
        (:meth:`pbicrl.inference.priors.ResolvedWeightPrior.proposal`).
        """
        rng = np.random.default_rng(rng)
        s = self.settings
        lik = self.likelihood
        d = self.n_features
        cand = self._cand
        prior = self.resolved_prior
        unit = self._step_unit()
        c = np.zeros(d, dtype=np.int8)
        if s.sampler == "bpl":
            c[:] = 1
        else:
            c[cand] = rng.integers(0, 2, cand.size).astype(np.int8)
        if s.sampler == "paper":
            w = rng.normal(0.0, s.init_scale, d)
        elif s.sampler == "authors":
            # the authors' code draws a weight for every feature but keeps it only where c_j starts on: a feature
            # that starts off has weight 0 (and, with the reset, is switched on at 0)
            w = np.where(c == 1, rng.uniform(s.init_range[0], s.init_range[1], d), 0.0)
        elif s.sampler == "bpl":
            w = self._bpl_initial_weights(rng)
        else:
            w = np.where(c == 1, prior.sample(rng), 0.0)
        P = self.n_params
        if self.constraints is not None:
            lo, hi = self.constraints.bounds[:, 0], self.constraints.bounds[:, 1]
            theta = rng.uniform(*self._start_box(lo, hi))
            qt_mu, qt_s = 0.5 * (lo + hi), (hi - lo) / 4.0
            sig_t = np.minimum(np.full(P, float(s.sigma_theta)), (hi - lo) / 4.0)
        else:
            theta = qt_mu = qt_s = sig_t = np.zeros(0)
        FbT = self._columns(theta)
        wn = np.concatenate([lik.nominal_weights, np.zeros(d - self.d_known)])
        a = _returns(FbT, wn + c * w)
        ll = lik.from_scaled_returns(a)
        lp = self._log_prior(c, w, theta)
        sigma = float(s.sigma) * unit
        # Flip-and-draw proposals from the prior's own scale (ResolvedWeightPrior.proposal). Only pbicrl uses
        # them; the other methods record them from the settings' prior, as they always did.
        qprior = self._settings_prior
        if qprior.kind == "improper":
            q_mean, q_scale = np.zeros(d), np.maximum(10.0 * sigma, 2.0 * s.init_scale * unit)
        else:
            q_mean, q_sd = qprior.proposal()
            q_scale = np.maximum(10.0 * sigma, q_sd)
        lsg, _, mu_a, s_a = self._log_proposals
        if lsg.any():  # log-magnitude moves: steps and proposals on eta = log|w|
            on_log = lsg != 0
            sigma = np.where(on_log, 0.5, sigma)
            q_mean = np.where(on_log, mu_a, q_mean)
            q_scale = np.where(on_log, s_a, q_scale)
        return ChainState(
            position=Position(c, w, theta.copy(), a, FbT, np.array([ll, lp])),
            iteration=0,
            adaptation=Adaptation(sigma, q_mean, q_scale, sig_t.copy(), qt_mu.copy(), qt_s.copy(), np.zeros((5, d)),
                                  np.zeros((5, P)), np.diag(sigma * sigma), np.zeros((3, d, d)),
                                  np.array([1.0, 0.0, 0.0])),
            best=MapTracker(c.copy(), w.copy(), theta.copy(), np.array([ll + lp, ll])),
            counts=np.zeros(N_COUNTS, dtype=np.int64))

    def _bpl_initial_weights(self, rng: np.random.Generator) -> NDArray[np.float64]:
        """:math:`\\mathcal{N}(0, (\\text{init\\_scale}\\,u_j)^2)` restricted to the prior's support, candidates only.

        Draw the normal for every feature first (the rng call of the paper's BPL initialisation), then redraw
        the candidates that fell outside the support from the truncated normal by its inverse CDF. That is
        exact: :math:`P(A) = N(A \\cap S) + (1 - N(S))\\,N(A \\cap S)/N(S) = N(A \\cap S)/N(S)`. With a wide
        ``flat`` prior nothing falls outside and no further random numbers are used.
        """
        s = self.settings
        prior = self.resolved_prior
        unit = self._step_unit()
        w = rng.normal(0.0, s.init_scale, self.n_features) * unit  # unit is exactly 1 unless scale-aware
        is_cand = np.zeros(self.n_features, dtype=bool)
        is_cand[self._cand] = True
        out = is_cand & ~((w >= prior.low) & (w <= prior.high))
        if out.any():
            k = np.flatnonzero(out)
            w[k] = truncated_normal_ppf(rng.random(k.size), 0.0, s.init_scale * unit[k], prior.low[k], prior.high[k])
        return np.where(is_cand, w, 0.0)

    def _pmax(self) -> int:
        if self.constraints is None:
            return 1
        return max(1, int(np.max(np.diff(self.constraints.param_offsets))))

    def draw_randoms(self, rng: np.random.Generator, n: int) -> Randoms:
        """Per-iteration random numbers: feature choice, move choice, normal, acceptance uniform, parameter normals,
        and with ``p_joint`` > 0 the joint moves' normals (drawn last: without them the stream is unchanged; a
        (1, 1) placeholder otherwise)."""
        out = (rng.random(n), rng.random(n), rng.standard_normal(n), rng.random(n))
        zt = rng.standard_normal((n, self._pmax())) if self.constraints is not None else np.zeros((n, 1))
        zj = rng.standard_normal((n, self.n_features)) if self.settings.p_joint > 0.0 else np.zeros((1, 1))
        return Randoms(*out, zt, zj)

    def new_buffers(self, n_draws: int) -> Draws:
        """Draw buffers ``(c, w, theta, ll, lp, n)`` for :meth:`run`."""
        d, P = self.n_features, self.n_params
        return Draws(np.zeros((n_draws, d), np.int8), np.zeros((n_draws, d)), np.zeros((n_draws, P)),
                     np.zeros(n_draws), np.zeros(n_draws), np.zeros(1, np.int64))

    @cached_property
    def _log_proposals(self) -> tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.float64],
                                      NDArray[np.float64], NDArray[np.float64]]:
        r"""``(log_sign, birth_bound, qa_mean, qa_scale)`` of the log-magnitude moves (:class:`Moves`).

        The defensive birth component is :math:`|w| \sim U(0, b_j)` with :math:`b_j` the prior's 99% quantile of
        :math:`|w|`; the adapted component :math:`\log|w| \sim \mathcal{N}(\mu_j, s_j^2)` starts at the prior's
        median with the spread of its 1%-99% range, or, where the rankings require a penalty (``min_penalty``
        :math:`m_j > 0`), just above the separation scale (:math:`\log m_j + 0.5`, sd 1), since the posterior of a
        required penalty starts at :math:`m_j`.
        """
        d = self.n_features
        zero = (np.zeros(d, np.int64), np.ones(d), np.zeros(d), np.ones(d))
        if not self.settings.log_moves_:
            return zero
        prior = self.resolved_prior
        lsg = np.where(prior.high <= 0.0, -1, np.where(prior.low >= 0.0, 1, 0)).astype(np.int64)
        lsg[(prior.high <= 0.0) & (prior.low >= 0.0)] = 0  # a point mass at 0: nothing to move
        if not lsg.any():
            return zero
        qs = np.abs(prior.ppf(np.array([0.01, 0.5, 0.99])))  # (3, d)
        tiny = np.finfo(float).tiny
        lq = np.log(np.maximum(qs, tiny))
        bound = np.maximum(qs[0], qs[2])
        mu_a = lq[1]
        s_a = np.maximum(np.abs(lq[2] - lq[0]) / 4.65, 0.5)  # the 1%-99% range of a normal is 4.65 sd
        if self.min_penalty is not None:
            mp = np.full(d, np.nan)
            mp[:min(d, len(self.min_penalty))] = np.asarray(self.min_penalty, dtype=float)[:d]
            req = np.isfinite(mp) & (mp > 0)
            mu_a[req] = np.log(mp[req]) + 0.5
            s_a[req] = 1.0
        bad = ~(np.isfinite(mu_a) & np.isfinite(s_a) & np.isfinite(bound) & (bound > 0))
        lsg[bad] = 0
        return lsg, np.where(bad, 1.0, bound), mu_a, s_a

    @cached_property
    def _moves(self) -> Moves:
        s = self.settings
        lsg, bound, _, _ = self._log_proposals
        return Moves(int(self.d_known), bool(s.naive_counts), self._cand, float(s.p_flip), float(self.p_theta_),
                     int(s.f_s), float(s.p_joint), lsg, bound)

    @cached_property
    def _model(self) -> Model:
        pkind, prm = self._prior_arrays()
        lik = self.likelihood
        return Model(float(lik.beta), float(lik.power), float(self.settings.indicator_prior.log_odds), pkind, prm)

    @cached_property
    def _constraint_arrays(self) -> ConstraintArrays:
        A = self._param_arrays()
        return ConstraintArrays(*(A[k] for k in ConstraintArrays._fields))

    def _advance(self, rng: np.random.Generator, state: ChainState, n: int,
                 out: tuple[NDArray, ...] | None) -> tuple[ChainState, NDArray[np.int64]]:
        """:meth:`run`, also returning [move code, accepted] of the last iteration."""
        s = self.settings
        d, N = self.n_features, self.likelihood.mean_features.shape[0]
        st = _copy_state(state)
        out = self.new_buffers(0) if out is None else Draws(*out)
        randoms = self.draw_randoms(rng, n)
        scratch = Scratch(np.empty(N), np.empty(N), np.empty(self.n_params), np.zeros(d, dtype=np.bool_), np.zeros(d),
                          np.zeros(2, np.int64))
        schedule = Schedule(MODES[s.sampler], int(n), int(st.iteration), s.burn_in_, s.thin_,
                            ADAPT_EVERY if s.adapt_ else 0)
        _mcmc.advance(schedule, st.position, self.likelihood.kernel_bundle(), self._constraint_arrays, self._moves,
                      self._model, Randoms(*randoms), st.adaptation, out, st.best, st.counts, scratch)
        return st._replace(iteration=st.iteration + n), scratch.last

    def run(self, rng: np.random.Generator, state: ChainState, n: int, out: tuple[NDArray, ...] | None = None) -> ChainState:
        """Advance ``n`` iterations in compiled code; ``out`` (from :meth:`new_buffers`) receives kept draws."""
        return self._advance(rng, state, n, out)[0]

    def step(self, rng: np.random.Generator, state: ChainState) -> tuple[ChainState, StepInfo]:
        """One Metropolis-Hastings iteration (pure: ``state`` is not modified)."""
        new, last = self._advance(rng, state, 1, None)
        return new, StepInfo(MOVE_NAMES[int(last[0])], bool(last[1]), new.log_likelihood)


def _returns(FbT: NDArray[np.float64], weights: NDArray[np.float64]) -> NDArray[np.float64]:
    """:math:`a = (\\beta\\bar\\Phi) w` summed feature by feature, in a fixed order.

    Not a BLAS matrix product: its summation order depends on the BLAS thread count (Ray workers run with one
    thread), and a 1-ulp difference in the initial returns is enough to make chains differ between executors.
    """
    a = np.zeros(FbT.shape[1])
    for j in range(FbT.shape[0]):
        a += weights[j] * FbT[j]
    return a


def _copy_state(s: ChainState) -> ChainState:
    """Every array copied: the compiled loop mutates them in place."""
    def fresh(bundle: Any) -> Any:
        return type(bundle)(*(x.copy() for x in bundle))

    return ChainState(fresh(s.position), int(s.iteration), fresh(s.adaptation), fresh(s.best), s.counts.copy())


def build_kernel(likelihood: PreferenceLikelihood, settings: SamplerSettings | None = None, *,
                 constraints: ConstraintSet | None = None, min_penalty: Any = None,
                 parameter_ranges: Any = None, **overrides) -> Kernel:
    """Bind settings to a likelihood: ``build_kernel(lik, sampler="bpl", sigma=0.5)``.

    ``min_penalty`` (d,): the separation scales of ``identify`` (see :attr:`Kernel.min_penalty`);
    ``parameter_ranges`` (P, 2): its parameter intervals (see :attr:`Kernel.parameter_ranges`)."""
    settings = SamplerSettings() if settings is None else settings
    if overrides:
        settings = settings.replace(**overrides)
    mp = None if min_penalty is None else tuple(float(x) if x is not None else float("nan") for x in min_penalty)
    pr = None if parameter_ranges is None else tuple((float(a), float(b)) for a, b in parameter_ranges)
    kernel = Kernel(likelihood, settings, constraints, mp, pr)
    if constraints is not None and constraints.dataset.n_trajectories != likelihood.mean_features.shape[0]:
        raise ValueError("constraints: built on a dataset with a different number of trajectories than the likelihood")
    kernel._cand  # validate candidates now  # noqa: B018
    s = kernel.settings
    rest = (s.p_flip if s.sampler == "pbicrl" else 0.0) + kernel.p_theta_
    if s.p_joint and rest + s.p_joint >= 1.0:
        raise ValueError(f"p_joint: the move probabilities must leave room for single-weight steps, got p_joint "
                         f"{s.p_joint} with {rest} for flips and parameter steps")
    kernel.resolved_prior  # and the prior against the data (e.g. a support without prior mass)  # noqa: B018
    return kernel
