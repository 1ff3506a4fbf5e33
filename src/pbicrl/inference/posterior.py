r"""Posterior draws and what they say: the selected constraints, conditional penalties, diagnostics.

The reward is :math:`r(s) = (w_n + c \circ w_p)^\top \phi(s)` with unknown indicators :math:`c` and penalty
weights :math:`w_p` (and, for parametric constraints, locations :math:`\vartheta`). A reversible-jump chain
visits states of different dimension, so the summaries that mean something are

* the **selected set**: features with :math:`P(c_j = 1 \mid \mathcal{D}) > 0.5`, the median-probability model
  (Barbieri & Berger 2004, optimal for prediction under squared loss);
* the **most frequent set** of active features over all kept draws, with its frequency;
* **conditional summaries** of :math:`w_{p,j}` given :math:`c_j = 1` (median, mean, 90% interval), each flagged
  ``prior_driven`` when it moves with the prior: measured by reweighting the draws to the fitted prior made
  tenfold wider (:mod:`pbicrl.inference.sensitivity`), for every reported number.

These hold for the ``pbicrl`` sampler. The ``paper`` / ``authors`` samplers do not target a posterior over
:math:`c`, so their share of draws with :math:`c_j = 1` is reported as the frequency on in the chain, with no
selection; ``bpl`` has no indicators (:data:`~pbicrl.inference.draws.INDICATOR_MEANINGS`).

The "MAP" kept in ``summary.json`` is *the highest-density visited draw*: in a reversible-jump chain it
compares densities of different dimensions (each active feature adds a prior density factor), so it is not
the mode of a common space and not a recommended point estimate.

``summary.json`` (:func:`pbicrl.inference.summary.summary_dict`, schema version
:data:`~pbicrl.inference.summary.SCHEMA_VERSION`; files without ``schema_version`` are version 1)::

    schema_version       3 (2: ``method`` for ``sampler``, and ``settings.method``; 1: no ``schema_version``)
    sampler, feature_names
    indicators           {"meaning": "posterior" | "chain_frequency" | "fixed", "label": ...}
                         (:data:`~pbicrl.inference.draws.INDICATOR_MEANINGS`)
    selected             [names with P(c=1) > 0.5] (pbicrl sampler; null for paper, authors, bpl)
    most_frequent_set    {"features": [...], "frequency": float} (null for bpl)
    not_identifiable     {name: reason}   features the rankings say nothing about (no R-hat / ESS)
    map                  highest-density visited draw: indicators, penalty_weights, effective_penalty,
                         parameters, log_posterior, log_likelihood, definition
    posterior            mean_effective_penalty, ci90 (of c_j w_pj), and p_constraint (pbicrl) or
                         frequency_on (paper, authors) or in_model (bpl),
                         penalty_given_active {mean, median, ci90, prior_driven, active_draws} (each by name),
                         prior_driven {basis, p_constraint | frequency_on, mean_effective_penalty, ci90,
                         penalty_given_active {mean, median, ci90}}: a flag for every number above (null: not
                         measured), prior_sensitivity (the measurement, :mod:`pbicrl.inference.sensitivity`),
                         authors_statistic (paper, authors: :meth:`Posterior.authors_statistic`),
                         rhat, diagnostics, parameters {name: {mean, median, ci90, active_draws,
                         prior_driven, identified_range}}
    identified           the attached identification (``Identification.to_dict()``) or null
    prior                the attached prior summary, else the sampler settings' prior dicts
    acceptance_rate, iterations, burn_in, thin, draws_per_chain, chains, seed, runtime_s, chain_runtime_s,
    likelihood_evaluations, settings, warnings, extra

Every number is finite or ``null``: the writer never emits ``NaN`` / ``Infinity`` (not JSON). Run directories
(``summary.json`` and ``chains.npz``, all kept draws ``(chains, draws, d)``, per-chain ``counts`` and the per-draw
``move``, ``accepted`` and ``acceptance_fraction``) are written atomically by :mod:`pbicrl.io.runs`
(:meth:`Posterior.save`); ``pbicrl.load_run`` (:func:`pbicrl.io.runs.load_run`, also :meth:`Posterior.load`)
reads one back into a :class:`Posterior` with the same draws, table and summary as the one that was saved.

The module is the data and its statistics (ArviZ's split): the table, HTML and data frame are drawn by
:mod:`pbicrl.analysis.report`, the diagnostics by :mod:`pbicrl.analysis.diagnostics`, files by
:mod:`pbicrl.io.runs`; the methods of the same names here are thin entry points to them.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Sequence

import numpy as np
from numpy.typing import NDArray

from pbicrl import errors
from pbicrl.config import accept_old_names
from pbicrl.inference.codes import C_FLIP_ACC, C_FLIP_PROP, C_T_ACC, C_T_PROP, C_W_ACC, C_W_PROP, N_COUNTS
from pbicrl.inference.draws import LEVEL, DrawsView, split_rhat
from pbicrl.inference.posterior_warnings import PosteriorWarnings
from pbicrl.inference.prior_driven import NON_VARYING_REASON, PriorDrivenSummaries
from pbicrl.inference.summary import SCHEMA_VERSION, is_real, summary_dict, to_py

if TYPE_CHECKING:
    from pbicrl.analysis.diagnostics import Diagnostics
    from pbicrl.inference.data import Dataset
    from pbicrl.inference.samplers.kernels import Kernel

__all__ = ["Posterior", "SCHEMA_VERSION", "AUTHORS_LAST_ITERATIONS"]

AUTHORS_LAST_ITERATIONS = 500
"""Iterations at the end of each chain that the paper authors' code averages (:meth:`Posterior.authors_statistic`)."""

_REPR_NAMES = 6  # names shown in a repr before "..."


@dataclass(frozen=True, eq=False)
class Posterior(PriorDrivenSummaries, PosteriorWarnings, DrawsView):
    r"""Draws of :math:`(c, w_p)` (and :math:`\vartheta`) from one or more chains, with run metadata.

    Every warning of :meth:`warnings` is issued once through :func:`pbicrl.errors.warn`
    (:class:`~pbicrl.errors.PbicrlWarning`) when the posterior is built, so API users can catch them.

    Attributes
    ----------
    indicators : ndarray, (chains, draws, d) int8
    penalty_weights : ndarray, (chains, draws, d)
        :math:`w_p` (0 where inactive for ``pbicrl``, latent for ``paper``).
    log_likelihood, log_prior : ndarray, (chains, draws)
    map_indicators, map_penalty_weights : ndarray, (d,)
        The highest-density visited draw over all chains (:data:`MAP_DEFINITION`).
    map_log_posterior, map_log_likelihood : float
    feature_names : tuple of str
    sampler : str
        ``pbicrl``, ``paper``, ``authors`` or ``bpl`` (formerly ``method``, still accepted until pbicrl 0.3).
    settings : dict
    counts : ndarray, (chains, N_COUNTS)
        Flip proposals/accepts, weight proposals/accepts, likelihood evaluations, parameter proposals/accepts.
    seed : int
    runtime_s : float
        Wall time of the whole sampling call.
    chain_runtime_s : ndarray, (chains,)
    parameters : ndarray, (chains, draws, P)
        Parametric constraint locations :math:`\vartheta` (NaN while the constraint is inactive, ``pbicrl``).
    map_parameters : ndarray, (P,)
    parameter_names : tuple of str
        ``"<constraint>.<parameter>"``.
    parameter_owner : tuple of int
        Feature index of the constraint each parameter belongs to.
    extra : dict
        Anything else to report (data description, margins, ...).
    identified : dict or None
        What the rankings identify, ``pbicrl.analysis.identify.identify(...).to_dict()`` (an object with ``to_dict``
        and ``warnings`` is accepted and converted): ``separable``, ``alpha``, per feature ``min_penalty``,
        ``unbounded``, ``direction``, ``identifiable``, ``reason`` (under ``features`` or at the top level),
        ``parameters`` ``{name: [low, high]}``, optionally ``warnings``. ``None``: heuristics are used.
    prior : dict or None
        Summary of the prior (``Kernel.prior_summary()``); ``None``: the settings' prior dicts.
    non_varying : tuple of str
        Candidate features whose per-trajectory mean never changes (found by :meth:`from_chains`): the
        rankings say nothing about their penalty.
    move, accepted, acceptance_fraction : ndarray, (chains, draws), or None
        Per kept draw: the move type of the iteration that produced it (int8, 0 none, 1 flip, 2 weight, 3
        parameter; :data:`pbicrl.inference.codes.MOVES`), whether it was accepted, and the fraction of
        iterations accepted since the previous kept draw. ``None`` for runs saved before they were recorded.
    path : Path or None
        The run directory this posterior was loaded from (:meth:`load`), else ``None``.
    recorded : dict
        Numbers of ``summary.json`` the saved arrays cannot give back (``acceptance_rate``,
        ``likelihood_evaluations`` of runs saved before ``chains.npz`` held the per-chain ``counts``); empty for
        a sampled posterior.
    issue_warnings : bool
        Issue :meth:`warnings` as :class:`~pbicrl.errors.PbicrlWarning` when built (default).
    """

    indicators: NDArray[np.int8]
    penalty_weights: NDArray[np.float64]
    log_likelihood: NDArray[np.float64]
    log_prior: NDArray[np.float64]
    map_indicators: NDArray[np.int8]
    map_penalty_weights: NDArray[np.float64]
    map_log_posterior: float
    map_log_likelihood: float
    feature_names: tuple[str, ...]
    sampler: str
    settings: dict
    counts: NDArray[np.int64]
    seed: int
    runtime_s: float
    chain_runtime_s: NDArray[np.float64]
    parameters: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 0, 0)))
    map_parameters: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))
    parameter_names: tuple[str, ...] = ()
    parameter_owner: tuple[int, ...] = ()
    extra: dict = field(default_factory=dict)
    identified: dict | None = None
    prior: dict | None = None
    non_varying: tuple[str, ...] = ()
    move: NDArray[np.int8] | None = None
    accepted: NDArray[np.bool_] | None = None
    acceptance_fraction: NDArray[np.float64] | None = None
    path: Path | None = None
    recorded: dict = field(default_factory=dict)
    issue_warnings: bool = field(default=True, repr=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "identified", _as_identification(self.identified))
        if self.prior is not None and not isinstance(self.prior, Mapping):
            raise TypeError(f"prior: expected a dict (Kernel.prior_summary()), got {type(self.prior).__name__}")
        object.__setattr__(self, "non_varying", tuple(str(n) for n in self.non_varying))
        object.__setattr__(self, "_issued", frozenset())
        if self.issue_warnings:
            # stacklevel 5: errors.warn <- _issue <- __post_init__ <- __init__ <- whoever built the posterior
            self._issue(self.warnings(), stacklevel=5)

    def emit_warnings(self, *, stacklevel: int = 2) -> None:
        """Issue those of :meth:`warnings` this posterior has not issued yet (:class:`~pbicrl.errors.PbicrlWarning`).

        ``stacklevel`` as for :func:`warnings.warn`: 2 (default) attributes them to the caller of this method.
        """
        self._issue(self.warnings(), stacklevel=stacklevel + 1)

    def _issue(self, messages: Sequence[str], *, stacklevel: int) -> None:
        issued = set(getattr(self, "_issued", frozenset()))
        for m in messages:
            if m not in issued:
                errors.warn(m, stacklevel=stacklevel)
                issued.add(m)
        object.__setattr__(self, "_issued", frozenset(issued))


    @classmethod
    def from_chains(cls, results: Sequence[dict], *, kernel: "Kernel", seed: int, runtime_s: float,
                    feature_names: Sequence[str] | None = None, identified: Any = None,
                    prior: Mapping[str, Any] | None = None, issue_warnings: bool = True) -> "Posterior":
        """Collect the chains of :func:`pbicrl.inference.samplers.driver.run_chain` into one posterior.

        Parameters
        ----------
        results : sequence of dict
            One per chain.
        kernel : Kernel
            The kernel that ran them (settings, likelihood, constraints; ``prior_summary()`` when it has one).
        seed : int
        runtime_s : float
        feature_names : sequence of str, optional
        identified : dict or Identification, optional
            What the rankings identify (see :attr:`identified`); pass it here rather than attaching it later
            so that the warnings are issued once, with it.
        prior : dict, optional
            Prior summary; default ``kernel.prior_summary()`` when the kernel has it.
        issue_warnings : bool
        """
        best = int(np.argmax([r["map_log_posterior"] for r in results]))
        dk = kernel.likelihood.n_features
        names = tuple(feature_names) if feature_names is not None else tuple(f"f{j}" for j in range(dk))
        cs = kernel.constraints
        owner: tuple[int, ...] = ()
        if cs is not None:
            names = names + cs.names
            owner = tuple(dk + m for m in range(cs.n_constraints) for _ in range(cs.constraints[m].n_params))
        if prior is None and callable(getattr(kernel, "prior_summary", None)):
            prior = kernel.prior_summary()

        def per_draw(key: str, dtype: Any) -> NDArray | None:  # chains run by older drivers lack them
            if not all(key in r for r in results):
                return None
            return np.stack([np.asarray(r[key], dtype=dtype) for r in results])

        return cls(
            indicators=np.stack([r["indicators"] for r in results]),
            penalty_weights=np.stack([r["penalty_weights"] for r in results]),
            log_likelihood=np.stack([r["log_likelihood"] for r in results]),
            log_prior=np.stack([r["log_prior"] for r in results]),
            map_indicators=np.asarray(results[best]["map_indicators"], dtype=np.int8),
            map_penalty_weights=np.asarray(results[best]["map_penalty_weights"]),
            map_log_posterior=float(results[best]["map_log_posterior"]),
            map_log_likelihood=float(results[best]["map_log_likelihood"]),
            feature_names=names,
            sampler=kernel.settings.sampler,
            settings=kernel.settings.to_dict() | {"beta": kernel.likelihood.beta,
                                                  "constraints": None if cs is None else cs.to_dict(),
                                                  "nominal_weights": kernel.likelihood.nominal_weights.tolist(),
                                                  "protocol": kernel.likelihood.preferences.protocol,
                                                  "n_pairs": kernel.likelihood.preferences.n_pairs,
                                                  "power": kernel.likelihood.power,
                                                  "likelihood": getattr(kernel.likelihood, "kind", "pairwise")},
            counts=np.stack([r["counts"] for r in results]),
            seed=seed,
            runtime_s=float(runtime_s),
            chain_runtime_s=np.array([r["runtime_s"] for r in results]),
            parameters=np.stack([r["parameters"] for r in results]),
            map_parameters=np.asarray(results[best]["map_parameters"]),
            parameter_names=() if cs is None else cs.param_names,
            parameter_owner=owner,
            identified=identified,
            prior=None if prior is None else dict(prior),
            non_varying=_non_varying(kernel, names),
            move=per_draw("move", np.int8),
            accepted=per_draw("accepted", bool),
            acceptance_fraction=per_draw("acceptance_fraction", np.float64),
            issue_warnings=issue_warnings,
        )

    @classmethod
    def from_record(cls, rec: Any, *, issue_warnings: bool = True) -> "Posterior":
        """A posterior from the checked contents of a run directory (:func:`pbicrl.io.runs.read_run`'s record).

        The draws, :meth:`table` and :meth:`summary` are those of the posterior that was saved (its
        identification, prior summary, settings and extra information come from ``summary.json``); what an
        older run did not record is ``None`` (per-draw statistics) or taken from its summary (acceptance rates).
        """
        s = rec.summary
        C, D, d = rec.indicators.shape
        m = s.get("map") if isinstance(s.get("map"), dict) else {}
        settings = dict(s.get("settings") or {})
        for key in ("iterations", "burn_in", "thin"):  # the table and summary need them
            if key not in settings:
                settings[key] = s.get(key, D if key == "iterations" else 0 if key == "burn_in" else 1)
        prior = s.get("prior")
        if prior == {"weight_prior": settings.get("weight_prior"), "indicator_prior": settings.get("indicator_prior")}:
            prior = None  # summary() wrote the settings' priors because none was attached
        recorded: dict[str, Any] = {}
        counts = rec.counts
        if counts is None:
            counts = np.zeros((C, N_COUNTS), dtype=np.int64)
            recorded = {k: s[k] for k in ("acceptance_rate", "likelihood_evaluations") if k in s}
        P = len(rec.parameter_names)
        params = rec.parameters if rec.parameters is not None else np.zeros((C, D, 0))
        mp = rec.map_parameters
        chain_rt = s.get("chain_runtime_s")

        def number(x: Any) -> float:
            return float(x) if is_real(x) else float("nan")

        post = cls(
            indicators=rec.indicators, penalty_weights=rec.penalty_weights, log_likelihood=rec.log_likelihood,
            log_prior=rec.log_prior, map_indicators=rec.map_indicators, map_penalty_weights=rec.map_penalty_weights,
            map_log_posterior=number(m.get("log_posterior")), map_log_likelihood=number(m.get("log_likelihood")),
            feature_names=tuple(rec.feature_names), sampler=rec.sampler, settings=settings, counts=counts,
            seed=rec.seed, runtime_s=number(s.get("runtime_s")),
            chain_runtime_s=(np.array([number(x) for x in chain_rt]) if isinstance(chain_rt, list)
                             else np.full(C, np.nan)),
            parameters=params,
            map_parameters=(np.asarray(mp, dtype=np.float64) if mp is not None and np.size(mp) == P
                            else np.full(P, np.nan)),
            parameter_names=tuple(rec.parameter_names), parameter_owner=tuple(rec.parameter_owner),
            extra=dict(s.get("extra") or {}), identified=rec.identified,
            prior=dict(prior) if isinstance(prior, Mapping) else None,
            non_varying=tuple(n for n, why in rec.not_identifiable().items() if why == NON_VARYING_REASON),
            move=rec.move, accepted=rec.accepted, acceptance_fraction=rec.acceptance_fraction,
            path=Path(rec.path), recorded=recorded, issue_warnings=False)
        if issue_warnings:
            post._issue(post.warnings(), stacklevel=3)  # attributed to the caller of from_record
        return post

    @classmethod
    def load(cls, run_dir: str | os.PathLike[str], *, issue_warnings: bool = True) -> "Posterior":
        """Read a run directory (``pbicrl infer --out``, :meth:`save`) back: :func:`pbicrl.io.runs.load_run`.

        Raises
        ------
        FileNotFoundError
            No such directory, or ``summary.json`` / ``chains.npz`` missing.
        pbicrl.io.runs.RunError
            A malformed file, or a ``schema_version`` newer than this pbicrl reads (the message names the file).
        """
        from pbicrl.io.runs import load_run  # facade: the files are io's

        post = load_run(run_dir, issue_warnings=False)
        if issue_warnings:
            post.emit_warnings(stacklevel=3)  # attributed to the caller of load
        return post

    def require_usable_draws(self) -> None:
        """Refuse draws holding NaN or infinite values: such a run is an error, not a result.

        Raises
        ------
        ValueError
            If ``penalty_weights`` or ``log_likelihood`` (shape ``(n_chains, n_draws, ...)``) holds a NaN or an
            infinity; the message counts them and says what to change.
        """
        for key in ("penalty_weights", "log_likelihood"):
            arr = np.asarray(getattr(self, key), dtype=np.float64)
            bad = int(arr.size - np.count_nonzero(np.isfinite(arr)))
            if bad:
                raise ValueError(f"{key}: {bad:,} of {arr.size:,} values of the draws are NaN or infinite, so the run "
                                 "has no usable draws and nothing was written; use a smaller beta or margins, or "
                                 "rescale the features")

    def save(self, out_dir: str | os.PathLike[str], *, overwrite: bool = False,
             extra_json: dict[str, Any] | None = None, inputs: Sequence[Any] = ()) -> Path:
        """Write the run directory (``summary.json``, ``chains.npz``, ...) atomically: :func:`pbicrl.io.runs.save_run`,
        which says what ``overwrite``, ``extra_json`` and ``inputs`` do and what it raises (``OutputExistsError``
        for an existing ``out_dir`` without ``overwrite``, ``OutputBusyError`` while another process writes it).
        """
        from pbicrl.io.runs import save_run  # facade: the files are io's

        return save_run(self, out_dir, overwrite=overwrite, extra_json=extra_json, inputs=inputs)

    # ------------------------------------------------------------------ display
    def __repr__(self) -> str:
        parts = [f"sampler={self.sampler!r}", f"chains={self.n_chains}", f"draws={self.n_draws}",
                 f"features={self.n_features} {_short_names(self.feature_names)}"]
        if self.indicators_are_posterior:
            parts.append(f"selected={_short_names(self.selected())}")
        elif self.indicator_meaning == "fixed":
            parts.append(f"in_model={_short_names([n for n, m in zip(self.feature_names, self.in_model()) if m])}")
        if self.parameter_names:
            parts.append(f"parameters={len(self.parameter_names)} {_short_names(self.parameter_names)}")
        parts.append(f"seed={self.seed}")
        if self.path is not None:
            parts.append(f"path={str(self.path)!r}")
        return f"Posterior({', '.join(parts)})"

    def table(self, width: int = 100) -> str:
        """A readable table of the summaries, footers and warnings: :func:`pbicrl.analysis.report.table`."""
        from pbicrl.analysis.report import table  # facade: presentation is analysis'

        return table(self, width)

    def to_dataframe(self) -> Any:
        """The content of :meth:`table` as a :class:`pandas.DataFrame`: :func:`pbicrl.analysis.report.to_dataframe`."""
        from pbicrl.analysis.report import to_dataframe  # facade: presentation is analysis'

        return to_dataframe(self)

    def _repr_html_(self) -> str:
        """An HTML table for notebooks: :func:`pbicrl.analysis.report.to_html`."""
        from pbicrl.analysis.report import to_html  # facade: presentation is analysis'

        return to_html(self)

    def attach(self, *, identified: Any = None, prior: Mapping[str, Any] | None = None) -> "Posterior":
        """A copy with an identification and/or prior summary attached (``None`` keeps the current one).

        Warnings of the copy that this posterior has not issued yet (e.g. the identification's) are issued
        now; those already issued are not repeated.
        """
        new = dataclasses.replace(self, identified=self.identified if identified is None else identified,
                                  prior=self.prior if prior is None else dict(prior), issue_warnings=False)
        object.__setattr__(new, "_issued", getattr(self, "_issued", frozenset()))
        if self.dataset is not None:
            new.keep_dataset(self.dataset)
        new._issue(new.warnings(), stacklevel=3)
        return new

    # ------------------------------------------------------------------ the run's dataset
    @property
    def dataset(self) -> "Dataset | None":
        """The dataset this posterior was inferred from, when :func:`pbicrl.infer` kept it (None otherwise)."""
        return getattr(self, "_dataset", None)

    def keep_dataset(self, dataset: "Dataset") -> None:
        """Keep the run's dataset with the posterior (for the pointwise log-likelihood of :meth:`to_arviz`, and
        stored by :meth:`save` when it has no file of its own).

        Raises
        ------
        ValueError
            The dataset's :meth:`~pbicrl.inference.data.Dataset.content_hash` differs from the one the run
            recorded in ``extra["data"]["sha256"]``.
        """
        want = (self.extra.get("data") or {}).get("sha256")
        if want is not None and dataset.content_hash() != want:
            raise ValueError("dataset: not the dataset this run was inferred from (its content hash differs from "
                             "extra['data']['sha256'])")
        object.__setattr__(self, "_dataset", dataset)

    # ------------------------------------------------------------------ summaries
    @property
    def mean_effective_penalty(self) -> NDArray[np.float64]:
        """Posterior mean of :math:`c_j w_{p,j}`, (d,)."""
        return self.effective_penalty.reshape(-1, self.n_features).mean(axis=0)

    def ci(self, level: float = LEVEL) -> NDArray[np.float64]:
        """Equal-tailed credible interval of :math:`c_j w_{p,j}`, (d, 2)."""
        q = (1 - level) / 2
        return np.quantile(self.effective_penalty.reshape(-1, self.n_features), [q, 1 - q], axis=0).T

    def conditional_penalty(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Mean and 90% interval of :math:`w_{p,j}` given :math:`c_j = 1` (NaN where never active)."""
        s = self.conditional_summary()
        return s["mean"], np.stack([s["low"], s["high"]], axis=1)

    @property
    def map_parameters_active(self) -> NDArray[np.float64]:
        """:math:`\\vartheta` of the highest-density draw, NaN for constraints that draw switches off."""
        out = self.map_parameters.astype(float).copy()
        for p, j in enumerate(self.parameter_owner):
            if not self.map_indicators[j]:
                out[p] = np.nan
        return out

    def acceptance_rate(self) -> dict[str, float]:
        """Acceptance rate per move type over all chains (as recorded, for runs saved without counts)."""
        if isinstance(self.recorded.get("acceptance_rate"), Mapping):
            return {str(k): float(v) for k, v in self.recorded["acceptance_rate"].items() if is_real(v)}
        tot = self.counts.sum(axis=0)
        has_theta = tot.size > C_T_ACC  # runs saved before parameter moves were counted have 5 counters
        out = {}
        if tot[C_FLIP_PROP]:
            out["flip"] = float(tot[C_FLIP_ACC] / tot[C_FLIP_PROP])
        if tot[C_W_PROP]:
            out["weight"] = float(tot[C_W_ACC] / tot[C_W_PROP])
        if has_theta and tot[C_T_PROP]:
            out["parameter"] = float(tot[C_T_ACC] / tot[C_T_PROP])
        prop = tot[C_FLIP_PROP] + tot[C_W_PROP] + (tot[C_T_PROP] if has_theta else 0)
        acc = tot[C_FLIP_ACC] + tot[C_W_ACC] + (tot[C_T_ACC] if has_theta else 0)
        out["overall"] = float(acc / prop) if prop else 0.0
        return out

    def rhat(self) -> dict[str, list[float]]:
        """Classic split-:math:`\\hat R` per feature for the effective penalty and the indicator.

        NaN where undefined (one chain, constant draws) or the feature is not identifiable
        (:meth:`not_identifiable`); ``summary.json`` writes ``null`` there.
        """
        if self.n_chains < 2:
            nan = [float("nan")] * self.n_features
            return {"effective_penalty": nan, "indicator": list(nan)}
        skip = self.not_identifiable()
        eff = self.effective_penalty
        out: dict[str, list[float]] = {"effective_penalty": [], "indicator": []}
        for j, n in enumerate(self.feature_names):
            undefined = n in skip
            out["effective_penalty"].append(float("nan") if undefined else split_rhat(eff[:, :, j]))
            out["indicator"].append(float("nan") if undefined else split_rhat(self.indicators[:, :, j].astype(float)))
        return out

    def diagnostics(self) -> "Diagnostics":
        """R-hat and bulk/tail ESS of every penalty, indicator and parameter (:mod:`pbicrl.analysis.diagnostics`)."""
        from pbicrl.analysis import diagnostics  # facade: the statistics are analysis'

        return diagnostics.compute(self)

    def to_arviz(self, **kwargs: Any) -> Any:
        """ArviZ InferenceData (arviz < 1) or DataTree (arviz >= 1); ``kwargs`` go to :func:`pbicrl.analysis.export.to_arviz`."""
        from pbicrl.analysis.export import to_arviz  # facade: the export is analysis'

        return to_arviz(self, **kwargs)

    def summary(self) -> dict[str, Any]:
        """Everything ``summary.json`` holds (:func:`pbicrl.inference.summary.summary_dict`; JSON-ready)."""
        return summary_dict(self)

    def authors_statistic(self, last: int = AUTHORS_LAST_ITERATIONS) -> dict[str, Any]:
        r"""The statistic the paper authors' code reports: per chain, the mean of :math:`c_j w_{p,j}` over its last
        ``last`` iterations (their code keeps the last 500 of the chain), then averaged over chains.

        It describes where a chain was when it stopped, not a posterior: for the ``paper`` / ``authors``
        samplers (no proper posterior over :math:`c`) it drifts with the chain's length. Shown beside the mean
        over all kept draws (``posterior.mean_effective_penalty``). With thinning, the kept draws that fall in
        the last ``last`` iterations are used (at least one per chain).
        """
        thin = int(self.settings.get("thin") or 1)
        n = max(1, min(self.n_draws, -(-int(last) // max(thin, 1))))
        eff = np.asarray(self.effective_penalty, dtype=np.float64)[:, -n:, :].mean(axis=1)  # (chains, d)
        names = list(self.feature_names)
        return {"definition": f"per chain the mean of c_j * w_pj over its last {int(last)} iterations (the paper "
                              "authors' statistic: where the chain was when it stopped), then the mean over chains",
                "last_iterations": int(last), "draws_per_chain": int(n),
                "value": {nm: to_py(v) for nm, v in zip(names, eff.mean(axis=0))},
                "per_chain": {nm: [to_py(v) for v in eff[:, j]] for j, nm in enumerate(names)},
                "posterior_mean": {nm: to_py(v) for nm, v in zip(names, self.mean_effective_penalty)}}


accept_old_names(Posterior, "Posterior")  # method= until pbicrl 0.3


# ---------------------------------------------------------------------------------------------- helpers
def _as_identification(x: Any) -> dict | None:
    """``None``, a mapping, or an object with ``to_dict()`` (and ``warnings()``) -> plain dict or ``None``."""
    if x is None:
        return None
    if isinstance(x, Mapping):
        return dict(x)
    to_dict = getattr(x, "to_dict", None)
    if callable(to_dict):
        d = dict(to_dict())
        w = getattr(x, "warnings", None)
        if "warnings" not in d and callable(w):
            d["warnings"] = [str(m) for m in w()]
        return d
    raise TypeError(f"identified: expected a dict or an Identification, got {type(x).__name__}")


def _non_varying(kernel: Any, names: Sequence[str]) -> tuple[str, ...]:
    """Candidate known features whose per-trajectory mean is the same for every trajectory.

    Such a feature shifts every return by the same amount, so no ranking depends on its penalty; its
    draws are the prior's and an R-hat of them measures nothing about the data.
    """
    F = np.asarray(kernel.likelihood.mean_features, dtype=np.float64)
    if F.ndim != 2 or F.shape[0] == 0:
        return ()
    cand = kernel.settings.candidates
    if cand is None:
        cand = range(F.shape[1]) if kernel.constraints is None else ()
    out = []
    for j in cand:
        if 0 <= int(j) < F.shape[1]:
            col = F[:, int(j)]
            if np.ptp(col) <= 1e-12 * max(1.0, float(np.max(np.abs(col)))):
                out.append(str(names[int(j)]))
    return tuple(out)


def _short_names(names: Sequence[str], limit: int = _REPR_NAMES) -> str:
    """``['a', 'b', ...]`` with at most ``limit`` names (reprs never grow with the data)."""
    names = [str(n) for n in names]
    shown = ", ".join(repr(_cut(n, 24)) for n in names[:limit])
    return f"[{shown}{', ...' if len(names) > limit else ''}]"


def _cut(name: str, width: int) -> str:
    return name if len(name) <= width else name[: width - 1] + "~"

