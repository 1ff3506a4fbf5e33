"""Numbers quoted in the documentation are recomputed here, so a stale one fails CI (issue 29, item 6)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]


def _sig4(x: float) -> str:
    return f"{x:.4g}"


def test_readme_separation_scales_of_the_shipped_point_mass():
    import pbicrl
    from pbicrl.analysis.identify import identify

    text = (ROOT / "README.md").read_text()
    m = re.search(r"on the shipped point mass data it is ([0-9.]+)\s+for `in_orange` and ([0-9.]+) for `in_red`",
                  text)
    assert m, "README: the sentence quoting the point-mass separation scales is gone; update this test"
    res = identify(pbicrl.load_dataset("point_mass"))
    assert (m.group(1), m.group(2)) == (_sig4(res["in_orange"].min_penalty), _sig4(res["in_red"].min_penalty))


def test_identify_docstring_quotes_no_numbers_of_its_own():
    from pbicrl.analysis import identify

    assert "about 56 and 352" not in identify.__doc__ and "tests/test_docs_numbers.py" in identify.__doc__


def test_one_trajectory_per_group_is_eq7_for_two_groups_only():
    # likelihood.py: "with two groups of one trajectory each the term is exactly Eq. 7's log sigma(a_i - m - a_j)"
    from pbicrl.inference.likelihood import PreferenceLikelihood
    from pbicrl.inference.preferences import Preferences

    def ll(a, kind):
        F = np.asarray(a, dtype=np.float64)[:, None]
        g = np.arange(1, F.shape[0] + 1)
        return PreferenceLikelihood(F, Preferences.from_groups(g), np.zeros(1), 1.0, kind=kind)(np.array([1.0]))

    assert ll([0.7, -0.4], "grouped") == pytest.approx(ll([0.7, -0.4], "pairwise"), rel=1e-12)
    assert ll([0.7, -0.4], "grouped") == pytest.approx(np.log(1 / (1 + np.exp(-1.1))), rel=1e-12)
    assert abs(ll([0.7, -0.4, 0.2], "grouped") - ll([0.7, -0.4, 0.2], "pairwise")) > 1e-3
