"""One driver for chains and draws: independent chains from one seed, spread over the cores.

Chain workers never outlive the process that started them: each asks the kernel to end it when its parent
dies (``PR_SET_PDEATHSIG`` on Linux, a watchdog thread elsewhere; :func:`die_with_parent`), so ``kill -TERM``
or ``kill -KILL`` of a ``pbicrl`` process leaves no chain running. Workers ignore SIGINT: on Ctrl-C (or
``kill -INT``) the parent stops them at once instead of waiting for their chains to finish.

The compiled sampler is cached on disk by Numba; the first run of an installation compiles it (about 15 s),
which :func:`sample` announces on stderr when it shows progress.

Per-draw statistics (:class:`_DrawStats`): besides the draws, every chain records for each kept draw the move
type of the iteration that produced it (:data:`MOVE_CODES`), whether that move was accepted, and the fraction
of iterations accepted since the previous kept draw. The compiled loop keeps counters only, so the driver runs
each chunk with ``thin = 1`` (the thinning only selects what is stored: the chain is the same) and reads the
acceptances off consecutive states; the move types follow from the chunk's random numbers, drawn again from a
copy of the generator. The kept draws, the chain and its random numbers are unchanged bit for bit. Cost: the
stored states of one chunk (20,000 rows) and, only when warm-up ends inside a chunk exactly at an adaptation
step, a replay of that chunk's warm-up part, once per chain (never with the default 400,000 iterations).
"""

from __future__ import annotations

import copy
import dataclasses
import multiprocessing as mp
import os
import signal
import sys
import threading
import time
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from typing import Any, Sequence

import numpy as np

from pbicrl.inference.codes import MOVE_FLIP, MOVE_NONE, MOVE_PARAMETER, MOVE_WEIGHT, MOVES
from pbicrl.inference.constraints import ConstraintSet
from pbicrl.inference.likelihood import PreferenceLikelihood
from pbicrl.inference.results import Posterior
from pbicrl.inference.samplers.kernels import ADAPT_EVERY, ChainState, Kernel, SamplerSettings, build_kernel

__all__ = ["progress_bar", "sample", "run_chain", "die_with_parent", "stop_pool", "sampler_needs_compiling", "MOVE_CODES"]

# Fixed: the random numbers of a chunk are drawn at once, so the chunk size is part of a chain's result.
_CHUNK = 20_000
_progress_counter: Any = None  # set in workers (inherited through fork) for the progress bar
_COMPILE_NOTE = "pbicrl: compiling the sampler (first run only, ~15 s)..."

MOVE_CODES = MOVES
"""Per-draw move codes (``Posterior.move``): the move the compiled loop chose at the iteration of a kept draw."""


# ---------------------------------------------------------------------------------------------- processes
def _prctl_pdeathsig(sig: int) -> bool:
    """``prctl(PR_SET_PDEATHSIG, sig)``: the kernel sends ``sig`` to this process when its parent exits."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        PR_SET_PDEATHSIG = 1
        return libc.prctl(ctypes.c_int(PR_SET_PDEATHSIG), ctypes.c_ulong(sig), ctypes.c_ulong(0),
                          ctypes.c_ulong(0), ctypes.c_ulong(0)) == 0
    except (OSError, AttributeError, TypeError):
        return False


def _exit_now(sig: int) -> None:
    try:
        os.kill(os.getpid(), sig)
        time.sleep(5.0)  # a handler may stop the process more gently; give it a moment
    finally:
        os._exit(1)


def _watch_parent(parent: int, sig: int, interval: float) -> None:
    while True:
        time.sleep(interval)
        if os.getppid() != parent:
            _exit_now(sig)


def die_with_parent(parent: int | None = None, *, sig: int | None = None, interval: float = 0.5) -> None:
    """End this (child) process when its parent process ends, however the parent ends.

    Call it first thing in a worker (e.g. as a pool ``initializer``). On Linux the kernel delivers ``sig``
    when the parent exits (``PR_SET_PDEATHSIG``, immediate, even while the worker runs compiled code);
    elsewhere a daemon thread polls the parent id every ``interval`` seconds.

    Parameters
    ----------
    parent : int, optional
        The parent's pid as the parent saw it (``os.getpid()`` passed in ``initargs``). If this process has
        already been re-parented (the parent died before the call), it exits at once.
    sig : int, optional
        Signal to end with (default ``SIGKILL``: chains hold nothing worth cleaning up; the parent's next run
        removes the temporaries of killed workers).
    interval : float
        Polling period of the fallback watchdog, in seconds.
    """
    if sig is None:
        sig = int(getattr(signal, "SIGKILL", signal.SIGTERM))
    expected = os.getppid() if parent is None else int(parent)
    armed = _prctl_pdeathsig(sig)
    if os.getppid() != expected:  # the parent died before the request took effect
        _exit_now(sig)
    if not armed:
        threading.Thread(target=_watch_parent, args=(expected, sig, interval), daemon=True,
                         name="pbicrl-parent-watchdog").start()


def _init_worker(counter: Any, parent: int | None = None) -> None:
    global _progress_counter
    die_with_parent(parent)
    # Ctrl-C reaches the whole process group; the parent alone decides, and stops the workers itself.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    # A SIGTERM handler inherited through fork (a sweep's, ICL's) must not keep a chain alive on terminate().
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    _progress_counter = counter


def stop_pool(pool: ProcessPoolExecutor, *, grace: float = 2.0) -> None:
    """Stop a process pool now, running work included: SIGTERM, then SIGKILL after ``grace`` seconds."""
    processes = list((getattr(pool, "_processes", None) or {}).values())  # no public API before Python 3.14
    pool.shutdown(wait=False, cancel_futures=True)
    for p in processes:
        if p.is_alive():
            p.terminate()
    deadline = time.monotonic() + grace
    for p in processes:
        p.join(timeout=max(0.0, deadline - time.monotonic()))
    for p in processes:
        if p.is_alive():  # a worker that handles SIGTERM (e.g. to checkpoint) and takes too long
            p.kill()
            p.join(timeout=grace)


# ---------------------------------------------------------------------------------------------- compiling
def sampler_needs_compiling() -> bool:
    """Whether the next chain will compile the sampler: not yet compiled in this process, and no entry in
    Numba's on-disk cache for the current source. Cheap (reads one small index file); False when unsure."""
    try:
        from pbicrl.inference.samplers import _mcmc

        dispatcher = _mcmc.advance
        if dispatcher.signatures:
            return False
        cache_file = getattr(getattr(dispatcher, "_cache", None), "_cache_file", None)
        if cache_file is None:
            return False
        return not cache_file._load_index()  # {} when missing or made from another version of the source
    except Exception:  # Numba internals differ between versions: never fail (or talk) because of this check
        return False


def _compile_here(kernel: Kernel) -> None:
    """Compile the sampler in this process (one iteration on a throwaway state), so that forked workers
    inherit the machine code instead of each compiling it again."""
    rng = np.random.default_rng(0)
    kernel.run(rng, kernel.init(rng), 1, kernel.new_buffers(1))


# ---------------------------------------------------------------------------------------------- chains
def run_chain(kernel: Kernel, seed: np.random.SeedSequence | int, progress_counter: Any = None) -> dict[str, Any]:
    """Run one chain to completion; returns its draws, MAP, counters, per-draw statistics and runtime.

    Per kept draw: ``move`` (int8, :data:`MOVE_CODES`), ``accepted`` (bool) and ``acceptance_fraction`` (the
    fraction of iterations accepted since the previous kept draw; for the first, its own iteration).
    """
    rng = np.random.default_rng(seed)
    s = kernel.settings
    out = kernel.new_buffers(s.n_draws)
    stats = _DrawStats(kernel, s.n_draws)
    t0 = time.perf_counter()
    state: ChainState = kernel.init(rng)
    done = 0
    while done < s.n_iterations:
        n = min(_CHUNK, s.n_iterations - done)
        state = stats.run(rng, state, n, out)
        done += n
        if progress_counter is not None:
            with progress_counter.get_lock():
                progress_counter.value += n
    runtime = time.perf_counter() - t0
    k = int(out[5][0])
    best, adapt = state.best, state.adaptation
    return {"indicators": out.indicators[:k], "penalty_weights": out.penalty_weights[:k],
            "parameters": out.parameters[:k], "log_likelihood": out.log_likelihood[:k], "log_prior": out.log_prior[:k],
            "map_indicators": best.indicators, "map_penalty_weights": best.penalty_weights,
            "map_parameters": best.parameters, "map_log_posterior": state.map_log_posterior,
            "map_log_likelihood": state.map_log_likelihood, "counts": state.counts, "sigma": adapt.sigma,
            "q_mean": adapt.q_mean, "q_scale": adapt.q_scale, "sigma_theta": adapt.sigma_theta, "move": stats.move[:k], "accepted": stats.accepted[:k],
            "acceptance_fraction": stats.fraction[:k],
            "runtime_s": runtime}


@dataclasses.dataclass(frozen=True, eq=False)
class _ReplayKernel(Kernel):
    """A kernel that takes its random numbers from ``randoms`` (one chunk's, drawn before) instead of a generator."""

    randoms: tuple[np.ndarray, ...] = ()

    def draw_randoms(self, rng: Any, n: int) -> tuple[np.ndarray, ...]:
        return tuple(r[:n] for r in self.randoms)


def _move_codes(kernel: Kernel, iterations: np.ndarray, u_j: np.ndarray, u_mv: np.ndarray,
               indicators_after: np.ndarray) -> np.ndarray:
    """The move the compiled loop chooses at each of ``iterations`` (:data:`MOVE_CODES`), from that iteration's
    feature and move uniforms and the indicators :math:`c` after it.

    The choice depends on :math:`c` before the iteration only for a ``pbicrl`` weight or parameter step (it picks
    among the active features, none if no feature is active); such a step leaves :math:`c` unchanged, so the
    indicators after it are the ones it saw.
    """
    s = kernel.settings
    cand = kernel._cand
    nc = cand.size
    dk = kernel.d_known
    p_theta = kernel.p_theta_
    j = cand[np.minimum((u_j * nc).astype(np.int64), nc - 1)]  # the loop's int(u * nc): truncation
    theta_move = (j >= dk) & (u_mv < p_theta)
    if s.method in ("paper", "authors"):
        first = 0 if s.method == "authors" else 1  # the paper counts iterations from 1, the authors' code from 0
        code = np.where((np.asarray(iterations) + first) % int(s.f_s) != 0, MOVE_FLIP,
                        np.where(theta_move, MOVE_PARAMETER, MOVE_WEIGHT))
    elif s.method == "bpl":
        code = np.where(theta_move, MOVE_PARAMETER, MOVE_WEIGHT)
    else:
        flip = u_mv < s.p_flip
        want_theta = u_mv < s.p_flip + p_theta
        on = np.asarray(indicators_after)[:, cand] == 1
        n_on = np.where(want_theta, (on & (cand >= dk)[None, :]).sum(axis=1), on.sum(axis=1))
        code = np.where(flip, MOVE_FLIP, np.where(n_on > 0, np.where(want_theta, MOVE_PARAMETER, MOVE_WEIGHT),
                                                   MOVE_NONE))
    return code.astype(np.int8)


def _last_warmup_adapts(settings: SamplerSettings) -> bool:
    """Whether the last warm-up iteration adapts the proposals (then storing it instead would change the chain)."""
    return bool(settings.adapt_) and settings.burn_in_ > 0 and settings.burn_in_ % ADAPT_EVERY == 0


class _DrawStats:
    r"""Runs a chain's chunks and records per-draw move codes, acceptances and acceptance fractions.

    Each chunk runs under a copy of the kernel with ``thin = 1`` into a scratch buffer, so that every iteration
    after warm-up is stored; the rows the real thinning keeps are copied into the chain's buffers (the same
    values the kernel would have stored), and a move counts as accepted when it changed :math:`(c, w_p,
    \vartheta)` (a rejected move changes nothing; an accepted one changes the state with probability one).
    When warm-up ends inside a chunk, the state just before the first kept iteration is needed for its flag.
    Running that chunk with ``burn_in`` one less stores it and leaves the chain unchanged, unless the last
    warm-up iteration adapts the proposals (adaptation on and ``burn_in`` a multiple of the adaptation period):
    then a replay of the chunk's warm-up iterations (same random numbers, ``burn_in`` one less) gives it.
    """

    def __init__(self, kernel: Kernel, n_draws: int) -> None:
        self.kernel = kernel
        s = kernel.settings
        self.burn_in, self.thin = s.burn_in_, s.thin_
        self.every = dataclasses.replace(kernel, settings=dataclasses.replace(s, thin=1))
        self.adapts_last = _last_warmup_adapts(s)
        self.move = np.zeros(n_draws, np.int8)
        self.accepted = np.zeros(n_draws, bool)
        self.fraction = np.zeros(n_draws)
        self._acc_since = 0  # accepted iterations since the previous kept draw (carried across chunks)
        self._n_since = 0
        poff = np.asarray(kernel.constraints.param_offsets) if kernel.constraints is not None else np.zeros(1, int)
        self._owner = np.repeat(np.arange(poff.size - 1), np.diff(poff)) + kernel.d_known  # feature of each theta

    def _row(self, state: ChainState) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``state`` as the compiled loop stores a draw (``pbicrl`` stores NaN for inactive constraints' theta)."""
        theta = np.asarray(state.parameters, dtype=np.float64).copy()
        if self.kernel.settings.method == "pbicrl" and theta.size:
            theta[np.asarray(state.indicators)[self._owner] == 0] = np.nan
        return (np.asarray(state.indicators)[None], np.asarray(state.penalty_weights)[None], theta[None])

    def _state_before(self, state: ChainState, randoms: tuple[np.ndarray, ...], m: int) -> tuple[np.ndarray, ...]:
        """The stored row of iteration ``burn_in - 1``, reached ``m`` iterations into the chunk that starts at
        ``state``: replayed with ``burn_in - 1`` (identical up to and including that iteration's move)."""
        s = self.kernel.settings
        k = self.kernel
        shadow = _ReplayKernel(k.likelihood, dataclasses.replace(s, burn_in=self.burn_in - 1, thin=1), k.constraints,
                               randoms=randoms)
        buf = shadow.new_buffers(1)
        shadow.run(None, state, m, buf)  # type: ignore[arg-type]  # the replay kernel ignores the generator
        return buf[0][:1], buf[1][:1], buf[2][:1]

    def run(self, rng: np.random.Generator, state: ChainState, n: int, out: tuple[np.ndarray, ...]) -> ChainState:
        """``kernel.run(rng, state, n, out)`` with the same result, recording the per-draw statistics."""
        it0, b = int(state.iteration), self.burn_in
        first = max(it0, b)
        if it0 + n <= b:  # all warm-up: nothing is kept
            return self.kernel.run(rng, state, n, out)
        replay = copy.deepcopy(rng)  # Kernel.run draws the chunk's random numbers first, from rng alone
        m = first - it0
        n_kept = it0 + n - first
        one_more = int(m > 0 and not self.adapts_last)  # also store iteration burn_in - 1: the state before
        runner = self.every
        if one_more:
            runner = dataclasses.replace(self.every, settings=dataclasses.replace(self.every.settings,
                                                                                  burn_in=self.burn_in - 1))
        buf = runner.new_buffers(n_kept + one_more)
        new = runner.run(rng, state, n, buf)
        if int(buf[5][0]) != n_kept + one_more:  # pragma: no cover - every iteration after warm-up is stored
            raise RuntimeError(f"sampling: expected {n_kept + one_more} stored iterations, got {int(buf[5][0])}")
        randoms = self.kernel.draw_randoms(replay, n)
        if one_more:
            prev = tuple(x[:1] for x in buf[:3])
            buf = tuple(x[1:] for x in buf[:5]) + (buf[5],)
        else:
            prev = self._row(state) if m == 0 else self._state_before(state, randoms, m)
        c, w, t = buf[0], buf[1], buf[2]
        cc, ww, tt = (np.concatenate([p, x]) for p, x in zip(prev, (c, w, t)))
        changed = (np.any(cc[1:] != cc[:-1], axis=1) | np.any(ww[1:] != ww[:-1], axis=1)
                   | np.any((tt[1:] != tt[:-1]) & ~(np.isnan(tt[1:]) & np.isnan(tt[:-1])), axis=1))
        its = np.arange(first, it0 + n)
        keep = np.flatnonzero((its - b) % self.thin == 0)
        r0 = int(out[5][0])
        k = min(keep.size, out[3].size - r0)
        keep = keep[:k]
        for dst, src in zip(out[:5], buf[:5]):
            dst[r0:r0 + k] = src[keep]
        out[5][0] = r0 + k
        self.move[r0:r0 + k] = _move_codes(self.kernel, its[keep], randoms[0][m + keep], randoms[1][m + keep], c[keep])
        self.accepted[r0:r0 + k] = changed[keep]
        cum = np.concatenate([[0], np.cumsum(changed)])
        ends = keep + 1
        starts = np.concatenate([[0], ends[:-1]])
        acc = cum[ends] - cum[starts]
        cnt = ends - starts
        if k:
            acc[0] += self._acc_since
            cnt[0] += self._n_since
            self.fraction[r0:r0 + k] = acc / cnt
            self._acc_since, self._n_since = 0, 0
        tail = ends[-1] if k else 0
        self._acc_since += int(cum[-1] - cum[tail])
        self._n_since += int(n_kept - tail)
        return new


def _worker(args: tuple[Kernel, np.random.SeedSequence]) -> dict[str, Any]:
    return run_chain(args[0], args[1], _progress_counter)


def _feature_names(likelihood: PreferenceLikelihood, given: Sequence[str] | None) -> tuple[str, ...] | None:
    """The names of the known features: ``given``, else the likelihood's own (if it carries them)."""
    names = given if given is not None else getattr(likelihood, "feature_names", None)
    if names is None or (not isinstance(names, str) and len(names) == 0 and given is None):
        return None
    if isinstance(names, (str, bytes)):
        raise ValueError(f"feature_names: expected a sequence of names, got the single string {names!r}")
    out = tuple(n.decode("utf-8") if isinstance(n, bytes) else n for n in names)
    d = likelihood.n_features
    if len(out) != d:
        raise ValueError(f"feature_names: expected {d} names (one per feature of the likelihood), got {len(out)}")
    if not all(isinstance(n, str) and n.strip() for n in out):
        raise ValueError(f"feature_names: expected non-empty strings, got {list(out)}")
    if len(set(out)) != d:
        raise ValueError(f"feature_names: names must be unique, got {list(out)}")
    return out


def sample(
    likelihood: PreferenceLikelihood,
    settings: SamplerSettings | None = None,
    *,
    n_chains: int = 4,
    seed: int = 0,
    n_jobs: int | None = None,
    progress: bool = True,
    feature_names: Sequence[str] | None = None,
    constraints: ConstraintSet | None = None,
    identified: Any = None,
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
        Worker processes (default: one per core, at most one per chain). 1 runs in-process; compiled code
        cannot be interrupted, so Ctrl-C then takes effect at the end of the current chunk of 20,000
        iterations (with workers it stops them at once).
    progress : bool
        Show a progress bar (on stderr), preceded by a note when the sampler has to be compiled first.
    feature_names : sequence of str, optional
        Names of the known features, one per column of the likelihood (``dataset.feature_names``). Default:
        the likelihood's ``feature_names`` if it has them, else ``f0, f1, ...``. Parametric constraints are
        named after themselves.
    constraints : ConstraintSet, optional
        Parametric constraints (paper Algorithm 2), appended after the known features.
    identified : Identification or dict, optional
        Result of :func:`pbicrl.analysis.identify.identify` for these data: recorded in ``summary.json`` and used for
        the warnings and the ``prior_driven`` flags.

    Raises
    ------
    ValueError
        Bad settings, chains or ``feature_names`` (the message names the argument).
    KeyboardInterrupt
        On Ctrl-C, after the worker processes have been stopped.
    """
    names = _feature_names(likelihood, feature_names)
    kernel = build_kernel(likelihood, settings, constraints=constraints, **overrides)
    if int(n_chains) < 1:
        raise ValueError(f"chains: need at least 1 chain, got {n_chains}")
    seeds = np.random.SeedSequence(int(seed)).spawn(int(n_chains))
    n_jobs = min(int(n_chains), os.cpu_count() or 1) if n_jobs is None else max(1, min(int(n_jobs), int(n_chains)))
    if sampler_needs_compiling():
        if progress:
            print(_COMPILE_NOTE, file=sys.stderr, flush=True)
        if n_jobs > 1:
            _compile_here(kernel)  # once here rather than once per worker
    total = int(kernel.settings.n_iterations) * int(n_chains)
    bar = progress_bar(total, progress)
    t0 = time.perf_counter()
    try:
        if n_jobs == 1:
            results = []
            for s in seeds:
                counter = _LocalCounter(bar)
                results.append(run_chain(kernel, s, counter))
        else:
            results = _run_pool(kernel, seeds, n_jobs, bar)
    finally:
        if bar is not None:
            bar.close()
    runtime = time.perf_counter() - t0
    return Posterior.from_chains(results, kernel=kernel, seed=int(seed), runtime_s=runtime, feature_names=names,
                                 identified=identified)


def _run_pool(kernel: Kernel, seeds: Sequence[np.random.SeedSequence], n_jobs: int, bar: Any) -> list[dict[str, Any]]:
    ctx = mp.get_context("fork") if "fork" in mp.get_all_start_methods() else mp.get_context()
    counter = ctx.Value("q", 0)
    pool = ProcessPoolExecutor(max_workers=n_jobs, mp_context=ctx, initializer=_init_worker,
                               initargs=(counter, os.getpid()))
    try:
        futures = [pool.submit(_worker, (kernel, s)) for s in seeds]
        last = 0
        while not all(f.done() for f in futures):
            time.sleep(0.1)
            v = counter.value
            if bar is not None:
                bar.update(v - last)
            last = v
        try:
            results = [f.result() for f in futures]
        except BrokenProcessPool:
            raise RuntimeError("sampling: a chain worker process died (killed for memory, or by a signal); "
                               "rerun with fewer --jobs or chains") from None
        if bar is not None:
            bar.update(counter.value - last)
    except BaseException:
        # Ctrl-C, an error, or a failing chain: stop the other chains now instead of waiting for them
        stop_pool(pool)
        raise
    pool.shutdown(wait=True)
    return results


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


def progress_bar(total: int, enabled: bool) -> Any:
    if not enabled:
        return None
    from tqdm.auto import tqdm

    return tqdm(total=total, unit="it", unit_scale=True, desc="sampling", leave=False, mininterval=0.5)
