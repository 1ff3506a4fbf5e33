"""Posterior draws and their summaries: MAP, posterior means, :math:`P(c_j = 1)`, credible intervals.

Written to a run directory as ``summary.json`` (every number a report needs) and ``chains.npz`` (all kept
draws, shape ``(chains, draws, d)``), atomically: a failed or interrupted write leaves no directory behind.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Sequence

import numpy as np
from numpy.typing import NDArray

if TYPE_CHECKING:
    from pbicrl.diagnostics import Diagnostics
    from pbicrl.samplers.kernels import Kernel

__all__ = ["Posterior", "DrawsView", "split_rhat", "write_run_dir"]


def split_rhat(x: NDArray[np.float64]) -> float:
    """Split-:math:`\\hat R` (Gelman et al., BDA3) of draws shaped (chains, draws); NaN if undefined."""
    x = np.asarray(x, dtype=np.float64)
    if x.ndim != 2 or x.shape[1] < 4:
        return float("nan")
    n = x.shape[1] // 2
    halves = np.concatenate([x[:, :n], x[:, -n:]], axis=0)
    m = halves.shape[0]
    means = halves.mean(axis=1)
    W = halves.var(axis=1, ddof=1).mean()
    B = n * means.var(ddof=1)
    if W == 0:
        return 1.0 if B == 0 else float("inf")
    var = (n - 1) / n * W + B / n
    return float(np.sqrt(var / W)) if m > 1 else float("nan")


class DrawsView:
    """Views shared by every holder of draws (:class:`Posterior`, :class:`pbicrl.runs.RunRecord`).

    Needs ``indicators`` and ``penalty_weights`` (chains, draws, d) and ``map_indicators``,
    ``map_penalty_weights`` (d,).
    """

    indicators: NDArray[np.int8]
    penalty_weights: NDArray[np.float64]
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
        return self.map_indicators * self.map_penalty_weights

    @property
    def p_constraint(self) -> NDArray[np.float64]:
        """:math:`P(c_j = 1 \\mid \\mathcal{D})`, (d,)."""
        return self.indicators.reshape(-1, self.n_features).mean(axis=0)


@dataclass(frozen=True, eq=False)
class Posterior(DrawsView):
    """Draws of :math:`(c, w_p)` from one or more chains, with MAP and run metadata.

    Attributes
    ----------
    indicators : ndarray, (chains, draws, d) int8
    penalty_weights : ndarray, (chains, draws, d)
        :math:`w_p` (0 where inactive for ``pbicrl``).
    log_likelihood, log_prior : ndarray, (chains, draws)
    map_indicators, map_penalty_weights : ndarray, (d,)
        Highest log-posterior state over all chains and iterations.
    map_log_posterior, map_log_likelihood : float
    feature_names : tuple of str
    method : str
    settings : dict
    counts : ndarray, (chains, 7)
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

    @classmethod
    def from_chains(cls, results: Sequence[dict], *, kernel: "Kernel", seed: int, runtime_s: float,
                    feature_names: Sequence[str] | None = None) -> "Posterior":
        best = int(np.argmax([r["map_log_posterior"] for r in results]))
        dk = kernel.likelihood.n_features
        names = tuple(feature_names) if feature_names is not None else tuple(f"f{j}" for j in range(dk))
        cs = kernel.constraints
        owner: tuple[int, ...] = ()
        if cs is not None:
            names = names + cs.names
            owner = tuple(dk + m for m in range(cs.n_constraints) for _ in range(cs.constraints[m].n_params))
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
                                                  "n_pairs": kernel.likelihood.preferences.n_pairs},
            counts=np.stack([r["counts"] for r in results]),
            seed=seed,
            runtime_s=float(runtime_s),
            chain_runtime_s=np.array([r["runtime_s"] for r in results]),
            parameters=np.stack([r["parameters"] for r in results]),
            map_parameters=np.asarray(results[best]["map_parameters"]),
            parameter_names=() if cs is None else cs.param_names,
            parameter_owner=owner,
        )

    # ------------------------------------------------------------------ summaries
    @property
    def mean_effective_penalty(self) -> NDArray[np.float64]:
        """Posterior mean of :math:`c_j w_{p,j}`, (d,)."""
        return self.effective_penalty.reshape(-1, self.n_features).mean(axis=0)

    def ci(self, level: float = 0.9) -> NDArray[np.float64]:
        """Equal-tailed credible interval of :math:`c_j w_{p,j}`, (d, 2)."""
        q = (1 - level) / 2
        return np.quantile(self.effective_penalty.reshape(-1, self.n_features), [q, 1 - q], axis=0).T

    def conditional_penalty(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Mean and 90% interval of :math:`w_{p,j}` given :math:`c_j = 1` (NaN where never active)."""
        w = self.penalty_weights.reshape(-1, self.n_features)
        c = self.indicators.reshape(-1, self.n_features).astype(bool)
        mean = np.full(self.n_features, np.nan)
        ci = np.full((self.n_features, 2), np.nan)
        for j in range(self.n_features):
            if c[:, j].any():
                mean[j] = w[c[:, j], j].mean()
                ci[j] = np.quantile(w[c[:, j], j], [0.05, 0.95])
        return mean, ci

    @property
    def map_parameters_active(self) -> NDArray[np.float64]:
        """MAP :math:`\vartheta`, NaN for parameters of constraints the MAP switches off."""
        out = self.map_parameters.astype(float).copy()
        for p, j in enumerate(self.parameter_owner):
            if not self.map_indicators[j]:
                out[p] = np.nan
        return out

    def parameter_summary(self) -> dict[str, dict[str, Any]]:
        """Per parameter: posterior mean and 90% interval over draws where its constraint is active."""
        out: dict[str, dict[str, Any]] = {}
        if not self.parameter_names:
            return out
        th = self.parameters.reshape(-1, len(self.parameter_names))
        on = self.indicators.reshape(-1, self.n_features)
        for p, name in enumerate(self.parameter_names):
            x = th[on[:, self.parameter_owner[p]] == 1, p]
            x = x[np.isfinite(x)]
            out[name] = {"mean": _py(x.mean()) if x.size else None,
                         "ci90": [_py(v) for v in np.quantile(x, [0.05, 0.95])] if x.size else [None, None],
                         "active_draws": int(x.size)}
        return out

    def acceptance_rate(self) -> dict[str, float]:
        """Acceptance rate per move type over all chains."""
        tot = self.counts.sum(axis=0)
        out = {}
        if tot[0]:
            out["flip"] = float(tot[1] / tot[0])
        if tot[2]:
            out["weight"] = float(tot[3] / tot[2])
        if tot.size > 5 and tot[5]:
            out["parameter"] = float(tot[6] / tot[5])
        prop = tot[0] + tot[2] + (tot[5] if tot.size > 5 else 0)
        acc = tot[1] + tot[3] + (tot[6] if tot.size > 5 else 0)
        out["overall"] = float(acc / prop) if prop else 0.0
        return out

    def rhat(self) -> dict[str, list[float]]:
        """Split-:math:`\\hat R` per feature for the effective penalty and the indicator."""
        if self.n_chains < 2:
            nan = [float("nan")] * self.n_features
            return {"effective_penalty": nan, "indicator": nan}
        eff = self.effective_penalty
        return {"effective_penalty": [split_rhat(eff[:, :, j]) for j in range(self.n_features)],
                "indicator": [split_rhat(self.indicators[:, :, j].astype(float)) for j in range(self.n_features)]}

    def warnings(self) -> list[str]:
        """Plain-language problems a user should know about."""
        out = []
        prior = self.settings.get("weight_prior", {})
        if self.method != "paper" and prior.get("kind") in ("flat", "uniform", "normal"):
            lo, hi = prior["low"], prior["high"]
            span = hi - lo
            eff = self.effective_penalty.reshape(-1, self.n_features)
            on = self.indicators.reshape(-1, self.n_features).astype(bool)
            for j, name in enumerate(self.feature_names):
                if on[:, j].mean() < 0.5:
                    continue
                near = np.mean((eff[on[:, j], j] < lo + 0.05 * span) | (eff[on[:, j], j] > hi - 0.05 * span))
                if near > 0.1:
                    out.append(f"{name}: {near:.0%} of active draws lie within 5% of the prior bound [{lo:g}, {hi:g}]; "
                               "the groups are (nearly) separated by this feature, so the data only bound the penalty's "
                               "magnitude from one side. Narrow the prior bounds or use margins to set the scale.")
        out.extend(self.diagnostics().warnings())  # R-hat > 1.01, bulk ESS < 400
        return out

    def diagnostics(self) -> "Diagnostics":
        """R-hat and bulk/tail ESS of every penalty, indicator and parameter (:mod:`pbicrl.diagnostics`)."""
        from pbicrl import diagnostics

        return diagnostics.compute(self)

    def to_arviz(self) -> Any:
        """ArviZ InferenceData (arviz < 1) or DataTree (arviz >= 1); see :mod:`pbicrl.export`."""
        from pbicrl.export import to_arviz

        return to_arviz(self)

    def summary(self) -> dict[str, Any]:
        """Everything ``summary.json`` holds."""
        names = list(self.feature_names)
        cmean, cci = self.conditional_penalty()

        def by_name(v: NDArray) -> dict[str, Any]:
            return {n: _py(x) for n, x in zip(names, v)}

        return {
            "method": self.method,
            "feature_names": names,
            "map": {
                "indicators": by_name(self.map_indicators.astype(int)),
                "penalty_weights": by_name(self.map_penalty_weights),
                "effective_penalty": by_name(self.map_effective_penalty),
                "parameters": {n: _py(v) for n, v in zip(self.parameter_names, self.map_parameters_active)},
                "log_posterior": self.map_log_posterior,
                "log_likelihood": self.map_log_likelihood,
            },
            "posterior": {
                "mean_effective_penalty": by_name(self.mean_effective_penalty),
                "p_constraint": by_name(self.p_constraint),
                "ci90": {n: [_py(a), _py(b)] for n, (a, b) in zip(names, self.ci(0.9))},
                "penalty_given_active": {"mean": by_name(cmean), "ci90": {n: [_py(a), _py(b)] for n, (a, b) in zip(names, cci)}},
                "rhat": {k: by_name(np.array(v)) for k, v in self.rhat().items()},
                "diagnostics": self.diagnostics().to_dict(),
                "parameters": self.parameter_summary(),
            },
            "acceptance_rate": self.acceptance_rate(),
            "iterations": int(self.settings["iterations"]),
            "burn_in": int(self.settings["burn_in"]),
            "thin": int(self.settings["thin"]),
            "draws_per_chain": self.n_draws,
            "chains": self.n_chains,
            "seed": self.seed,
            "runtime_s": self.runtime_s,
            "chain_runtime_s": self.chain_runtime_s.tolist(),
            "likelihood_evaluations": int(self.counts[:, 4].sum()),
            "settings": self.settings,
            "warnings": self.warnings(),
        } | ({"extra": self.extra} if self.extra else {})

    def table(self) -> str:
        """A readable table of the main results."""
        names = list(self.feature_names)
        w = max(8, max(len(n) for n in names))
        ci = self.ci(0.9)
        diag = self.diagnostics()
        head = (f"{'feature':<{w}}  {'P(c=1)':>7}  {'MAP c':>5}  {'MAP c*w_p':>10}  {'mean c*w_p':>10}  "
                f"{'90% interval':>22}  {'R-hat':>6}  {'ESS bulk':>8}  {'ESS tail':>8}")
        lines = [head, "-" * len(head)]
        for j, n in enumerate(names):
            lines.append(f"{n:<{w}}  {self.p_constraint[j]:7.3f}  {int(self.map_indicators[j]):5d}  "
                         f"{self.map_effective_penalty[j]:10.4g}  {self.mean_effective_penalty[j]:10.4g}  "
                         f"[{ci[j, 0]:9.4g}, {ci[j, 1]:9.4g}]  {diag.cells('feature', n)}")
        if self.parameter_names:
            pw = max(10, max(len(n) for n in self.parameter_names))
            lines.append("")
            lines.append(f"{'parameter':<{pw}}  {'MAP':>10}  {'mean':>10}  {'90% interval':>22}  {'R-hat':>6}  {'ESS bulk':>8}  {'ESS tail':>8}")
            mp = self.map_parameters_active
            for k, (n, v) in enumerate(self.parameter_summary().items()):
                lo, hi = (v["ci90"][0], v["ci90"][1]) if v["mean"] is not None else (np.nan, np.nan)
                mean = np.nan if v["mean"] is None else v["mean"]
                lines.append(f"{n:<{pw}}  {mp[k]:10.4g}  {mean:10.4g}  [{lo:9.4g}, {hi:9.4g}]  {diag.cells('parameter', n)}")
        acc = ", ".join(f"{k} {v:.1%}" for k, v in self.acceptance_rate().items())
        lines.append(f"method {self.method}; {self.n_chains} chains x {self.settings['iterations']:,} iterations "
                     f"({self.n_draws} kept each); acceptance {acc}; {self.runtime_s:.2f} s")
        lines.append(diag.footer())
        for msg in self.warnings():
            lines.append(f"warning: {msg}")
        return "\n".join(lines)

    def save(self, out_dir: str | os.PathLike[str], *, overwrite: bool = False) -> Path:
        """Write ``summary.json`` and ``chains.npz`` to ``out_dir`` atomically."""
        arrays = {"indicators": self.indicators, "penalty_weights": self.penalty_weights,
                  "effective_penalty": self.effective_penalty, "log_likelihood": self.log_likelihood,
                  "log_prior": self.log_prior, "feature_names": np.array(self.feature_names, dtype=np.str_),
                  "map_indicators": self.map_indicators, "map_penalty_weights": self.map_penalty_weights,
                  "parameters": self.parameters, "map_parameters": self.map_parameters,
                  "parameter_names": np.array(self.parameter_names, dtype=np.str_)}
        return write_run_dir(out_dir, {"summary.json": self.summary()}, {"chains.npz": arrays}, overwrite=overwrite)


def _py(x: Any) -> Any:
    if isinstance(x, (int, np.integer)):
        return int(x)
    x = float(x) if np.ndim(x) == 0 else x
    if isinstance(x, float) and not np.isfinite(x):
        return None
    return x


def write_run_dir(out_dir: str | os.PathLike[str], json_files: dict[str, Any], npz_files: dict[str, dict[str, Any]],
                  *, overwrite: bool = False) -> Path:
    """Create ``out_dir`` with the given files in one atomic rename (no half-written directory)."""
    out = Path(out_dir)
    if out.exists() and not overwrite:
        if out.is_dir() and not any(out.iterdir()):
            out.rmdir()
        else:
            raise FileExistsError(f"--out: {out} already exists; choose another directory or pass --overwrite")
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.tmp-", dir=out.parent))
    try:
        for name, content in json_files.items():
            (tmp / name).write_text(json.dumps(content, indent=2, default=_json_default) + "\n")
        for name, arrays in npz_files.items():
            np.savez_compressed(tmp / name, **arrays)
        if out.exists():
            backup = Path(tempfile.mkdtemp(prefix=f".{out.name}.old-", dir=out.parent))
            os.replace(out, backup / "old")
            os.replace(tmp, out)
            shutil.rmtree(backup, ignore_errors=True)
        else:
            os.replace(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return out


def _json_default(o: Any) -> Any:
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, np.generic):
        return o.item()
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")
