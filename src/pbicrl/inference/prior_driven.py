r"""Which summaries of a posterior come from the prior rather than the rankings.

:class:`PriorDrivenSummaries` is a mixin of :class:`pbicrl.inference.posterior.Posterior`: the features the rankings
say nothing about (:meth:`~PriorDrivenSummaries.not_identifiable`), the smallest penalty they require
(:meth:`~PriorDrivenSummaries.min_penalty`), and per reported number whether it moves with the prior of
:math:`w_p`: measured by reweighting the draws to a tenfold wider prior (:mod:`pbicrl.inference.sensitivity`),
else from the attached identification or the prior-quantile heuristic (:meth:`~PriorDrivenSummaries.prior_driven`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from pbicrl.inference.draws import LEVEL
from pbicrl.inference.priors import prior_quantile
from pbicrl.inference.sensitivity import PriorSensitivity, prior_sensitivity, weight_prior_spec
from pbicrl.inference.summary import is_real, to_py

__all__ = ["PriorDrivenSummaries", "NON_VARYING_REASON"]

NON_VARYING_REASON = "constant across trajectories: the likelihood does not depend on its penalty"
"""The reason :meth:`PriorDrivenSummaries.not_identifiable` gives for a feature that never varies."""


class PriorDrivenSummaries:
    """Mixin: needs the :class:`~pbicrl.inference.draws.DrawsView` views and ``identified``, ``prior``,
    ``settings``, ``non_varying``, ``method`` (:class:`~pbicrl.inference.posterior.Posterior`)."""

    def not_identifiable(self) -> dict[str, str]:
        """Features the rankings carry no information about, with the reason.

        Candidate features that never vary across trajectories (:attr:`non_varying`), and those the attached
        identification marks ``identifiable: false``. They get no R-hat or ESS (undefined, ``null``) and raise
        no convergence warning: their penalty's draws are the prior's.
        """
        out = {n: NON_VARYING_REASON for n in self.non_varying}
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
            out.append(v if is_real(v) and math.isfinite(v) else None)
        return out

    def prior_sensitivity(self, level: float = LEVEL) -> PriorSensitivity:
        """Which summaries move with the weight prior, measured by reweighting the draws to a tenfold wider prior
        (:mod:`pbicrl.inference.sensitivity`). Nothing is measured for the ``paper`` / ``authors`` samplers
        (they ignore the prior) or a prior that cannot be reweighted."""
        key = ("_sensitivity", float(level))
        cached = getattr(self, "_cache", {}).get(key)
        if cached is not None:
            return cached
        latent = self.sampler in ("paper", "authors")
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
            plo, phi = prior_quantile(spec, q), prior_quantile(spec, 1.0 - q)
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
            rng = [None if v is None else to_py(v) for v in rng] if ok else None
            out[name] = {"mean": to_py(s["mean"][p]) if has else None,
                         "median": to_py(s["median"][p]) if has else None,
                         "ci90": [to_py(s["low"][p]), to_py(s["high"][p])] if has else [None, None],
                         "active_draws": int(s["active_draws"][p]),
                         "identified_range": rng,
                         "prior_driven": _parameter_prior_driven(rng, bounds[p], s["low"][p], s["high"][p], has)}
        return out

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

