"""Shared fixtures: small synthetic problems with known constraints, and a command wrapper for Ctrl-C tests."""

from __future__ import annotations

import sys

import pytest

from pbicrl.inference.synthetic import make_problem


@pytest.fixture(scope="session")
def violations_problem():
    """3 groups x 30 trajectories labelled by the worst constraint entered (the paper's labelling)."""
    return make_problem(30, labels="violations", violation_rate=0.4, seed=11)


@pytest.fixture(scope="session")
def ranked_problem():
    """3 groups x 25 trajectories ranked by a noisy true return."""
    return make_problem(25, noise=1.0, seed=5)


# A child inherits an ignored SIGINT (POSIX: a non-interactive shell starts `&` commands with SIGINT ignored, e.g.
# `nohup python -m pytest &` in a script), and Python then installs no KeyboardInterrupt handler: Ctrl-C tests
# would hang there.
_DEFAULT_SIGINT_THEN_EXEC = ("import os, signal, sys; signal.signal(signal.SIGINT, signal.SIG_DFL); "
                             "os.execv(sys.argv[1], sys.argv[1:])")


@pytest.fixture
def with_default_sigint():
    """Wrap a command line so that it runs (same pid, via ``exec``) with SIGINT at its default disposition,
    however the test session itself was started."""
    def wrap(argv: list[str]) -> list[str]:
        return [sys.executable, "-c", _DEFAULT_SIGINT_THEN_EXEC, *argv]

    return wrap
