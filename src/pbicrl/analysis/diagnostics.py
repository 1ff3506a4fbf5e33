"""Convergence diagnostics of a posterior: rank-normalised split R-hat and bulk / tail ESS.

For every feature the diagnostics cover the effective penalty :math:`c_j w_{p,j}` (``penalty``) and the
indicator :math:`c_j` (``indicator``); for parametric constraints every parameter (``parameter``); and the
total log-likelihood (``log_likelihood``), a one-number summary of whether the chains explore the same region.
A parameter exists only while its constraint is active (the sampler stores NaN otherwise); its statistics
use each chain's active draws, cut to a common length.

The statistics are the rank-normalised split :math:`\\hat R` and bulk / tail effective sample sizes of Vehtari
et al. (2021), computed by :mod:`pbicrl.inference.convergence` (NumPy only, equal to ArviZ's to 1e-9 in the tests;
``backend="auto"``, the default, needs no extra and no import of ArviZ, which takes seconds). ``backend="arviz"``
computes them with ArviZ itself (``pip install "pbicrl[diag]"``); ``backend="numpy"`` gives the classic split
:math:`\\hat R` (:func:`split_rhat`) only.

A quantity that never changes in any chain (a feature that is not a candidate, or an indicator that is on
in every draw) has no R-hat or ESS (``None``) and raises no warning; chains that are each constant but at
different values get :math:`\\hat R = \\infty`. Features the rankings carry no information about (a
posterior's ``not_identifiable()``, e.g. a feature that is constant across trajectories) are not diagnosed
either: their penalty and indicator are the prior's, so an R-hat of them says nothing about the data; they
get ``None`` and are listed in :attr:`Diagnostics.excluded`.
"""

from __future__ import annotations

import math
import warnings as _warnings
import weakref
from dataclasses import dataclass, field
from collections.abc import Mapping
from typing import Any, Sequence

import numpy as np
from numpy.typing import NDArray

from pbicrl.inference.draws import split_rhat  # the statistic lives with the draws (re-exported)

__all__ = ["Diagnostics", "compute", "split_rhat", "require_arviz", "arviz_available", "arviz_major", "RHAT_MAX",
           "ESS_MIN", "INSTALL_HINT"]

RHAT_MAX = 1.01
"""Warn when :math:`\\hat R` exceeds this (Vehtari et al. 2021)."""
ESS_MIN = 400.0
"""Warn when the bulk ESS is below this (Vehtari et al. 2021: 100 per chain, 4 chains)."""
INSTALL_HINT = 'pip install "pbicrl[diag]"'

_KINDS = ("penalty", "indicator", "parameter", "log_likelihood")
_LABEL = {"penalty": "penalty c*w_p", "indicator": "indicator c", "parameter": "parameter",
          "log_likelihood": "log-likelihood"}


def require_arviz() -> Any:
    """Import ArviZ (quietly) or raise an ImportError naming the pip command."""
    try:
        with _warnings.catch_warnings():
            # arviz 0.2x announces its 1.0 refactor with a FutureWarning on import.
            _warnings.simplefilter("ignore", FutureWarning)
            import arviz
    except ImportError as exc:
        raise ImportError(f"this needs ArviZ ({exc}): {INSTALL_HINT}") from exc
    return arviz


def arviz_available() -> bool:
    """Whether ArviZ can be imported."""
    try:
        require_arviz()
    except ImportError:
        return False
    return True


def arviz_major(az: Any) -> int:
    """Major version of an imported ArviZ module (0 when its version string is not a number)."""
    try:
        return int(str(az.__version__).split(".")[0])
    except ValueError:
        return 0


@dataclass(frozen=True)
class Diagnostics:
    """R-hat and ESS per quantity.

    Attributes
    ----------
    backend : str
        ``"pbicrl"`` (rank-normalised, :mod:`pbicrl.inference.convergence`), ``"arviz <version>"`` or ``"numpy"``
        (split R-hat only, no ESS).
    n_chains, n_draws : int
        Chains and kept draws per chain.
    values : dict
        ``values[kind][name] = {"rhat": float | None, "ess_bulk": float | None, "ess_tail": float | None}``
        with ``kind`` one of ``penalty``, ``indicator``, ``parameter``, ``log_likelihood``; ``None`` where a
        statistic is undefined (constant draws) or unavailable.
    message : str or None
        Why something is unavailable (e.g. ESS without ArviZ).
    rhat_max, ess_min : float
        Warning thresholds.
    excluded : dict
        ``{feature: reason}`` of features not diagnosed because the rankings carry no information about them
        (their penalty and indicator entries are ``None``).
    """

    backend: str
    n_chains: int
    n_draws: int
    values: dict[str, dict[str, dict[str, float | None]]]
    message: str | None = None
    rhat_max: float = RHAT_MAX
    ess_min: float = ESS_MIN
    excluded: dict[str, str] = field(default_factory=dict)

    def get(self, kind: str, stat: str) -> dict[str, float | None]:
        """``{name: value}`` of one statistic (``rhat``, ``ess_bulk``, ``ess_tail``) for one kind."""
        return {n: v[stat] for n, v in self.values.get(kind, {}).items()}

    def worst(self) -> dict[str, float | None]:
        """Largest R-hat and smallest bulk / tail ESS over all quantities (``None`` if none defined)."""
        def pick(stat: str, fn: Any) -> float | None:
            vals = [v[stat] for kv in self.values.values() for v in kv.values() if v[stat] is not None]
            return fn(vals) if vals else None
        return {"rhat": pick("rhat", max), "ess_bulk": pick("ess_bulk", min), "ess_tail": pick("ess_tail", min)}

    def worst_of(self, kinds: Sequence[str], name: str) -> dict[str, float | None]:
        """Largest R-hat and smallest ESS of ``name`` over several kinds (e.g. its penalty and indicator)."""
        vals = [self.values[k][name] for k in kinds if name in self.values.get(k, {})]

        def pick(stat: str, fn: Any) -> float | None:
            xs = [v[stat] for v in vals if v[stat] is not None]
            return fn(xs) if xs else None
        return {"rhat": pick("rhat", max), "ess_bulk": pick("ess_bulk", min), "ess_tail": pick("ess_tail", min)}

    def cells(self, kind: str, name: str, *, compact: bool = False) -> str:
        """``R-hat  ESS bulk  ESS tail`` columns for a results table (widths 6, 8, 8).

        ``kind="feature"`` shows the worse of the feature's penalty and indicator. ``compact``: two columns,
        ``R-hat  ESS`` (widths 6, 6), the ESS being the smaller of bulk and tail.
        """
        v = self.worst_of(("penalty", "indicator") if kind == "feature" else (kind,), name)
        if compact:
            ess = [x for x in (v["ess_bulk"], v["ess_tail"]) if x is not None]
            return f"{_fmt(v['rhat'], 3):>6}  {_fmt(min(ess) if ess else None, 0):>6}"
        return f"{_fmt(v['rhat'], 3):>6}  {_fmt(v['ess_bulk'], 0):>8}  {_fmt(v['ess_tail'], 0):>8}"

    def footer(self, *, compact: bool = False) -> str:
        """One line saying where the R-hat / ESS columns come from (``compact``: as :meth:`cells` makes them)."""
        ranked = self.backend != "numpy"
        src = ("rank-normalised split R-hat and ESS (" + ("ArviZ" if self.backend.startswith("arviz") else
                                                            "as ArviZ") + ")" if ranked else "classic split R-hat, no ESS")
        ess = "; ESS = the smaller of bulk and tail" if compact and ranked else ""
        line = (f"diagnostics: {src}; per feature the worse of c and c*w_p{ess}; "
                "'-' = constant, undefined or not identifiable")
        return line + (f"; {self.message}" if self.message and not ranked else "")

    def warnings(self) -> list[str]:
        """Plain-language convergence warnings (one line per kind of quantity and problem)."""
        out = []
        if self.n_chains < 2:
            out.append(f"only {self.n_chains} chain: R-hat needs at least 2 chains (4 recommended); "
                       "run more chains to check convergence")
        for kind in _KINDS:
            vals = self.values.get(kind, {})
            high = [(n, v["rhat"]) for n, v in vals.items() if v["rhat"] is not None and v["rhat"] > self.rhat_max]
            if high:
                lst = _names(kind, [(n, _fmt(r, 3)) for n, r in high])
                out.append(f"R-hat > {self.rhat_max:g} for the {_LABEL[kind]}{lst}: the chains disagree; "
                           "run longer (more iterations) or check for multiple modes")
            low = [(n, v["ess_bulk"]) for n, v in vals.items()
                   if v["ess_bulk"] is not None and v["ess_bulk"] < self.ess_min]
            if low:
                lst = _names(kind, [(n, _fmt(e, 0)) for n, e in low])
                out.append(f"bulk ESS < {self.ess_min:g} for the {_LABEL[kind]}{lst}: too few effective draws "
                           "for reliable means and intervals; run longer or use more chains")
        return out

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form (``summary.json`` ``posterior.diagnostics``); an infinite R-hat (chains stuck at
        different values) becomes ``null`` there, and is named in :meth:`warnings`."""
        def finite(v: dict[str, float | None]) -> dict[str, float | None]:
            return {k: (x if x is None or math.isfinite(x) else None) for k, x in v.items()}

        return {"backend": self.backend, "chains": self.n_chains, "draws_per_chain": self.n_draws,
                "thresholds": {"rhat_max": self.rhat_max, "ess_bulk_min": self.ess_min},
                "message": self.message, "worst": finite(self.worst()), "not_identifiable": dict(self.excluded),
                **{k: {n: finite(v) for n, v in self.values[k].items()} for k in _KINDS if k in self.values}}

    def table(self) -> str:
        """One row per quantity: R-hat, bulk ESS, tail ESS."""
        rows = [(f"{k}[{n}]" if k != "log_likelihood" else "log_likelihood", v)
                for k in _KINDS for n, v in self.values.get(k, {}).items()]
        w = max([len(r[0]) for r in rows] + [8])
        head = f"{'quantity':<{w}}  {'R-hat':>7}  {'ESS bulk':>8}  {'ESS tail':>8}"
        lines = [head, "-" * len(head)]
        for name, v in rows:
            lines.append(f"{name:<{w}}  {_fmt(v['rhat'], 3):>7}  {_fmt(v['ess_bulk'], 0):>8}  {_fmt(v['ess_tail'], 0):>8}")
        lines.append(f"{self.n_chains} chains x {self.n_draws} draws; statistics from {self.backend}")
        if self.excluded:
            lines.append("not diagnosed (not identifiable): "
                         + "; ".join(f"{n} ({r})" for n, r in self.excluded.items()))
        if self.message:
            lines.append(f"note: {self.message}")
        return "\n".join(lines)


def _names(kind: str, items: list[tuple[str, str]]) -> str:
    if kind == "log_likelihood":
        return f" ({items[0][1]})"
    return " of " + ", ".join(f"{n} ({v})" for n, v in items)


def _fmt(x: float | None, digits: int) -> str:
    if x is None:
        return "-"
    if math.isinf(x):
        return "inf"
    return f"{x:.{digits}f}"


def _clean(x: Any) -> float | None:
    x = float(np.asarray(x).reshape(-1)[0]) if np.size(x) else float("nan")
    return None if math.isnan(x) else x


def _stats_numpy(x: NDArray[np.float64]) -> dict[str, float | None]:
    return {"rhat": _clean(split_rhat(x)) if x.shape[0] > 1 else None, "ess_bulk": None, "ess_tail": None}


def _stats_ranked(x: NDArray[np.float64]) -> dict[str, float | None]:
    from pbicrl.inference.convergence import ess_bulk, ess_tail, rhat

    with np.errstate(all="ignore"):
        r = _clean(rhat(x)) if x.shape[0] > 1 else None
        return {"rhat": r, "ess_bulk": _clean(ess_bulk(x)), "ess_tail": _clean(ess_tail(x))}


def _stats_arviz(az: Any, x: NDArray[np.float64]) -> dict[str, float | None]:
    with np.errstate(all="ignore"), _warnings.catch_warnings():
        _warnings.simplefilter("ignore", RuntimeWarning)
        rhat = _clean(az.rhat(x, method="rank")) if x.shape[0] > 1 else None
        ess_bulk = _clean(az.ess(x, method="bulk"))
        ess_tail = _clean(az.ess(x, method="tail", prob=(0.05, 0.95)))  # arviz 1.x needs prob
    if rhat is None and x.shape[0] > 1:
        # ArviZ gives NaN when every chain is constant; if the constants differ the chains disagree completely.
            rhat = _clean(split_rhat(x))
    if rhat is not None and rhat > 1e6:  # zero within-chain variance, up to rounding (arviz 1.x)
        rhat = math.inf
    return {"rhat": rhat, "ess_bulk": ess_bulk, "ess_tail": ess_tail}


def _quantities(post: Any) -> dict[str, dict[str, NDArray[np.float64]]]:
    """Draws (chains, draws) of every diagnosed quantity, by kind and name."""
    names = list(post.feature_names)
    c = np.asarray(post.indicators, dtype=np.float64)
    eff = c * np.asarray(post.penalty_weights, dtype=np.float64)
    out: dict[str, dict[str, NDArray[np.float64]]] = {
        "penalty": {n: eff[:, :, j] for j, n in enumerate(names)},
        "indicator": {n: c[:, :, j] for j, n in enumerate(names)},
    }
    params = getattr(post, "parameters", None)
    if params is not None and np.size(params):
        params = np.asarray(params, dtype=np.float64)
        if params.ndim == 2:
            params = params[:, :, None]
        pnames = list(getattr(post, "parameter_names", None) or [f"theta{k}" for k in range(params.shape[2])])
        out["parameter"] = {n: _active_draws(params[:, :, k]) for k, n in enumerate(pnames)}
    ll = getattr(post, "log_likelihood", None)
    if ll is not None and np.size(ll):
        out["log_likelihood"] = {"total": np.asarray(ll, dtype=np.float64)}
    return out


def _active_draws(x: NDArray[np.float64]) -> NDArray[np.float64]:
    """A parameter's draws while its constraint is active (the sampler stores NaN otherwise).

    Each chain keeps its finite draws in order; chains are cut to the shortest such run so the result is
    rectangular (chains with fewer than 4 active draws are left out). Empty if nothing is left.
    """
    if np.all(np.isfinite(x)):
        return x
    runs = [row[np.isfinite(row)] for row in x]
    runs = [r for r in runs if r.size >= 4]
    if not runs:
        return np.zeros((0, 0))
    n = min(r.size for r in runs)
    return np.stack([r[:n] for r in runs])


def _not_identifiable(post: Any) -> dict[str, str]:
    """``post.not_identifiable`` as a ``{name: reason}`` dict (empty when the object has none)."""
    v = getattr(post, "not_identifiable", None)
    if callable(v):
        v = v()
    if isinstance(v, Mapping):
        return {str(k): str(r) for k, r in v.items()}
    if isinstance(v, (list, tuple, set, frozenset)):
        return {str(k): "not identifiable" for k in v}
    return {}


_CACHE: "weakref.WeakKeyDictionary[Any, tuple[tuple[Any, ...], Diagnostics]]" = weakref.WeakKeyDictionary()


def compute(post: Any, *, backend: str = "auto", cache: bool = True) -> Diagnostics:
    """Diagnostics of a :class:`~pbicrl.inference.posterior.Posterior` (or a run loaded with :func:`pbicrl.io.runs.read_run`).

    Parameters
    ----------
    post : Posterior or RunRecord
        Anything with ``indicators`` and ``penalty_weights`` (chains, draws, d), ``feature_names`` and
        ``log_likelihood`` (chains, draws); ``parameters`` (chains, draws, p), ``parameter_names`` and
        ``not_identifiable`` (a ``{feature: reason}`` mapping, or a method returning one) are used when
        present.
    backend : {"auto", "arviz", "numpy"}
        ``auto``: rank-normalised R-hat and bulk / tail ESS from :mod:`pbicrl.inference.convergence` (no extra).
        ``arviz``: the same statistics from ArviZ (requires it). ``numpy``: classic split R-hat only.
    cache : bool
        Reuse the result for the same object (summaries, tables and warnings all ask for it).

    Returns
    -------
    Diagnostics
    """
    if backend not in ("auto", "arviz", "numpy"):
        raise ValueError(f"backend: expected 'auto', 'arviz' or 'numpy', got {backend!r}")
    excluded = _not_identifiable(post)
    key = (backend, tuple(sorted(excluded)))
    if cache:
        try:
            hit = _CACHE.get(post)
        except TypeError:  # not weak-referenceable
            hit = None
        if hit is not None and hit[0] == key:
            return hit[1]
    az = None
    message = None
    if backend == "arviz":
        az = require_arviz()
    elif backend == "numpy":
        message = "ESS not computed (numpy backend; classic split R-hat)"
    quantities = _quantities(post)
    n_chains, n_draws = np.asarray(post.indicators).shape[:2]
    values: dict[str, dict[str, dict[str, float | None]]] = {}
    for kind, by_name in quantities.items():
        values[kind] = {}
        for name, x in by_name.items():
            if (kind in ("penalty", "indicator") and name in excluded) or x.shape[1] < 4 or np.all(x == x.flat[0]):
                values[kind][name] = {"rhat": None, "ess_bulk": None, "ess_tail": None}
            elif az is not None:
                values[kind][name] = _stats_arviz(az, x)
            elif backend == "auto":
                values[kind][name] = _stats_ranked(x)
            else:
                values[kind][name] = _stats_numpy(x)
    label = f"arviz {az.__version__}" if az is not None else ("pbicrl" if backend == "auto" else "numpy")
    diag = Diagnostics(backend=label, n_chains=int(n_chains),
                       n_draws=int(n_draws), values=values, message=message, excluded=excluded)
    if cache:
        try:
            _CACHE[post] = (key, diag)
        except TypeError:
            pass
    return diag
