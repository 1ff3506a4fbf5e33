"""One driver for chains and draws: independent chains from one seed, spread over the cores.

Chain workers never outlive the process that started them: each asks the kernel to end it when its parent
dies (``PR_SET_PDEATHSIG`` on Linux, a watchdog thread elsewhere; :func:`die_with_parent`), so ``kill -TERM``
or ``kill -KILL`` of a ``pbicrl`` process leaves no chain running. Workers ignore SIGINT: on Ctrl-C (or
``kill -INT``) the parent stops them at once instead of waiting for their chains to finish.

The compiled sampler is cached on disk by Numba; the first run of an installation compiles it (about 15 s),
which :func:`sample` announces on stderr when it shows progress.

Runs inside a sweep (:mod:`pbicrl.experiments.sweep`) show no bar of their own; they count their iterations, and
whether they are compiling, in the sweep's :class:`RunsCounter` (shared with the sweep's worker processes), whose
bar shows the progress inside the runs in progress.

Per-draw statistics (:class:`_DrawStats`): besides the draws, every chain records for each kept draw the move
type of the iteration that produced it (:data:`pbicrl.inference.codes.MOVES`), whether that move was accepted, and the fraction
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
import math
import multiprocessing as mp
import os
import signal
import sys
import threading
import time
from collections.abc import Callable
from concurrent.futures import ALL_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from typing import Any, NamedTuple, Self, Sequence

import numpy as np

from pbicrl.inference.codes import MOVE_FLIP, MOVE_NONE, MOVE_PARAMETER, MOVE_WEIGHT
from pbicrl.inference.constraints import ConstraintSet
from pbicrl.inference.convergence import TARGET_ESS, TARGET_RHAT, Convergence, check_convergence, reported_quantities
from pbicrl.inference.likelihood import PreferenceLikelihood
from pbicrl.inference.posterior import Posterior
from pbicrl.inference.samplers.kernels import ADAPT_EVERY, ChainState, Kernel, SamplerSettings, build_kernel

__all__ = ["progress_bar", "sample", "run_chain", "die_with_parent", "stop_pool", "sampler_needs_compiling",
           "StoppingRule", "RunsCounter", "RunsSnapshot", "set_runs_counter", "COMPILE_NOTE"]

# Fixed: the random numbers of a chunk are drawn at once, so the chunk size is part of a chain's result.
_CHUNK = 20_000
_progress_counter: Any = None  # set in workers (inherited through fork) for the progress bar
COMPILE_NOTE = "pbicrl: compiling the sampler (first run only: about a minute, cached afterwards)..."
"""What :func:`sample` (with progress) and a sweep's bar print once before a run compiles the sampler."""
_runs_counter: RunsCounter | None = None  # a sweep's, in the process that runs its tasks (set_runs_counter)
_current_run: _RunShare | None = None  # the run sample() is doing in this process, counted in _runs_counter


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
    global _progress_counter, _runs_counter, _current_run
    die_with_parent(parent)
    # Ctrl-C reaches the whole process group; the parent alone decides, and stops the workers itself.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    # A SIGTERM handler inherited through fork (a sweep's, ICL's) must not keep a chain alive on terminate().
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    _progress_counter = counter
    # a chain worker forked from a sweep's task reports to the task (through ``counter``), never to the sweep
    _runs_counter = _current_run = None


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


# ---------------------------------------------------------------------------------------------- sweeps
class RunsSnapshot(NamedTuple):
    """What a :class:`RunsCounter` holds at one moment (the runs in progress only)."""

    done: int
    """Iterations done by the fixed-length runs in progress (all chains)."""
    planned: int
    """Iterations those runs will do in all."""
    done_until_converged: int
    """Iterations done by the runs until converged in progress (no total is known in advance)."""
    compiling: int
    """Runs that are compiling the sampler (before their first iteration)."""


class RunsCounter:
    """Sampler iterations of a sweep's runs in progress, shared with the processes that run them.

    A sweep makes one and hands it to its executor, which installs it (:func:`set_runs_counter`) where the
    tasks run: in its pool's worker processes (through the pool's initializer, with ``fork`` or ``spawn``) or
    in this process. :func:`sample` then adds its run's planned and done iterations as the chains advance (every
    20,000 iterations of a chain, 2,000 in runs until converged) and takes them out again when the run ends,
    so the counts describe the runs in progress only.

    Parameters
    ----------
    on_change : callable, optional
        ``on_change(snapshot)``, called with a :class:`RunsSnapshot` in the process that made the counter (never
        in a worker), from :meth:`add` (runs in this process) and :meth:`tick` (an executor waiting for its
        workers), at most every ``interval`` seconds for iterations done (at once when a run starts or ends,
        or starts or ends compiling).
    interval : float, optional
        Seconds between two calls of ``on_change`` (default :attr:`interval`); also how often an executor that
        waits for its workers calls :meth:`tick`.
    """

    interval: float = 0.5
    """Default seconds between two calls of ``on_change``."""

    def __init__(self, on_change: Callable[[RunsSnapshot], None] | None = None, *, interval: float | None = None
                 ) -> None:
        self.reset()
        self.on_change = on_change
        self.interval = float(type(self).interval if interval is None else interval)
        self._owner = os.getpid()
        self._last = -math.inf

    def __getstate__(self) -> dict[str, Any]:  # pickled for a spawned worker: the callback stays here
        return self.__dict__ | {"on_change": None}

    def add(self, done: int = 0, planned: int = 0, done_until_converged: int = 0, compiling: int = 0) -> None:
        """Add to the counts (negative numbers take a finished run's share out)."""
        with self.values.get_lock():
            for k, n in enumerate((done, planned, done_until_converged, compiling)):
                if n:
                    self.values[k] += int(n)
        # a run starts or ends, or starts or ends compiling: show it now
        self.tick(force=bool(planned or compiling) or min(done, done_until_converged) < 0)

    def reset(self, ctx: Any = None) -> None:
        """Zero the counts, in new shared memory of the ``multiprocessing`` context ``ctx`` (that of the pool that
        will share them). Only with no run in progress (an executor starting a pool): a killed worker's share
        is gone."""
        self.values = (ctx or mp.get_context()).Array("q", len(RunsSnapshot._fields))

    def snapshot(self) -> RunsSnapshot:
        with self.values.get_lock():
            return RunsSnapshot(*(int(v) for v in self.values))

    def tick(self, *, force: bool = False) -> None:
        """Call ``on_change`` if this is the process that made the counter and ``interval`` has passed."""
        if self.on_change is None or os.getpid() != self._owner:
            return
        now = time.monotonic()
        if force or now - self._last >= self.interval:
            self._last = now
            self.on_change(self.snapshot())


def set_runs_counter(counter: RunsCounter | None) -> RunsCounter | None:
    """Count the runs of this process in ``counter`` (None: in none); returns the counter it replaces."""
    global _runs_counter
    old, _runs_counter = _runs_counter, counter
    return old


class _RunShare:
    """The run :func:`sample` is doing, as counted in the sweep's :class:`RunsCounter` (nothing outside a sweep).

    ``planned`` None: a run until converged."""

    def __init__(self, planned: int | None) -> None:
        self.counter = _runs_counter
        self.planned = planned
        self.done = 0
        self.compiling = False

    def __enter__(self) -> Self:
        global _current_run
        self._outer, _current_run = _current_run, self
        if self.counter is not None and self.planned:
            self.counter.add(planned=self.planned)
        return self

    def set_compiling(self, on: bool) -> None:
        if self.counter is not None and on != self.compiling:
            self.counter.add(compiling=1 if on else -1)
        self.compiling = on

    def add(self, n: int) -> None:
        if self.counter is None or n <= 0:
            return
        self.done += n
        off = -1 if self.compiling else 0  # the first iterations are done: compiled
        self.compiling = False
        if self.planned is None:
            self.counter.add(done_until_converged=n, compiling=off)
        else:
            self.counter.add(done=n, compiling=off)

    def __exit__(self, *exc: object) -> None:
        global _current_run
        _current_run = self._outer
        if self.counter is not None:
            done = -self.done
            self.counter.add(done=0 if self.planned is None else done, planned=-(self.planned or 0),
                             done_until_converged=done if self.planned is None else 0,
                             compiling=-int(self.compiling))


def _report(n: int) -> None:
    """``n`` more iterations of this process's run (for the sweep's counter, if any)."""
    if _current_run is not None:
        _current_run.add(n)


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

    Per kept draw: ``move`` (int8, :data:`pbicrl.inference.codes.MOVES`), ``accepted`` (bool) and ``acceptance_fraction`` (the
    fraction of iterations accepted since the previous kept draw; for the first, its own iteration).
    """
    rng = np.random.default_rng(seed)
    s = kernel.settings
    out = kernel.new_buffers(s.n_draws)
    stats = _DrawStats(kernel, s.n_draws)
    t0 = time.perf_counter()
    state: ChainState = kernel.init(rng)
    done = 0
    while done < s.iterations:
        n = min(_CHUNK, s.iterations - done)
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
    """The move the compiled loop chooses at each of ``iterations`` (:data:`pbicrl.inference.codes.MOVES`), from that iteration's
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
    if s.sampler in ("paper", "authors"):
        first = 0 if s.sampler == "authors" else 1  # the paper counts iterations from 1, the authors' code from 0
        code = np.where((np.asarray(iterations) + first) % int(s.f_s) != 0, MOVE_FLIP,
                        np.where(theta_move, MOVE_PARAMETER, MOVE_WEIGHT))
    elif s.sampler == "bpl":
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
        if self.kernel.settings.sampler == "pbicrl" and theta.size:
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
    chains: int = 4,
    seed: int = 0,
    jobs: int | None = None,
    progress: bool = True,
    feature_names: Sequence[str] | None = None,
    constraints: ConstraintSet | None = None,
    identified: Any = None,
    stopping: StoppingRule | None = None,
    **overrides: Any,
) -> Posterior:
    """Sample the posterior with ``chains`` independent chains.

    Parameters
    ----------
    likelihood : PreferenceLikelihood
    settings : SamplerSettings, optional
        Keyword ``overrides`` replace fields, e.g. ``sample(lik, sampler="bpl", iterations=10_000)``.
    chains : int
        Independent chains (formerly ``n_chains``); chain ``k`` uses the ``k``-th child of
        ``numpy.random.SeedSequence(seed)``, so results do not depend on ``jobs``.
    seed : int
    jobs : int, optional
        Worker processes (formerly ``n_jobs``) (default: one per core, at most one per chain). 1 runs in-process; compiled code
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
    stopping : StoppingRule, optional
        Run until converged (``iterations = "auto"``): the chains run in rounds until every reported quantity
        meets the rule's targets or its time is spent (see :class:`StoppingRule`); ``settings.iterations``,
        ``burn_in`` and ``thin`` are then ignored. The verdict is ``Posterior.extra["convergence"]``.

    Raises
    ------
    ValueError
        Bad settings, chains or ``feature_names`` (the message names the argument).
    KeyboardInterrupt
        On Ctrl-C, after the worker processes have been stopped.
    """
    if overrides:  # the old names n_chains, n_jobs (and method, n_iterations) work until 0.3, with a warning
        from pbicrl.config import canonical_names

        overrides = canonical_names(overrides, where="sample() argument", stacklevel=2)
        chains, jobs = overrides.pop("chains", chains), overrides.pop("jobs", jobs)
    n_chains, n_jobs = chains, jobs
    names = _feature_names(likelihood, feature_names)
    kernel = build_kernel(likelihood, settings, constraints=constraints, min_penalty=_min_penalty(identified),
                          parameter_ranges=_parameter_ranges(identified, constraints), **overrides)
    if int(n_chains) < 1:
        raise ValueError(f"chains: need at least 1 chain, got {n_chains}")
    seeds = np.random.SeedSequence(int(seed)).spawn(int(n_chains))
    n_jobs = min(int(n_chains), os.cpu_count() or 1) if n_jobs is None else max(1, min(int(n_jobs), int(n_chains)))
    total = int(kernel.settings.iterations) * int(n_chains)
    with _RunShare(None if stopping is not None else total) as share:  # counted in a sweep's bar, if any
        if sampler_needs_compiling():
            share.set_compiling(True)  # until the first iterations are done
            if progress:
                print(COMPILE_NOTE, file=sys.stderr, flush=True)
            if n_jobs > 1:
                _compile_here(kernel)  # once here rather than once per worker
                share.set_compiling(False)
        if stopping is not None:
            return _sample_auto(kernel, stopping, seeds, n_jobs, progress, names, identified, int(seed))
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


def _parameter_ranges(identified: Any, constraints: Any) -> list[tuple[float, float]] | None:
    """The identified interval of every constraint parameter (object or ``summary.json`` dict), in the
    constraints' parameter order; NaN ends where none."""
    if identified is None or constraints is None:
        return None
    names = list(constraints.param_names)
    got: dict[str, Any] = {}
    params = getattr(identified, "parameters", None) if not isinstance(identified, dict) else identified.get("parameters")
    if isinstance(params, dict):
        got = {k: v for k, v in params.items() if isinstance(v, (list, tuple)) and len(v) == 2}
    elif params is not None:
        got = {p.name: (p.low, p.high) for p in params}
    if not got:
        return None

    def num(x: Any) -> float:
        return float(x) if isinstance(x, (int, float)) else float("nan")  # None: no end

    return [(num(got[n][0]), num(got[n][1])) if n in got else (float("nan"), float("nan")) for n in names]


def _min_penalty(identified: Any) -> list[float] | None:
    """The separation scales :math:`m_j` of an identification (object or ``summary.json`` dict), NaN where none."""
    if identified is None:
        return None
    mp = getattr(identified, "min_penalty", None)
    if mp is not None and not callable(mp):
        return [float(x) for x in np.asarray(mp, dtype=float)]
    feats = identified.get("features") if isinstance(identified, dict) else None
    if isinstance(feats, dict):
        out = []
        for v in feats.values():
            x = v.get("min_penalty") if isinstance(v, dict) else None
            out.append(float(x) if isinstance(x, (int, float)) else float("nan"))
        return out
    return None


def _run_pool(kernel: Kernel, seeds: Sequence[np.random.SeedSequence], n_jobs: int, bar: Any) -> list[dict[str, Any]]:
    ctx = mp.get_context("fork") if "fork" in mp.get_all_start_methods() else mp.get_context()
    counter = ctx.Value("q", 0)
    pool = ProcessPoolExecutor(max_workers=n_jobs, mp_context=ctx, initializer=_init_worker,
                               initargs=(counter, os.getpid()))
    try:
        futures = [pool.submit(_worker, (kernel, s)) for s in seeds]
        results = _collect(futures, counter, bar, 0)
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

    def get_lock(self) -> _LocalCounter:
        return self

    def __enter__(self) -> None:
        self._before = self.value

    def __exit__(self, *exc: object) -> None:
        if self.bar is not None:
            self.bar.update(self.value - self._before)
        _report(self.value - self._before)


def progress_bar(total: int | None, enabled: bool) -> Any:
    """A tqdm bar on stderr (``total`` None: a run until converged, whose rounds add the smallest ESS and the
    largest R-hat so far)."""
    if not enabled:
        return None
    from tqdm.auto import tqdm

    return tqdm(total=total, unit="it", unit_scale=True, desc="sampling" if total else "sampling until converged",
                leave=False, mininterval=0.5)


# ---------------------------------------------------------------------------------------------- run until converged
@dataclasses.dataclass(frozen=True)
class StoppingRule:
    r"""Run until converged (``iterations = "auto"``): rounds of sampling until every reported quantity
    (:mod:`pbicrl.inference.convergence`) has split :math:`\hat R` < ``target_rhat`` and bulk and tail ESS >=
    ``target_ess``, or until ``max_time`` seconds are spent.

    Attributes
    ----------
    target_ess : float
        Bulk and tail ESS every reported quantity needs (over all chains).
    target_rhat : float
        Largest rank-normalised split :math:`\hat R`.
    max_time : float
        Seconds (wall) after which the run stops converged or not (the run then says which quantities fall short).
    warmup : int
        Warm-up iterations per chain (adaptation; not kept).
    first_check : int
        Kept iterations per chain before the first check.
    max_draws : int
        Kept draws stored per chain; longer runs are thinned evenly to this many.
    """

    target_ess: float = TARGET_ESS
    target_rhat: float = TARGET_RHAT
    max_time: float = 600.0
    warmup: int = 2_000
    first_check: int = 1_500
    max_draws: int = 20_000

    def __post_init__(self) -> None:
        if not (math.isfinite(self.target_ess) and self.target_ess > 0):
            raise ValueError(f"target_ess: must be a positive number, got {self.target_ess!r}")
        if not (math.isfinite(self.target_rhat) and self.target_rhat > 1.0):
            raise ValueError(f"target_rhat: must be a number > 1, got {self.target_rhat!r}")
        if not (math.isfinite(self.max_time) and self.max_time > 0):
            raise ValueError(f"max_time: must be a positive number of seconds, got {self.max_time!r}")
        for name in ("warmup", "first_check", "max_draws"):
            v = getattr(self, name)
            if int(v) != v or v < (0 if name == "warmup" else 4):
                raise ValueError(f"{name}: must be an integer >= {0 if name == 'warmup' else 4}, got {v!r}")

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


_AUTO_CHUNK = 2_000  # iterations between progress updates inside a round (does not change the chain)
_DRAW_KEYS = ("indicators", "penalty_weights", "parameters", "log_likelihood", "log_prior", "move", "accepted",
              "acceptance_fraction")


def _auto_round(args: tuple[Kernel, ChainState, np.random.Generator, int, tuple[int, int]]) -> tuple[Any, ...]:
    """Advance one chain ``n`` iterations; returns the new state and generator, the kept draws (with per-draw
    statistics), the acceptance carry and the process time used."""
    kernel, state, rng, n, carry = args
    b = kernel.settings.burn_in_
    it0 = int(state.iteration)
    kept = max(0, it0 + n - max(it0, b))
    stats = _DrawStats(kernel, kept)
    stats._acc_since, stats._n_since = carry
    out = kernel.new_buffers(kept)
    t0 = time.process_time()
    done = 0
    while done < n:
        m = min(_AUTO_CHUNK, n - done)
        state = stats.run(rng, state, m, out)
        done += m
        if _progress_counter is not None:
            with _progress_counter.get_lock():
                _progress_counter.value += m
    k = int(out[5][0])
    draws = {"indicators": out.indicators[:k], "penalty_weights": out.penalty_weights[:k],
             "parameters": out.parameters[:k], "log_likelihood": out.log_likelihood[:k],
             "log_prior": out.log_prior[:k], "move": stats.move[:k], "accepted": stats.accepted[:k],
             "acceptance_fraction": stats.fraction[:k]}
    return state, rng, draws, (stats._acc_since, stats._n_since), time.process_time() - t0


def _auto_worker(args: tuple[Any, ...]) -> tuple[Any, ...]:
    return _auto_round(args)


def _converged(kernel: Kernel, parts: list[dict[str, list[np.ndarray]]], names: Sequence[str] | None,
               rule: StoppingRule, skip: Sequence[str]) -> tuple[Convergence, int]:
    """The stopping rule on the kept draws so far, and how many leading draws per chain it discarded (the first
    half, when the chains agree on the second half only: extended warm-up, no adaptation, so still valid)."""
    def stack(key: str) -> np.ndarray:
        return np.stack([np.concatenate(p[key]) for p in parts])

    c, w, ll, th = stack("indicators"), stack("penalty_weights"), stack("log_likelihood"), stack("parameters")
    d = c.shape[2]
    fnames = list(names) if names is not None else [f"f{j}" for j in range(kernel.d_known)]
    if kernel.constraints is not None:
        fnames += list(kernel.constraints.names)
    fnames = fnames[:d]
    pnames = list(kernel.constraints.param_names) if kernel.constraints is not None and th.shape[2] else None

    def verdict(lo: int) -> Convergence:
        q = reported_quantities(c[:, lo:], w[:, lo:], ll[:, lo:], fnames, th[:, lo:] if th.shape[2] else None,
                                pnames, skip=skip)
        return check_convergence(q, target_ess=rule.target_ess, target_rhat=rule.target_rhat)

    full = verdict(0)
    n = c.shape[1]
    if not full.converged and full.max_rhat > rule.target_rhat and n >= 2 * rule.first_check:
        half = verdict(n // 2)
        if half.converged:
            return half, n // 2
    return full, 0


def _skip_names(identified: Any) -> list[str]:
    """Features the data carry no information about (identify's ``identifiable`` False): not diagnosed."""
    feats = None
    if identified is not None and not isinstance(identified, dict):
        try:
            return [f.name for f in identified.features if not f.identifiable]
        except AttributeError:
            return []
    if isinstance(identified, dict):
        feats = identified.get("features")
    if isinstance(feats, dict):
        return [k for k, v in feats.items() if isinstance(v, dict) and v.get("identifiable") is False]
    return []


def _sample_auto(kernel: Kernel, rule: StoppingRule, seeds: Sequence[np.random.SeedSequence], n_jobs: int,
                 progress: bool, names: Sequence[str] | None, identified: Any, seed: int) -> Posterior:
    """:func:`sample` with a :class:`StoppingRule`: rounds until converged or out of time."""
    s = kernel.settings
    big = 1 << 60
    kernel = dataclasses.replace(kernel, settings=dataclasses.replace(s, iterations=big, burn_in=int(rule.warmup),
                                                                      thin=1))
    skip = _skip_names(identified)
    rngs = [np.random.default_rng(sd) for sd in seeds]
    states = [kernel.init(r) for r in rngs]
    carries = [(0, 0)] * len(seeds)
    parts: list[dict[str, list[np.ndarray]]] = [{k: [] for k in _DRAW_KEYS} for _ in seeds]
    cpu = np.zeros(len(seeds))
    bar = progress_bar(None, progress)
    t0 = time.perf_counter()
    pool = counter = None
    if n_jobs > 1:
        ctx = mp.get_context("fork") if "fork" in mp.get_all_start_methods() else mp.get_context()
        counter = ctx.Value("q", 0)
        pool = ProcessPoolExecutor(max_workers=n_jobs, mp_context=ctx, initializer=_init_worker,
                                   initargs=(counter, os.getpid()))
    n_round = int(rule.warmup) + int(rule.first_check)
    done = 0
    conv: Convergence | None = None
    discard = 0
    rounds = 0
    try:
        while True:
            tasks = [(kernel, st, r, n_round, cy) for st, r, cy in zip(states, rngs, carries)]
            t_round = time.perf_counter()
            outs = _run_round(tasks, pool, counter, bar, done * len(seeds), t0)
            rounds += 1
            for k, (st, r, dr, cy, pt) in enumerate(outs):
                states[k], rngs[k], carries[k] = st, r, cy
                cpu[k] += pt
                for key in _DRAW_KEYS:
                    parts[k][key].append(dr[key])
            done += n_round
            kept = done - int(rule.warmup)
            conv, discard = _converged(kernel, parts, names, rule, skip)
            elapsed = time.perf_counter() - t0
            if bar is not None:
                if hasattr(bar, "set_convergence"):  # the labelling page's reporter
                    bar.set_convergence(conv.min_ess, rule.target_ess, conv.max_rhat, elapsed)
                else:
                    bar.set_postfix_str(f"min ESS {conv.min_ess:.0f}/{rule.target_ess:g}, max R-hat "
                                        f"{conv.max_rhat:.3f}, {elapsed:.0f}s", refresh=True)
            if conv.converged or elapsed >= rule.max_time:
                break
            rate = n_round / max(time.perf_counter() - t_round, 1e-9)  # iterations per chain per second
            ess = conv.min_ess if math.isfinite(conv.min_ess) and conv.min_ess > 0 else 1.0
            # ESS grows with the draws, and R-hat - 1 shrinks about as 1 / ESS once the chains mix
            need = kept * max(rule.target_ess / ess - 1.0,
                              (conv.max_rhat - 1.0) / (rule.target_rhat - 1.0) - 1.0) * 1.15
            if not math.isfinite(need) or conv.max_rhat > 1.0 + 10.0 * (rule.target_rhat - 1.0):
                need = kept  # far from mixing: the largest round (a third more)
            # 70% of the prediction, and at most a third more draws: the prediction is noisy (R-hat's spread at a
            # given ESS), and overshooting cost more than the extra checks (benchmarks/reports/fast_default.md)
            n_round = int(max(0.7 * need, 200))
            n_round = min(n_round, int(kept) // 3, int(max(rate * (rule.max_time - elapsed), 100)))
            n_round = max(n_round, 100)
    except BaseException:
        if pool is not None:
            stop_pool(pool)
        raise
    finally:
        if bar is not None:
            bar.close()
    if pool is not None:
        pool.shutdown(wait=True)
    runtime = time.perf_counter() - t0
    assert conv is not None
    kept = done - int(rule.warmup)
    keep_n = kept - discard
    stride = max(1, -(-keep_n // int(rule.max_draws)))
    results = []
    for k, st in enumerate(states):
        r: dict[str, Any] = {key: np.concatenate(parts[k][key])[discard::stride] for key in _DRAW_KEYS}
        best, adapt = st.best, st.adaptation
        r.update({"map_indicators": best.indicators, "map_penalty_weights": best.penalty_weights,
                  "map_parameters": best.parameters, "map_log_posterior": st.map_log_posterior,
                  "map_log_likelihood": st.map_log_likelihood, "counts": st.counts, "sigma": adapt.sigma,
                  "q_mean": adapt.q_mean, "q_scale": adapt.q_scale, "sigma_theta": adapt.sigma_theta,
                  "runtime_s": float(cpu[k])})
        results.append(r)
    final = dataclasses.replace(kernel, settings=dataclasses.replace(
        kernel.settings, iterations=int(done), burn_in=int(rule.warmup) + int(discard), thin=int(stride)))
    post = Posterior.from_chains(results, kernel=final, seed=seed, runtime_s=runtime, feature_names=names,
                                 identified=identified, issue_warnings=False)
    post.extra["convergence"] = conv.to_dict() | {
        "iterations": "auto", "iterations_run": int(done), "rounds": rounds, "discarded_after_warmup": int(discard),
        "wall_s": runtime, "stopping_rule": rule.to_dict(),
        "note": ("conditional summaries are checked through the indicators 1[c=1, w <= q] at the conditional "
                 "5/50/95% quantiles (defined for every draw), and for selected features also on log|w| while "
                 "active; see pbicrl.inference.convergence")}
    post.emit_warnings(stacklevel=4)
    return post


def _run_round(tasks: list[tuple[Any, ...]], pool: Any, counter: Any, bar: Any, base: int,
               t0: float) -> list[tuple[Any, ...]]:
    """Run one round of every chain, in the pool or here, updating the progress bar as iterations complete."""
    if pool is None:
        local = _LocalCounter(bar)
        global _progress_counter
        saved = _progress_counter
        _progress_counter = local
        try:
            return [_auto_round(t) for t in tasks]
        finally:
            _progress_counter = saved
    start = counter.value
    futures = [pool.submit(_auto_worker, t) for t in tasks]
    return _collect(futures, counter, bar, start)


def _collect(futures: list[Any], counter: Any, bar: Any, last: int) -> list[Any]:
    """Wait for the chains' futures, moving the progress bar by the workers' shared counter (from ``last``)."""
    while not all(f.done() for f in futures):
        wait(futures, timeout=0.1, return_when=ALL_COMPLETED)  # back at once when the last chain ends: rounds are short
        v = counter.value
        if v != last:
            if bar is not None:
                bar.update(v - last)
            _report(v - last)
            last = v
    try:
        outs = [f.result() for f in futures]
    except BrokenProcessPool:
        raise RuntimeError("sampling: a chain worker process died (killed for memory, or by a signal); "
                           "rerun with fewer --jobs or chains") from None
    if bar is not None:
        bar.update(counter.value - last)
    _report(counter.value - last)
    return outs

