"""The plain-language warnings of a posterior (issued once, when it is built).

:class:`PosteriorWarnings` is a mixin of :class:`pbicrl.inference.posterior.Posterior`: a log-likelihood that
is not finite, penalties the rankings leave unbounded (from the identification, :func:`short_warnings`, or the
prior-driven heuristic), a required penalty the run switches off, and convergence.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import numpy as np

from pbicrl.inference.draws import SELECTION_THRESHOLD
from pbicrl.inference.summary import is_real

if TYPE_CHECKING:
    from pbicrl.analysis.diagnostics import Diagnostics

__all__ = ["PosteriorWarnings", "short_warnings"]


class PosteriorWarnings:
    """Mixin: needs the summaries of :class:`~pbicrl.inference.posterior.Posterior` and its ``diagnostics()``."""

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
        if self.sampler not in ("pbicrl", "bpl") or self.n_chains < 2:
            return []
        pj = self.settings.get("p_joint", 0.0)
        if not is_real(pj) or float(pj) > 0.0:
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

    def _likelihood_warnings(self) -> list[str]:
        out = []
        ll = np.asarray(self.log_likelihood, dtype=np.float64)
        bad = int(ll.size - np.isfinite(ll).sum())
        if bad or not math.isfinite(self.map_log_likelihood):
            beta = self.settings.get("beta")
            out.append(f"the log-likelihood is NaN or infinite in {bad:,} of {ll.size:,} kept draws"
                       + (f" (beta {beta:g})" if is_real(beta) else "")
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
        prob = f" with probability >= {1 - alpha:g}" if is_real(alpha) else ""
        skip = self.not_identifiable()
        out = []
        for name in self.feature_names:
            e = self._ident_entry(name)
            if e is None or not e.get("unbounded") or name in skip:
                continue
            mp = e.get("min_penalty")
            scale = (f"|w_p| >= {mp:.4g}" if is_real(mp) and math.isfinite(mp)
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




def _num_s(x: Any) -> str:
    """Seconds for a message (``?`` when unknown)."""
    return f"{float(x):.0f} s" if is_real(x) else "?"


def short_warnings(ident: Mapping[str, Any]) -> list[str] | None:
    """One short line per feature from an identification's dict (:meth:`Identification.to_dict`, also as read back
    from an older ``summary.json``): ``in_red: |w_p| >= 455.9 identified; magnitude beyond that is the prior's``.

    None when the dict has no per-feature entries (then a caller keeps the messages it has).
    """
    feats = ident.get("features")
    if not isinstance(feats, Mapping):
        return None
    alpha = ident.get("alpha")
    at = f" at alpha = {float(alpha):g}" if isinstance(alpha, (int, float)) and not isinstance(alpha, bool) else ""
    out, unbounded = [], []
    for name, e in feats.items():
        if not isinstance(e, Mapping):
            continue
        if e.get("candidate", True) and e.get("identifiable") is False:
            out.append(f"{name}: not identifiable ({e.get('reason') or 'no information in the rankings'}); its "
                       "posterior is the prior's")
        elif e.get("unbounded"):
            mp = e.get("min_penalty")
            if not isinstance(mp, (int, float)) or isinstance(mp, bool) or not math.isfinite(mp):
                unbounded.append(f"{name}: unbounded by the data (rankings not separable{at}); its magnitude is "
                                 "the prior's")
            elif float(mp) == 0.0:
                unbounded.append(f"{name}: not required by the rankings (min|w_p| = 0); its magnitude is the prior's")
            else:
                unbounded.append(f"{name}: |w_p| >= {float(mp):.4g} identified; magnitude beyond that is the prior's")
    return out + unbounded
