"""The chain driver: seeds per chain, processes vs in-process, per-draw records, workers that die with the parent."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np
import pytest

from pbicrl.inference.likelihood import PreferenceLikelihood
from pbicrl.inference.samplers import build_kernel, run_chain, sample
from pbicrl.inference.codes import MOVES
from pbicrl.inference.samplers.driver import sampler_needs_compiling, stop_pool
from pbicrl.inference.synthetic import make_problem

N = 3000


@pytest.fixture(scope="module")
def lik():
    return PreferenceLikelihood.from_dataset(make_problem(12, labels="violations", violation_rate=0.4,
                                                          seed=5).dataset, margins=[0.5, 1.0])


@pytest.mark.parametrize("method", ["pbicrl", "paper"])
def test_chain_k_is_run_chain_on_the_kth_child_seed_whatever_the_processes(lik, method):
    serial = sample(lik, method=method, n_iterations=N, n_chains=3, seed=11, n_jobs=1, progress=False)
    pooled = sample(lik, method=method, n_iterations=N, n_chains=3, seed=11, n_jobs=3, progress=False)
    kernel = build_kernel(lik, method=method, n_iterations=N)
    children = np.random.SeedSequence(11).spawn(3)
    for k in range(3):
        alone = run_chain(kernel, children[k])
        for post in (serial, pooled):
            np.testing.assert_array_equal(post.penalty_weights[k], alone["penalty_weights"])
            np.testing.assert_array_equal(post.indicators[k], alone["indicators"])
            np.testing.assert_array_equal(post.move[k], alone["move"])
    fewer = sample(lik, method=method, n_iterations=N, n_chains=2, seed=11, n_jobs=2, progress=False)
    np.testing.assert_array_equal(fewer.penalty_weights, serial.penalty_weights[:2])  # more chains add, never change


def test_per_draw_records_are_consistent(lik):
    post = sample(lik, n_iterations=N, n_chains=2, seed=1, n_jobs=1, progress=False)
    assert post.move.shape == post.accepted.shape == post.acceptance_fraction.shape == post.log_likelihood.shape
    assert set(np.unique(post.move)) <= set(MOVES)
    assert np.all((post.acceptance_fraction >= 0) & (post.acceptance_fraction <= 1))
    # a draw that was accepted differs from the previous kept draw only if thinning is 1; with thinning the
    # fraction of accepted iterations since the previous draw is positive whenever the state changed
    changed = np.any(np.diff(post.penalty_weights, axis=1) != 0, axis=2)
    assert np.all(post.acceptance_fraction[:, 1:][changed] > 0)


def test_bad_chain_counts_name_the_argument(lik):
    with pytest.raises(ValueError, match="chains: need at least 1 chain, got 0"):
        sample(lik, n_iterations=100, n_chains=0, progress=False)


def test_the_sampler_is_compiled_once_it_ran(lik):
    sample(lik, n_iterations=100, n_chains=1, seed=0, n_jobs=1, progress=False)
    assert sampler_needs_compiling() is False


def _sleep(seconds: float) -> int:
    time.sleep(seconds)
    return os.getpid()


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_stop_pool_stops_running_work_at_once():
    import multiprocessing as mp

    pool = ProcessPoolExecutor(max_workers=2, mp_context=mp.get_context("fork"))
    futures = [pool.submit(_sleep, 60) for _ in range(2)]
    while not all(f.running() for f in futures):
        time.sleep(0.05)
    pids = [p.pid for p in pool._processes.values()]
    t0 = time.monotonic()
    stop_pool(pool, grace=2.0)
    # Ask the OS, not Process.is_alive(): the executor's own thread may reap a worker first, and is_alive()
    # of a process reaped elsewhere stays True.
    while time.monotonic() - t0 < 10 and not all(_gone(pid) for pid in pids):
        time.sleep(0.05)
    assert all(_gone(pid) for pid in pids)
    assert time.monotonic() - t0 < 10


def _gone(pid: int) -> bool:
    """True once ``pid`` has exited (reaped, or a zombie waiting to be)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(") ", 1)[-1][:1] in ("Z", "X")
    except FileNotFoundError:
        return True


_ORPHAN = textwrap.dedent("""
    import multiprocessing as mp, os, sys, time
    from pbicrl.inference.samplers import driver

    def child(parent, watchdog, path):
        if watchdog:  # the portable fallback instead of the kernel's parent-death signal
            driver._prctl_pdeathsig = lambda sig: False
        driver.die_with_parent(parent, interval=0.1)
        with open(path, "w") as fh:
            fh.write(str(os.getpid()))
        time.sleep(60)

    if __name__ == "__main__":
        ctx = mp.get_context("fork")
        p = ctx.Process(target=child, args=(os.getpid(), sys.argv[1] == "watchdog", sys.argv[2]))
        p.start()
        while not os.path.exists(sys.argv[2]) or not open(sys.argv[2]).read():
            time.sleep(0.05)
        os._exit(0)  # the parent ends without stopping its child, as a killed process would
""")


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    try:  # an orphan killed but not yet reaped is a zombie
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().rsplit(")", 1)[1].split()[0] not in ("Z", "X")
    except OSError:
        return False


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="fork and /proc")
@pytest.mark.parametrize("mode", ["pdeathsig", "watchdog"])
def test_a_worker_dies_when_its_parent_dies(tmp_path, mode):
    script, pidfile = tmp_path / "orphan.py", tmp_path / "pid"
    script.write_text(_ORPHAN)
    subprocess.run([sys.executable, str(script), mode, str(pidfile)], check=True, timeout=120)
    pid = int(pidfile.read_text())
    deadline = time.monotonic() + 10
    while _alive(pid) and time.monotonic() < deadline:
        time.sleep(0.05)
    try:
        assert not _alive(pid)
    finally:
        if _alive(pid):
            os.kill(pid, 9)


# ------------------------------------------------------------------------------------------------ sweep counting
@pytest.mark.parametrize("jobs, auto", [(1, False), (2, False), (1, True)])
def test_a_run_counts_its_iterations_in_the_sweeps_counter_and_takes_them_out_at_the_end(lik, jobs, auto):
    """Issue 30 item 13: a sweep's bar shows the progress inside its runs from this counter."""
    from pbicrl.inference.samplers.driver import (
        RunsCounter,
        RunsSnapshot,
        StoppingRule,
        set_runs_counter,
    )

    snaps: list[RunsSnapshot] = []
    counter = RunsCounter(snaps.append, interval=0.0)
    n = 60_000  # three chunks of 20,000 per chain
    old = set_runs_counter(counter)
    try:
        if auto:
            sample(lik, n_chains=2, seed=3, n_jobs=jobs, progress=False,
                   stopping=StoppingRule(max_time=2.0, warmup=1000, first_check=3000))
        else:
            sample(lik, n_iterations=n, n_chains=2, seed=3, n_jobs=jobs, progress=False)
    finally:
        set_runs_counter(old)
    assert snaps[-1] == RunsSnapshot(0, 0, 0, 0) == counter.snapshot()  # the ended run's share is out
    running = snaps[:-1]
    if auto:
        assert all(s.planned == 0 and s.done == 0 for s in running)
        seen = [s.done_until_converged for s in running]
        assert seen == sorted(seen) and 0 < seen[0] and len(set(seen)) >= 3  # counted per 2,000 iterations
    else:
        assert all(s.planned == 2 * n for s in running)
        seen = [s.done for s in running]
        assert seen == sorted(seen) and seen[-1] == 2 * n
        assert any(0 < d < 2 * n for d in seen)  # progress inside the run, before it ends
        if jobs == 1:
            assert [d for d in seen if d] == [20_000 * k for k in range(1, 7)]  # every chunk of both chains


def _sweep_globals() -> tuple[bool, bool]:
    from pbicrl.inference.samplers import driver

    return driver._runs_counter is None, driver._current_run is None


def test_no_counting_outside_a_sweep_and_a_chain_worker_never_counts_for_the_sweep(lik):
    import multiprocessing as mp

    from pbicrl.inference.samplers import driver

    assert driver._runs_counter is None and driver._current_run is None
    sample(lik, n_iterations=100, n_chains=1, seed=0, n_jobs=1, progress=False)  # nothing to count in: no error
    if "fork" not in mp.get_all_start_methods():
        pytest.skip("needs fork (the worker inherits the task's counter)")
    old = driver.set_runs_counter(driver.RunsCounter())
    try:
        ctx = mp.get_context("fork")
        with ProcessPoolExecutor(1, mp_context=ctx, initializer=driver._init_worker,
                                 initargs=(ctx.Value("q", 0), os.getpid())) as pool:
            assert pool.submit(_sweep_globals).result() == (True, True)
    finally:
        driver.set_runs_counter(old)
