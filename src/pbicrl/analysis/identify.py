r"""What do the rankings identify? Separation analysis before sampling.

With reward :math:`r(s) = (w_n + c \circ w_p)^\top \phi(s)` the length-normalised return of trajectory
:math:`\tau_i` is :math:`\bar r_i = \bar\phi_i^\top (w_n + w_p)`, and the margin-respecting Bradley-Terry
model (paper Eq. 7) gives :math:`P(\tau_i \succ \tau_j) = \sigma(\beta(\bar r_i - \bar r_j) - m_{k\ell})` for
:math:`\tau_i \in \mathcal{G}_k`, :math:`\tau_j \in \mathcal{G}_\ell`, :math:`k < \ell`. Every quantity below is
computed with small linear programs over *group extremes*: the :math:`|\mathcal{G}_k|\,|\mathcal{G}_\ell|` pair
constraints of a block reduce to :math:`\min_{i \in \mathcal{G}_k} \bar r_i - \max_{j \in \mathcal{G}_\ell} \bar r_j`,
so an LP has the free penalties plus :math:`2K` group bounds as variables and :math:`O(N + K^2)` rows
(``/work/shared/notes/identifiability.md``, section "Separation"); with additive margins (zeros or gaps, e.g. a
total ranking) the adjacent groups' rows imply all others, :math:`O(N + K)` rows, so many groups need nothing of
size :math:`K \times K`.

Definitions
-----------
Admissible penalties
    :math:`w_{p,j} = 0` for features that are not candidates; :math:`w_{p,j} \le 0` for candidates when
    ``penalty_sign="negative"`` (the default: a constraint is a cost), unrestricted for ``"any"``.
Separating set :math:`S_\alpha`
    Admissible :math:`w_p` with :math:`\beta(\min_{\mathcal{G}_k}\bar r - \max_{\mathcal{G}_\ell}\bar r) \ge
    m_{k\ell} + \operatorname{logit}(1-\alpha)` for all :math:`k < \ell`: every cross-group pair is ordered with
    probability at least :math:`1-\alpha` under Eq. 7. The rankings are *separable* (at level
    :math:`\alpha`) when :math:`S_\alpha \neq \emptyset`.
Separation scale (``min_penalty``)
    :math:`\min_{w_p \in S_\alpha} |w_{p,j}|`, the other penalties free within their support: the smallest
    penalty on feature :math:`j` with which the data are explained at level :math:`\alpha`; 0 when feature
    :math:`j` is not needed, ``None`` when :math:`S_\alpha = \emptyset`. It grows with :math:`1/\beta`, the
    margins and :math:`\operatorname{logit}(1-\alpha)`. It is **not** a bound on, nor an estimate of, the
    true penalty: on the shipped point-mass data (simulated with penalties 10 and 100) it is several times
    larger (the README gives the numbers; ``tests/test_docs_numbers.py`` keeps them current).
Unbounded penalty
    Feature :math:`j` is unbounded in direction :math:`s = \pm 1` when some recession direction
    :math:`\delta` (admissible sign, :math:`s\,\delta_j > 0`) satisfies
    :math:`\min_{\mathcal{G}_k} \bar\Phi\delta \ge \max_{\mathcal{G}_\ell} \bar\Phi\delta` for all :math:`k<\ell`
    and is not flat (:math:`\bar\Phi\delta` not constant). Along :math:`w_p + t\delta` no pair's return
    difference ever decreases and at least one increases, so the likelihood increases monotonically and
    saturates as :math:`t \to \infty`: the maximum is at infinity and the posterior there follows the
    prior. This depends on neither :math:`\alpha`, :math:`\beta` nor the margins (margins only move the
    separation scale). It is reported whether or not the data are separable. When some admissible
    direction orders every cross-group pair *strictly*, a small multiple of any other admissible direction can
    be added to it, so then every candidate is unbounded: what the data say is then in the directions (which
    penalties must run off together, and how fast) and in the separation scales, not in the magnitudes.
Not identifiable
    A candidate whose per-trajectory mean feature is constant (the penalty shifts every return equally and
    cancels in every comparison), or that is affinely dependent on other candidates (the likelihood is flat
    along a combination of their penalties). Constant features are left out of the LPs.
Threshold interval of an axis half-space
    See :func:`threshold_interval`.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import os
import sys
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Literal, Mapping, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from pbicrl.inference.constraints import AxisHalfspace, Constraint, ConstraintSet, constraint_from_dict
from pbicrl.inference.data import Dataset
from pbicrl.errors import warn
from pbicrl.inference.posterior_warnings import short_warnings
from pbicrl.inference.preferences import Margins, Preferences

__all__ = ["identify", "Identification", "FeatureIdentification", "ParameterInterval", "IdentifyError",
           "threshold_interval", "short_warnings", "WARNING_EXPLANATION"]

PenaltySign = Literal["negative", "any"]

# A recession direction counts when its normalised improvement t (in units of the standardised feature range)
# exceeds this; HiGHS solves to ~1e-9 on these well-scaled problems.
_T_MIN = 1e-6
# Box on standardised weights so that relaxed (cutting-plane) LPs stay bounded; ends of the separating set are
# only asked for where the recession LP says they are finite, so the box is never active at the solution.
_BIG = 1e10
_END_BOXES = (1e5, 1e7)  # boxes tried first for the ends of S_alpha (see identify's end())
# Warm-started HiGHS models (_LPSolver): None = when highspy is installed, False = never (scipy's linprog for every LP)
_WARM: bool | None = None
_TABLE_MARGINS = 12  # margins listed in the header of Identification.table (a total ranking has K - 1 of them)


class IdentifyError(ValueError):
    """Invalid argument to :func:`identify`; the message names the offending field."""


# ---------------------------------------------------------------------------------------------- results
@dataclass(frozen=True)
class FeatureIdentification:
    r"""What the rankings say about the penalty :math:`w_{p,j}` of one known feature.

    Attributes
    ----------
    name : str
        Feature name.
    candidate : bool
        Whether the feature may carry a penalty (otherwise :math:`w_{p,j} = 0` and nothing is estimated).
    identifiable : bool or None
        ``False`` for a constant or affinely dependent candidate (the likelihood is flat along its penalty);
        ``None`` for non-candidates; ``True`` otherwise. An unbounded penalty is identifiable from one side
        only, see ``unbounded``.
    reason : str
        Plain-language explanation of the entry.
    min_penalty : float or None
        Separation scale :math:`\min_{S_\alpha} |w_{p,j}|` (see the module docstring); ``None`` when the
        rankings are not separable at level :math:`\alpha` or the feature is not analysed.
    penalty_range : tuple of float or None
        ``(low, high)``: the values :math:`w_{p,j}` takes over the separating set :math:`S_\alpha`; an end is
        infinite where the penalty is unbounded. ``None`` where ``min_penalty`` is.
    unbounded : bool
        Whether the likelihood never decreases as :math:`|w_{p,j}| \to \infty` in an admissible direction.
    direction : {"-inf", "+inf", "both"} or None
        Which way :math:`w_{p,j}` runs off (``None`` when bounded).
    recession : tuple of dict
        One normalised recession direction per way in ``direction``: feature name -> coefficient of
        :math:`\delta` (raw weight units, largest magnitude 1; only non-zero entries). It shows which
        penalties must run off together with this one; the sparsest such set is chosen.
    spread : float
        Range (max - min) of the per-trajectory mean feature; 0 for a constant feature.
    """

    name: str
    candidate: bool
    identifiable: bool | None
    reason: str
    min_penalty: float | None = None
    penalty_range: tuple[float, float] | None = None
    unbounded: bool = False
    direction: Literal["-inf", "+inf", "both"] | None = None
    recession: tuple[dict[str, float], ...] = ()
    spread: float = 0.0

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready; infinite ends of ``penalty_range`` become ``None``."""
        return {
            "min_penalty": self.min_penalty,
            "unbounded": self.unbounded,
            "direction": self.direction,
            "identifiable": self.identifiable,
            "reason": self.reason,
            "candidate": self.candidate,
            "penalty_range": None if self.penalty_range is None else [_finite_or_none(v) for v in self.penalty_range],
            "recession": [dict(d) for d in self.recession],
            "spread": self.spread,
        }


@dataclass(frozen=True)
class ParameterInterval:
    """Identified interval of one constraint parameter (see :func:`threshold_interval`).

    Attributes
    ----------
    name : str
        ``"<constraint>.<parameter>"`` as in :attr:`pbicrl.inference.constraints.ConstraintSet.param_names`.
    constraint, family : str
        Constraint name and family.
    low, high : float or None
        Interval ends; both ``None`` when not identified or not computed (see ``reason``).
    low_closed, high_closed : bool
        Whether each end belongs to the interval.
    n_violating : int
        Trajectories of worse groups that enter the region for every threshold in the interval.
    n_worse : int
        Trajectories of worse groups (all but the best group).
    violating_per_group : dict of int to int
        ``n_violating`` by group label.
    reason : str
        Definition used, or why there is no interval.
    """

    name: str
    constraint: str
    family: str
    low: float | None
    high: float | None
    low_closed: bool = False
    high_closed: bool = False
    n_violating: int = 0
    n_worse: int = 0
    violating_per_group: dict[int, int] = field(default_factory=dict)
    reason: str = ""

    @property
    def interval(self) -> list[float] | None:
        """``[low, high]`` or ``None``."""
        return None if self.low is None or self.high is None else [self.low, self.high]

    def to_dict(self) -> dict[str, Any]:
        return {"interval": self.interval, "low_closed": self.low_closed, "high_closed": self.high_closed,
                "n_violating": self.n_violating, "n_worse": self.n_worse,
                "violating_per_group": {str(k): v for k, v in self.violating_per_group.items()},
                "family": self.family, "constraint": self.constraint, "reason": self.reason}

    def text(self) -> str:
        """``(7.5, 8.2]``-style interval or ``-``."""
        if self.low is None or self.high is None:
            return "-"
        return f"{'[' if self.low_closed else '('}{self.low:.6g}, {self.high:.6g}{']' if self.high_closed else ')'}"


@dataclass(frozen=True, eq=False)
class Identification:
    r"""Result of :func:`identify`.

    Attributes
    ----------
    feature_names : tuple of str, length d
    features : tuple of FeatureIdentification, length d
        One entry per known feature, in dataset order.
    separable : bool
        Whether :math:`S_\alpha \neq \emptyset` (see the module docstring).
    alpha, beta : float
        Level :math:`\alpha` and inverse temperature :math:`\beta` used.
    margins : Margins
        Margins :math:`m_{k\ell}` used (:class:`~pbicrl.inference.preferences.Margins`; additive ones are K offsets,
        ``margins.matrix`` builds the K x K matrix on request).
    penalty_sign : {"negative", "any"}
    nominal_weights : ndarray, shape (d,)
        :math:`w_n` used.
    group_labels : tuple of int, length K
        Group labels, best first.
    unbounded_directions : tuple of dict
        Distinct normalised recession directions (feature name -> coefficient), see
        :attr:`FeatureIdentification.recession`.
    parameters : tuple of ParameterInterval
        One per parameter of the parametric constraints (empty without constraints).
    n_lp : int
        Linear programs solved (including cutting-plane rounds).
    companions : bool
        Whether the sparsest companions of unbounded penalties were computed (``recession`` of each unbounded
        feature); see :func:`identify`'s ``companions``.
    runtime_s : float
    pairs : dict or None
        ``None``: the analysis covers every cross-group pair (what the grouped and the all-pairs likelihoods use).
        Otherwise the likelihood uses sampled pairs (``--pairs N``) and so does the analysis: ``protocol``,
        ``n_pairs``, and ``parameters_from`` (parameter intervals still come from the groups).
    """

    feature_names: tuple[str, ...]
    features: tuple[FeatureIdentification, ...]
    separable: bool
    alpha: float
    beta: float
    margins: Margins
    penalty_sign: PenaltySign
    nominal_weights: NDArray[np.float64]
    group_labels: tuple[int, ...]
    unbounded_directions: tuple[dict[str, float], ...]
    parameters: tuple[ParameterInterval, ...] = ()
    n_lp: int = 0
    runtime_s: float = 0.0
    pairs: dict[str, Any] | None = None
    companions: bool = True

    @property
    def pair_words(self) -> str:
        """Which pairs the analysis orders: ``"cross-group pair"`` or ``"sampled pair"`` (:attr:`pairs`)."""
        return "cross-group pair" if self.pairs is None else "sampled pair"

    def __getitem__(self, name: str) -> FeatureIdentification:
        """Entry of the feature ``name``."""
        try:
            return self.features[self.feature_names.index(name)]
        except ValueError:
            raise KeyError(f"no feature {name!r}; features are {list(self.feature_names)}") from None

    @property
    def min_penalty(self) -> NDArray[np.float64]:
        """Separation scales, shape (d,), NaN where not defined."""
        return np.array([np.nan if f.min_penalty is None else f.min_penalty for f in self.features])

    @property
    def unbounded(self) -> NDArray[np.bool_]:
        """Unbounded flags, shape (d,)."""
        return np.array([f.unbounded for f in self.features], dtype=bool)

    @property
    def logit_level(self) -> float:
        r""":math:`\operatorname{logit}(1-\alpha)`."""
        return math.log((1.0 - self.alpha) / self.alpha)

    def to_dict(self, *, explain: bool = True) -> dict[str, Any]:
        """JSON-ready summary (``summary.json``'s ``identified`` block).

        Features are nested under ``"features"`` so that a feature name can never clash with a top-level
        key; ``"parameters"`` maps ``"<constraint>.<parameter>"`` to ``[low, high]`` or ``None`` (details,
        open/closed ends and reasons in ``"parameter_details"``); infinite values are ``None``. ``"warnings"``
        holds the short lines of :meth:`warnings`, ``"explanations"`` (with ``explain``) the full text of each
        (:meth:`explanations`) and ``"explanation"`` :data:`WARNING_EXPLANATION`.
        """
        out = {
            "separable": self.separable,
            "alpha": self.alpha,
            "beta": self.beta,
            "logit_level": self.logit_level,
            "margins": self.margins.as_dict(),
            "penalty_sign": self.penalty_sign,
            "nominal_weights": {n: float(w) for n, w in zip(self.feature_names, self.nominal_weights)},
            "features": {f.name: f.to_dict() for f in self.features},
            "unbounded_directions": [dict(d) for d in self.unbounded_directions],
            "parameters": {p.name: p.interval for p in self.parameters},
            "parameter_details": {p.name: p.to_dict() for p in self.parameters},
            "n_lp": self.n_lp,
            "runtime_s": self.runtime_s,
            "companions": self.companions,
            "pairs": ({"used": "all cross-group pairs"} if self.pairs is None
                      else {"used": "sampled pairs (the ones the likelihood uses)", **self.pairs}),
        }
        if explain:
            out["warnings"] = short_warnings(out) or []
            out["explanations"] = self.explanations()
            out["explanation"] = WARNING_EXPLANATION
        return out

    # ------------------------------------------------------------------------------------ messages
    def warnings(self) -> list[str]:
        """One short line per non-identifiable candidate and per unbounded penalty (:func:`short_warnings`); the
        full explanation of each is in :meth:`explanations` (``summary.json``: ``identified.explanations``)."""
        return short_warnings(self.to_dict(explain=False)) or []

    def explanations(self) -> dict[str, str]:
        """Per feature that :meth:`warnings` names, the full explanation: why the penalty is unbounded, what the
        separation scale means and what to report (:data:`WARNING_EXPLANATION` says it once for all)."""
        out: dict[str, str] = {}
        level = f"{1 - self.alpha:g}"
        for f in self.features:
            if f.candidate and f.identifiable is False:
                out[f.name] = (f"{f.name}: not identifiable - {f.reason}. Its posterior reflects only the prior; "
                               "drop it from the candidates (or keep only one of a dependent set).")
        for f in self.features:
            if not f.unbounded or f.name in out:
                continue
            toward = {"-inf": "-inf", "+inf": "+inf", "both": "+/-inf"}[f.direction or "-inf"]
            runs = ("; ".join(_direction_text(d) for d in f.recession) if f.recession
                    else "a direction that moves it (its companions were not computed)")
            head = (f"{f.name}: penalty unbounded by the data - along {runs} (w_p -> {toward}) no pair's probability "
                    "ever decreases and some increase, so the likelihood's maximum is at infinity.")
            if f.min_penalty is None:
                scale = (f" The rankings are not separable at alpha = {self.alpha:g}, so no separation scale exists; "
                         "beyond the point where the pairs this direction orders saturate, the posterior of the "
                         "magnitude reflects the prior, not the data.")
            elif f.min_penalty == 0.0:
                scale = (f" The rankings are explained without this penalty (separation scale 0 at alpha = "
                         f"{self.alpha:g}, beta = {self.beta:g}), yet nothing in the data stops it from growing: its "
                         "posterior magnitude reflects the prior.")
            else:
                scale = (f" What the data identify is the separation scale |w_p| >= {f.min_penalty:.4g}: the smallest "
                         f"penalty with which every {self.pair_words} is ordered with probability >= {level} "
                         f"(alpha = {self.alpha:g}, beta = {self.beta:g}) - a scale at which the rankings are "
                         "explained, not an estimate of the true penalty. Beyond it the posterior reflects the prior "
                         "(its bounds or scale), not the data.")
            if f.min_penalty == 0.0:
                advice = (" Report that the rankings do not require this penalty and that its magnitude is not "
                          "identified, not its posterior mean or interval. Margins do not fix the scale.")
            else:
                advice = (" Report this lower bound and the selected constraint set (P(c=1)), not the posterior mean "
                          "or interval of the magnitude. Margins move the lower bound only; they do not fix the scale.")
            out[f.name] = head + scale + advice
        return out

    def issue_warnings(self) -> list[str]:
        """Issue every :meth:`warnings` message as a :class:`pbicrl.errors.PbicrlWarning`; returns them."""
        msgs = self.warnings()
        for m in msgs:
            warn(m, stacklevel=2)
        return msgs

    def table(self) -> str:
        """Readable terminal report."""
        K = len(self.group_labels)
        m = self.margins.as_dict()
        shown = " ".join(f"{k}={v:g}" for k, v in list(m.items())[:_TABLE_MARGINS])
        if len(m) > _TABLE_MARGINS:
            shown += f" ... ({len(m)} in all)"
        sign = "w_p <= 0" if self.penalty_sign == "negative" else "w_p of any sign"
        lines = [f"identifiability: {K} groups, beta {self.beta:g}, alpha {self.alpha:g} "
                 f"(logit(1-alpha) = {self.logit_level:.4g}), margins "
                 + shown + f", {sign}"]
        lines.append("pairs: every cross-group pair (as the likelihood uses)" if self.pairs is None else
                     f"pairs: the {self.pairs['n_pairs']:,} sampled pairs the likelihood uses "
                     f"({self.pairs['protocol']}, seed {self.pairs.get('seed')}), not every cross-group pair")
        if self.separable:
            lines.append(f"separable: yes - some admissible penalty vector orders every {self.pair_words} with "
                         f"probability >= {1 - self.alpha:g}; unbounded penalties are identified only up to that scale")
        else:
            lines.append(f"separable: no - no admissible penalty vector orders every {self.pair_words} with probability "
                         f">= {1 - self.alpha:g}; the likelihood itself fixes the scale of bounded penalties")
        w = max(8, max(len(n) for n in self.feature_names))
        head = (f"{'feature':<{w}}  {'cand':>4}  {'ident':>5}  {'min |w_p|':>10}  {'w_p range over S_alpha':>26}  "
                f"{'unbounded':>9}")
        lines += ["", head, "-" * len(head)]
        for f in self.features:
            ident = "-" if f.identifiable is None else ("yes" if f.identifiable else "NO")
            mp = "-" if f.min_penalty is None else f"{f.min_penalty:.4g}"
            rng = "-" if f.penalty_range is None else f"[{f.penalty_range[0]:.4g}, {f.penalty_range[1]:.4g}]"
            unb = f.direction if f.unbounded else "no"
            cand = "yes" if f.candidate else "no"
            lines.append(f"{f.name:<{w}}  {cand:>4}  {ident:>5}  {mp:>10}  {rng:>26}  {unb:>9}")
            if f.identifiable is False:
                lines.append(f"{'':<{w}}    {f.reason}")
        n_unb = int(self.unbounded.sum())
        if not self.companions and n_unb:
            lines += ["", f"directions along which the likelihood never decreases: not computed for the {n_unb:,} "
                          "unbounded penalties (one LP each; `pbicrl identify --companions`)"]
        if self.unbounded_directions:
            lines += ["", "directions along which the likelihood never decreases (w_p + t*delta, t -> inf):"]
            lines += [f"  {i + 1}. {_direction_text(d)}" for i, d in enumerate(self.unbounded_directions)]
        if self.parameters:
            pw = max(10, max(len(p.name) for p in self.parameters))
            lines += ["", f"{'parameter':<{pw}}  {'identified interval':>24}  note"]
            for p in self.parameters:
                note = (f"{p.n_violating} of {p.n_worse} worse trajectories cross" if p.low is not None else p.reason)
                lines.append(f"{p.name:<{pw}}  {p.text():>24}  {note}")
        for msg in self.warnings():
            lines.append(f"warning: {msg}")
        return "\n".join(lines)


WARNING_EXPLANATION = (
    "A penalty is unbounded by the data when, along some admissible direction, no pair's probability ever "
    "decreases as |w_p| grows and some increase: the likelihood's maximum is at infinity, so beyond the separation "
    "scale min|w_p| (the smallest penalty with which every cross-group pair is ordered with probability >= "
    "1 - alpha) the posterior of the magnitude is the prior's (its scale or bounds), not the data's. min|w_p| is a "
    "scale at which the rankings are explained, not an estimate of the true penalty; 0 means the rankings are "
    "explained without the penalty. Report the selected set (P(c=1)) and min|w_p|, not the posterior mean or "
    "interval of the magnitude; margins move the lower bound only, they do not fix the scale. A candidate that is "
    "not identifiable (e.g. constant across trajectories, or collinear with others) has a posterior that is only "
    "the prior: drop it from the candidates (or keep one of a dependent set).")
"""The long explanation behind the one-line identification warnings, given once (``summary.json``:
``identified.explanation``; the README's *What the rankings identify*)."""


def _direction_text(d: Mapping[str, float]) -> str:
    return ", ".join(f"{n} {v:+.3g}" for n, v in d.items())


def _finite_or_none(v: float) -> float | None:
    return float(v) if math.isfinite(v) else None


# ---------------------------------------------------------------------------------------------- LPs
@functools.lru_cache(maxsize=1)
def _c_fflush() -> Any:
    """The C library's ``fflush`` (opened once: a model is made per LP slot and working set), or None."""
    import ctypes

    try:
        return ctypes.CDLL(None).fflush
    except (OSError, AttributeError):  # no C library by that name: nothing buffered to lose
        return None


def _quiet_highs(hs: Any) -> Any:
    """``hs.Highs()`` with its output off. HiGHS >= 1.16 prints a banner on stdout when the object is made,
    before any option can be set: that would corrupt a command's ``--json`` output (and a child process's pipe),
    so the process's file descriptor 1 points at ``/dev/null`` while it is made (C stdio flushed before it
    returns)."""
    sys.stdout.flush()
    saved = os.dup(1)
    try:
        with open(os.devnull, "wb") as null:
            os.dup2(null.fileno(), 1)
            try:
                h = hs.Highs()
                h.setOptionValue("output_flag", False)
            finally:
                flush = _c_fflush()
                if flush is not None:
                    flush(None)
                os.dup2(saved, 1)
    finally:
        os.close(saved)
    return h


class _LPSolver:
    """``min c @ x`` s.t. ``A @ x <= b``, ``lb <= x <= ub`` with HiGHS.

    With the optional ``highspy`` package (``pip install highspy``) every *slot* (one kind of LP: the per-feature
    recession LPs, the sparsest directions, the ends of the separating set) keeps one HiGHS model; the next LP of that
    slot is passed as the changes from the last one (an objective entry, a bound, a coefficient of an extra row), and
    HiGHS starts from the last optimal basis, a few simplex iterations instead of a solve from scratch. Without
    ``highspy``, or for an LP without a slot, or when a warm solve ends in anything but optimal or infeasible, each LP
    is solved on its own by :func:`scipy.optimize.linprog` (the HiGHS that SciPy ships). Both give the same optimal
    values; where an LP has several optimal vertices they may return different ones.
    """

    def __init__(self, warm: bool | None = None) -> None:
        hs = None
        if warm is None or warm:
            try:
                import highspy as hs
            except ImportError:
                if warm:
                    raise
        self._hs = hs
        self._models: dict[str, list[Any]] = {}
        self.reduced_costs: NDArray[np.float64] | None = None  # of the last optimal LP

    @property
    def warm(self) -> bool:
        """Whether LPs with a slot reuse a HiGHS model (``highspy`` installed)."""
        return self._hs is not None

    def drop(self, *slots: str) -> None:
        """Free the models of ``slots`` (a phase is over): each holds a copy of the LP's rows, 6 million non-zeros
        with 10,000 dense features."""
        for slot in slots:
            self._models.pop(slot, None)

    def solve(self, slot: str | None, c: NDArray[np.float64], A: Any, b: NDArray[np.float64], lb: NDArray[np.float64],
              ub: NDArray[np.float64], extra: Any = None, extra_b: NDArray[np.float64] | None = None
              ) -> tuple[int, NDArray[np.float64] | None, str]:
        """``(status, x, message)``; status as :func:`scipy.optimize.linprog` (0 optimal, 2 infeasible). ``A`` (csr)
        is reused between calls (the working set's rows: the same object until the set grows), ``extra`` (csr) are the
        rows that change from one LP to the next."""
        if self._hs is not None:
            # an LP without a slot gets a model of its own, dropped after: with highspy no LP goes through
            # scipy.optimize.linprog, whose import costs 0.6-0.75 s of every `pbicrl infer`
            key = slot if slot is not None else "\0once"
            out = self._solve_warm(key, c, A, b, lb, ub, extra, extra_b)
            if slot is None or out is None:
                self._models.pop(key, None)  # anything unusual: solve from scratch, and rebuild the model next time
            if out is not None:
                return out
        from scipy.optimize import linprog
        from scipy.sparse import vstack

        if extra is not None:
            A = vstack([A, extra], format="csr")
            b = np.concatenate([b, extra_b])
        bnd = np.column_stack([np.where(np.isinf(lb), None, lb), np.where(np.isinf(ub), None, ub)])
        res = linprog(c, A_ub=A, b_ub=b, bounds=bnd, method="highs")
        self.reduced_costs = None
        if res.status == 0:
            self.reduced_costs = np.asarray(res.lower.marginals) + np.asarray(res.upper.marginals)
        return int(res.status), (res.x if res.status == 0 else None), str(res.message)

    def _solve_warm(self, slot: str, c: NDArray[np.float64], A: Any, b: NDArray[np.float64], lb: NDArray[np.float64],
                    ub: NDArray[np.float64], extra: Any, extra_b: NDArray[np.float64] | None
                    ) -> tuple[int, NDArray[np.float64] | None, str] | None:
        from scipy.sparse import csr_matrix

        hs = self._hs
        E = csr_matrix((0, A.shape[1])) if extra is None else csr_matrix(extra)
        e = np.zeros(0) if extra_b is None else np.asarray(extra_b, dtype=np.float64)
        m = self._models.get(slot)
        if m is None or m[1] is not A or m[2].shape != E.shape:
            from scipy.sparse import vstack

            full = vstack([A, E], format="csr")
            full.sort_indices()
            h = _quiet_highs(hs)
            lp = hs.HighsLp()
            lp.num_col_, lp.num_row_ = full.shape[1], full.shape[0]
            lp.col_cost_, lp.col_lower_, lp.col_upper_ = c, lb, ub
            lp.row_lower_ = np.full(full.shape[0], -np.inf)
            lp.row_upper_ = np.concatenate([b, e])
            lp.a_matrix_.format_ = hs.MatrixFormat.kRowwise
            lp.a_matrix_.num_col_, lp.a_matrix_.num_row_ = full.shape[1], full.shape[0]
            lp.a_matrix_.start_, lp.a_matrix_.index_, lp.a_matrix_.value_ = full.indptr, full.indices, full.data
            if h.passModel(lp) == hs.HighsStatus.kError:  # kWarning: entries below 1e-9 dropped, as linprog does
                return None
            m = [h, A, E, c.copy(), lb.copy(), ub.copy(), np.concatenate([b, e])]
            self._models[slot] = m
        else:
            h, _, E0, c0, lb0, ub0, r0 = m
            D = (E - E0).tocoo()
            if D.nnz:  # coefficients of the extra rows that changed (or appeared, or went to 0)
                vals = np.asarray(E[D.row, D.col]).ravel()
                for i, j, v in zip((D.row + A.shape[0]).tolist(), D.col.tolist(), vals.tolist()):
                    h.changeCoeff(i, j, v)
            k = np.flatnonzero(c != c0)
            if k.size:
                h.changeColsCost(k.size, k.astype(np.int32), c[k])
            k = np.flatnonzero((lb != lb0) | (ub != ub0))
            if k.size:
                h.changeColsBounds(k.size, k.astype(np.int32), lb[k], ub[k])
            r = np.concatenate([b, e])
            k = np.flatnonzero(r != r0)
            if k.size:
                h.changeRowsBounds(k.size, k.astype(np.int32), np.full(k.size, -np.inf), r[k])
            m[2:] = [E, c.copy(), lb.copy(), ub.copy(), r]
        h.run()
        st = h.getModelStatus()
        if st == hs.HighsModelStatus.kOptimal:
            sol = h.getSolution()
            self.reduced_costs = np.asarray(sol.col_dual, dtype=np.float64)
            return 0, np.asarray(sol.col_value, dtype=np.float64), "optimal"
        if st == hs.HighsModelStatus.kInfeasible:
            return 2, None, "infeasible"
        return None


class _GroupLP:
    r"""Cutting-plane LPs over group extremes.

    Variables ``z = [w (p), u (K), v (K), t, a (p)]`` (``n_var`` of them, what callers index): standardised
    penalties (or a recession direction), lower bounds :math:`u_k \le \min_{\mathcal{G}_k}` and upper bounds
    :math:`v_k \ge \max_{\mathcal{G}_k}` of the returns, a free scalar ``t`` and auxiliaries ``a`` (for absolute
    values). Rows are :math:`u_k \le c_i + X_i w` and :math:`v_k \ge c_i + X_i w` for trajectories in a working set,
    plus the group ordering :math:`u_k - v_\ell \ge g_{k\ell}` for :math:`k < \ell`. Only a few trajectories per
    group are extreme at the optimum, so the working set starts from per-group extremes and grows by the extremes
    of the current solution until the solution is feasible for all ``N`` trajectories; that makes it the optimum of
    the full LP (the relaxation is a superset of the full feasible set) and the LP stays small for any ``N``.

    The ordering rows take one of two forms:

    * **additive** margins (``shift`` given): :math:`g_{k\ell} = s_\ell - s_k + b` with :math:`s_k = o_k/\beta` and
      :math:`b` = ``base`` :math:`\ge 0` (:math:`\operatorname{logit}(1-\alpha)/\beta` with :math:`\alpha \le 1/2`, or 0
      for the recession cone). Adjacent groups suffice: :math:`u_k + s_k \ge v_{k+1} + s_{k+1} + b` for every
      :math:`k` chains, through :math:`v_j \ge u_j`, to :math:`u_k + s_k \ge v_\ell + s_\ell + (\ell - k) b \ge
      v_\ell + s_\ell + b` for every :math:`k < \ell`. So K - 1 rows instead of K(K-1)/2 (a total ranking of
      20,000 groups would need 2e8), with the same feasible penalties;
    * a general K x K ``gaps`` matrix: one row per group pair (K is then small: the matrix was given as such).

    A group of one trajectory needs no bound variables: :math:`u_k = v_k = c_i + X_i w` is substituted into its
    ordering rows (a total ranking then has only the penalties as variables). The LP solved has the remaining
    columns; :meth:`solve` takes and returns the full layout (a single member's ``u_k``, ``v_k`` = its return).
    Rows are assembled as a sparse matrix, so neither form holds anything of size K x K beyond a given matrix.
    """

    def __init__(self, X: NDArray[np.float64], c: NDArray[np.float64], starts: NDArray[np.int64], *,
                 gaps: NDArray[np.float64] | None = None, shift: NDArray[np.float64] | None = None,
                 base: float = 0.0, warm: bool | None = None) -> None:
        if (gaps is None) == (shift is None):
            raise ValueError("_GroupLP: give either gaps (K x K) or shift (K) with base")
        if shift is not None and not base >= 0.0:
            raise ValueError("_GroupLP: adjacent ordering rows need base >= 0")
        self.X, self.c, self.starts = X, c, starts
        self.x_max = float(np.max(np.abs(X), initial=0.0))
        from scipy.sparse import csr_matrix

        # Products with X in the cutting-plane loop go through scipy.sparse, not BLAS: OpenBLAS's threads, woken by a
        # product of a few hundred rows, spin afterwards and took the solver's core on a loaded machine (3x slower).
        self._Xs = csr_matrix(X)
        self._absXs = abs(self._Xs)
        self.gaps, self.shift, self.base = gaps, shift, float(base)
        self.N, self.p = X.shape
        self.K = starts.size - 1
        self.n_var = 2 * self.p + 2 * self.K + 1
        self.n_lp = 0
        self.in_work = np.zeros(self.N, dtype=bool)
        self.work: list[int] = []
        sizes = np.diff(starts)
        self.group_of = np.repeat(np.arange(self.K), sizes)
        self.single = sizes == 1
        self.member = starts[:-1]                       # the member of a single-trajectory group
        self.in_work[self.member[self.single]] = True   # always in the LP, through the substitution
        keep = np.ones(self.n_var, dtype=bool)
        keep[self.p + np.flatnonzero(self.single)] = False
        keep[self.p + self.K + np.flatnonzero(self.single)] = False
        self.keep = np.flatnonzero(keep)               # LP columns, as indices of the full layout
        self.col = np.full(self.n_var, -1, dtype=np.int64)
        self.col[self.keep] = np.arange(self.keep.size)
        if shift is not None:
            # (k, l) = (k, k + 1) and g_k = s_{k+1} - s_k + b
            self.pair_k = np.arange(self.K - 1)
            self.pair_l = self.pair_k + 1
            self.pair_gap = shift[1:] - shift[:-1] + self.base
            self.gap_max = self._additive_gap_max(shift, self.base)
        else:
            self.pair_k, self.pair_l = np.triu_indices(self.K, 1)
            self.pair_gap = gaps[self.pair_k, self.pair_l]
            self.gap_max = float(np.max(np.abs(gaps), initial=0.0))
        self._order_rows = self._ordering_rows()
        self._rows_cache: tuple[int, bool, Any] | None = None
        self.solver = _LPSolver(_WARM if warm is None else warm)
        self.reduced_costs = np.zeros(self.n_var)  # of the last solve's optimum (full layout)
        self._seed()

    @staticmethod
    def _additive_gap_max(shift: NDArray[np.float64], base: float) -> float:
        """max |g_kl| over the K x K gap matrix as the dense form builds it (b below the diagonal), in O(K): the
        solver tolerance scales with it, as it did when every pair had a row."""
        d_hi = shift[1:] - np.minimum.accumulate(shift)[:-1]  # max_{k<l} (s_l - s_k) for each l
        d_lo = shift[1:] - np.maximum.accumulate(shift)[:-1]
        return float(max(abs(base), abs(d_hi.max() + base), abs(d_lo.min() + base)))

    # -- working set
    def _seed(self) -> None:
        """Each group's extremes of the nominal returns, then of every standardised feature (both signs), then of
        the nominal returns plus or minus each feature: per column at once, O(N p), in the order in which one
        probe after the other would add them."""
        self._add_extremes(self.c)
        if not self.p:
            return
        multi = np.flatnonzero(~self.single)
        if multi.size == 0:  # every group is one trajectory, always in the LP
            return
        for add_c in (False, True):
            parts = []
            for sgn in (1.0, -1.0):
                step = max(1, (1 << 24) // max(1, self.N))  # columns per chunk: the N x chunk arrays stay ~100 MB
                lo_hi = []
                for j0 in range(0, self.p, step):
                    M = sgn * self.X[:, j0:j0 + step]
                    if add_c:
                        M = M + self.c[:, None]
                    lo_hi.append(np.stack([self._segment_arg_cols(M, np.minimum),
                                           self._segment_arg_cols(M, np.maximum)], axis=0))  # (2, K, chunk)
                parts.append(np.concatenate(lo_hi, axis=2))
            # probe order: feature j with +1 then -1; within a probe, group by group: argmin, argmax
            arr = np.stack(parts, axis=0)                  # (sign, min/max, K, p)
            cand = arr.transpose(3, 0, 2, 1)[:, :, multi, :].ravel()
            _, first = np.unique(cand, return_index=True)
            new = cand[np.sort(first)]
            new = new[~self.in_work[new]]
            self.in_work[new] = True
            self.work.extend(new.tolist())

    def _segment_arg_cols(self, M: NDArray[np.float64], reduce: np.ufunc) -> NDArray[np.int64]:
        """First row index of each group's min (``np.minimum``) or max in every column of ``M``: (K, columns)."""
        ext = reduce.reduceat(M, self.starts[:-1], axis=0)
        idx = np.where(M == ext[self.group_of], np.arange(self.N)[:, None], self.N)
        out = np.minimum.reduceat(idx, self.starts[:-1], axis=0)
        return np.where(out == self.N, self.starts[:-1, None], out)  # a NaN extreme: the group's first member

    def _segment_arg(self, r: NDArray[np.float64], reduce: np.ufunc) -> NDArray[np.int64]:
        """First index of each group's min (``np.minimum``) or max, as ``np.argmin``/``argmax`` per segment."""
        ext = reduce.reduceat(r, self.starts[:-1])
        hit = np.flatnonzero(r == ext[self.group_of])
        g = self.group_of[hit]
        first = np.ones(hit.size, dtype=bool)
        first[1:] = g[1:] != g[:-1]
        out = self.starts[:-1].copy()  # a group whose extreme is NaN: its first member
        out[g[first]] = hit[first]
        return out

    def _add_extremes(self, r: NDArray[np.float64]) -> int:
        # per group: argmin, then argmax (the order in which a loop over the groups would add them)
        cand = np.column_stack([self._segment_arg(r, np.minimum), self._segment_arg(r, np.maximum)]).ravel()
        _, first = np.unique(cand, return_index=True)
        keep = np.zeros(cand.size, dtype=bool)
        keep[first] = True
        new = cand[keep & ~self.in_work[cand]]
        self.in_work[new] = True
        self.work.extend(new.tolist())
        return int(new.size)

    def _ordering_rows(self) -> tuple[Any, NDArray[np.float64], NDArray[np.float64]]:
        """Sparse rows ``v_l - u_k <= -g_kl`` of the group pairs (adjacent ones for additive margins) over the LP's
        columns, with the right-hand sides of the inhomogeneous and of the homogeneous LP."""
        from scipy.sparse import coo_matrix

        p, K = self.p, self.K
        k, l = self.pair_k, self.pair_l
        n = k.size
        r_parts, c_parts, v_parts = [], [], []
        rhs = -self.pair_gap.astype(np.float64, copy=True)
        rhs_h = np.zeros(n)
        for side, grp, sign in (("u", k, -1.0), ("v", l, 1.0)):
            one = self.single[grp]
            rows = np.flatnonzero(~one)                   # a bound variable: +-1
            r_parts.append(rows)
            c_parts.append(self.col[(p if side == "u" else p + K) + grp[rows]])
            v_parts.append(np.full(rows.size, sign))
            rows = np.flatnonzero(one)                    # the member's return c_i + X_i w: +-X_i, c_i to the rhs
            m = self.member[grp[rows]]
            r_parts.append(np.repeat(rows, p))
            c_parts.append(np.tile(np.arange(p), rows.size))
            v_parts.append((sign * self.X[m]).ravel())
            rhs[rows] -= sign * self.c[m]
        vals = np.concatenate(v_parts)
        nz = vals != 0.0  # sparse features stay sparse
        A = coo_matrix((vals[nz], (np.concatenate(r_parts)[nz], np.concatenate(c_parts)[nz])),
                       shape=(n, self.keep.size)).tocsr()
        return A, rhs, rhs_h

    def rows_nnz(self, homogeneous: bool) -> int:
        """Non-zeros of the working set's and the ordering rows (what an LP over them holds)."""
        return int(self._rows(homogeneous)[0].nnz)

    def _rows(self, homogeneous: bool) -> tuple[Any, NDArray[np.float64]]:
        """The working set's rows and the ordering rows, and their right-hand sides (cached until the set grows)."""
        key = (len(self.work), homogeneous)
        if self._rows_cache is not None and self._rows_cache[:2] == key:
            return self._rows_cache[2]
        out = self._build_rows(homogeneous)
        self._rows_cache = (*key, out)
        return out

    def _build_rows(self, homogeneous: bool) -> tuple[Any, NDArray[np.float64]]:
        from scipy.sparse import coo_matrix, vstack

        idx = np.asarray(self.work, dtype=np.int64)
        g = self.group_of[idx]
        n, p, K = idx.size, self.p, self.K
        ci = np.zeros(n) if homogeneous else self.c[idx]
        r = np.arange(n)
        # u_k - X_i w <= c_i  and  X_i w - v_k <= -c_i: p + 1 entries per row (groups of two or more only)
        Xw = self.X[idx]
        rows = np.concatenate([np.repeat(r, p), r, np.repeat(n + r, p), n + r])
        cols = np.concatenate([np.tile(np.arange(p), n), self.col[p + g], np.tile(np.arange(p), n),
                               self.col[p + K + g]])
        vals = np.concatenate([-Xw.ravel(), np.ones(n), Xw.ravel(), -np.ones(n)])
        nz = vals != 0.0  # sparse features (indicators, cells) stay sparse for the solver
        work = coo_matrix((vals[nz], (rows[nz], cols[nz])), shape=(2 * n, self.keep.size))
        A_ord, b_ord, b_hom = self._order_rows
        A = vstack([work, A_ord], format="csr")
        b = np.concatenate([ci, -ci, b_hom if homogeneous else b_ord])
        return A, b

    def _violated(self, w: NDArray[np.float64], homogeneous: bool, tol: float) -> bool:
        r = self._Xs @ w if homogeneous else self.c + self._Xs @ w
        lo = np.minimum.reduceat(r, self.starts[:-1])
        hi = np.maximum.reduceat(r, self.starts[:-1])
        need = 0.0 if homogeneous else self.pair_gap
        bad = bool(np.any(lo[self.pair_k] - hi[self.pair_l] < need - tol))
        if bad and self._add_extremes(r) == 0:
            return False  # the extremes are already rows: the residual violation is solver tolerance
        return bad

    # -- solve
    def solve(self, objective: NDArray[np.float64], bounds: list[tuple[float | None, float | None]], *,
              homogeneous: bool, extra_A: NDArray[np.float64] | Any | None = None,
              extra_b: NDArray[np.float64] | None = None, slot: str | None = None) -> NDArray[np.float64] | None:
        """Minimise ``objective @ z``; ``None`` if infeasible. ``bounds`` cover all ``n_var`` variables; ``extra_A``
        (dense or sparse) adds rows ``extra_A @ z <= extra_b``. LPs of one ``slot`` (same kind, differing in a few
        entries) warm-start one another (:class:`_LPSolver`)."""
        from scipy.sparse import csr_matrix

        # callers never weight the bound variables of single-trajectory groups (they are not LP columns)
        extra = None if extra_A is None else csr_matrix(extra_A)[:, self.keep]
        obj = np.asarray(objective, dtype=np.float64)[self.keep]
        lb = np.array([-np.inf if bounds[i][0] is None else bounds[i][0] for i in self.keep], dtype=np.float64)
        ub = np.array([np.inf if bounds[i][1] is None else bounds[i][1] for i in self.keep], dtype=np.float64)
        while True:
            A, b = self._rows(homogeneous)
            status, z, message = self.solver.solve(slot, obj, A, b, lb, ub, extra, extra_b)
            self.n_lp += 1
            if status == 2:
                return None  # a relaxation is infeasible, hence the full problem too
            if status != 0 or z is None:
                raise RuntimeError(f"identify: LP solver failed ({message})")
            w = z[:self.p]
            if homogeneous:  # |w| <= 1 (the recession box)
                tol = 1e-7 * (1.0 + float(np.max(np.abs(w), initial=0.0)) * self.x_max)
            else:
                # The solver's tolerance on the data's scale, plus the rounding of returns c + X w: where a penalty sits
                # at the box (+-1e10, a companion of an unbounded one) 1e-7 |w| would let violations of 1e3 pass and
                # stop the cutting planes short of the optimum (a wrong end of S_alpha).
                big = float(np.max(self._absXs @ np.abs(w), initial=0.0)) if self.p else 0.0
                tol = 1e-7 * (1.0 + float(np.max(np.abs(self.c), initial=0.0)) + self.gap_max) + 1e-13 * big
            if not self._violated(w, homogeneous, tol):
                x = np.zeros(self.n_var)
                x[self.keep] = z
                self.reduced_costs = np.zeros(self.n_var)
                if self.solver.reduced_costs is not None:
                    self.reduced_costs[self.keep] = self.solver.reduced_costs
                one = np.flatnonzero(self.single)
                ret = self._Xs[self.member[one]] @ w + (0.0 if homogeneous else self.c[self.member[one]])
                x[self.p + one] = ret
                x[self.p + self.K + one] = ret
                return x


# ---------------------------------------------------------------------------------------------- inputs
def _resolve_candidates(dataset: Dataset, candidates: Sequence[str | int] | None,
                        cset: ConstraintSet | None) -> tuple[int, ...]:
    """Indices of the known features that may carry a penalty (constraint names are accepted and skipped)."""
    d = dataset.n_features
    names = list(dataset.feature_names) + (list(cset.names) if cset is not None else [])
    if candidates is None:
        # As pbicrl.infer: with parametric constraints only those are candidates (paper Algorithm 2).
        return () if cset is not None else tuple(range(d))
    if isinstance(candidates, (str, bytes)) or not isinstance(candidates, Sequence):
        raise IdentifyError(f"candidates: expected a list of feature names or indices, got {candidates!r}")
    out: list[int] = []
    for c in candidates:
        if isinstance(c, (int, np.integer)) and not isinstance(c, (bool, np.bool_)):
            j = int(c)
        elif isinstance(c, str) and c.isdigit():
            j = int(c)
        elif isinstance(c, str):
            if c not in names:
                raise IdentifyError(f"candidates: unknown feature '{c}'; features are {names}")
            j = names.index(c)
        else:
            raise IdentifyError(f"candidates: expected feature names or indices, got {c!r}")
        if not 0 <= j < len(names):
            raise IdentifyError(f"candidates: index {j} out of range [0, {len(names)})")
        if j in out:
            raise IdentifyError(f"candidates: '{names[j]}' listed twice")
        out.append(j)
    if not out:
        raise IdentifyError("candidates: empty; name at least one feature that may be a constraint")
    return tuple(j for j in out if j < d)


def _constraint_set(dataset: Dataset, constraints: Any) -> ConstraintSet | None:
    if constraints is None:
        return None
    if isinstance(constraints, ConstraintSet):
        if constraints.dataset is not dataset and (
                constraints.dataset.n_trajectories != dataset.n_trajectories
                or constraints.dataset.states is None or dataset.states is None
                or constraints.dataset.states.shape != dataset.states.shape
                or not np.array_equal(constraints.dataset.offsets, dataset.offsets)):
            raise IdentifyError("constraints: the ConstraintSet is bound to a different dataset")
        return constraints
    if isinstance(constraints, (Constraint, dict)):
        constraints = [constraints]
    if not isinstance(constraints, Sequence) or isinstance(constraints, (str, bytes)):
        raise IdentifyError("constraints: expected a ConstraintSet or a list of constraints, got "
                            f"{type(constraints).__name__}")
    if len(constraints) == 0:
        return None
    items = []
    for c in constraints:
        if isinstance(c, Constraint):
            items.append(c)
        elif isinstance(c, dict):
            items.append(constraint_from_dict(c))
        else:
            raise IdentifyError(f"constraints: expected Constraint objects or dicts, got {type(c).__name__}")
    return ConstraintSet(tuple(items), dataset)


def _check_scalar(name: str, value: Any, lo: float, hi: float, *, lo_open: bool, hi_open: bool) -> float:
    if isinstance(value, (bool, np.bool_)):
        raise IdentifyError(f"{name}: expected a number, got {value!r}")
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise IdentifyError(f"{name}: expected a number, got {value!r}") from None
    ok = math.isfinite(x) and (x > lo if lo_open else x >= lo) and (x < hi if hi_open else x <= hi)
    if not ok:
        span = f"{'(' if lo_open else '['}{lo:g}, {hi:g}{')' if hi_open else ']'}"
        raise IdentifyError(f"{name}: must lie in {span}, got {value!r}")
    return x


# ---------------------------------------------------------------------------------------------- thresholds
def threshold_interval(dataset: Dataset, constraint: AxisHalfspace, *, name: str | None = None,
                       prior_bounds: tuple[float, float] | None = None) -> ParameterInterval:
    r"""Threshold interval of an axis half-space identified by the ranking.

    Let :math:`x` be the constrained state coordinate, :math:`\mathcal{G}_1` the best group and :math:`W` the
    trajectories of all worse groups. The best group is taken not to enter the region and worse trajectories
    that enter it are explained by it:

    * ``">="`` (region :math:`x \ge \vartheta`, a wall crossed by going *up*): :math:`\mathcal{G}_1` stays out
      iff :math:`\vartheta > a = \max_{s \in \mathcal{G}_1} x(s)`, the furthest coordinate it reaches. The violating
      trajectories :math:`V` are those of :math:`W` that reach beyond :math:`a`; each enters the region iff
      :math:`\vartheta \le \max_{s\in\tau} x(s)`, so all of them do iff :math:`\vartheta \le b =
      \min_{\tau \in V} \max_{s \in \tau} x(s)` (the nearest violating reach). Interval :math:`(a, b]`.
    * ``"<="`` (region :math:`x \le \vartheta`): mirrored, :math:`b = \min_{s \in \mathcal{G}_1} x(s)`,
      :math:`V` the worse trajectories going below :math:`b`, :math:`a = \max_{\tau \in V} \min_{s \in \tau}
      x(s)`. Interval :math:`[a, b)`.

    Within the interval the best group never violates and every trajectory of :math:`V` does; outside it
    either a best-group state is inside the region or a violating trajectory no longer touches it. Worse
    trajectories not in :math:`V` (``n_worse - n_violating``) are not explained by this constraint at any
    threshold that keeps the best group out. When :math:`V` is empty there is no interval.

    Parameters
    ----------
    dataset : Dataset
        Must have ``states``.
    constraint : AxisHalfspace
    name : str, optional
        Parameter name (default ``"<constraint>.threshold"``).
    prior_bounds : (low, high), optional
        The sampler's uniform bounds on the threshold; a note is added when the interval misses them.

    Returns
    -------
    ParameterInterval
    """
    pname = name or f"{constraint.name}.threshold"
    if dataset.states is None:
        raise IdentifyError("constraints: the dataset has no states; parametric constraints are defined on states")
    x = dataset.states[:, constraint.dims[0]]
    starts = dataset.offsets[:-1]
    best = dataset.group == dataset.group_labels[0]
    worse = ~best
    ge = constraint.direction == ">="
    # Per-trajectory reach towards the region: the max coordinate for ">=", the min for "<=".
    reach = np.maximum.reduceat(x, starts) if ge else np.minimum.reduceat(x, starts)
    frontier = float(reach[best].max()) if ge else float(reach[best].min())
    viol = worse & ((reach > frontier) if ge else (reach < frontier))
    per_group = {int(k): int(np.sum(viol & (dataset.group == k))) for k in dataset.group_labels[1:]}
    common = dict(name=pname, constraint=constraint.name, family=constraint.family,
                  n_violating=int(viol.sum()), n_worse=int(worse.sum()), violating_per_group=per_group)
    side = "beyond" if ge else "below"
    if not viol.any():
        return ParameterInterval(low=None, high=None, reason=(
            f"no trajectory of a worse group reaches {side} the best group's furthest coordinate "
            f"x[{constraint.dims[0]}] = {frontier:.6g}; the ranking does not place this constraint"), **common)
    if ge:
        low, high, lc, hc = frontier, float(reach[viol].min()), False, True
        why = (f"threshold > {low:.6g} keeps every best-group state out of x >= threshold; threshold <= {high:.6g} "
               "puts at least one state of every violating worse trajectory in")
    else:
        low, high, lc, hc = float(reach[viol].max()), frontier, True, False
        why = (f"threshold < {high:.6g} keeps every best-group state out of x <= threshold; threshold >= {low:.6g} "
               "puts at least one state of every violating worse trajectory in")
    unexplained = int(worse.sum() - viol.sum())
    if unexplained:
        why += f"; {unexplained} worse trajectories never cross the best group's frontier (not explained by it)"
    if prior_bounds is not None and (high < prior_bounds[0] or low > prior_bounds[1]):
        why += f"; NOTE the interval lies outside the prior bounds [{prior_bounds[0]:g}, {prior_bounds[1]:g}]"
    return ParameterInterval(low=low, high=high, low_closed=lc, high_closed=hc, reason=why, **common)


# ---------------------------------------------------------------------------------------------- main
_PROGRESS_DELAY_S = 2.0
# identify(companions=None) finds the sparsest companions of unbounded penalties (w_p <= 0) for at most this many
# unbounded penalties, and only when their number times the non-zeros of the LP's rows is at most _COMPANION_WORK: one
# warm-started LP each, 2-20 ms with a few hundred trajectories (one-hot cells to 100 dense features), 60 ms with
# 300 dense ones (benchmarks/reports/identify.md).
_COMPANION_MAX = 200
_COMPANION_WORK = 2e7


class _Progress:
    """A tqdm bar on stderr (or nothing) that appears once the analysis started at ``t0`` (``time.perf_counter``)
    has run :data:`_PROGRESS_DELAY_S` seconds, so a quick analysis prints nothing and a long one shows each phase.
    A thread redraws it every second, so its clock runs while a single LP takes long (10,000 dense features: 15 s
    per LP; HiGHS releases the GIL while it solves)."""

    def __init__(self, enabled: bool, what: str, total: int | None = None, unit: str = "feature",
                 t0: float | None = None, into: list["_Progress"] | None = None) -> None:
        self.bar = None
        if into is not None:
            into.append(self)
        self._stop = threading.Event()
        self._ticker: threading.Thread | None = None
        if enabled:
            from tqdm import tqdm

            waited = 0.0 if t0 is None else time.perf_counter() - t0
            delay = max(0.0, _PROGRESS_DELAY_S - waited)
            self.bar = tqdm(desc=what, total=total, unit=unit, delay=delay, leave=False, dynamic_ncols=True)
            self._ticker = threading.Thread(target=self._redraw, args=(delay,), daemon=True)
            self._ticker.start()

    def _redraw(self, delay: float) -> None:
        if self._stop.wait(delay):
            return
        while self.bar is not None and not self._stop.wait(1.0):
            self.bar.refresh()

    def step(self, n: int = 1) -> None:
        if self.bar is not None:
            self.bar.update(n)

    def close(self) -> None:
        self._stop.set()
        if self._ticker is not None:
            self._ticker.join()
        if self.bar is not None:
            self.bar.close()


def _shifted(F: NDArray[np.float64], spread: NDArray[np.float64]) -> NDArray[np.float64]:
    """Columns of ``F`` over their ``spread``, shifted by 0 where the column's range contains 0 and by the column's
    minimum otherwise: every entry in [-1, 1], and a zero of ``F`` stays an exact zero."""
    lo, hi = F.min(axis=0), F.max(axis=0)
    shift = np.where((lo <= 0.0) & (hi >= 0.0), 0.0, lo)
    return np.ascontiguousarray((F - shift) / spread)


_FLAT_PARTNERS_SHOWN = 20  # partners listed per affinely dependent feature (with more features than trajectories
# every feature depends on nearly every other: the full lists would be p^2 names)


def _flat_partners(X: NDArray[np.float64]) -> dict[int, tuple[list[int], bool]]:
    """Affinely dependent columns of the centred, standardised mean features ``X`` (N, p).

    Returns, for every column ``a`` with a null direction through it, the first :data:`_FLAT_PARTNERS_SHOWN`
    columns ``b`` (``a`` included, in column order) with :math:`|P_{ab}| > 10^{-8}`, :math:`P` the projector on the
    null space of ``X``, and whether there are more. :math:`P` is built a tile at a time, from the null vectors or as
    :math:`I - V_r V_r^\\top` from the row space, whichever is thinner, so nothing p x p is held.
    """
    N, p = X.shape
    if not p:
        return {}
    if N >= p:
        # X and its triangular factor R have the same singular values and right vectors; R is p x p, so the SVD
        # costs nothing and the QR is one O(N p^2) pass without forming Q.
        _, sv, vt = np.linalg.svd(np.linalg.qr(X, mode="r"))
    else:
        # X^T = Q R (Householder, p x N), R^T = U S W^T, so X = U S (Q W)^T: the thin SVD from an N x N one, 20-50x
        # faster than LAPACK's on the wide matrix when OpenBLAS shares a loaded machine; the other p - N values are 0.
        q, r = np.linalg.qr(X.T)
        _, sv, wt = np.linalg.svd(r.T)
        vt = wt @ q.T
        sv = np.concatenate([sv, np.zeros(p - N)])
    tol = sv.max() * max(X.shape) * np.finfo(float).eps
    rank = int(np.sum(sv[:vt.shape[0]] > tol))
    if rank == p:
        return {}
    if N >= p and p - rank <= rank:  # few null directions: P = Z Z^T
        Z = vt[rank:].T
        diag = np.einsum("ij,ij->i", Z, Z)

        def tile(A: NDArray[np.int64], B: NDArray[np.int64]) -> NDArray[np.float64]:
            return Z[A] @ Z[B].T
    else:  # many: P = I - V_r V_r^T
        V = vt[:rank].T
        diag = 1.0 - np.einsum("ij,ij->i", V, V)

        def tile(A: NDArray[np.int64], B: NDArray[np.int64]) -> NDArray[np.float64]:
            return (A[:, None] == B[None, :]).astype(np.float64) - V[A] @ V[B].T
    out: dict[int, tuple[list[int], bool]] = {}
    rows = np.flatnonzero(diag > 1e-8)
    step = 512
    for r0 in range(0, rows.size, step):
        A = rows[r0:r0 + step]
        found: dict[int, list[int]] = {int(a): [] for a in A}
        more = dict.fromkeys(found, False)
        open_ = A
        for c0 in range(0, p, step):
            B = np.arange(c0, min(p, c0 + step))
            hit = np.abs(tile(open_, B)) > 1e-8
            for i, a in enumerate(open_.tolist()):
                bs = B[hit[i]].tolist()
                room = _FLAT_PARTNERS_SHOWN - len(found[a])
                if len(bs) > room:
                    more[a] = True
                found[a].extend(bs[:room])
            open_ = np.array([a for a in open_.tolist() if not more[a]], dtype=np.int64)
            if open_.size == 0:
                break
        out.update({a: (found[a], more[a]) for a in found})
    return out


def _recession_support(lp: "_GroupLP", p: int, K: int, free_uv: list, tick: _Progress,
                       gbar: NDArray[np.float64]) -> tuple[list[int], NDArray[np.float64] | None]:
    r"""The standardised features that some direction of the recession cone can move (penalties :math:`\le 0`).

    Every direction :math:`\delta` of the cone has :math:`\delta \le 0`, so :math:`\sum_{j \in R} -\delta_j` over
    :math:`\delta \in [-1, 0]^p` is at least :math:`-\delta'_j` for any single direction :math:`\delta'` and
    :math:`j \in R`: one LP finds features whose penalty can grow without bound, and repeating it over the rest
    until its optimum is below the threshold of the per-feature test certifies that no other one can. Only the
    features found get the per-feature LPs, so a dataset with no unbounded penalty costs one or two LPs instead
    of one per feature (the per-feature LPs decide exactly as before: this only skips those that must fail).

    Also returns the first of these directions that improves the ranking (:math:`\bar g^\top\delta > T_{min}`), or
    ``None``: without companions that is all :func:`identify` needs to know that every feature found is unbounded.
    """
    rest = np.ones(p, dtype=bool)
    found: list[int] = []
    improving = None
    bnd = [(-1.0, 0.0)] * p + free_uv + [(0.0, 0.0)] + [(0.0, 0.0)] * p
    while rest.any():
        obj = np.zeros(lp.n_var)
        obj[:p] = rest.astype(np.float64)  # minimise sum_R delta_j = maximise sum_R -delta_j
        x = lp.solve(obj, bnd, homogeneous=True, slot="support")
        tick.step()
        if x is None or -float(obj[:p] @ x[:p]) <= _T_MIN:
            break
        if improving is None and float(gbar @ x[:p]) > _T_MIN:
            improving = x[:p].copy()
        hit = np.flatnonzero(rest & (x[:p] < -_T_MIN / (2.0 * p)))
        if hit.size == 0:
            break
        rest[hit] = False
        found.extend(int(a) for a in hit)
    return sorted(found), improving


def _improving(lp: "_GroupLP", p: int, free_uv: list, gbar: NDArray[np.float64], neg: bool,
               tick: _Progress) -> NDArray[np.float64] | None:
    r"""Whether some direction of the recession cone improves the ranking (is not flat): :math:`\max \bar g^\top
    \delta > T_{min}` over the cone within the per-feature LPs' box.

    Each per-feature LP maximises :math:`t \le \bar g^\top\delta` over that box, so when this maximum is at most
    the threshold no penalty is unbounded and none of them needs solving (exact, not a heuristic). That is the
    usual case for rankings no direction orders, e.g. noisy ones, where the cone holds only flat directions (an
    affinely dependent set such as one-hot cells, whose fractions sum to 1), which move every feature they touch.

    Returns the maximiser (a direction of the cone in that box) when it improves, else ``None``.
    """
    obj = np.zeros(lp.n_var)
    obj[:p] = -gbar
    bnd = [((-1.0, 0.0) if neg else (-1.0, 1.0))] * p + free_uv + [(0.0, 0.0)] + [(0.0, 0.0)] * p
    x = lp.solve(obj, bnd, homogeneous=True)
    tick.step()
    return x[:p] if x is not None and float(gbar @ x[:p]) > _T_MIN else None


def identify(
    dataset: Dataset,
    *,
    nominal_weights: ArrayLike | None = None,
    beta: float = 1.0,
    margins: Margins | ArrayLike | None = None,
    alpha: float = 0.05,
    candidates: Sequence[str | int] | None = None,
    penalty_sign: PenaltySign = "negative",
    constraints: ConstraintSet | Sequence[Constraint | dict] | None = None,
    preferences: Preferences | None = None,
    pairs_seed: int | None = None,
    progress: bool = False,
    companions: bool | None = None,
) -> Identification:
    r"""Identifiability analysis of a ranked dataset, before sampling.

    Parameters
    ----------
    dataset : Dataset
        Ranked demonstrations; the mean features :math:`\bar\Phi` (N, d) and groups are used.
    nominal_weights : array-like, shape (d,), optional
        Known :math:`w_n`; default: the dataset's, else zeros (as :func:`pbicrl.infer`).
    beta : float
        Inverse temperature :math:`\beta > 0`.
    margins : Margins, K-1 gaps or K x K matrix, optional
        :math:`m_{k\ell}` (default 0), parsed by :meth:`pbicrl.inference.preferences.Margins.parse`.
    alpha : float
        Level in (0, 0.5]: every cross-group pair must be ordered with probability :math:`\ge 1-\alpha`.
        The separation scales depend on it (through :math:`\operatorname{logit}(1-\alpha)`); unboundedness
        does not.
    candidates : feature names or indices, optional
        Features that may carry a penalty; the others have :math:`w_p = 0`. Default as :func:`pbicrl.infer`:
        all known features, or none of them when parametric ``constraints`` are given (Algorithm 2).
        Names of parametric constraints are accepted (they do not enter the LPs).
    penalty_sign : {"negative", "any"}
        ``"negative"``: :math:`w_p \le 0` (constraints cost reward); ``"any"``: unrestricted.
    constraints : ConstraintSet or list of Constraint (or dicts), optional
        Parametric constraints; axis half-spaces get a threshold interval (:func:`threshold_interval`), other
        families an entry without interval and with a reason. Their penalties are not part of the LPs (their
        features depend on the unknown location).
    preferences : Preferences, optional
        The pairs the likelihood uses. With sampled pairs (``protocol`` not ``"all"``, ``--pairs N``) the
        analysis is of those pairs, not of every cross-group pair (:attr:`Identification.pairs` says which);
        ``None`` or all pairs: the groups. ``pairs_seed`` is only recorded.
    pairs_seed : int, optional
    progress : bool
        Show a progress bar on stderr when the analysis runs longer than a few seconds (many features).
    companions : bool, optional
        Whether to find, for every unbounded penalty, the sparsest set of penalties that must run off with it
        (:attr:`FeatureIdentification.recession`): one LP per unbounded feature. ``None`` (default): when that is
        cheap, for up to 200 unbounded penalties whose number times the non-zeros of the LP's rows is at most
        ``2e7`` (with many dense features each direction involves most features anyway). With ``False``, or
        ``None`` above that size, which penalties are unbounded is still decided exactly (from the shared LPs) and
        ``recession`` is empty (:attr:`Identification.companions` says so). With ``penalty_sign="any"`` the LP that
        decides whether a penalty is unbounded is the companions' LP, so they are always found.

    Returns
    -------
    Identification

    Raises
    ------
    IdentifyError, PreferenceError, ConstraintError
        With a message naming the offending argument.

    Notes
    -----
    Cost: a few shared LPs (with :math:`w_p \le 0`: the features some recession direction moves, whether any
    direction improves the ranking, the point of :math:`S_\alpha` with the smallest :math:`\sum_j |w_{p,j}|` and the
    like over the penalties not yet seen at 0), then at most one LP per candidate and way: the sparsest direction of
    an unbounded penalty (``companions``; with :math:`w_p \le 0` it only finds the companions, which penalties are
    unbounded is known from the shared LPs; with ``"any"`` it also decides it), and an end of :math:`w_{p,j}` over
    :math:`S_\alpha` that is neither infinite (unbounded) nor settled at 0 by a point found so far (no ends when the
    ranking is not separable). The sparsest direction asks for an improvement :math:`\bar g^\top\delta` of at least
    half of :math:`\min(1, g^*)`, :math:`g^*` the largest improvement over the cone in the unit box. Each LP is over
    ``p + 2K + 1 (+ p)`` variables (less two per single-trajectory group) and the rows of a small working set of
    extreme trajectories (cutting planes, exact at termination) plus the group-ordering rows: K - 1 for additive
    margins (zeros, gaps), K(K-1)/2 for a general matrix; every round checks all ``N`` trajectories in
    :math:`O(Np + K)`. Features enter the LPs shifted, not centred, so a sparse feature (an indicator, a cell
    fraction) keeps its zeros. With ``highspy`` installed (``pip install "pbicrl[lp]"``) the LPs of one kind are
    warm-started from the last basis; else each is solved by :func:`scipy.optimize.linprog`. Memory is O(N p + K)
    for additive margins: a total ranking of 20,000 trajectories takes a few seconds and tens of MB
    (``tests/analysis/test_identify.py``). 300 trajectories with 1,000 or 10,000 one-hot cell features take about a
    second, with 1,000 dense features under 10 s, with 10,000 dense ones (6 million non-zeros per LP) a minute or
    two (``benchmarks/reports/identify.md``).
    """
    bars: list[_Progress] = []
    try:
        return _identify(dataset, nominal_weights=nominal_weights, beta=beta, margins=margins, alpha=alpha,
                         candidates=candidates, penalty_sign=penalty_sign, constraints=constraints,
                         preferences=preferences, pairs_seed=pairs_seed, progress=progress, companions=companions,
                         bars=bars)
    finally:  # an error or Ctrl-C mid-way must not leave a bar's redraw thread printing
        for bar in bars:
            bar.close()


def _identify(dataset: Dataset, *, nominal_weights: ArrayLike | None, beta: float, margins: Margins | ArrayLike | None,
              alpha: float, candidates: Sequence[str | int] | None, penalty_sign: PenaltySign,
              constraints: ConstraintSet | Sequence[Constraint | dict] | None, preferences: Preferences | None,
              pairs_seed: int | None, progress: bool, companions: bool | None,
              bars: list[_Progress]) -> Identification:
    """The body of :func:`identify`; ``bars`` collects the progress bars it opens (the caller closes them)."""
    t0 = time.perf_counter()
    if not isinstance(dataset, Dataset):
        raise IdentifyError(f"dataset: expected a pbicrl.inference.data.Dataset, got {type(dataset).__name__}")
    if preferences is not None and preferences.protocol != "all":
        return _identify_pairs(dataset, preferences, pairs_seed, nominal_weights=nominal_weights, beta=beta,
                               margins=margins, alpha=alpha, candidates=candidates, penalty_sign=penalty_sign,
                               constraints=constraints, t0=t0, companions=companions)
    if penalty_sign not in ("negative", "any"):
        raise IdentifyError(f"penalty_sign: expected 'negative' or 'any', got {penalty_sign!r}")
    from pbicrl.inference.likelihood import check_beta

    try:
        beta = check_beta(beta)
    except ValueError as exc:
        raise IdentifyError(str(exc)) from None
    alpha = _check_scalar("alpha", alpha, 0.0, 0.5, lo_open=True, hi_open=False)
    d = dataset.n_features
    names = dataset.feature_names
    if nominal_weights is None:
        wn = dataset.nominal_weights if dataset.nominal_weights is not None else np.zeros(d)
    else:
        try:
            wn = np.asarray(nominal_weights, dtype=np.float64).reshape(-1)
        except (TypeError, ValueError):
            raise IdentifyError("nominal_weights: values must be numeric") from None
        if wn.shape != (d,):
            raise IdentifyError(f"nominal_weights: expected {d} values (one per feature), got {wn.size}")
        if not np.all(np.isfinite(wn)):
            raise IdentifyError("nominal_weights: contains NaN or inf")
    labels = dataset.group_labels
    K = labels.size
    mar = Margins.parse(margins, K)
    cset = _constraint_set(dataset, constraints)
    cand = _resolve_candidates(dataset, candidates, cset)

    F = dataset.mean_features
    spread = F.max(axis=0) - F.min(axis=0)
    # Means of a per-state constant differ by an ulp between lengths, hence the relative tolerance.
    constant = spread <= 1e-10 * np.maximum(1.0, np.abs(F).max(axis=0))
    free = [j for j in cand if not constant[j]]
    p = len(free)

    # Sort trajectories by group rank so per-group extremes are contiguous reductions.
    rank = np.searchsorted(labels, dataset.group)
    order = np.argsort(rank, kind="stable")
    starts = np.concatenate([[0], np.cumsum(np.bincount(rank, minlength=K))]).astype(np.int64)
    s = spread[free] if p else np.zeros(0)
    # Standardise the free features to unit range (and centre them; constants cancel in every comparison) so
    # one tolerance fits all features; weights map back by w_j = w~_j / spread_j.
    X = (F[order][:, free] - F[:, free].mean(axis=0)) / s if p else np.zeros((F.shape[0], 0))
    X = np.ascontiguousarray(X)
    # The LPs see each column shifted by a constant instead of centred: a shift moves every return, and with it the
    # group bounds u, v, by the same amount, so every LP has the same penalties feasible and the same optimal value.
    # Shifting by 0 where the column takes 0 (else by its minimum) keeps |X| <= 1, so one tolerance still fits all,
    # and keeps sparse features (indicators, cell fractions) sparse: centred, a cell 3 of 300 trajectories visit has
    # 300 non-zeros in every LP row block, shifted it has 3.
    X_lp = _shifted(F[order][:, free], s) if p else X
    c = F[order] @ wn
    L = math.log((1.0 - alpha) / alpha)
    if mar.offsets is not None:  # additive margins (zeros, gaps): O(K) ordering rows, nothing K x K
        lp = _GroupLP(X_lp, c, starts, shift=mar.offsets / beta, base=L / beta)
    else:  # a general matrix, given as such
        lp = _GroupLP(X_lp, c, starts, gaps=(mar.matrix + L) / beta)
    from scipy.sparse import csr_matrix

    nv, ia = lp.n_var, p + 2 * K + 1  # columns: w (p), u, v (2K), t, a (p)
    neg = penalty_sign == "negative"

    free_uv: list[tuple[float | None, float | None]] = [(None, None)] * (2 * K)  # group bounds u, v

    def w_bounds(box: float = _BIG) -> list[tuple[float | None, float | None]]:
        b: list[tuple[float | None, float | None]] = [(-box, 0.0 if neg else box)] * p
        return b + free_uv + [(0.0, 0.0)] + [(0.0, 0.0)] * p

    def end(obj: NDArray[np.float64], a: int) -> NDArray[np.float64]:
        """A maximiser of ``-obj @ z`` over S_alpha, accurate where companions of unbounded penalties could run to
        the box: a vertex at +-1e10 loses digits (the returns are sums of terms of 1e10; HiGHS's tolerances apply to
        them). The optimal value v(B) under a box B is concave, non-decreasing and piecewise linear in B, and finite
        ends are attained: so where no penalty sits at a box of 1e5 the box is inactive and the point optimal; where
        v(1e7) = v(1e5), v is flat from there on, v(1e5) is the end. Else (an end at infinity): the box of 1e10.
        A penalty at the box whose reduced cost is 0 does not bind (the point with the same duals is optimal without
        that bound, the KKT conditions hold), so where all of them are 0 the first box's point is optimal already."""
        prev = None
        for box in _END_BOXES:
            x = lp.solve(obj, w_bounds(box), homogeneous=False, slot=f"ends {box:g}")
            if x is None:  # cannot happen: the feasibility LP succeeded on a subset of these rows
                raise RuntimeError("identify: LP solver reported an infeasible end of a feasible set")
            at_box = np.abs(x[:p]) >= 0.5 * box
            if not np.any(at_box):
                return x
            if abs(x[a]) < 0.5 * box and np.all(np.abs(lp.reduced_costs[:p][at_box]) <= 1e-12):
                return x
            if prev is not None and abs(x[a] - prev[a]) <= 1e-9 * (1.0 + abs(prev[a])):
                return prev
            prev = x
        x = lp.solve(obj, w_bounds(), homogeneous=False, slot="ends")
        if x is None:
            raise RuntimeError("identify: LP solver reported an infeasible end of a feasible set")
        return x

    # ---- flat directions (affine dependence among free candidates): the likelihood is constant along them
    flat_groups = {free[a]: ([free[b] for b in bs], more) for a, (bs, more) in _flat_partners(X).items()}

    # ---- recession analysis (independent of alpha, beta, margins)
    gbar = X[starts[0]:starts[1]].mean(axis=0) - X[starts[K - 1]:starts[K]].mean(axis=0) if p else np.zeros(0)
    recess: dict[int, dict[int, NDArray[np.float64]]] = {j: {} for j in free}
    tick = _Progress(progress, "identify: unbounded penalties", unit="LP", t0=t0, into=bars)
    movable, seen = _recession_support(lp, p, K, free_uv, tick, gbar) if neg else (list(range(p)), None)
    lp.solver.drop("support")
    work = len(movable) * lp.rows_nnz(homogeneous=True) if movable else 0
    cheap = len(movable) <= _COMPANION_MAX and work <= _COMPANION_WORK
    with_companions = (not neg) or (cheap if companions is None else bool(companions))
    if movable and not with_companions and seen is not None:
        best_dir = seen  # an improving direction exists: every movable penalty is unbounded (below); no LP for g*
    else:
        best_dir = _improving(lp, p, free_uv, gbar, neg, tick) if movable else None
    if best_dir is None:
        movable = []
    tick.close()
    tick = _Progress(progress and bool(movable), "identify: recession directions", total=len(movable), t0=t0,
                     into=bars)
    signs = (-1.0,) if neg else (-1.0, 1.0)
    # One required improvement for every feature: eps = t_up / 2, t_up = min(1, g*), g* = max gbar@delta over the cone
    # in the unit box (_improving's optimal value, unique whichever vertex the solver returns). For feature a, sign s,
    # the sparsest-direction LP below (s*delta_a = 1, the others unboxed) can reach any improvement up to
    # M_a = sup gbar@delta/|delta_a|, and M_a >= g* whenever some cone direction D has s*D_a > 0 and gbar@D > 0: add a
    # small multiple of D to the maximiser D* (if s*D*_a >= 0, the ratio tends to g*/|D*_a| >= g*; if s*D*_a < 0 it
    # grows without bound where the sum's a-th coordinate crosses 0). So that LP is feasible exactly when the penalty is
    # unbounded in that direction, and it decides it: no per-feature max-t LP (which, with dense features, was 3/4 of
    # the time: one O(N p) LP per feature, none settled by another's vertex).
    eps = 0.5 * min(1.0, float(gbar @ best_dir)) if best_dir is not None else 0.0  # g* exact: _improving's
    for a in movable:
        j = free[a]
        if not with_companions:
            # w_p <= 0: every direction of the cone has gbar@delta >= 0 (the best group's mean return is at least
            # the worst's), so one that moves w_j plus the improving one (best_dir) moves w_j and improves: movable
            # features are exactly the unbounded ones
            recess[j][-1] = None
            tick.step()
            continue
        for sgn in signs:
            # Sparsest companions: fix sgn*delta_j = 1, minimise sum |delta_i| over the others, improving by >= eps.
            obj = np.zeros(nv)
            bnd = [((None, 0.0) if neg else (None, None))] * p + free_uv + [(0.0, 0.0)] + [(0.0, None)] * p
            bnd[a] = (sgn, sgn)
            if neg:  # delta <= 0: |delta_i| = -delta_i, no auxiliaries needed
                obj[:p] = -1.0
                obj[a] = 0.0
                bnd[ia:] = [(0.0, 0.0)] * p
                extra = csr_matrix((-gbar, (np.zeros(p, dtype=np.int64), np.arange(p))), shape=(1, nv))
            else:  # a_b >= +-delta_b, as sparse rows (2p of them)
                obj[ia:ia + p] = 1.0
                obj[ia + a] = 0.0
                b_ = np.arange(p)
                rr = np.concatenate([np.zeros(p, dtype=np.int64), 1 + 2 * b_, 1 + 2 * b_, 2 + 2 * b_, 2 + 2 * b_])
                cc = np.concatenate([b_, b_, ia + b_, b_, ia + b_])
                vv = np.concatenate([-gbar, np.ones(p), -np.ones(p), -np.ones(p), -np.ones(p)])
                extra = csr_matrix((vv, (rr, cc)), shape=(2 * p + 1, nv))
            rhs = np.zeros(extra.shape[0])
            rhs[0] = -eps                              # gbar@delta >= eps
            y = lp.solve(obj, bnd, homogeneous=True, extra_A=extra, extra_b=rhs, slot="sparsest")
            if y is None:  # no direction moves w_j this way and improves the ranking: bounded on this side
                continue
            delta = y[:p] / s
            recess[j][int(sgn)] = delta / np.abs(delta).max()
        tick.step()

    # ---- separating set S_alpha and the separation scales
    lp.solver.drop("sparsest")
    tick.close()
    tick = _Progress(progress and p > 0, "identify: separation scales", total=p, t0=t0, into=bars)
    zero = np.zeros(nv)
    if neg:  # the point of S_alpha with the smallest sum |w_j|: its zeros settle upper ends (below)
        zero[:p] = -1.0
    x0 = lp.solve(zero, w_bounds(), homogeneous=False)
    separable = x0 is not None
    rng: dict[int, tuple[float, float]] = {}
    if separable:
        # A point of S_alpha with w_j = 0 settles the upper end of w_j <= 0 (it is 0) without an LP. The smallest
        # sum |w| (x0) has few non-zero penalties; then, while that finds new zeros, the point with the smallest sum
        # |w_j| over the features not yet settled (the settled ones free within the first box: any point of S_alpha
        # in a box is one of S_alpha). What is left needs its own end LP (the points those return settle more). With
        # 1,000 dense features: 1 such LP and no end LP, where 55 end LPs took 42 s.
        at_zero = (x0[:p] == 0.0) if neg else np.zeros(p, dtype=bool)
        while neg and not at_zero.all():
            obj = np.zeros(nv)
            obj[:p] = np.where(at_zero, 0.0, -1.0)
            xz = lp.solve(obj, w_bounds(_END_BOXES[0]), homogeneous=False, slot="zeros")
            tick.step(0)  # a refresh: a long LP shows the bar
            if xz is None:  # S_alpha lies outside the box: the end LPs decide
                break
            new_zero = (xz[:p] == 0.0) & ~at_zero
            if not new_zero.any():
                break
            at_zero |= new_zero
        lp.solver.drop("zeros")
        for a, j in enumerate(free):
            tick.step()
            ends = []
            for sgn in (-1.0, 1.0):  # sgn=-1: lowest w_j, sgn=+1: highest
                if int(sgn) in recess[j]:
                    ends.append(sgn * math.inf)  # a recession direction: that end is at infinity
                    continue
                if sgn > 0 and at_zero[a]:
                    ends.append(0.0)
                    continue
                obj = np.zeros(nv)
                obj[a] = -sgn
                x = end(obj, a)
                if neg:
                    at_zero |= x[:p] == 0.0
                ends.append(sgn * math.inf if abs(x[a]) >= 0.5 * _BIG else float(x[a]) / s[a])
            rng[j] = (ends[0], ends[1])

    tick.close()
    # ---- assemble per-feature entries
    feats = []
    for j, n in enumerate(names):
        if j not in cand:
            feats.append(FeatureIdentification(n, False, None, "not a candidate: w_p fixed at 0",
                                               spread=float(spread[j])))
            continue
        if constant[j]:
            col = F[:, j]
            why = ("all zeros: the feature never fires in the data" if not np.any(col)
                   else f"constant: every trajectory has mean feature {float(col[0]):.6g}, so its penalty shifts all "
                        "returns equally and cancels in every comparison")
            feats.append(FeatureIdentification(n, True, False, why + " (left out of the separation analysis)",
                                               spread=float(spread[j])))
            continue
        ident = j not in flat_groups
        lo_hi = rng.get(j)
        mp: float | None = None
        if lo_hi is not None:
            lo, hi = lo_hi
            if neg:
                hi = min(hi, 0.0)
                lo_hi = (lo, hi)
            mp = 0.0 if lo <= 0.0 <= hi else float(min(abs(lo), abs(hi)))
            if mp * spread[j] < 1e-8:  # below the LP tolerance (standardised units): not needed
                mp = 0.0
        ways = sorted(recess[j])
        direction = None if not ways else ("both" if len(ways) == 2 else ("-inf" if ways[0] < 0 else "+inf"))
        rec = tuple(_named(recess[j][w], free, names) for w in ways if recess[j][w] is not None)
        if not ident:
            partners = [names[i] for i in flat_groups[j][0] if i != j]
            reason = (f"affinely dependent on {', '.join(partners)}{' and others' if flat_groups[j][1] else ''}: "
                      "a combination of these penalties leaves every "
                      "return difference unchanged, so only combinations are identified")
        elif direction and not rec:
            reason = (f"unbounded ({direction}); its companions were not computed ({len(movable)} unbounded "
                      "penalties, one LP each: identify(companions=True), `pbicrl identify --companions`)"
                      + (f"; separation scale {mp:.4g}" if mp is not None else "; not separable at this alpha"))
        elif direction:
            others = ", ".join(k for k in rec[0] if k != n)
            reason = (f"unbounded ({direction})" + (f" together with {others}" if others else " on its own")
                      + (f"; separation scale {mp:.4g}" if mp is not None else "; not separable at this alpha"))
        elif mp is not None:
            reason = f"bounded by the data; separation scale {mp:.4g}"
        else:
            reason = "bounded by the data (not separable at this alpha: the likelihood fixes the scale)"
        feats.append(FeatureIdentification(n, True, ident, reason, min_penalty=mp, penalty_range=lo_hi,
                                           unbounded=bool(ways), direction=direction, recession=rec,
                                           spread=float(spread[j])))

    seen: dict[tuple[tuple[str, float], ...], dict[str, float]] = {}
    for f in feats:
        for dvec in f.recession:
            seen.setdefault(tuple((k, round(v, 6)) for k, v in dvec.items()), dvec)

    params: list[ParameterInterval] = []
    if cset is not None:
        for m, con in enumerate(cset.constraints):
            pb = cset.bounds[cset.param_offsets[m]:cset.param_offsets[m + 1]]
            if isinstance(con, AxisHalfspace):
                params.append(threshold_interval(dataset, con, prior_bounds=(float(pb[0, 0]), float(pb[0, 1]))))
            else:
                for pn in con.param_names():
                    params.append(ParameterInterval(
                        name=f"{con.name}.{pn}", constraint=con.name, family=con.family, low=None, high=None,
                        reason=(f"{con.family}: the parameters consistent with the ranking form a joint region, not "
                                "an interval per parameter; only axis half-spaces get an identified interval")))

    return Identification(
        feature_names=names, features=tuple(feats), separable=separable, alpha=alpha, beta=beta,
        margins=mar, penalty_sign=penalty_sign, nominal_weights=np.asarray(wn, dtype=np.float64).copy(),
        group_labels=tuple(int(k) for k in labels), unbounded_directions=tuple(seen.values()),
        parameters=tuple(params), n_lp=lp.n_lp, runtime_s=time.perf_counter() - t0, companions=with_companions)


_MARGIN_COLUMN = "__pair_margin__"


def _identify_pairs(dataset: Dataset, preferences: Preferences, pairs_seed: int | None, *, t0: float,
                    **kw: Any) -> Identification:
    r""":func:`identify` of the pairs a sampled-pairs likelihood uses.

    A pair :math:`(i, j)` with margin :math:`m` asks :math:`\beta\,(\bar\phi_i - \bar\phi_j)^\top w - m \ge
    \operatorname{logit}(1-\alpha)`. That is the group analysis of a two-group dataset: group 1 holds one row
    :math:`\bar\phi_i - \bar\phi_j` per pair (and :math:`-m/\beta` in an extra column with nominal weight 1), group 2
    a single zero row; "every row of group 1 above group 2" is then exactly "every pair ordered", and its recession
    directions are those of the pairs.
    """
    if preferences.n_trajectories != dataset.n_trajectories:
        raise IdentifyError(f"preferences: built for {preferences.n_trajectories} trajectories, the dataset has "
                            f"{dataset.n_trajectories}")
    d = dataset.n_features
    names = dataset.feature_names
    beta = _check_scalar("beta", kw["beta"], 0.0, math.inf, lo_open=True, hi_open=True)
    wn = kw["nominal_weights"]
    wn = (dataset.nominal_weights if dataset.nominal_weights is not None else np.zeros(d)) if wn is None else wn
    wn = np.asarray(wn, dtype=np.float64).reshape(-1)
    I, J, M = preferences.to_pair_list()
    F = dataset.mean_features
    rows = np.vstack([np.column_stack([F[I] - F[J], -np.asarray(M, dtype=np.float64) / beta]), np.zeros((1, d + 1))])
    pseudo = Dataset.from_trajectories([r[None, :] for r in rows], group=[1] * I.size + [2],
                                       feature_names=tuple(names) + (_MARGIN_COLUMN,),
                                       nominal_weights=np.append(wn, 1.0))
    cset = _constraint_set(dataset, kw["constraints"])
    cand = _resolve_candidates(dataset, kw["candidates"], cset)
    sub = identify(pseudo, beta=beta, alpha=kw["alpha"], candidates=[names[j] for j in cand] or [_MARGIN_COLUMN],
                   penalty_sign=kw["penalty_sign"], nominal_weights=np.append(wn, 1.0), companions=kw["companions"])
    # The ends of w_j over S_alpha straight from the pair rows (one LP each, every row present): the group LP's
    # cutting planes stop at a tolerance that grows with the box an unbounded companion runs to.
    from scipy.optimize import linprog

    L = math.log((1.0 - sub.alpha) / sub.alpha)
    D = (F[I] - F[J])[:, list(cand)]
    rhs = (F[I] - F[J]) @ wn - (L + np.asarray(M, dtype=np.float64)) / beta  # D w >= (L + m)/beta - D w_n
    neg = kw["penalty_sign"] == "negative"
    box = [(None, 0.0) if neg else (None, None)] * len(cand)
    feasible = bool(cand) and linprog(np.zeros(len(cand)), A_ub=-D, b_ub=rhs, bounds=box, method="highs").status == 0
    feats = []
    spread = F.max(axis=0) - F.min(axis=0)
    for j, f in enumerate(sub.features[:d]):
        if not cand or j not in cand:
            f = FeatureIdentification(names[j], False, None, "not a candidate: w_p fixed at 0", spread=float(spread[j]))
        elif f.identifiable is not False and feasible:
            a = list(cand).index(j)
            ends = []
            for sgn in (-1.0, 1.0):
                obj = np.zeros(len(cand))
                obj[a] = -sgn
                r = linprog(obj, A_ub=-D, b_ub=rhs, bounds=box, method="highs")
                ends.append(sgn * math.inf if r.status == 3 else float(r.x[a]))
            lo, hi = ends
            mp = 0.0 if lo <= 0.0 <= hi else float(min(abs(lo), abs(hi)))
            reason = f.reason.split("; separation scale")[0] + f"; separation scale {mp:.4g}" if f.unbounded else \
                f"bounded by the data; separation scale {mp:.4g}"
            f = dataclasses.replace(f, min_penalty=mp, penalty_range=(lo, hi), reason=reason)
        elif not feasible:
            f = dataclasses.replace(f, min_penalty=None, penalty_range=None)
        feats.append(dataclasses.replace(f, spread=float(spread[j])))
    params: tuple[ParameterInterval, ...] = ()
    if cset is not None:  # locations from the groups: the pairs' analysis covers the known features' penalties
        params = identify(dataset, **{k: v for k, v in kw.items()}).parameters
    labels = dataset.group_labels
    return Identification(
        feature_names=tuple(names), features=tuple(feats), separable=feasible, alpha=sub.alpha, beta=beta,
        margins=Margins.parse(kw["margins"], labels.size), penalty_sign=kw["penalty_sign"], nominal_weights=wn.copy(),
        group_labels=tuple(int(k) for k in labels), unbounded_directions=sub.unbounded_directions,
        parameters=params, n_lp=sub.n_lp, runtime_s=time.perf_counter() - t0, companions=sub.companions,
        pairs={"protocol": preferences.protocol, "n_pairs": int(I.size), "seed": pairs_seed,
               "parameters_from": "groups" if params else None})


def _named(delta: NDArray[np.float64], free: Sequence[int], names: Sequence[str]) -> dict[str, float]:
    """Non-zero entries of a direction over the free features, by name."""
    return {names[j]: float(v) for j, v in zip(free, delta) if abs(v) > 1e-9}
