r"""Draws of a reversible-jump chain and the views every holder of them shares.

:class:`DrawsView` is the mixin of :class:`pbicrl.inference.posterior.Posterior` (a fresh or loaded posterior) and
:class:`pbicrl.io.runs.RunRecord` (the checked reader of a run directory): the probability of each constraint
:math:`P(c_j = 1 \mid \mathcal{D})`, the selected (median-probability) set, the most frequent set, summaries of
:math:`w_{p,j}` and :math:`\vartheta` given the constraint is on, and point estimates. It needs only the
arrays, so diagnostics, export and plots accept either holder.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = ["DrawsView", "SELECTION_THRESHOLD", "ESTIMATORS", "LEVEL", "INDICATOR_MEANINGS", "indicator_meaning",
           "INDICATOR_LABELS", "split_rhat", "parameter_draws"]

SELECTION_THRESHOLD = 0.5
""":math:`P(c_j = 1) >` this selects feature :math:`j` (median-probability model, Barbieri & Berger 2004)."""
ESTIMATORS = ("selected", "map", "mean")
"""Point estimates :meth:`DrawsView.point_estimate` offers (``selected`` is the default everywhere)."""
LEVEL = 0.9
"""Mass of the equal-tailed intervals reported by default (90%)."""

INDICATOR_MEANINGS = {"pbicrl": "posterior", "paper": "chain_frequency", "authors": "chain_frequency",
                      "bpl": "fixed"}
"""What the share of kept draws with :math:`c_j = 1` is, per sampler.

``posterior``: :math:`P(c_j = 1 \\mid \\mathcal{D})` of a valid reversible-jump chain (``pbicrl``); the selected
set is the median-probability model. ``chain_frequency``: Algorithm 1's indicator moves keep a latent weight
(``paper``) or reset it (``authors``) and accept by the likelihood ratio alone, so they do not target a
posterior over :math:`c`: the share is how often the chain had the feature on, nothing more, and no set is
selected from it (the paper reports the highest-density visited draw, ``map``). ``fixed``: ``bpl`` has no
indicators; the candidates are in the model, the other features are not."""
INDICATOR_LABELS = {"posterior": "P(c=1)", "chain_frequency": "frequency on in the chain", "fixed": "in the model"}
"""How :data:`INDICATOR_MEANINGS` are named in tables, ``summary.json``, figures and the labelling page."""


def indicator_meaning(method: str | None) -> str:
    """:data:`INDICATOR_MEANINGS` of a sampler (``posterior`` for runs that recorded none)."""
    return INDICATOR_MEANINGS.get(str(method or "pbicrl"), "chain_frequency")


def split_rhat(x: NDArray[np.float64]) -> float:
    """Split-:math:`\\hat R` (Gelman et al., BDA3) of draws shaped (chains, draws).

    NaN when undefined: fewer than 4 draws, one chain, or draws that never change (R-hat of a constant is
    not 1, it is meaningless; the diagnostics report it as ``None``). Infinite when every chain is
    constant but at different values.
    """
    x = np.asarray(x, dtype=np.float64)
    if x.ndim != 2 or x.shape[1] < 4 or x.shape[0] < 1:
        return float("nan")
    n = x.shape[1] // 2
    halves = np.concatenate([x[:, :n], x[:, -n:]], axis=0)
    m = halves.shape[0]
    means = halves.mean(axis=1)
    W = halves.var(axis=1, ddof=1).mean()
    B = n * means.var(ddof=1)
    if W == 0:
        return float("nan") if B == 0 else float("inf")
    var = (n - 1) / n * W + B / n
    return float(np.sqrt(var / W)) if m > 1 else float("nan")


def parameter_draws(post: Any) -> tuple[NDArray[np.float64] | None, list[str]]:
    r"""The :math:`\vartheta` draws of a holder of draws as (chains, draws, P) floats, and their names.

    ``(None, [])`` without parametric constraints; a 2-D ``parameters`` is one parameter; missing
    ``parameter_names`` are ``theta0``, ``theta1``, ...
    """
    params = getattr(post, "parameters", None)
    if params is None or not np.size(params):
        return None, []
    params = np.asarray(params, dtype=np.float64)
    if params.ndim == 2:
        params = params[:, :, None]
    names = getattr(post, "parameter_names", None) or [f"theta{k}" for k in range(params.shape[2])]
    return params, [str(n) for n in names]


class DrawsView:
    r"""Views shared by every holder of draws (:class:`pbicrl.inference.posterior.Posterior`, :class:`pbicrl.io.runs.RunRecord`).

    Needs ``indicators`` and ``penalty_weights`` (chains, draws, d), ``feature_names`` and
    ``map_indicators``, ``map_penalty_weights`` (d,); uses ``parameters`` (chains, draws, P),
    ``parameter_names``, ``parameter_owner`` and ``map_parameters`` when present.
    """

    indicators: NDArray[np.int8]
    penalty_weights: NDArray[np.float64]
    feature_names: tuple[str, ...]
    map_indicators: NDArray[np.int8]
    map_penalty_weights: NDArray[np.float64]

    @property
    def n_chains(self) -> int:
        return int(self.indicators.shape[0])

    @property
    def n_draws(self) -> int:
        return int(self.indicators.shape[1])

    @property
    def n_features(self) -> int:
        return int(self.indicators.shape[2])

    @property
    def effective_penalty(self) -> NDArray[np.float64]:
        """Draws of :math:`c \\circ w_p`, (chains, draws, d)."""
        return self.indicators * self.penalty_weights

    @property
    def map_effective_penalty(self) -> NDArray[np.float64]:
        """:math:`c \\circ w_p` of the highest-density visited draw (see :data:`pbicrl.inference.summary.MAP_DEFINITION`)."""
        return self.map_indicators * self.map_penalty_weights

    @property
    def p_constraint(self) -> NDArray[np.float64]:
        """:math:`P(c_j = 1 \\mid \\mathcal{D})`, (d,)."""
        return self.indicators.reshape(-1, self.n_features).mean(axis=0)

    # ------------------------------------------------------------------ what the indicators mean
    @property
    def indicator_meaning(self) -> str:
        """``posterior``, ``chain_frequency`` or ``fixed`` (:data:`INDICATOR_MEANINGS` of :attr:`method`)."""
        return indicator_meaning(getattr(self, "sampler", None))

    @property
    def indicators_are_posterior(self) -> bool:
        """Whether :attr:`p_constraint` is a posterior probability and :meth:`selected` a selection
        (the ``pbicrl`` sampler only; see :data:`INDICATOR_MEANINGS`)."""
        return self.indicator_meaning == "posterior"

    def in_model(self) -> NDArray[np.bool_]:
        """Per feature: is its penalty part of the sampled model? (d,) bool.

        All features except for ``bpl``, whose non-candidates are fixed at :math:`w_{p,j} = 0` (their
        indicator is stored as 1 but means nothing): there, the candidates (``settings["candidates"]``; by
        default every known feature, or only the parametric constraints when there are any).
        """
        d = self.n_features
        if self.indicator_meaning != "fixed":
            return np.ones(d, dtype=bool)
        settings = getattr(self, "settings", None) or {}
        cand = settings.get("candidates")
        out = np.zeros(d, dtype=bool)
        if cand is None:
            n_cons = len(settings.get("constraints") or [])
            out[d - n_cons if n_cons else 0:] = True
        else:
            out[[int(j) for j in cand if 0 <= int(j) < d]] = True
        return out

    # ------------------------------------------------------------------ selection
    def selected(self) -> list[str]:
        """Names of the features with :math:`P(c_j = 1 \\mid \\mathcal{D}) > 0.5`, in feature order.

        The median-probability set (Barbieri & Berger 2004). Unlike the highest-density draw it does not
        compare densities of different dimensions. Only a selection where :attr:`indicators_are_posterior`:
        for ``paper`` / ``authors`` the same rule on the chain's frequencies (tables and ``summary.json``
        show no selection for them), for ``bpl`` the candidates.
        """
        on = (self.p_constraint > SELECTION_THRESHOLD) & self.in_model()
        return [n for n, s in zip(self.feature_names, on) if s]

    def most_frequent_set(self) -> dict[str, Any]:
        """The set of active features visited most often over all kept draws of all chains.

        Returns
        -------
        dict
            ``{"features": [names], "frequency": fraction of kept draws}``. Ties go to the smaller set, then
            to the indicator vector that is smallest read in feature order (deterministic).
        """
        rows = np.asarray(self.indicators, dtype=np.int8).reshape(-1, self.n_features)
        if rows.shape[0] == 0:
            return {"features": [], "frequency": None}
        sets, counts = np.unique(rows, axis=0, return_counts=True)
        best = min(range(len(sets)), key=lambda k: (-int(counts[k]), int(sets[k].sum()), tuple(sets[k].tolist())))
        return {"features": [n for n, on in zip(self.feature_names, sets[best]) if on],
                "frequency": float(counts[best] / rows.shape[0])}

    # ------------------------------------------------------------------ conditional on c_j = 1
    def conditional_summary(self, level: float = LEVEL) -> dict[str, NDArray[np.float64]]:
        r"""Summaries of :math:`w_{p,j}` over the draws with :math:`c_j = 1`.

        Parameters
        ----------
        level : float
            Mass of the equal-tailed interval.

        Returns
        -------
        dict
            ``mean``, ``median``, ``low``, ``high`` (d,) float, NaN where :math:`c_j` is never 1;
            ``active_draws`` (d,) int (0 for a ``bpl`` non-candidate: it is not in the model).
        """
        d = self.n_features
        w = np.asarray(self.penalty_weights, dtype=np.float64).reshape(-1, d)
        c = np.asarray(self.indicators).reshape(-1, d).astype(bool) & self.in_model()  # bpl: candidates only
        q = (1.0 - level) / 2.0
        out = {k: np.full(d, np.nan) for k in ("mean", "median", "low", "high")}
        n = np.zeros(d, dtype=np.int64)
        for j in range(d):
            x = w[c[:, j], j]
            x = x[np.isfinite(x)]
            n[j] = x.size
            if x.size:
                out["mean"][j] = x.mean()
                out["median"][j] = np.median(x)
                out["low"][j], out["high"][j] = np.quantile(x, [q, 1.0 - q])
        out["active_draws"] = n
        return out

    def conditional_median(self) -> NDArray[np.float64]:
        """Posterior median of :math:`w_{p,j}` given :math:`c_j = 1`, (d,); NaN where never active."""
        return self.conditional_summary()["median"]

    def parameter_conditional(self, level: float = LEVEL) -> dict[str, NDArray[np.float64]]:
        r"""Summaries of each parametric-constraint parameter :math:`\vartheta_k` while its constraint is on.

        Returns
        -------
        dict
            ``mean``, ``median``, ``low``, ``high`` (P,) float (NaN where never active) and ``active_draws``
            (P,) int. Without ``parameter_owner`` every finite draw counts.
        """
        names = tuple(getattr(self, "parameter_names", ()) or ())
        P = len(names)
        out = {k: np.full(P, np.nan) for k in ("mean", "median", "low", "high")}
        out["active_draws"] = np.zeros(P, dtype=np.int64)
        params = getattr(self, "parameters", None)
        if not P or params is None or np.size(params) == 0:
            return out
        th = np.asarray(params, dtype=np.float64).reshape(-1, P)
        on = np.asarray(self.indicators).reshape(-1, self.n_features)
        owner = tuple(getattr(self, "parameter_owner", ()) or ())
        q = (1.0 - level) / 2.0
        for p in range(P):
            keep = np.isfinite(th[:, p])
            if len(owner) == P:
                keep &= on[:, owner[p]] == 1
            x = th[keep, p]
            out["active_draws"][p] = x.size
            if x.size:
                out["mean"][p] = x.mean()
                out["median"][p] = np.median(x)
                out["low"][p], out["high"][p] = np.quantile(x, [q, 1.0 - q])
        return out

    def point_estimate(self, estimator: str = "selected") -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        r"""One reward to plot or score: effective penalties :math:`c \circ w_p` (d,) and locations
        :math:`\vartheta` (P,), NaN for parameters of constraints that are off.

        Parameters
        ----------
        estimator : {"selected", "map", "mean"}
            ``selected`` (default): :math:`c_j = 1` for the selected set (:meth:`selected`), :math:`w_{p,j}`
            and :math:`\vartheta` their posterior medians given :math:`c_j = 1`. ``map``: the highest-density
            visited draw. ``mean``: posterior mean of :math:`c_j w_{p,j}`, parameters' means while active.
        """
        d = self.n_features
        owner = tuple(getattr(self, "parameter_owner", ()) or ())
        if estimator == "selected":
            on = self.p_constraint > SELECTION_THRESHOLD
            eff = np.where(on, np.nan_to_num(self.conditional_median()), 0.0)
            theta = self.parameter_conditional()["median"]
            keep = on
        elif estimator == "map":
            eff = np.asarray(self.map_effective_penalty, dtype=np.float64)
            mp = getattr(self, "map_parameters", None)
            P = len(tuple(getattr(self, "parameter_names", ()) or ()))
            theta = np.full(P, np.nan) if mp is None or np.size(mp) != P else np.asarray(mp, dtype=np.float64).copy()
            keep = np.asarray(self.map_indicators).astype(bool)
        elif estimator == "mean":
            eff = np.asarray(self.effective_penalty, dtype=np.float64).reshape(-1, d).mean(axis=0)
            theta = self.parameter_conditional()["mean"]
            keep = self.p_constraint > 0
        else:
            raise ValueError(f"estimator: expected one of {', '.join(ESTIMATORS)}, got {estimator!r}")
        theta = np.asarray(theta, dtype=np.float64).copy()
        if len(owner) == theta.size:
            for p, j in enumerate(owner):
                if not keep[j]:
                    theta[p] = np.nan
        return eff, theta
