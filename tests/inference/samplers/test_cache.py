"""Numba's on-disk cache follows edits of a cached function's callees in other files (issue 18 leftover)."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

import pbicrl
from pbicrl.inference.samplers import _cache, _mcmc

SRC = Path(pbicrl.__file__).resolve().parents[1]

CALLEE = "from numba import njit\n\n\n@njit(cache=True)\ndef f(x):\n    return x + 1.0\n"
CALLER = """from numba import njit

import callee


@njit(cache=True)
def g(x):
    return 2.0 * callee.f(x)


if GUARD:
    from pbicrl.inference.samplers._cache import flush_stale

    flush_stale([g], [__file__, callee.__file__])
"""


def _run(tmp: Path, code: str) -> str:
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp / "cache"),
               PYTHONPATH=os.pathsep.join([str(tmp), str(SRC), os.environ.get("PYTHONPATH", "")]))
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd=tmp, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return proc.stdout.strip().splitlines()[-1]


@pytest.mark.parametrize("guard", [False, True])
def test_an_edited_callee_reaches_the_cached_caller_only_with_the_stamp(tmp_path, guard):
    (tmp_path / "callee.py").write_text(CALLEE)
    (tmp_path / "caller.py").write_text(CALLER.replace("GUARD", str(guard)))
    show = "import caller; print(caller.g(1.0))"
    assert _run(tmp_path, show) == "4.0"
    assert _run(tmp_path, show) == "4.0"  # now from the cache
    (tmp_path / "callee.py").write_text(CALLEE.replace("x + 1.0", "x + 2.0"))
    # Without the stamp Numba keeps the old callee (the caller's file did not change): the problem is real
    assert _run(tmp_path, show) == ("6.0" if guard else "4.0")
    if guard:
        assert _run(tmp_path, show) == "6.0"  # and the recompiled caller is cached again


def test_the_sampler_modules_stamp_their_cached_functions():
    """Import of ``_mcmc`` stamped every cached sampler function with the hash of the files it compiles in."""
    from pbicrl.inference import codes, likelihood_kernels
    from pbicrl.inference.samplers import _parametric, _priorkern, bundles

    want = _cache.source_digest([m.__file__ for m in (_mcmc, codes, likelihood_kernels, _parametric, _priorkern,
                                                       bundles)])
    stamp = _cache.stamp_path(_mcmc.advance)
    assert stamp is not None and stamp.read_text() == want
    lk = _cache.stamp_path(likelihood_kernels.loglik)
    assert lk is not None and lk.read_text() == _cache.source_digest([likelihood_kernels.__file__, codes.__file__])


def test_flush_stale_is_quiet_without_a_disk_cache(tmp_path):
    from numba import njit

    @njit  # no cache: nothing to stamp
    def h(x):
        return x

    assert _cache.stamp_path(h) is None
    assert _cache.flush_stale([h], [__file__]) == []
    assert _cache.flush_stale([_mcmc.advance], [tmp_path / "missing.py"]) == []  # unreadable source: no change


@pytest.mark.slow
def test_an_edit_of_the_likelihood_kernels_reaches_the_cached_sampler(tmp_path):
    """The real package, copied: edit ``likelihood_kernels.loglik`` and the cached sampler loop uses the edit."""
    shutil.copytree(SRC / "pbicrl", tmp_path / "pbicrl", ignore=shutil.ignore_patterns("__pycache__", "data"))
    code = ("import numpy as np, warnings; warnings.simplefilter('ignore')\n"
            "from pbicrl.inference.likelihood import PreferenceLikelihood\n"
            "from pbicrl.inference.samplers import build_kernel\n"
            "from pbicrl.inference.synthetic import make_problem\n"
            "lik = PreferenceLikelihood.from_dataset(make_problem(8, seed=1).dataset)\n"
            "k = build_kernel(lik, method='bpl', n_iterations=50, burn_in=0, thin=1)\n"
            "s = k.init(0); out = k.new_buffers(50); k.run(np.random.default_rng(1), s, 50, out)\n"
            "end = k.run(np.random.default_rng(1), s, 50)\n"
            "print(abs(out.log_likelihood[-1] - k.likelihood.from_scaled_returns(end.scaled_returns)) < 1e-6)\n")
    env_src = tmp_path
    assert _run(env_src, code) == "True"
    assert _run(env_src, code) == "True"  # cached
    f = tmp_path / "pbicrl" / "inference" / "likelihood_kernels.py"
    text = f.read_text()
    old = "    return total_loglik(a, lik.brows, lik.broff,"  # loglik's pairwise branch (the test's likelihood)
    assert text.count(old) == 1
    f.write_text(text.replace(old, old.replace("return total_loglik(", "return 1.0 + total_loglik(")))
    # the loop (cached in _mcmc.py, unchanged) and the Python-side evaluation must both see the edit
    assert _run(env_src, code) == "True"  # a stale loop would be 1.0 off
