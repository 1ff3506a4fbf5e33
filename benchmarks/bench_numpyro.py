"""The pbicrl default model written by hand in NumPyro: effective draws per second, wall time and R-hat.

Issue 27 item 6(d): what a statistician would otherwise write. The same posterior as ``pbicrl infer`` with its
defaults (every feature a candidate, margins 0, beta 1):

* :math:`a_i = \\beta\\,\\bar\\phi_i^\\top (w_n + c \\circ w_p)` with :math:`w_n` the dataset's nominal weights;
* :math:`c_j \\sim \\mathrm{Bernoulli}(1/2)`;
* :math:`w_{p,j} \\mid c_j = 1` half-Student-t on :math:`(-\\infty, 0]`, 3 degrees of freedom, scale
  :math:`s_j = 2.5 / (\\beta\\,\\mathrm{sd}_j)` (``WeightPrior().resolve``: sd over trajectories, ``ddof=0``; a
  constant column uses sd 1). NumPyro cannot change the dimension of the parameter vector, so every
  :math:`w_j` is always drawn from that prior and multiplied by :math:`c_j` (the pseudo-prior trick with the
  prior as pseudo-prior): when :math:`c_j = 0` it is a free prior draw that the likelihood ignores. It is
  written non-centred, :math:`w_j = -s_j z_j` with :math:`z_j \\sim |t_3|`; NumPyro's NUTS moves
  :math:`\\log z_j` (the support transform of a positive site);
* the grouped Plackett-Luce log-likelihood (margins 0), ``numpyro.factor``:
  :math:`\\log L = \\sum_{k<K} \\log P_k`,
  :math:`P_k = \\int_0^\\infty e^{-t} \\prod_{i \\in G_k}(1 - e^{-t \\lambda_i / \\Lambda_k})\\,dt`.

Quadrature (float64). In :math:`s = \\log t` the integrand is
:math:`e^{g(s)}`, :math:`g(s) = s - e^s + \\sum_{i \\in G_k} \\log(1 - \\exp(-e^{s + x_i}))`,
:math:`x_i = a_i - \\log\\Lambda_k`; :math:`g` is concave with its mode in :math:`[0, \\log(n_k + 1)]`. Per evaluation:
a fixed number of safeguarded Newton steps find the mode :math:`s_0` and the curvature there
(:math:`\\sigma = (-g''(s_0))^{-1/2}`), both under ``stop_gradient``; then a fixed trapezoid rule of
261 nodes (``U_LEFT``, ``U_RIGHT``, ``U_STEP``) :math:`s = s_0 + \\sigma\\,m(u)` on a fixed :math:`u` grid, with
:math:`m(u) = u + c\\,(1 - e^{-\\gamma u})/\\gamma` stretching the slowly decaying left tail exponentially.
Gradients flow through the integrand values only, i.e. they are the exact gradients of the quadrature rule
with the nodes held where they are (the rule's value does not depend on where the nodes sit, to its accuracy).
``--verify`` compares it with pbicrl's exact kernel (``PreferenceLikelihood(..., likelihood="grouped")``) at
prior draws and at posterior-like weights.

Sampler: ``DiscreteHMCGibbs(NUTS(model))`` with NumPyro's defaults (Gibbs updates of the indicators from
their full conditionals, NUTS with adapted step size and diagonal mass matrix for the log-magnitudes),
4 chains run ``sequential``-ly on CPU JAX.

Reported quantities (ArviZ, rank-normalised split R-hat, bulk and tail ESS): the indicator :math:`c_j` of
every feature, :math:`\\log|w_j|` on the draws where :math:`c_j = 1` (each chain's active draws in order,
every chain cut to the shortest; skipped where fewer than ``--min-active`` active draws per chain), and the
total log-likelihood. A quantity constant over every draw of every chain (an indicator always on) counts as
converged and has no ESS. Effective draws per second = the smallest bulk or tail ESS over them divided by the
sampling wall time (warm-up + draws, compile excluded). Compile time = JAX's own trace + lowering + backend
compile durations (``jax.monitoring``), subtracted from the wall time of ``mcmc.run``.

Needs the ``bench`` extra (``pip install "pbicrl[bench]"``: NumPyro, JAX and the ``diag`` extra's ArviZ).

    nice python benchmarks/bench_numpyro.py --verify
    nice python benchmarks/bench_numpyro.py point_mass fetch_reach --json benchmarks/reports/numpyro.json
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

import pbicrl
from pbicrl.inference.likelihood import PreferenceLikelihood
from pbicrl.inference.priors import WeightPrior

__all__ = ["GroupedPL", "build_model", "prior_scales", "verify", "summarise", "run_numpyro", "main"]

INSTALL_HINT = 'NumPyro, JAX and ArviZ are needed for this benchmark: pip install "pbicrl[bench]"'

# Quadrature constants (checked by --verify against the exact kernel).
NEWTON_STEPS = 30
U_LEFT, U_RIGHT, U_STEP = -14.0, 12.0, 0.1  # u grid: 261 nodes (0.25: 105 nodes, 2e-4 off at posterior draws)
STRETCH_C, STRETCH_GAMMA = 0.15, 0.3
L_TINY = -30.0  # u below: log(1 - exp(-e^u)) = u - e^u / 2 to 1e-26
V_HUGE = 745.0  # e^u above: the factor 1 - exp(-v) is exactly 1


def _require_jax() -> tuple[Any, Any, Any]:
    try:
        import jax
        import jax.numpy as jnp
        import numpyro
        import arviz  # noqa: F401  (the diagnostics)
    except ImportError as exc:  # pragma: no cover - the message is the point
        raise SystemExit(f"{INSTALL_HINT} ({exc})") from None
    jax.config.update("jax_enable_x64", True)
    return jax, jnp, numpyro


class GroupedPL:
    """Grouped Plackett-Luce log-likelihood in JAX for one dataset (margins 0).

    Parameters
    ----------
    group : ndarray (N,)
        Group label per trajectory, lower = better.
    """

    def __init__(self, group: np.ndarray, *, u_left: float = U_LEFT, u_right: float = U_RIGHT,
                 u_step: float = U_STEP) -> None:
        jax, jnp, _ = _require_jax()
        self.jax, self.jnp = jax, jnp
        g = np.asarray(group)
        labels = np.unique(g)
        self.terms = []
        for k in range(labels.size - 1):
            top = np.flatnonzero(g == labels[k])
            rest = np.flatnonzero(g > labels[k])
            self.terms.append((jnp.asarray(top), jnp.asarray(rest)))
        u = np.arange(u_left, u_right + 0.5 * u_step, u_step)
        eg = np.exp(-STRETCH_GAMMA * u)
        self.m = jnp.asarray(u + STRETCH_C * (1.0 - eg) / STRETCH_GAMMA)  # m(u)
        w = np.full(u.size, u_step) * (1.0 + STRETCH_C * eg)  # trapezoid weight * m'(u) (ends negligible)
        self.logw = jnp.asarray(np.log(w))
        self.n_nodes = int(u.size)

        @jax.custom_jvp
        def log1m_exp_exp(u):  # L(u) = log(1 - exp(-e^u))
            v = jnp.exp(jnp.clip(u, L_TINY, 10.0))
            mid = jnp.where(v <= math.log(2.0), jnp.log(-jnp.expm1(-v)), jnp.log1p(-jnp.exp(-v)))
            low = u - 0.5 * jnp.exp(jnp.minimum(u, L_TINY))
            return jnp.where(u < L_TINY, low, jnp.where(u > 10.0, 0.0, mid))

        @log1m_exp_exp.defjvp
        def _jvp(primals, tangents):
            (u,), (du,) = primals, tangents
            return log1m_exp_exp(u), _phi(u) * du

        def _phi(u):  # L'(u) = v / (e^v - 1)
            v = jnp.exp(jnp.clip(u, L_TINY, 10.0))
            mid = v / jnp.expm1(v)
            return jnp.where(u < L_TINY, 1.0 - 0.5 * jnp.exp(jnp.minimum(u, L_TINY)), jnp.where(u > 10.0, 0.0, mid))

        def _dphi(u):  # L''(u) = phi (1 - v / (1 - e^{-v}))
            v = jnp.exp(jnp.clip(u, L_TINY, 10.0))
            d = _phi(u) * (1.0 - v / (-jnp.expm1(-v)))
            return jnp.where(u < L_TINY, -0.5 * jnp.exp(jnp.minimum(u, L_TINY)), jnp.where(u > 10.0, 0.0, d))

        self._L, self._phi, self._dphi = log1m_exp_exp, _phi, _dphi

    def _mode(self, x):
        """Mode of g and sigma (no gradient): safeguarded Newton on g' in [-1, log(n+1) + 1]."""
        jax, jnp = self.jax, self.jnp
        x = jax.lax.stop_gradient(x)
        n = x.shape[0]

        def d12(s):
            u = s + x
            return 1.0 - jnp.exp(s) + jnp.sum(self._phi(u)), -jnp.exp(s) + jnp.sum(self._dphi(u))

        def body(_, st):
            s, lo, hi = st
            d1, d2 = d12(s)
            lo = jnp.where(d1 > 0, s, lo)
            hi = jnp.where(d1 > 0, hi, s)
            sn = s - d1 / d2
            ok = (d2 < 0) & (sn >= lo) & (sn <= hi)  # >=: a converged step lands on its bracket end
            return jnp.where(ok, sn, 0.5 * (lo + hi)), lo, hi

        s0, _, _ = jax.lax.fori_loop(0, NEWTON_STEPS, body,
                                     (0.5 * math.log(n + 1.0), -1.0, math.log(n + 1.0) + 1.0))
        _, d2 = d12(s0)
        return s0, 1.0 / jnp.sqrt(-d2)

    def log_pk(self, x):
        """:math:`\\log P_k` for :math:`x_i = a_i - \\log\\Lambda_k`, shape (n_k,)."""
        jnp = self.jnp
        s0, sig = self._mode(x)
        s = s0 + sig * self.m  # (Q,)
        gs = s - jnp.exp(s) + jnp.sum(self._L(s[:, None] + x[None, :]), axis=1)
        return self.jax.scipy.special.logsumexp(gs + self.logw) + jnp.log(sig)

    def __call__(self, a):
        """Total log-likelihood for scaled returns ``a`` (N,)."""
        jax = self.jax
        total = 0.0
        for top, rest in self.terms:
            log_lam = jax.scipy.special.logsumexp(a[rest])
            total = total + self.log_pk(a[top] - log_lam)
        return total


def prior_scales(dataset: pbicrl.Dataset, beta: float = 1.0) -> np.ndarray:
    """:math:`s_j` of the default prior, from pbicrl itself (so the model cannot drift from it)."""
    res = WeightPrior().resolve(dataset.mean_features, beta=beta)
    assert res.prior.kind == "student_t" and res.prior.df == 3.0 and res.prior.sign == "negative"
    return np.asarray(res.scale, dtype=np.float64)


def build_model(dataset: pbicrl.Dataset, beta: float = 1.0):
    """The NumPyro model and its likelihood object."""
    jax, jnp, numpyro = _require_jax()
    import numpyro.distributions as dist

    F = jnp.asarray(beta * np.asarray(dataset.mean_features, dtype=np.float64))
    wn = jnp.asarray(np.asarray(dataset.nominal_weights, dtype=np.float64))
    scale = jnp.asarray(prior_scales(dataset, beta))
    lik = GroupedPL(dataset.group)
    d = F.shape[1]
    half_t = dist.FoldedDistribution(dist.StudentT(3.0, 0.0, 1.0))

    def model():
        with numpyro.plate("feature", d):
            c = numpyro.sample("c", dist.Bernoulli(0.5))
            z = numpyro.sample("z", half_t)  # |w_j| / s_j, always drawn (pseudo-prior = prior)
        w = -scale * z
        a = F @ (wn + c * w)
        ll = lik(a)
        numpyro.deterministic("w", w)
        numpyro.deterministic("loglik", ll)
        numpyro.factor("grouped_pl", ll)

    return model, lik


def verify(dataset: pbicrl.Dataset, n_random: int = 20, seed: int = 0, posterior_w: np.ndarray | None = None,
           posterior_c: np.ndarray | None = None) -> dict[str, Any]:
    """Largest relative difference of the JAX quadrature from pbicrl's exact grouped kernel.

    Weights: ``n_random`` prior draws (random indicators, half-t penalties), ``n_random`` draws with the
    penalties shrunk (prior / 20), ``n_random`` with :math:`|w_j| / s_j` log-uniform on [1, 100] (near-certain
    orderings: the posterior of separated groups), and the given posterior draws.
    """
    jax, jnp, _ = _require_jax()
    exact = PreferenceLikelihood.from_dataset(dataset, likelihood="grouped")
    lik = GroupedPL(dataset.group)
    F = np.asarray(dataset.mean_features, dtype=np.float64)
    f = jax.jit(lambda a: lik(a))
    g = jax.jit(jax.grad(lambda a: lik(a)))
    rng = np.random.default_rng(seed)
    scale = prior_scales(dataset)
    d = F.shape[1]
    cases = []
    for shrink in (1.0, 20.0):
        for _ in range(n_random):
            c = rng.integers(0, 2, d).astype(float)
            w = -np.abs(rng.standard_t(3.0, d)) * scale / shrink
            cases.append((f"prior/{shrink:g}", w, c))
    for _ in range(n_random):  # near-certain orderings, as in the posterior of separated data
        c = rng.integers(0, 2, d).astype(float)
        w = -scale * np.exp(rng.uniform(0.0, math.log(100.0), d))
        cases.append(("separating", w, c))
    if posterior_w is not None:
        for w, c in zip(posterior_w, posterior_c):
            cases.append(("posterior", np.asarray(w, float), np.asarray(c, float)))
    worst = {}
    rows = []
    for label, w, c in cases:
        ref = exact(w, c)
        a = exact.beta * (F @ exact.weights(w, c))
        val = float(f(jnp.asarray(a)))
        rel = abs(val - ref) / max(abs(ref), 1e-300)
        grad = np.asarray(g(jnp.asarray(a)))
        rows.append({"set": label, "exact": ref, "jax": val, "rel": rel, "grad_finite": bool(np.all(np.isfinite(grad)))})
        worst[label] = max(worst.get(label, 0.0), rel)
    # gradient against central differences of the exact kernel along a random direction, at 5 cases
    gchecks = []
    for label, w, c in cases[n_random:n_random + 5]:
        a = exact.beta * (F @ exact.weights(w, c))
        dirn = rng.standard_normal(a.size)
        eps = 1e-5
        fd = (exact.from_scaled_returns(a + eps * dirn) - exact.from_scaled_returns(a - eps * dirn)) / (2 * eps)
        an = float(np.asarray(g(jnp.asarray(a))) @ dirn)
        gchecks.append(abs(an - fd) / max(abs(fd), 1e-12))
    return {"n_cases": len(rows), "max_rel_by_set": worst, "max_rel": max(r["rel"] for r in rows),
            "all_grad_finite": all(r["grad_finite"] for r in rows),
            "grad_vs_central_difference_max_rel": max(gchecks), "nodes": lik.n_nodes,
            "newton_steps": NEWTON_STEPS, "cases": rows}


class _CompileClock:
    """Union of JAX's trace, lowering and backend-compile time spans (seconds) while it is active."""

    EVENTS = ("/jax/core/compile/jaxpr_trace_duration", "/jax/core/compile/jaxpr_to_mlir_module_duration",
              "/jax/core/compile/backend_compile_duration")

    def __init__(self) -> None:
        self.spans: list[tuple[float, float]] = []

    def __call__(self, event: str, start_time: float, end_time: float, **_: Any) -> None:
        if event in self.EVENTS:
            self.spans.append((start_time, end_time))

    def __enter__(self) -> "_CompileClock":
        import jax.monitoring

        jax.monitoring.register_event_time_span_listener(self)
        return self

    def __exit__(self, *exc: Any) -> None:
        import jax.monitoring

        jax.monitoring.unregister_event_time_span_listener(self)

    @property
    def seconds(self) -> float:
        total, end = 0.0, -math.inf
        for a, b in sorted(self.spans):  # nested spans (a trace inside a trace) count once
            if b > end:
                total += b - max(a, end)
                end = b
        return total


def _diag(x: np.ndarray) -> dict[str, Any]:
    """Split R-hat, bulk and tail ESS (ArviZ, rank-normalised) of draws shaped (chains, draws)."""
    import arviz as az

    x = np.asarray(x, dtype=np.float64)
    if np.ptp(x) == 0.0:
        return {"constant": True, "value": float(x.flat[0]), "rhat": 1.0, "ess_bulk": None, "ess_tail": None}
    return {"constant": False, "rhat": float(az.rhat(x, method="rank")), "ess_bulk": float(az.ess(x, method="bulk")),
            "ess_tail": float(az.ess(x, method="tail"))}


def summarise(c: np.ndarray, w: np.ndarray, loglik: np.ndarray, names: tuple[str, ...],
              min_active: int = 50) -> dict[str, Any]:
    """Diagnostics of the reported quantities from draws ``c``, ``w`` (chains, draws, d) and ``loglik``.

    :math:`\\log|w_j|` given :math:`c_j = 1`: each chain's active draws in order, every chain cut to the shortest
    active run (``min_active`` at least, else not assessed).
    """
    out: dict[str, Any] = {"quantities": {}}
    q = out["quantities"]
    for j, name in enumerate(names):
        cj = c[:, :, j].astype(np.float64)
        q[f"c[{name}]"] = {**_diag(cj), "mean": float(cj.mean()), "chain_means": cj.mean(axis=1).tolist()}
        counts = cj.sum(axis=1).astype(int)
        entry: dict[str, Any] = {"active_per_chain": counts.tolist()}
        if counts.min() >= min_active:
            m = int(counts.min())
            act = np.stack([np.log(-w[k, cj[k] == 1, j])[:m] for k in range(c.shape[0])])
            wa = np.concatenate([w[k, cj[k] == 1, j] for k in range(c.shape[0])])
            entry.update(_diag(act))
            entry.update({"draws_per_chain_used": m, "median_w": float(np.median(wa)),
                          "q05_w": float(np.quantile(wa, 0.05)), "q95_w": float(np.quantile(wa, 0.95))})
        else:
            entry.update({"assessed": False, "reason": f"fewer than {min_active} active draws in some chain"})
        q[f"log|w|[{name}] | c=1"] = entry
    q["loglik"] = {**_diag(loglik), "mean": float(np.mean(loglik))}
    ess = [v[k] for v in q.values() if not v.get("constant", True) for k in ("ess_bulk", "ess_tail")
           if v.get(k) is not None]
    rh = [v["rhat"] for v in q.values() if "rhat" in v]
    out["min_ess"] = float(min(ess)) if ess else None
    out["max_rhat"] = float(max(rh)) if rh else None
    return out


def run_numpyro(dataset: pbicrl.Dataset, *, chains: int = 4, warmup: int = 1000, samples: int = 1000,
                chain_method: str = "sequential", seed: int = 0, progress_bar: bool = True,
                min_active: int = 50) -> dict[str, Any]:
    """One NumPyro run of the default model: timings and diagnostics of the reported quantities."""
    jax, jnp, numpyro = _require_jax()
    from numpyro.infer import MCMC, NUTS, DiscreteHMCGibbs

    model, lik = build_model(dataset)
    kernel = DiscreteHMCGibbs(NUTS(model))
    mcmc = MCMC(kernel, num_warmup=warmup, num_samples=samples, num_chains=chains, chain_method=chain_method,
                progress_bar=progress_bar)
    with _CompileClock() as clock:
        t0, cpu0 = time.perf_counter(), time.process_time()
        mcmc.run(jax.random.PRNGKey(seed))
        jax.block_until_ready(mcmc.get_samples())
        wall, cpu = time.perf_counter() - t0, time.process_time() - cpu0
    compile_s = clock.seconds
    sampling_s = wall - compile_s
    smp = mcmc.get_samples(group_by_chain=True)
    c = np.asarray(smp["c"])
    w = np.asarray(smp["w"])
    ll = np.asarray(smp["loglik"])
    diag = summarise(c, w, ll, tuple(dataset.feature_names), min_active)
    iters = chains * (warmup + samples)
    out = {"chains": chains, "warmup": warmup, "samples": samples, "chain_method": chain_method, "seed": seed,
           "progress_bar": progress_bar, "wall_s": wall, "compile_s": compile_s, "sampling_s": sampling_s,
           # CPU seconds of the process (all threads) over the whole run, compile included: on a shared machine
           # wall / CPU says how much of a core the run got
           "process_cpu_s": cpu,
           "seconds_per_1000_iterations_per_chain": sampling_s / iters * 1000.0,
           **diag,
           "effective_draws_per_s": (diag["min_ess"] / sampling_s) if diag["min_ess"] else None,
           "converged": bool(diag["max_rhat"] is not None and diag["max_rhat"] < 1.01
                             and (diag["min_ess"] is None or diag["min_ess"] >= 400)),
           "p_constraint": {n: float(c[:, :, j].mean()) for j, n in enumerate(dataset.feature_names)}}
    try:
        extra = mcmc.get_extra_fields(group_by_chain=True)
        if "diverging" in extra:
            out["divergences"] = int(np.asarray(extra["diverging"]).sum())
    except Exception:  # noqa: BLE001 - optional detail
        pass
    return out, (c, w, ll)


def _versions() -> dict[str, str]:
    import arviz
    import jax
    import jaxlib
    import numpyro

    return {"numpyro": numpyro.__version__, "jax": jax.__version__, "jaxlib": jaxlib.__version__,
            "arviz": arviz.__version__, "numpy": np.__version__, "pbicrl": pbicrl.__version__,
            "python": platform.python_version(), "cpu_count": str(os.cpu_count())}


def _loadavg() -> list[float] | None:
    """1, 5 and 15 minute load averages (other jobs share the machine), where the OS reports them."""
    try:
        return [float(x) for x in os.getloadavg()]
    except (AttributeError, OSError):
        return None


def _write_json(path: Path, obj: Any) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    with os.fdopen(fd, "w") as fh:
        json.dump(obj, fh, indent=2)
    os.chmod(tmp, 0o644)
    os.replace(tmp, path)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("data", nargs="*", default=["point_mass", "fetch_reach"],
                    help="shipped dataset names (pbicrl.load_dataset) or .npz paths")
    ap.add_argument("--chains", type=int, default=4)
    ap.add_argument("--warmup", type=int, default=1000)
    ap.add_argument("--samples", type=int, default=1000)
    ap.add_argument("--chain-method", choices=("sequential", "vectorized"), default="sequential")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--min-active", type=int, default=50)
    ap.add_argument("--no-progress", action="store_true", help="NumPyro's progress_bar=False")
    ap.add_argument("--verify", action="store_true", help="compare the JAX likelihood with pbicrl's exact kernel")
    ap.add_argument("--no-run", action="store_true", help="with --verify: verify only")
    ap.add_argument("--json", type=Path, default=None, help="write the results here (atomically)")
    args = ap.parse_args(argv)
    _require_jax()
    report: dict[str, Any] = {"versions": _versions(), "command": " ".join(sys.argv), "runs": {},
                              "loadavg_at_start": _loadavg()}
    for name in args.data:
        ds = pbicrl.load_dataset(name)
        entry: dict[str, Any] = {"n_trajectories": int(ds.n_trajectories), "n_features": int(ds.n_features),
                                 "group_counts": {str(k): int(v) for k, v in ds.group_counts().items()}}
        if not args.no_run:
            res, (c, w, ll) = run_numpyro(ds, chains=args.chains, warmup=args.warmup, samples=args.samples,
                                          chain_method=args.chain_method, seed=args.seed,
                                          progress_bar=not args.no_progress, min_active=args.min_active)
            entry["numpyro"] = res
            print(f"== {name}: wall {res['wall_s']:.1f} s (compile {res['compile_s']:.1f} s, sampling "
                  f"{res['sampling_s']:.1f} s), min ESS {res['min_ess']}, max R-hat {res['max_rhat']:.4f}, "
                  f"effective draws/s {res['effective_draws_per_s']}")
            for k, v in res["quantities"].items():
                print(f"   {k:38s} {json.dumps({kk: vv for kk, vv in v.items() if kk != 'chain_means'})}")
        if args.verify:
            kw = {}
            if not args.no_run:  # 20 posterior draws as well
                flat_c = c.reshape(-1, c.shape[-1])
                flat_w = w.reshape(-1, w.shape[-1])
                pick = np.random.default_rng(args.seed).choice(flat_c.shape[0], 20, replace=False)
                kw = {"posterior_w": flat_w[pick], "posterior_c": flat_c[pick]}
            ver = verify(ds, seed=args.seed, **kw)
            entry["verify"] = {k: v for k, v in ver.items() if k != "cases"}
            print(f"   verify: {json.dumps(entry['verify'])}")
        entry["loadavg_after"] = _loadavg()
        report["runs"][name] = entry
        if args.json is not None:  # after every dataset: a long run keeps what it measured
            _write_json(args.json, report)


if __name__ == "__main__":
    main()
