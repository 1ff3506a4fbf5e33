"""``summary.json``: everything a posterior reports, JSON-ready (numbers finite or ``null``).

:func:`summary_dict` builds the document :meth:`pbicrl.inference.posterior.Posterior.summary` returns and
:func:`pbicrl.io.runs.save_run` writes (layout :data:`SCHEMA_VERSION`, described in
:mod:`pbicrl.inference.posterior`); :func:`json_safe` is the sanitiser every JSON file of a run goes through.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from typing import Any, Sequence

import numpy as np
from numpy.typing import NDArray

from pbicrl.inference.codes import C_EVALS
from pbicrl.inference.draws import INDICATOR_LABELS

__all__ = ["SCHEMA_VERSION", "MAP_DEFINITION", "summary_dict", "prior_driven_block", "json_safe", "to_py",
           "is_real"]

SCHEMA_VERSION = 3
"""Version of the ``summary.json`` layout :meth:`pbicrl.inference.posterior.Posterior.save` writes (files without
one are 1)."""

MAP_DEFINITION = ("the highest-density visited draw (log prior + log likelihood) over all chains; in a "
                  "reversible-jump chain this compares densities of different dimensions, so it is not the mode "
                  "of a common space: prefer 'selected' with the conditional medians")
"""What ``summary.json``'s ``map`` block is, written into the block itself."""


def summary_dict(post: Any) -> dict[str, Any]:
    """Everything ``summary.json`` holds for ``post`` (a :class:`~pbicrl.inference.posterior.Posterior`)."""
    names = list(post.feature_names)
    cs = post.conditional_summary()

    def by_name(v: Sequence[Any] | NDArray) -> dict[str, Any]:
        return {n: to_py(x) for n, x in zip(names, v)}

    settings = post.settings
    prior = post.prior if post.prior is not None else {"weight_prior": settings.get("weight_prior"),
                                                        "indicator_prior": settings.get("indicator_prior")}
    meaning = post.indicator_meaning
    posterior_c = meaning == "posterior"
    model = dict(zip(names, post.in_model()))

    def out_of_model(d: dict[str, Any], empty: Any = None) -> dict[str, Any]:
        """bpl: a feature that is not a candidate is not in the model and gets no number."""
        return {n: (v if model[n] else empty) for n, v in d.items()}
    indicator_block: dict[str, Any]
    if posterior_c:
        indicator_block = {"p_constraint": by_name(post.p_constraint)}
    elif meaning == "chain_frequency":
        indicator_block = {"frequency_on": by_name(post.p_constraint)}
    else:
        indicator_block = {"in_model": dict(zip(names, (bool(m) for m in post.in_model())))}
    out = {
        "schema_version": SCHEMA_VERSION,
        "sampler": post.sampler,
        "feature_names": names,
        "indicators": {"meaning": meaning, "label": INDICATOR_LABELS[meaning]},
        "selected": post.selected() if posterior_c else None,
        "most_frequent_set": post.most_frequent_set() if meaning != "fixed" else None,
        "not_identifiable": post.not_identifiable(),
        "map": {
            "indicators": out_of_model(by_name(post.map_indicators.astype(int))),
            "penalty_weights": by_name(post.map_penalty_weights),
            "effective_penalty": by_name(post.map_effective_penalty),
            "parameters": {n: to_py(v) for n, v in zip(post.parameter_names, post.map_parameters_active)},
            "log_posterior": to_py(post.map_log_posterior),
            "log_likelihood": to_py(post.map_log_likelihood),
            "definition": MAP_DEFINITION,
        },
        "posterior": {
            "mean_effective_penalty": out_of_model(by_name(post.mean_effective_penalty)),
            **indicator_block,
            "ci90": out_of_model({n: [to_py(a), to_py(b)] for n, (a, b) in zip(names, post.ci(0.9))}, [None, None]),
            "penalty_given_active": {
                "mean": by_name(cs["mean"]),
                "median": by_name(cs["median"]),
                "ci90": {n: [to_py(a), to_py(b)] for n, a, b in zip(names, cs["low"], cs["high"])},
                "prior_driven": dict(zip(names, post.prior_driven())),
                "active_draws": by_name(cs["active_draws"]),
            },
            "prior_driven": prior_driven_block(post),
            **({"authors_statistic": post.authors_statistic()} if post.sampler in ("authors", "paper") else {}),
            "prior_sensitivity": post.prior_sensitivity().to_dict(names),
            "rhat": {k: by_name(np.array(v)) for k, v in post.rhat().items()},
            "diagnostics": post.diagnostics().to_dict(),
            "parameters": post.parameter_summary(),
        },
        "identified": post.identified,
        "prior": prior,
        "acceptance_rate": post.acceptance_rate(),
        "iterations": int(settings["iterations"]),
        "burn_in": int(settings["burn_in"]),
        "thin": int(settings["thin"]),
        "draws_per_chain": post.n_draws,
        "chains": post.n_chains,
        "seed": post.seed,
        "runtime_s": post.runtime_s,
        "chain_runtime_s": post.chain_runtime_s.tolist(),
        "likelihood_evaluations": (int(post.recorded["likelihood_evaluations"])
                                   if is_real(post.recorded.get("likelihood_evaluations"))
                                   else int(post.counts[:, C_EVALS].sum())),
        "settings": settings,
        "warnings": post.warnings(),
    } | ({"converged": post.converged} if post.convergence is not None else {}) \
      | ({"extra": post.extra} if post.extra else {})
    return json_safe(out)


def prior_driven_block(post: Any) -> dict[str, Any]:
    """``posterior.prior_driven``: a flag for every number ``posterior`` reports (``None``: not measured)."""
    names = list(post.feature_names)
    sens = post.prior_sensitivity()
    f = sens.flags
    ends = post.end_flags()
    ind_key = {"posterior": "p_constraint", "chain_frequency": "frequency_on", "fixed": None}[post.indicator_meaning]
    out: dict[str, Any] = {"basis": sens.basis if sens.measured else (
        "not measured (the sampler ignores the prior or it cannot be reweighted); penalty_given_active from "
        + ("the identification's unbounded flag" if post.identified is not None else "the prior-quantile heuristic"))}
    if ind_key is not None:
        out[ind_key] = dict(zip(names, f["p_constraint"]))
    out["mean_effective_penalty"] = dict(zip(names, f["mean_effective_penalty"]))
    out["ci90"] = {n: [f["ci90_low"][j], f["ci90_high"][j]] for j, n in enumerate(names)}
    out["penalty_given_active"] = {
        "mean": {n: (f["given_active_mean"][j] if sens.measured else ends[j][1]) for j, n in enumerate(names)},
        "median": {n: (f["given_active_median"][j] if sens.measured else ends[j][1]) for j, n in enumerate(names)},
        "ci90": {n: [ends[j][0], ends[j][2]] for j, n in enumerate(names)}}
    return out


def is_real(x: Any) -> bool:
    """A real number (Python or NumPy), not a bool."""
    return isinstance(x, (int, float, np.integer, np.floating)) and not isinstance(x, (bool, np.bool_))


def to_py(x: Any) -> Any:
    """A NumPy or Python scalar as a Python ``bool`` / ``int`` / ``float``, ``None`` for NaN and infinities."""
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
