"""Shared fixtures: small synthetic problems with known constraints."""

from __future__ import annotations

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
