"""One driver for chains and draws: independent chains from one seed, spread over the cores."""

from __future__ import annotations

import multiprocessing as mp
import os
import time
from concurrent.futures import ProcessPoolExecutor
from typing import Any

import numpy as np

from pbicrl.constraints import ConstraintSet
from pbicrl.likelihood import PreferenceLikelihood
from pbicrl.results import Posterior
from pbicrl.samplers.kernels import ChainState, Kernel, SamplerSettings, build_kernel

__all__ = ["sample", "run_chain"]

_CHUNK = 20_000
_progress_counter: Any = None  # set in workers (inherited through fork) for the progress bar


def run_chain(kernel: Kernel, seed: np.random.SeedSequence | int, progress_counter: Any = None) -> dict[str, Any]:
    """Run one chain to completion; returns its draws, MAP, counters and runtime."""
    rng = np.random.default_rng(seed)
    s = kernel.settings
    out = kernel.new_buffers(s.n_draws)
    t0 = time.perf_counter()
    state: ChainState = kernel.init(rng)
    done = 0
    while done < s.n_iterations:
        n = min(_CHUNK, s.n_iterations - done)
        state = kernel.run(rng, state, n, out)
        done += n
        if progress_counter is not None:
            with progress_counter.get_lock():
                progress_counter.value += n
    runtime = time.perf_counter() - t0
    k = int(out[5][0])
    return {"indicators": out[0][:k], "penalty_weights": out[1][:k], "parameters": out[2][:k],
            "log_likelihood": out[3][:k], "log_prior": out[4][:k], "map_indicators": state.map_indicators,
            "map_penalty_weights": state.map_penalty_weights, "map_parameters": state.map_parameters,
            "map_log_posterior": state.map_log_posterior, "map_log_likelihood": state.map_log_likelihood,
            "counts": state.counts, "sigma": state.sigma, "q_mean": state.q_mean, "q_scale": state.q_scale,
            "sigma_theta": state.sigma_theta,
            "runtime_s": runtime}


def _worker(args: tuple[Kernel, np.random.SeedSequence]) -> dict[str, Any]:
    return run_chain(args[0], args[1], _progress_counter)


def _init_worker(counter: Any) -> None:
    global _progress_counter
    _progress_counter = counter


def sample(
    likelihood: PreferenceLikelihood,
    settings: SamplerSettings | None = None,
    *,
    n_chains: int = 4,
    seed: int = 0,
    n_jobs: int | None = None,
    progress: bool = True,
    feature_names: tuple[str, ...] | None = None,
    constraints: ConstraintSet | None = None,
    **overrides: Any,
) -> Posterior:
    """Sample the posterior with ``n_chains`` independent chains.

    Parameters
    ----------
    likelihood : PreferenceLikelihood
    settings : SamplerSettings, optional
        Keyword ``overrides`` replace fields, e.g. ``sample(lik, method="bpl", n_iterations=10_000)``.
    n_chains : int
        Independent chains; chain ``k`` uses the ``k``-th child of ``numpy.random.SeedSequence(seed)``,
        so results do not depend on ``n_jobs``.
    seed : int
    n_jobs : int, optional
        Worker processes (default: one per core, at most one per chain). 1 runs in-process.
    progress : bool
        Show a progress bar (on stderr).
    feature_names : tuple of str, optional
        Names of the known features (parametric constraints are named after themselves).
    constraints : ConstraintSet, optional
        Parametric constraints (paper Algorithm 2), appended after the known features.
    """
    kernel = build_kernel(likelihood, settings, constraints=constraints, **overrides)
    if int(n_chains) < 1:
        raise ValueError(f"chains: need at least 1 chain, got {n_chains}")
    seeds = np.random.SeedSequence(int(seed)).spawn(int(n_chains))
    n_jobs = min(int(n_chains), os.cpu_count() or 1) if n_jobs is None else max(1, min(int(n_jobs), int(n_chains)))
    total = int(kernel.settings.n_iterations) * int(n_chains)
    bar = _progress_bar(total, progress)
    t0 = time.perf_counter()
    if n_jobs == 1:
        results = []
        for s in seeds:
            counter = _LocalCounter(bar)
            results.append(run_chain(kernel, s, counter))
    else:
        ctx = mp.get_context("fork") if "fork" in mp.get_all_start_methods() else mp.get_context()
        counter = ctx.Value("q", 0)
        with ProcessPoolExecutor(max_workers=n_jobs, mp_context=ctx, initializer=_init_worker, initargs=(counter,)) as ex:
            futures = [ex.submit(_worker, (kernel, s)) for s in seeds]
            last = 0
            while not all(f.done() for f in futures):
                time.sleep(0.1)
                v = counter.value
                if bar is not None:
                    bar.update(v - last)
                last = v
            results = [f.result() for f in futures]
            if bar is not None:
                bar.update(counter.value - last)
    if bar is not None:
        bar.close()
    runtime = time.perf_counter() - t0
    return Posterior.from_chains(results, kernel=kernel, seed=int(seed), runtime_s=runtime,
                                 feature_names=feature_names)


class _LocalCounter:
    """Counter with the ``get_lock``/``value`` interface, updating a tqdm bar directly."""

    def __init__(self, bar: Any) -> None:
        self.bar = bar
        self.value = 0

    def get_lock(self) -> "_LocalCounter":
        return self

    def __enter__(self) -> None:
        self._before = self.value

    def __exit__(self, *exc: object) -> None:
        if self.bar is not None:
            self.bar.update(self.value - self._before)


def _progress_bar(total: int, enabled: bool) -> Any:
    if not enabled:
        return None
    from tqdm.auto import tqdm

    return tqdm(total=total, unit="it", unit_scale=True, desc="sampling", leave=False, mininterval=0.5)
