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
