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

``summary.json`` (schema version :data:`SCHEMA_VERSION`; files without ``schema_version`` are version 1)::

    schema_version       2
    method, feature_names
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
``move``, ``accepted`` and ``acceptance_fraction``) are written atomically: a failed or interrupted write leaves
no directory behind. Directories and files get the permissions the process's umask gives new files, and a run
directory being written is claimed (an advisory lock ``.<name>.lock`` beside it, :func:`claim_out_dir`), so two
processes writing the same directory cannot interleave: the second gets :class:`OutputBusyError`.

:meth:`Posterior.load` (also ``pbicrl.load_run``) reads a run directory back into a :class:`Posterior` with the
same draws, table and summary as the one that was saved.
"""

from __future__ import annotations

import dataclasses
import html
import json
import math
import os
import socket
import textwrap
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from statistics import NormalDist
from typing import TYPE_CHECKING, Any, Sequence

import numpy as np
from numpy.typing import NDArray

from pbicrl import errors
from pbicrl._atomic import (OUTPUT_MARKER, OutputBusyError, OutputExistsError, atomic_dir, check_replaceable,
                            clean_stale_temporaries, inputs_inside)
from pbicrl.analysis.diagnostics import split_rhat
from pbicrl.inference.codes import (C_EVALS, C_FLIP_ACC, C_FLIP_PROP, C_T_ACC, C_T_PROP, C_W_ACC, C_W_PROP,
                                    N_COUNTS)
from pbicrl.inference.draws import ESTIMATORS, INDICATOR_LABELS, LEVEL, SELECTION_THRESHOLD, DrawsView
from pbicrl.inference.sensitivity import PriorSensitivity, prior_sensitivity, weight_prior_spec
from pbicrl.runs import DATASET_FILE, SCHEMA_VERSION, load_run

if TYPE_CHECKING:
    from pbicrl.analysis.diagnostics import Diagnostics
    from pbicrl.inference.data import Dataset
    from pbicrl.inference.samplers.kernels import Kernel

__all__ = ["Posterior", "DrawsView", "split_rhat", "write_run_dir", "check_out_dir", "claim_out_dir",
           "release_out_dir", "is_run_dir", "json_safe", "OutputExistsError", "OutputBusyError", "SCHEMA_VERSION",
           "SELECTION_THRESHOLD", "MAP_DEFINITION", "ESTIMATORS"]

MAP_DEFINITION = ("the highest-density visited draw (log prior + log likelihood) over all chains; in a "
                  "reversible-jump chain this compares densities of different dimensions, so it is not the mode "
                  "of a common space: prefer 'selected' with the conditional medians")
"""What ``summary.json``'s ``map`` block is, written into the block itself."""

AUTHORS_LAST_ITERATIONS = 500
"""Iterations at the end of each chain that the paper authors' code averages (:meth:`Posterior.authors_statistic`)."""

_NON_VARYING_REASON = "constant across trajectories: the likelihood does not depend on its penalty"
_REPR_NAMES = 6  # names shown in a repr before "..."


@dataclass(frozen=True, eq=False)
class Posterior(DrawsView):
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
    method : str
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
    method: str
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
            method=kernel.settings.method,
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
    def load(cls, run_dir: str | os.PathLike[str], *, issue_warnings: bool = True) -> "Posterior":
        """Read a run directory (``pbicrl infer --out``, :meth:`save`) back into a posterior.

        The draws, :meth:`table` and :meth:`summary` are those of the posterior that was saved (its
        identification, prior summary, settings and extra information come from ``summary.json``). Every
        ``summary.json`` schema version up to :data:`SCHEMA_VERSION` loads; what an older run did not record is
        ``None`` (per-draw statistics) or taken from its summary (acceptance rates).

        Parameters
        ----------
        run_dir : path
        issue_warnings : bool
            Issue the posterior's warnings (:class:`~pbicrl.errors.PbicrlWarning`), as sampling did.

        Raises
        ------
        FileNotFoundError
            No such directory, or ``summary.json`` / ``chains.npz`` missing.
        pbicrl.runs.RunError
            A malformed file, or a ``schema_version`` newer than this pbicrl reads (the message names the file).
        """
        rec = load_run(run_dir)
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
            return float(x) if _is_real(x) else float("nan")

        post = cls(
            indicators=rec.indicators, penalty_weights=rec.penalty_weights, log_likelihood=rec.log_likelihood,
            log_prior=rec.log_prior, map_indicators=rec.map_indicators, map_penalty_weights=rec.map_penalty_weights,
            map_log_posterior=number(m.get("log_posterior")), map_log_likelihood=number(m.get("log_likelihood")),
            feature_names=tuple(rec.feature_names), method=rec.method, settings=settings, counts=counts,
            seed=rec.seed, runtime_s=number(s.get("runtime_s")),
            chain_runtime_s=(np.array([number(x) for x in chain_rt]) if isinstance(chain_rt, list)
                             else np.full(C, np.nan)),
            parameters=params,
            map_parameters=(np.asarray(mp, dtype=np.float64) if mp is not None and np.size(mp) == P
                            else np.full(P, np.nan)),
            parameter_names=tuple(rec.parameter_names), parameter_owner=tuple(rec.parameter_owner),
            extra=dict(s.get("extra") or {}), identified=rec.identified,
            prior=dict(prior) if isinstance(prior, Mapping) else None,
            non_varying=tuple(n for n, why in rec.not_identifiable().items() if why == _NON_VARYING_REASON),
            move=rec.move, accepted=rec.accepted, acceptance_fraction=rec.acceptance_fraction,
            path=Path(run_dir), recorded=recorded, issue_warnings=False)
        if issue_warnings:
            post._issue(post.warnings(), stacklevel=3)  # attributed to the caller of load
        return post

    # ------------------------------------------------------------------ display
    def __repr__(self) -> str:
        parts = [f"method={self.method!r}", f"chains={self.n_chains}", f"draws={self.n_draws}",
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

    def _records(self) -> list[dict[str, Any]]:
        """The rows of :meth:`table` as records: one per feature, then one per constraint parameter."""
        cs = self.conditional_summary()
        pdriven = self.prior_driven()
        mins = self.min_penalty()
        skip = self.not_identifiable()
        diag = self.diagnostics()
        p = self.p_constraint
        meaning = self.indicator_meaning
        model = self.in_model()

        def f(x: Any) -> float:
            return float(x) if _is_real(x) else float("nan")

        def indicator_cells(j: int) -> dict[str, Any]:
            """The columns that say what c_j means for this sampler (:data:`INDICATOR_MEANINGS`)."""
            if meaning == "posterior":
                return {"p_constraint": float(p[j]), "selected": bool(p[j] > SELECTION_THRESHOLD)}
            if meaning == "chain_frequency":
                return {"frequency_on": float(p[j]), "map_indicator": bool(self.map_indicators[j])}
            return {"in_model": bool(model[j])}

        rows: list[dict[str, Any]] = []
        for j, n in enumerate(self.feature_names):
            v = diag.worst_of(("penalty", "indicator"), n)
            rows.append({"name": n, "kind": "feature", **indicator_cells(j),
                         "min_penalty": float("nan") if n in skip or not model[j] else f(mins[j]),
                         "median": f(cs["median"][j]), "mean": f(cs["mean"][j]),
                         "ci90_low": f(cs["low"][j]), "ci90_high": f(cs["high"][j]),
                         "prior_driven": pdriven[j], "active_draws": int(cs["active_draws"][j]),
                         "rhat": f(v["rhat"]), "ess_bulk": f(v["ess_bulk"]), "ess_tail": f(v["ess_tail"]),
                         "identifiable": n not in skip, "identified_range": None})
        owner = tuple(self.parameter_owner)
        for k, (n, v) in enumerate(self.parameter_summary().items()):
            dv = diag.worst_of(("parameter",), n)
            j = owner[k] if len(owner) == len(self.parameter_names) else None
            lo, hi = v["ci90"]
            own = {k: (float("nan") if isinstance(x, float) else None) for k, x in indicator_cells(0).items()} \
                if j is None else indicator_cells(j)
            rows.append({"name": n, "kind": "parameter", **own,
                         "min_penalty": float("nan"), "median": f(v["median"]), "mean": f(v["mean"]),
                         "ci90_low": f(lo), "ci90_high": f(hi), "prior_driven": v["prior_driven"],
                         "active_draws": int(v["active_draws"]), "rhat": f(dv["rhat"]),
                         "ess_bulk": f(dv["ess_bulk"]), "ess_tail": f(dv["ess_tail"]), "identifiable": True,
                         "identified_range": v["identified_range"]})
        return rows

    def to_dataframe(self) -> Any:
        r"""The content of :meth:`table` as a :class:`pandas.DataFrame`, one row per feature and parameter.

        Index ``name``; columns ``kind`` (``feature`` / ``parameter``), then what the indicators mean for the
        sampler (:data:`~pbicrl.inference.draws.INDICATOR_MEANINGS`): ``p_constraint``
        (:math:`P(c_j = 1 \mid \mathcal{D})`, of the owning constraint for a parameter) and ``selected`` for
        ``pbicrl``; ``frequency_on`` (share of kept draws with :math:`c_j = 1`) and ``map_indicator`` for
        ``paper`` / ``authors``; ``in_model`` for ``bpl``;
        ``min_penalty`` (identification), ``median``, ``mean``, ``ci90_low``, ``ci90_high`` (of :math:`w_{p,j}`
        given :math:`c_j = 1`; of :math:`\vartheta_k` while its constraint is on), ``prior_driven``,
        ``active_draws``, ``rhat``, ``ess_bulk``, ``ess_tail`` (the worse of penalty and indicator), ``identifiable``
        and ``identified_range``. Undefined numbers are NaN.

        Raises
        ------
        ImportError
            If pandas is not installed (``pip install pandas``).
        """
        try:
            import pandas as pd
        except ImportError as exc:
            raise ImportError(f"Posterior.to_dataframe needs pandas ({exc}): pip install pandas "
                              "(or pip install \"pbicrl[diag]\")") from exc
        return pd.DataFrame.from_records(self._records()).set_index("name")

    def _repr_html_(self) -> str:
        """An HTML table of :meth:`table`'s content (for notebooks); every text is escaped."""
        e = html.escape
        c1, c2 = _INDICATOR_COLUMNS[self.indicator_meaning]
        head = ["feature", c1, c2, "min|w_p|", "med | c=1", "90% interval | c=1", "R-hat", "ESS bulk", "ESS tail"]
        out = [f"<div><p><b>{e(repr(self))}</b></p>", "<table>",
               "<thead><tr>" + "".join(f"<th>{e(h)}</th>" for h in head) + "</tr></thead>", "<tbody>"]
        for r in self._records():
            star = "*" if r["prior_driven"] else ""
            iv = ("-" if not (math.isfinite(r["ci90_low"]) and math.isfinite(r["ci90_high"]))
                  else f"[{_num(r['ci90_low'], 9)}, {_num(r['ci90_high'], 9)}]{star}")
            a, b = _indicator_cells(r, self.indicator_meaning)
            cells = [r["name"] if r["kind"] == "feature" else f"parameter {r['name']}",
                     a if r["kind"] == "feature" else "", b,
                     "n/a" if not r["identifiable"] else _num(r["min_penalty"], 8), _num(r["median"], 9), iv,
                     _num(r["rhat"], 6), _num(r["ess_bulk"], 8), _num(r["ess_tail"], 8)]
            out.append("<tr>" + "".join(f"<td>{e(str(c))}</td>" for c in cells) + "</tr>")
        out += ["</tbody></table>", "<ul>"]
        out += [f"<li>{e(line)}</li>" for line in self._footer()]
        out.append("</ul></div>")
        return "\n".join(out)

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

    def not_identifiable(self) -> dict[str, str]:
        """Features the rankings carry no information about, with the reason.

        Candidate features that never vary across trajectories (:attr:`non_varying`), and those the attached
        identification marks ``identifiable: false``. They get no R-hat or ESS (undefined, ``null``) and raise
        no convergence warning: their penalty's draws are the prior's.
        """
        out = {n: _NON_VARYING_REASON for n in self.non_varying}
        for name in self.feature_names:
            e = self._ident_entry(name)
            if e is not None and e.get("identifiable") is False and name not in out:
                out[name] = str(e.get("reason") or "not identifiable from the rankings")
        return out

    def min_penalty(self) -> list[float | None]:
        """Per feature, the smallest :math:`|w_{p,j}|` the rankings require (identification), else ``None``."""
        out: list[float | None] = []
        for name in self.feature_names:
            e = self._ident_entry(name)
            v = None if e is None else e.get("min_penalty")
            out.append(v if _is_real(v) and math.isfinite(v) else None)
        return out

    def prior_sensitivity(self, level: float = LEVEL) -> PriorSensitivity:
        """Which summaries move with the weight prior, measured by reweighting the draws to a tenfold wider prior
        (:mod:`pbicrl.inference.sensitivity`). Nothing is measured for the ``paper`` / ``authors`` samplers
        (they ignore the prior) or a prior that cannot be reweighted."""
        key = ("_sensitivity", float(level))
        cached = getattr(self, "_cache", {}).get(key)
        if cached is not None:
            return cached
        latent = self.method in ("paper", "authors")
        out = prior_sensitivity(self.indicators, self.penalty_weights,
                                lambda j: None if latent else self._weight_prior_spec(j), self.in_model(), level=level)
        cache = dict(getattr(self, "_cache", {}))
        cache[key] = out
        object.__setattr__(self, "_cache", cache)
        return out

    def end_flags(self, level: float = LEVEL) -> list[tuple[bool | None, bool | None, bool | None]]:
        r"""Per feature, (low end, median, high end) of :math:`w_{p,j} \mid c_j = 1`: prior-driven?

        Measured (:meth:`prior_sensitivity`) where possible; otherwise from :meth:`prior_driven`'s fallback,
        which marks the large-:math:`|w|` end (and the median) of a flagged feature.
        """
        sens = self.prior_sensitivity(level)
        cs = self.conditional_summary(level)
        pd = self.prior_driven(level)
        out: list[tuple[bool | None, bool | None, bool | None]] = []
        for j in range(self.n_features):
            f = sens.flags
            if f["given_active_high"][j] is not None:
                med = bool(f["given_active_median"][j] or f["given_active_mean"][j])
                out.append((bool(f["given_active_low"][j]), med, bool(f["given_active_high"][j])))
                continue
            if not pd[j]:
                out.append((pd[j], pd[j], pd[j]))
                continue
            m = cs["median"][j]
            out.append((bool(m <= 0), True, bool(m >= 0)))
        return out

    def prior_driven(self, level: float = LEVEL) -> list[bool | None]:
        r"""Per feature: does the interval of :math:`w_{p,j} \mid c_j = 1` (an end, its median or mean) come
        from the prior?

        Measured where the sampler used a prior that can be reweighted (:meth:`prior_sensitivity`): one of those
        numbers moves when the prior is made tenfold wider, or, under a bounded prior, the interval reaches the
        bound. Otherwise (``paper`` / ``authors``, which ignore the prior, or never active), with an
        identification: its ``unbounded`` flag (the data leave :math:`|w_{p,j}|` unbounded). Without one, a
        heuristic: the conditional draws' large-:math:`|w|` quantile
        (the ``(1 - level)/2`` one on the side of the conditional median's sign, both sides at 0) lies beyond
        the prior's own quantile at the same level. A penalty the data pin down has a far narrower interval
        than the prior, so its tail stays inside the prior's; a one-sided (separated) likelihood leaves the
        prior's tail beyond the data's lower bound, which puts the posterior's quantile beyond the prior's.
        A penalty identified far out in the prior's tail is flagged too (a false alarm on the safe side).
        ``None``: no active draws, or the prior has no known quantiles (e.g. ``improper``).
        """
        s = self.conditional_summary(level)
        sens = self.prior_sensitivity(level)
        q = (1.0 - level) / 2.0
        out: list[bool | None] = []
        for j, name in enumerate(self.feature_names):
            measured = [sens.flags[k][j] for k in ("given_active_low", "given_active_high", "given_active_median",
                                                   "given_active_mean")]
            if measured[0] is not None:
                out.append(any(bool(x) for x in measured))
                continue
            e = self._ident_entry(name)
            if e is not None and "unbounded" in e:
                out.append(None if e["unbounded"] is None else bool(e["unbounded"]))
                continue
            if not s["active_draws"][j]:
                out.append(None)
                continue
            spec = self._weight_prior_spec(j)
            plo, phi = _prior_quantile(spec, q), _prior_quantile(spec, 1.0 - q)
            med, lo, hi = s["median"][j], s["low"][j], s["high"][j]
            low_end = None if plo is None else bool(lo < plo)
            high_end = None if phi is None else bool(hi > phi)
            if med < 0:
                out.append(low_end)
            elif med > 0:
                out.append(high_end)
            else:
                out.append(None if low_end is None and high_end is None else bool(low_end or high_end))
        return out

    def parameter_summary(self) -> dict[str, dict[str, Any]]:
        r"""Per parameter :math:`\vartheta_k`, over draws where its constraint is active: ``mean``, ``median``,
        ``ci90``, ``active_draws``; ``identified_range`` (the identification's ``[low, high]`` or ``None``) and
        ``prior_driven``.

        ``prior_driven``, with an identified range: an end of it is open (``None`` or infinite) or reaches
        the parameter's prior bound, i.e. the rankings do not tell locations on that side apart, so the
        posterior spreads there as the prior does. Without one: an end of the 90% interval lies beyond the
        uniform prior's own 5% / 95% quantile (``None`` when the prior bounds are unknown).
        """
        out: dict[str, dict[str, Any]] = {}
        if not self.parameter_names:
            return out
        s = self.parameter_conditional()
        bounds = self._parameter_bounds()
        ranges = (self.identified or {}).get("parameters") or {}
        for p, name in enumerate(self.parameter_names):
            has = bool(s["active_draws"][p])
            rng = ranges.get(name) if isinstance(ranges, Mapping) else None
            ok = isinstance(rng, (list, tuple)) and len(rng) == 2
            rng = [None if v is None else _py(v) for v in rng] if ok else None
            out[name] = {"mean": _py(s["mean"][p]) if has else None,
                         "median": _py(s["median"][p]) if has else None,
                         "ci90": [_py(s["low"][p]), _py(s["high"][p])] if has else [None, None],
                         "active_draws": int(s["active_draws"][p]),
                         "identified_range": rng,
                         "prior_driven": _parameter_prior_driven(rng, bounds[p], s["low"][p], s["high"][p], has)}
        return out

    def acceptance_rate(self) -> dict[str, float]:
        """Acceptance rate per move type over all chains (as recorded, for runs saved without counts)."""
        if isinstance(self.recorded.get("acceptance_rate"), Mapping):
            return {str(k): float(v) for k, v in self.recorded["acceptance_rate"].items() if _is_real(v)}
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

    def warnings(self) -> list[str]:
        """Plain-language problems a user should know about (computed afresh; issued once, when built).

        * a log-likelihood that is not finite (numerical overflow);
        * penalties the rankings leave unbounded: from the attached identification (its ``warnings`` when
          it has them, else one line per unbounded feature with its smallest required penalty), or, without
          one, the :meth:`prior_driven` heuristic over the selected features;
        * convergence (:meth:`pbicrl.analysis.diagnostics.Diagnostics.warnings`; not-identifiable features excluded),
          and, when penalties that failed it are strongly correlated in the draws of a run without joint moves, a
          pointer to the joint weight step (``p_joint``).
        """
        out = self._likelihood_warnings()
        out.extend(self._identification_warnings() if self.identified is not None else self._heuristic_warnings())
        out.extend(self._required_but_off_warnings())
        conv = self.convergence
        if conv is not None:  # a run until converged: its stopping rule's verdict is the one convergence message
            if conv.get("converged") is False:
                failing = conv.get("failing") or {}
                worst = "; ".join(f"{k}: {v}" for k, v in list(failing.items())[:4])
                out.append(f"NOT CONVERGED after {_num_s(conv.get('wall_s'))} (max_time "
                           f"{_num_s((conv.get('stopping_rule') or {}).get('max_time'))}): {len(failing)} reported "
                           f"quantities fall short ({worst}); the summaries are not to be trusted yet - rerun with a "
                           "larger --max-time, or look at the trace plots")
            return out
        diag = self.diagnostics()
        out.extend(diag.warnings())  # R-hat > 1.01, bulk ESS < 400
        out.extend(self._joint_move_hint(diag))
        return out

    @property
    def convergence(self) -> dict | None:
        """The stopping rule's verdict of a run until converged (``iterations="auto"``), else None: ``converged``,
        ``failing`` (quantity -> what falls short), per-quantity R-hat / ESS, ``iterations_run``, ``wall_s``."""
        conv = self.extra.get("convergence") if isinstance(self.extra, dict) else None
        return conv if isinstance(conv, dict) else None

    @property
    def converged(self) -> bool | None:
        """Whether a run until converged met its stopping rule (None for a fixed-length run)."""
        conv = self.convergence
        return None if conv is None else bool(conv.get("converged"))

    def _joint_move_hint(self, diag: "Diagnostics") -> list[str]:
        """One line when single-weight moves are the likely reason for poor mixing: a ``pbicrl``/``bpl`` run with
        ``p_joint`` 0 in which a penalty failing R-hat or bulk ESS is correlated with another selected one at
        ``|r| >= 0.8`` (pooled draws where both are on). Measured (``benchmarks/reports/speed.md``, section 7): on
        3 x 200 synthetic demonstrations, ``p_joint=0.4`` raised the smallest bulk ESS of such a pair from 23-27 to
        422-498 at the same iterations."""
        if self.method not in ("pbicrl", "bpl") or self.n_chains < 2:
            return []
        pj = self.settings.get("p_joint", 0.0)
        if not _is_real(pj) or float(pj) > 0.0:
            return []
        slow = {n for n, v in diag.values.get("penalty", {}).items()
                if (v["rhat"] is not None and v["rhat"] > diag.rhat_max)
                or (v["ess_bulk"] is not None and v["ess_bulk"] < diag.ess_min)}
        if not slow:
            return []
        d = self.n_features
        c = np.asarray(self.indicators).reshape(-1, d).astype(bool)
        w = np.asarray(self.penalty_weights, dtype=np.float64).reshape(-1, d)
        chosen = np.flatnonzero(self.p_constraint > SELECTION_THRESHOLD).tolist()
        best: tuple[float, str, str] | None = None
        for a_, j in enumerate(chosen):
            for k in chosen[a_ + 1:]:
                names = (self.feature_names[j], self.feature_names[k])
                if not (set(names) & slow):
                    continue
                both = c[:, j] & c[:, k]
                if both.sum() < 50 or np.ptp(w[both, j]) == 0 or np.ptp(w[both, k]) == 0:
                    continue
                r = float(np.corrcoef(w[both, j], w[both, k])[0, 1])
                if math.isfinite(r) and abs(r) >= 0.8 and (best is None or abs(r) > abs(best[0])):
                    best = (r, *names)
        if best is None:
            return []
        r, a, b = best
        return [f"the penalties of {a} and {b} are strongly correlated in the draws (r = {r:+.2f}) and mix slowly "
                "one at a time: the joint weight step moves them together (p_joint=0.4 in Python or TOML, "
                "--p-joint 0.4 on the command line)"]

    def diagnostics(self) -> "Diagnostics":
        """R-hat and bulk/tail ESS of every penalty, indicator and parameter (:mod:`pbicrl.analysis.diagnostics`)."""
        from pbicrl.analysis import diagnostics
        return diagnostics.compute(self)

    def to_arviz(self, **kwargs: Any) -> Any:
        """ArviZ InferenceData (arviz < 1) or DataTree (arviz >= 1); ``kwargs`` go to :func:`pbicrl.analysis.export.to_arviz`."""
        from pbicrl.analysis.export import to_arviz

        return to_arviz(self, **kwargs)

    def summary(self) -> dict[str, Any]:
        """Everything ``summary.json`` holds (schema :data:`SCHEMA_VERSION`, see the module docstring).

        JSON-ready: numbers are finite or ``None``.
        """
        names = list(self.feature_names)
        cs = self.conditional_summary()

        def by_name(v: Sequence[Any] | NDArray) -> dict[str, Any]:
            return {n: _py(x) for n, x in zip(names, v)}

        settings = self.settings
        prior = self.prior if self.prior is not None else {"weight_prior": settings.get("weight_prior"),
                                                            "indicator_prior": settings.get("indicator_prior")}
        meaning = self.indicator_meaning
        posterior_c = meaning == "posterior"
        model = dict(zip(names, self.in_model()))

        def out_of_model(d: dict[str, Any], empty: Any = None) -> dict[str, Any]:
            """bpl: a feature that is not a candidate is not in the model and gets no number."""
            return {n: (v if model[n] else empty) for n, v in d.items()}
        indicator_block: dict[str, Any]
        if posterior_c:
            indicator_block = {"p_constraint": by_name(self.p_constraint)}
        elif meaning == "chain_frequency":
            indicator_block = {"frequency_on": by_name(self.p_constraint)}
        else:
            indicator_block = {"in_model": dict(zip(names, (bool(m) for m in self.in_model())))}
        out = {
            "schema_version": SCHEMA_VERSION,
            "method": self.method,
            "feature_names": names,
            "indicators": {"meaning": meaning, "label": INDICATOR_LABELS[meaning]},
            "selected": self.selected() if posterior_c else None,
            "most_frequent_set": self.most_frequent_set() if meaning != "fixed" else None,
            "not_identifiable": self.not_identifiable(),
            "map": {
                "indicators": out_of_model(by_name(self.map_indicators.astype(int))),
                "penalty_weights": by_name(self.map_penalty_weights),
                "effective_penalty": by_name(self.map_effective_penalty),
                "parameters": {n: _py(v) for n, v in zip(self.parameter_names, self.map_parameters_active)},
                "log_posterior": _py(self.map_log_posterior),
                "log_likelihood": _py(self.map_log_likelihood),
                "definition": MAP_DEFINITION,
            },
            "posterior": {
                "mean_effective_penalty": out_of_model(by_name(self.mean_effective_penalty)),
                **indicator_block,
                "ci90": out_of_model({n: [_py(a), _py(b)] for n, (a, b) in zip(names, self.ci(0.9))}, [None, None]),
                "penalty_given_active": {
                    "mean": by_name(cs["mean"]),
                    "median": by_name(cs["median"]),
                    "ci90": {n: [_py(a), _py(b)] for n, a, b in zip(names, cs["low"], cs["high"])},
                    "prior_driven": dict(zip(names, self.prior_driven())),
                    "active_draws": by_name(cs["active_draws"]),
                },
                "prior_driven": self._prior_driven_block(),
                **({"authors_statistic": self.authors_statistic()} if self.method in ("authors", "paper") else {}),
                "prior_sensitivity": self.prior_sensitivity().to_dict(names),
                "rhat": {k: by_name(np.array(v)) for k, v in self.rhat().items()},
                "diagnostics": self.diagnostics().to_dict(),
                "parameters": self.parameter_summary(),
            },
            "identified": self.identified,
            "prior": prior,
            "acceptance_rate": self.acceptance_rate(),
            "iterations": int(settings["iterations"]),
            "burn_in": int(settings["burn_in"]),
            "thin": int(settings["thin"]),
            "draws_per_chain": self.n_draws,
            "chains": self.n_chains,
            "seed": self.seed,
            "runtime_s": self.runtime_s,
            "chain_runtime_s": self.chain_runtime_s.tolist(),
            "likelihood_evaluations": (int(self.recorded["likelihood_evaluations"])
                                       if _is_real(self.recorded.get("likelihood_evaluations"))
                                       else int(self.counts[:, C_EVALS].sum())),
            "settings": settings,
            "warnings": self.warnings(),
        } | ({"converged": self.converged} if self.convergence is not None else {}) \
          | ({"extra": self.extra} if self.extra else {})
        return json_safe(out)

    def table(self, width: int = 100) -> str:
        """A readable table: per feature P(c=1), selected, the identified smallest penalty and the median and
        90% interval of :math:`w_{p,j}` given :math:`c_j = 1`; then parameters; footers; warnings.

        ``*`` marks an interval end that comes from the prior (see :meth:`prior_driven`).
        """
        names = list(self.feature_names)
        nw = min(24, max(8, max(len(n) for n in names)))
        cs = self.conditional_summary()
        pd = self.prior_driven()
        ends = self.end_flags()
        sens = self.prior_sensitivity()
        mins = self.min_penalty()
        skip = self.not_identifiable()
        diag = self.diagnostics()
        meaning = self.indicator_meaning
        c1, c2 = _INDICATOR_COLUMNS[meaning]
        w1, w2 = max(6, len(c1)), max(3, len(c2))
        model = self.in_model()
        head = (f"{'feature':<{nw}}  {c1:>{w1}}  {c2:>{w2}}  {'min|w_p|':>8}  {'med|c=1':>9}  "
                f"{'90% interval | c=1':^24}  {'R-hat':>6}  {'ESS':>6}")
        lines = [head, "-" * len(head)]
        records = [r for r in self._records() if r["kind"] == "feature"]
        for j, n in enumerate(names):
            a, b = _indicator_cells(records[j], meaning)
            if meaning != "fixed" and sens.flags["p_constraint"][j]:
                a += "*"
            mp = "n/a" if n in skip else _num(mins[j], 8) if model[j] else "-"
            lo_d, med_d, hi_d = ends[j]
            iv = _interval(cs["low"][j], cs["high"][j], marks=(bool(lo_d), bool(hi_d)))
            med = _num(cs["median"][j], 8) + ("*" if med_d and math.isfinite(cs["median"][j]) else "")
            lines.append(f"{_cut(n, nw):<{nw}}  {a:>{w1}}  {b:>{w2}}  {mp:>8}  "
                         f"{med:>9}  {iv}  {diag.cells('feature', n, compact=True)}")
        psum = self.parameter_summary()
        if psum:
            pw = min(24, max(10, max(len(n) for n in psum)))
            lines += ["", f"{'parameter':<{pw}}  {'med|on':>9}  {'90% interval | on':^24}  {'identified range':^21}  "
                          f"{'R-hat':>6}  {'ESS':>6}"]
            for n, v in psum.items():
                lo, hi = (np.nan if x is None else x for x in v["ci90"])
                iv = _interval(lo, hi, marks=(bool(v["prior_driven"]), bool(v["prior_driven"])))
                rng = v["identified_range"]
                rs = "-" if rng is None else f"[{_num(rng[0], 9)}, {_num(rng[1], 9)}]"
                lines.append(f"{_cut(n, pw):<{pw}}  {_num(v['median'], 9):>9}  {iv}  {rs:^21}  "
                             f"{diag.cells('parameter', n, compact=True)}")
        for line in self._footer(psum, pd, skip, diag):
            lines.extend(textwrap.wrap(line, width=width, subsequent_indent="  ", break_on_hyphens=False) or [""])
        return "\n".join(lines)

    def _footer(self, psum: dict[str, dict[str, Any]] | None = None, pd: list[bool | None] | None = None,
                skip: dict[str, str] | None = None, diag: "Diagnostics | None" = None) -> list[str]:
        """The lines under :meth:`table`'s rows: selection, legend, prior-driven ends, run facts, warnings."""
        names = list(self.feature_names)
        psum = self.parameter_summary() if psum is None else psum
        pd = self.prior_driven() if pd is None else pd
        skip = self.not_identifiable() if skip is None else skip
        diag = self.diagnostics() if diag is None else diag
        foot = [self._indicator_footer()]
        if self.identified is not None:
            a = self.identified.get("alpha")
            sampled = isinstance(self.identified.get("pairs"), Mapping) and self.identified["pairs"].get("n_pairs")
            foot.append("min|w_p|: smallest penalty with which the rankings order every "
                        + (f"one of the {sampled:,} sampled pairs the likelihood uses" if sampled else "cross-group pair")
                        + (f" with probability >= {1 - a:g}" if _is_real(a) else "")
                        + " (identification); '-' = none")
        else:
            foot.append("min|w_p|: '-' (no identification attached)")
        driven = [n for n, x in zip(names, pd) if x] + [n for n, v in psum.items() if v["prior_driven"]]
        sens = self.prior_sensitivity()
        if sens.measured:
            foot.append(f"* prior-driven (measured: {sens.basis}): "
                        + (", ".join(driven) if driven else "none of the intervals")
                        + "; summary.json flags every reported number (posterior.prior_driven)")
        elif driven:
            src = "the identification" if self.identified is not None else \
                "heuristic: interval end beyond the prior's own 5%/95% quantile"
            foot.append(f"* prior-driven ({src}; not measured: the {self.method} sampler ignores the prior or it "
                        f"cannot be reweighted): {', '.join(driven)}: the data leave this end open, so it, "
                        "the median and the mean move with the prior")
        if skip:
            foot.append("not identifiable (no R-hat/ESS): " + "; ".join(f"{n} ({r})" for n, r in skip.items()))
        if self.method in ("authors", "paper"):
            st = self.authors_statistic()
            foot.append(f"authors' statistic (mean of c*w_p over the last {st['last_iterations']} iterations, mean of "
                        "chains) vs mean over all kept draws: " + "; ".join(
                            f"{n} {_num(st['value'][n], 9)} vs {_num(st['posterior_mean'][n], 9)}" for n in names))
        acc = ", ".join(f"{k} {v:.1%}" for k, v in self.acceptance_rate().items())
        foot.append(f"method {self.method}; {self.n_chains} chains x {self.settings['iterations']:,} iterations "
                    f"({self.n_draws} kept each); acceptance {acc}; {self.runtime_s:.2f} s")
        foot.append(diag.footer(compact=True))
        foot += [f"warning: {m}" for m in self.warnings()]
        return foot

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
                "value": {nm: _py(v) for nm, v in zip(names, eff.mean(axis=0))},
                "per_chain": {nm: [_py(v) for v in eff[:, j]] for j, nm in enumerate(names)},
                "posterior_mean": {nm: _py(v) for nm, v in zip(names, self.mean_effective_penalty)}}

    def _prior_driven_block(self) -> dict[str, Any]:
        """``posterior.prior_driven``: a flag for every number ``posterior`` reports (``None``: not measured)."""
        names = list(self.feature_names)
        sens = self.prior_sensitivity()
        f = sens.flags
        ends = self.end_flags()
        ind_key = {"posterior": "p_constraint", "chain_frequency": "frequency_on", "fixed": None}[self.indicator_meaning]
        out: dict[str, Any] = {"basis": sens.basis if sens.measured else (
            "not measured (the sampler ignores the prior or it cannot be reweighted); penalty_given_active from "
            + ("the identification's unbounded flag" if self.identified is not None else "the prior-quantile heuristic"))}
        if ind_key is not None:
            out[ind_key] = dict(zip(names, f["p_constraint"]))
        out["mean_effective_penalty"] = dict(zip(names, f["mean_effective_penalty"]))
        out["ci90"] = {n: [f["ci90_low"][j], f["ci90_high"][j]] for j, n in enumerate(names)}
        out["penalty_given_active"] = {
            "mean": {n: (f["given_active_mean"][j] if sens.measured else ends[j][1]) for j, n in enumerate(names)},
            "median": {n: (f["given_active_median"][j] if sens.measured else ends[j][1]) for j, n in enumerate(names)},
            "ci90": {n: [ends[j][0], ends[j][2]] for j, n in enumerate(names)}}
        return out

    def _indicator_footer(self) -> str:
        """The first footer line: the selection, or what the indicator column is when it is not a selection."""
        mfs = self.most_frequent_set()
        most = (f"{{{', '.join(mfs['features'])}}} in {(mfs['frequency'] or 0.0):.1%} of kept draws")
        if self.indicator_meaning == "posterior":
            return f"selected (P(c=1) > 0.5): {', '.join(self.selected()) or 'none'}; most frequent set: {most}"
        if self.indicator_meaning == "chain_frequency":
            on = [n for n, c in zip(self.feature_names, self.map_indicators) if c]
            return (f"freq on: {INDICATOR_LABELS['chain_frequency']} (share of kept draws with c_j = 1). The "
                    f"{self.method} sampler's indicator moves (Algorithm 1: likelihood-ratio acceptance, latent "
                    "weights) do not target a posterior, so this is not P(c=1) and no set is selected from it. MAP: "
                    f"indicators of the highest-density visited draw, as the paper reports: {{{', '.join(on)}}}; "
                    f"most frequent set in the chain: {most}")
        model = [n for n, m in zip(self.feature_names, self.in_model()) if m]
        return (f"model: bpl samples the penalties of the candidates ({', '.join(model) or 'none'}) with no "
                "indicators, so there is no P(c=1) and no selection; features that are not candidates are fixed "
                "at w_p = 0 and show '-'")

    def save(self, out_dir: str | os.PathLike[str], *, overwrite: bool = False,
             extra_json: dict[str, Any] | None = None, inputs: Sequence[Any] = ()) -> Path:
        """Write ``summary.json`` and ``chains.npz`` (and any ``extra_json`` files) to ``out_dir`` atomically; with
        a dataset kept in memory (:meth:`keep_dataset`) and no file recorded, also a copy of it,
        :data:`~pbicrl.runs.DATASET_FILE`, so that the export can rebuild the pointwise log-likelihood.

        :meth:`load` reads it back. ``overwrite=True`` replaces a previous run directory holding only what
        pbicrl wrote there, never anything else, nor a directory holding one of ``inputs`` (paths).

        Raises
        ------
        OutputExistsError
            ``out_dir`` exists (a :class:`FileExistsError`; pass ``overwrite=True`` to replace a previous run).
        OutputBusyError
            Another process is writing ``out_dir`` at the same time.
        FileExistsError
            ``out_dir`` is a file, a symbolic link or a directory that is not a run (even with ``overwrite``).
        """
        arrays = {"indicators": self.indicators, "penalty_weights": self.penalty_weights,
                  "effective_penalty": self.effective_penalty, "log_likelihood": self.log_likelihood,
                  "log_prior": self.log_prior, "feature_names": np.array(self.feature_names, dtype=np.str_),
                  "map_indicators": self.map_indicators, "map_penalty_weights": self.map_penalty_weights,
                  "parameters": self.parameters, "map_parameters": self.map_parameters,
                  "parameter_names": np.array(self.parameter_names, dtype=np.str_),
                  "parameter_owner": np.array(self.parameter_owner, dtype=np.int64)}
        if not self.recorded:  # a loaded run without counts keeps its recorded rates instead
            arrays["counts"] = np.asarray(self.counts, dtype=np.int64)
        for key in ("move", "accepted", "acceptance_fraction"):
            v = getattr(self, key)
            if v is not None:
                arrays[key] = np.asarray(v)
        npz = {"chains.npz": arrays}
        if self.dataset is not None and not (self.extra.get("data") or {}).get("path"):
            # an in-memory dataset: stored with the run, so that the export can always rebuild the likelihood
            npz[DATASET_FILE] = self.dataset.to_arrays()
        return write_run_dir(out_dir, {"summary.json": self.summary(), **(extra_json or {})}, npz,
                             overwrite=overwrite, inputs=inputs)

    # ------------------------------------------------------------------ internals
    def _ident_entry(self, name: str) -> dict[str, Any] | None:
        """The identification's record of one feature (under ``features`` or at the top level)."""
        ident = self.identified
        if ident is None:
            return None
        feats = ident.get("features")
        e = feats.get(name) if isinstance(feats, Mapping) else None
        if e is None:
            e = ident.get(name)
        return dict(e) if isinstance(e, Mapping) else None

    def _weight_prior_spec(self, j: int) -> dict[str, Any] | None:
        """The prior of :math:`w_{p,j}` as one flat dict (``kind``, ``support``/``low``/``high``, ``mean``,
        ``scale``, ``df``): the attached summary, else the settings' ``weight_prior``.

        A summary is a prior's dict (``kind`` at the top, or under ``weight_prior`` / ``weight``) with optional
        per-feature entries under ``features``, keyed by feature name or index, that override it (e.g. the
        resolved scale of a scale-aware prior). An attached summary that cannot be read gives ``None`` rather
        than a fallback to the settings, which might not describe the prior that was used.
        """
        src: Any = self.prior if self.prior is not None else self.settings.get("weight_prior")
        return weight_prior_spec(src, self.feature_names, j)

    def _parameter_bounds(self) -> list[tuple[float, float] | None]:
        """Uniform prior bounds of every parameter (``settings["constraints"][m]["resolved_bounds"]``)."""
        bounds: list[tuple[float, float] | None] = []
        for spec in self.settings.get("constraints") or []:
            for b in (spec.get("resolved_bounds") or spec.get("bounds") or []):
                bounds.append((float(b[0]), float(b[1])))
        n = len(self.parameter_names)
        return bounds if len(bounds) == n else [None] * n

    def _likelihood_warnings(self) -> list[str]:
        out = []
        ll = np.asarray(self.log_likelihood, dtype=np.float64)
        bad = int(ll.size - np.isfinite(ll).sum())
        if bad or not math.isfinite(self.map_log_likelihood):
            beta = self.settings.get("beta")
            out.append(f"the log-likelihood is NaN or infinite in {bad:,} of {ll.size:,} kept draws"
                       + (f" (beta {beta:g})" if _is_real(beta) else "")
                       + ": the returns overflow, so the draws and every summary are meaningless; use a smaller "
                         "beta or rescale the features")
        lp = np.asarray(self.log_prior, dtype=np.float64)
        bad = int(lp.size - np.isfinite(lp).sum())
        if bad:
            out.append(f"the log prior is NaN or infinite in {bad:,} of {lp.size:,} kept draws: the chain holds states "
                       "the prior does not allow, so the draws are not from the stated posterior (please report "
                       "this with the settings used)")
        return out

    def _identification_warnings(self) -> list[str]:
        from pbicrl.analysis.identify import short_warnings

        ident = self.identified or {}
        given = ident.get("warnings")
        short = short_warnings(ident)  # one line per feature, also for runs that stored the long paragraphs
        if short is not None:
            feats = set(ident.get("features") or {})
            other = [str(m) for m in given if str(m).split(":", 1)[0] not in feats] \
                if isinstance(given, (list, tuple)) else []
            return short + other
        if isinstance(given, (list, tuple)):
            return [str(m) for m in given]
        alpha = ident.get("alpha")
        prob = f" with probability >= {1 - alpha:g}" if _is_real(alpha) else ""
        skip = self.not_identifiable()
        out = []
        for name in self.feature_names:
            e = self._ident_entry(name)
            if e is None or not e.get("unbounded") or name in skip:
                continue
            mp = e.get("min_penalty")
            scale = (f"|w_p| >= {mp:.4g}" if _is_real(mp) and math.isfinite(mp)
                     else "a lower bound on |w_p|")
            direction = f" (direction {e['direction']})" if e.get("direction") not in (None, "") else ""
            out.append(f"{name}: the groups are separated by this feature{direction}: the rankings require {scale} "
                       f"(every cross-group pair ordered{prob}) and set no upper limit, so the far end of its "
                       "interval, its median and its mean come from the prior. Report the lower bound; margins "
                       "raise it but cannot bound the magnitude; only the prior (its scale or bounds) or data in "
                       "which the groups overlap set the magnitude.")
        return out

    def _required_but_off_warnings(self) -> list[str]:
        """A feature the rankings require (identified ``min_penalty > 0``) that the run mostly switches off."""
        if self.indicator_meaning == "fixed" or self.identified is None:
            return []
        label = "P(c=1)" if self.indicators_are_posterior else "its frequency on in the chain"
        out = []
        for j, (n, mp) in enumerate(zip(self.feature_names, self.min_penalty())):
            if mp is None or not mp > 0 or self.p_constraint[j] >= SELECTION_THRESHOLD:
                continue
            out.append(f"{n}: the rankings require this penalty (|w_p| >= {mp:.4g}, identification) but {label} is "
                       f"{self.p_constraint[j]:.3f} < 0.5, so the run leaves it out: the result contradicts the data. "
                       "The usual cause is the prior: a very wide or bounded (flat) prior on w_p makes a needed "
                       "penalty cost more prior mass than it gains in likelihood (P(c=1) falls as the prior widens); "
                       "use the default scale-aware student-t prior or a smaller --prior-scale, and check convergence")
        return out

    def _heuristic_warnings(self) -> list[str]:
        cs = self.conditional_summary()
        skip = self.not_identifiable()
        hits = [f"{n} ([{cs['low'][j]:.4g}, {cs['high'][j]:.4g}])"
                for j, (n, pd) in enumerate(zip(self.feature_names, self.prior_driven()))
                if pd and self.p_constraint[j] > SELECTION_THRESHOLD and n not in skip]
        if not hits:
            return []
        why = ("moves when the prior is made tenfold wider (measured by reweighting the draws)"
               if self.prior_sensitivity().measured else "lies beyond the prior's own quantile")
        return [f"{', '.join(hits)}: given c_j = 1 the 90% interval {why}, so it comes from the prior: the "
                "groups are (nearly) separated by these features and "
                "the rankings bound |w_p| from below only. Read the small-|w_p| end as what the data say; the far "
                "end, median and mean move with the prior's scale or bounds, and margins raise the lower bound only "
                "(they do not fix the scale). An identification (pbicrl.analysis.identify) gives the smallest penalty the "
                "rankings require."]


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


def _prior_quantile(spec: Mapping[str, Any] | None, p: float) -> float | None:
    """Quantile ``p`` of a one-dimensional prior described by a dict, or ``None`` if it has none we know.

    Kinds: ``flat`` / ``uniform``; ``normal``; ``student_t`` / ``t`` (``df`` or ``nu``) and ``cauchy``, with
    ``mean`` (or ``loc``) and ``scale``, truncated to ``support`` ``[a, b]`` (``None`` = infinite; else
    ``low`` / ``high``). Explicit ``q05`` / ``q95`` entries win (5% / 95% only). Needs only the standard
    library: the Student-t CDF is integrated numerically (:func:`_t_cdf_table`).
    """
    if not isinstance(spec, Mapping):
        return None
    explicit = {0.05: spec.get("q05"), 0.95: spec.get("q95")}.get(round(p, 12))
    if _is_real(explicit) and math.isfinite(explicit):
        return float(explicit)
    kind = str(spec.get("kind", "")).lower()
    sup = spec.get("support")
    if isinstance(sup, (list, tuple)) and len(sup) == 2:
        lo = float(sup[0]) if _is_real(sup[0]) else -math.inf
        hi = float(sup[1]) if _is_real(sup[1]) else math.inf
    else:
        lo = float(spec["low"]) if _is_real(spec.get("low")) else -math.inf
        hi = float(spec["high"]) if _is_real(spec.get("high")) else math.inf
    if not hi > lo:
        return None
    if kind in ("flat", "uniform"):
        return lo + p * (hi - lo) if math.isfinite(lo) and math.isfinite(hi) else None
    loc = spec.get("loc", spec.get("mean", 0.0))
    scale = spec.get("scale")
    if not (_is_real(scale) and scale > 0 and _is_real(loc)):
        return None
    a, b = (lo - loc) / scale, (hi - loc) / scale  # standardised support
    if kind == "normal":
        z = NormalDist()
        fa, fb = z.cdf(a) if math.isfinite(a) else 0.0, z.cdf(b) if math.isfinite(b) else 1.0
        u = fa + p * (fb - fa)
        return float(loc + scale * z.inv_cdf(u)) if 0.0 < u < 1.0 and fb > fa else None
    if kind in ("student_t", "studentt", "student-t", "t", "cauchy"):
        df = 1.0 if kind == "cauchy" else spec.get("df", spec.get("nu"))
        if not (_is_real(df) and df >= 1.0):
            return None
        zq = _t_truncated_quantile(float(df), p, a, b)
        return None if zq is None else float(loc + scale * zq)
    return None


def _is_real(x: Any) -> bool:
    return isinstance(x, (int, float, np.integer, np.floating)) and not isinstance(x, (bool, np.bool_))


def _t_truncated_quantile(df: float, p: float, a: float, b: float, n: int = 20_001) -> float | None:
    r"""Quantile ``p`` of a standard Student-t (``df >= 1``) truncated to ``[a, b]``.

    Integrates the density over :math:`\theta = \arctan z`, where it is bounded for ``df >= 1``
    (:math:`t_\nu(\tan\theta)\sec^2\theta \sim |z|^{1-\nu}`), with the trapezoid rule on ``n`` points and
    inverts the cumulative sum linearly; the error (~1e-6 in probability) is far below what the
    prior-driven comparison needs.
    """
    ta, tb = math.atan(a) if math.isfinite(a) else -math.pi / 2, math.atan(b) if math.isfinite(b) else math.pi / 2
    if not tb > ta:
        return None
    th = np.linspace(ta, tb, n)
    with np.errstate(over="ignore", divide="ignore", invalid="ignore"):
        z = np.tan(th)
        c = np.cos(th)
        # t density up to its constant, times dz/dtheta = 1/cos^2; at |theta| = pi/2 the limit is 0 for
        # df > 1 and 1 for df = 1 (Cauchy)
        f = np.where(c > 1e-12, (1.0 + z * z / df) ** (-(df + 1.0) / 2.0) / np.maximum(c * c, 1e-300),
                     1.0 if df == 1.0 else 0.0)
    f = np.nan_to_num(f, nan=0.0, posinf=0.0)
    cum = np.concatenate([[0.0], np.cumsum((f[1:] + f[:-1]) * 0.5 * np.diff(th))])
    if not cum[-1] > 0:
        return None
    t = float(np.interp(p * cum[-1], cum, th))
    return math.tan(t)


def _parameter_prior_driven(rng: list | None, bounds: tuple[float, float] | None, lo: float, hi: float,
                            has: bool) -> bool | None:
    if rng is not None:
        ends = [None if v is None or not math.isfinite(v) else float(v) for v in rng]
        if ends[0] is None or ends[1] is None:
            return True
        if bounds is None:
            return False
        tol = 1e-9 * max(1.0, abs(bounds[0]), abs(bounds[1]))
        return bool(ends[0] <= bounds[0] + tol or ends[1] >= bounds[1] - tol)
    if not has or bounds is None or not bounds[1] > bounds[0]:
        return None
    span = bounds[1] - bounds[0]
    return bool(lo < bounds[0] + 0.05 * span or hi > bounds[0] + 0.95 * span)


def _num_s(x: Any) -> str:
    """Seconds for a message (``?`` when unknown)."""
    return f"{float(x):.0f} s" if _is_real(x) else "?"


_INDICATOR_COLUMNS = {"posterior": ("P(c=1)", "sel"), "chain_frequency": ("freq on", "MAP"), "fixed": ("model", "")}
"""Headers of the two indicator columns of :meth:`Posterior.table` per :data:`~pbicrl.inference.draws.INDICATOR_MEANINGS`."""


def _indicator_cells(r: Mapping[str, Any], meaning: str) -> tuple[str, str]:
    """The two indicator cells of a table row (a :meth:`Posterior._records` record)."""
    if meaning == "posterior":
        sel = r.get("selected")
        return _prob(r.get("p_constraint")), "-" if sel is None else ("yes" if sel else "no")
    if meaning == "chain_frequency":
        on = r.get("map_indicator")
        return _prob(r.get("frequency_on")), "-" if on is None else ("on" if on else "off")
    m = r.get("in_model")
    return "-" if m is None else ("yes" if m else "no"), ""


def _prob(x: Any) -> str:
    return f"{float(x):.3f}" if _is_real(x) and math.isfinite(float(x)) else "-"


def _num(x: Any, width: int) -> str:
    """A number in at most ``width`` characters (4 significant digits), ``-`` for none / NaN."""
    if x is None or not isinstance(x, (int, float, np.integer, np.floating)) or not math.isfinite(float(x)):
        return "-"
    x = float(x)
    s = f"{x:.4g}" if 1e-3 <= abs(x) < 1e4 or x == 0 else f"{x:.2e}"
    return s if len(s) <= width else f"{x:.1e}"


def _interval(lo: float, hi: float, *, marks: tuple[bool, bool] = (False, False)) -> str:
    """``[  lo , hi ]`` in 24 characters; ``*`` after each end that is prior-driven (``marks``)."""
    mark_lo = "*" if marks[0] else " "
    mark_hi = "*" if marks[1] else " "
    if not (math.isfinite(lo) and math.isfinite(hi)):
        return f"{'-':^24}"
    return f"[{_num(lo, 9):>9}{mark_lo}, {_num(hi, 9):>9}{mark_hi}]"


def _short_names(names: Sequence[str], limit: int = _REPR_NAMES) -> str:
    """``['a', 'b', ...]`` with at most ``limit`` names (reprs never grow with the data)."""
    names = [str(n) for n in names]
    shown = ", ".join(repr(_cut(n, 24)) for n in names[:limit])
    return f"[{shown}{', ...' if len(names) > limit else ''}]"


def _cut(name: str, width: int) -> str:
    return name if len(name) <= width else name[: width - 1] + "~"


def _py(x: Any) -> Any:
    if isinstance(x, (bool, np.bool_)):
        return bool(x)
    if isinstance(x, (int, np.integer)):
        return int(x)
    x = float(x) if np.ndim(x) == 0 else x
    if isinstance(x, float) and not np.isfinite(x):
        return None
    return x


def json_safe(obj: Any) -> Any:
    """A copy of ``obj`` that strict JSON can hold: NaN and infinities become ``None``, NumPy scalars and
    arrays become Python numbers and lists, tuples lists, mapping keys strings.

    Raises
    ------
    TypeError
        For objects JSON has no form for.
    """
    if obj is None or isinstance(obj, (str, bool)):
        return obj
    if isinstance(obj, (np.bool_,)):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        v = float(obj)
        return v if math.isfinite(v) else None
    if isinstance(obj, Mapping):
        return {str(k): json_safe(v) for k, v in obj.items()}
    if isinstance(obj, np.ndarray):
        return json_safe(obj.tolist())
    if isinstance(obj, (list, tuple)):
        return [json_safe(v) for v in obj]
    if isinstance(obj, np.generic):
        return json_safe(obj.item())
    if isinstance(obj, os.PathLike):
        return os.fspath(obj)
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")


def is_run_dir(path: str | os.PathLike[str]) -> bool:
    """True for a directory written by :func:`write_run_dir` (it holds ``summary.json``), empty or not."""
    p = Path(path)
    return p.is_dir() and not p.is_symlink() and (p / "summary.json").is_file()


def _check_writable(parent: Path) -> None:
    if parent.exists() and not os.access(parent, os.W_OK | os.X_OK):
        raise PermissionError(f"out_dir: cannot write into {parent} (permission denied)")


# Run directories claimed by this process: absolute path -> (descriptor of the locked file, its path).
_CLAIMS: dict[str, tuple[int, str]] = {}


def _lock_file(out: Path) -> Path:
    return out.parent / f".{out.name}.lock"


def claim_out_dir(out_dir: str | os.PathLike[str]) -> Path:
    """Claim ``out_dir`` for this process until :func:`release_out_dir` or the end of the process.

    The claim is an advisory lock (``flock``) on ``.<name>.lock`` beside ``out_dir`` (its parent directory is
    created if missing); the operating system drops it when the process ends, however it ends, so a killed
    writer never blocks later runs (the lock file it leaves is reused). :func:`write_run_dir` claims the
    directory while it writes; a command claims it before sampling (:func:`check_out_dir` with ``claim=True``)
    so that a second run writing to the same directory fails at once instead of after its sampling.
    Claiming again from the same process is a no-op. Where the platform or file system has no ``flock`` the
    claim is skipped (the writes stay atomic).

    Raises
    ------
    OutputBusyError
        Another process holds the claim; the message names it (host and process id).
    """
    out = Path(out_dir)
    key = os.path.abspath(out)
    if key in _CLAIMS:
        return out
    try:
        import fcntl
    except ImportError:  # pragma: no cover - not on POSIX
        return out
    out.parent.mkdir(parents=True, exist_ok=True)
    lock = _lock_file(out)
    for _ in range(20):
        fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o666)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 200, 0).decode("utf-8", "replace").strip() or "unknown"
            os.close(fd)
            raise OutputBusyError(f"out_dir: {out} is being written by another pbicrl process ({holder}); wait for it "
                                  "to finish or choose another directory") from None
        except OSError:  # no locks on this file system
            os.close(fd)
            return out
        # the previous holder may have removed the file between our open and flock: then retry on the new one
        try:
            current = os.stat(lock)
        except FileNotFoundError:
            current = None
        if current is not None and os.path.samestat(os.fstat(fd), current):
            os.ftruncate(fd, 0)
            os.pwrite(fd, f"host {socket.gethostname()}, pid {os.getpid()}\n".encode(), 0)
            _CLAIMS[key] = (fd, str(lock))
            return out
        os.close(fd)
    raise OutputBusyError(f"out_dir: {out}: could not claim it (its lock file keeps changing); try again")


def release_out_dir(out_dir: str | os.PathLike[str] | None = None) -> None:
    """End this process's claim on ``out_dir`` (``None``: on every directory it claimed); removes the lock file."""
    keys = list(_CLAIMS) if out_dir is None else [os.path.abspath(Path(out_dir))]
    for key in keys:
        held = _CLAIMS.pop(key, None)
        if held is None:
            continue
        fd, lock = held
        try:
            os.unlink(lock)  # while still locked, so nobody locks the file we remove
        except OSError:
            pass
        os.close(fd)


def check_out_dir(out_dir: str | os.PathLike[str], *, overwrite: bool = False, claim: bool = False,
                  inputs: Sequence[Any] = ()) -> Path:
    """Fail early (before sampling) when ``out_dir`` could not be written by :func:`write_run_dir`.

    Parameters
    ----------
    out_dir : path
    overwrite : bool
        Whether a previous run directory there may be replaced.
    claim : bool
        Also claim the directory for this process (:func:`claim_out_dir`) until :func:`write_run_dir` has
        written it (or :func:`release_out_dir`), so that a concurrent run to the same directory fails now.
    inputs : sequence of path
        The command's inputs (dataset, config): none may be ``out_dir`` or lie inside it.

    Raises
    ------
    OutputExistsError
        ``out_dir`` exists and ``overwrite`` is false.
    FileExistsError
        ``out_dir`` is a file, a symbolic link or a directory that is not a run, or names no directory.
    OutputBusyError
        Another process claims ``out_dir`` (``claim=True``).
    PermissionError
        Its parent directory is not writable.
    """
    out = Path(out_dir)
    if out.name in ("", ".", ".."):
        raise FileExistsError(f"out_dir: {out_dir!s} names no new directory; give a directory name such as runs/pm")
    if len(os.fsencode(out.name)) > 200:
        raise ValueError(f"out_dir: the directory name is {len(os.fsencode(out.name))} bytes long; at most 200")
    if out.is_symlink():
        raise FileExistsError(f"out_dir: {out} is a symbolic link; give a real directory path")
    parent = out.parent
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    if parent.exists() and not parent.is_dir():
        raise FileExistsError(f"out_dir: {parent} is a file, not a directory")
    _check_writable(parent)
    inside = inputs_inside(out, inputs)
    if inside:
        raise FileExistsError(f"out_dir: {out} holds this command's input {inside[0]}; choose another directory")
    if claim:
        claim_out_dir(out)
    try:
        _check_existing(out, overwrite, inputs)
    except BaseException:
        if claim:
            release_out_dir(out)
        raise
    return out


#: What a run directory written before markers (:data:`pbicrl._atomic.OUTPUT_MARKER`) may hold: the files
#: ``write_run_dir`` wrote, and what the labelling page added (its dataset and figures).
_LEGACY_RUN_ENTRIES = frozenset({"summary.json", "chains.npz", "check.json", "tuning.json", "data.npz", "plots"})
_FIGURE_SUFFIXES = (".png", ".pdf", ".svg")


def _legacy_run_entries(out: Path) -> set[str] | None:
    if not is_run_dir(out):
        return None
    plots = out / "plots"
    if plots.is_dir() and not plots.is_symlink() and not all(
            p.is_file() and p.suffix in _FIGURE_SUFFIXES for p in plots.iterdir()):
        return set(_LEGACY_RUN_ENTRIES - {"plots"})  # plots/ holds something else: not ours to remove
    return set(_LEGACY_RUN_ENTRIES)


def _check_existing(out: Path, overwrite: bool, inputs: Sequence[Any] = ()) -> None:
    if out.exists() and not (out.is_dir() and not any(out.iterdir())):
        if not overwrite:
            raise OutputExistsError("out_dir", out)
        # overwrite replaces a run directory pbicrl wrote and nothing else: never a data file, an unrelated
        # directory, a file pbicrl did not put there, or the command's own input
        check_replaceable(out, "run", field="out_dir", inputs=inputs, legacy=_legacy_run_entries)
    elif inputs_inside(out, inputs):
        raise FileExistsError(f"out_dir: {out} holds this command's input {inputs_inside(out, inputs)[0]}; "
                              "choose another directory")


def write_run_dir(out_dir: str | os.PathLike[str], json_files: dict[str, Any], npz_files: dict[str, dict[str, Any]],
                  *, overwrite: bool = False, inputs: Sequence[Any] = ()) -> Path:
    """Create ``out_dir`` with the given files in one atomic rename (no half-written directory).

    JSON content goes through :func:`json_safe` (non-finite numbers become ``null``) and is written with
    ``allow_nan=False``, so every file is valid JSON. The directory is claimed while it is written
    (:func:`claim_out_dir`; a claim this process took before, e.g. by :func:`check_out_dir`, ends here) and
    gets the permissions of the process's umask, as a plain ``mkdir`` would. A marker
    (:data:`pbicrl._atomic.OUTPUT_MARKER`) records the directory as a run and the files in it, so that a later
    ``overwrite`` replaces it only while it holds nothing else, and never while it holds one of ``inputs``.

    Raises
    ------
    OutputExistsError
        ``out_dir`` exists and ``overwrite`` is false.
    OutputBusyError
        Another process is writing ``out_dir``.
    FileExistsError
        ``out_dir`` is a symbolic link, a file or a directory that is not a run (``overwrite`` or not).
    """
    out = Path(out_dir)
    if out.is_symlink():
        raise FileExistsError(f"out_dir: {out} is a symbolic link; give a real directory path")
    texts = {name: json.dumps(json_safe(content), indent=2, allow_nan=False) + "\n"
             for name, content in json_files.items()}  # before creating anything: a TypeError leaves no trace
    parent = out.parent
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    _check_writable(parent)
    out.parent.mkdir(parents=True, exist_ok=True)
    claim_out_dir(out)
    try:
        clean_stale_temporaries(out)
        if out.is_symlink():
            raise FileExistsError(f"out_dir: {out} is a symbolic link; give a real directory path")
        _check_existing(out, overwrite, inputs)
        if out.is_dir() and not any(out.iterdir()):
            out.rmdir()
        with atomic_dir(out, replace=True) as tmp:
            for name, text in texts.items():
                (tmp / name).write_text(text)
            for name, arrays in npz_files.items():
                np.savez_compressed(tmp / name, **arrays)
            (tmp / OUTPUT_MARKER).write_text(json.dumps({"kind": "run", "entries": sorted([*texts, *npz_files])}) + "\n")
    finally:
        release_out_dir(out)
    return out
