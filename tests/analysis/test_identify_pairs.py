"""``identify`` under sampled pairs identifies what the fitted likelihood uses (issue 29, item 4).

With ``--pairs N`` the likelihood is Eq. 7 over N random pairs per group pair; its separation scales are those of
those pairs (a brute-force LP over them here), not of every cross-group pair, and the output says which.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import linprog

from pbicrl.analysis.identify import identify
from pbicrl.inference.preferences import Preferences
from pbicrl.inference.synthetic import make_problem


def _brute_min_penalty(ds, prefs, alpha=0.05, beta=1.0):
    """min |w_j| over {w <= 0 : beta (phi_i - phi_j).(w_n + w) - m >= logit(1 - alpha) for every pair}."""
    I, J, M = prefs.to_pair_list()
    F = ds.mean_features
    D = F[I] - F[J]
    L = np.log((1 - alpha) / alpha)
    b = -(L + M) / beta + D @ ds.nominal_weights  # D w >= (L + M)/beta - D w_n
    out = []
    for j in range(F.shape[1]):
        c = np.zeros(F.shape[1])
        c[j] = -1.0  # maximise w_j (closest to 0 from below)
        r = linprog(c, A_ub=-D, b_ub=b, bounds=[(-1e7, 0.0)] * F.shape[1], method="highs")
        assert r.status == 0
        out.append(max(0.0, -r.x[j]))
    return np.array(out)


@pytest.mark.parametrize("seed", [0, 1])
def test_sampled_pairs_match_brute_force_and_differ_from_all_pairs(seed):
    ds = make_problem(40, violation_rate=0.4, seed=seed).dataset
    prefs = Preferences.from_groups(ds.group, None, protocol=10, seed=seed)
    res = identify(ds, preferences=prefs, pairs_seed=seed)
    full = identify(ds)
    brute = _brute_min_penalty(ds, prefs)
    np.testing.assert_allclose(res.min_penalty, brute, rtol=1e-5, atol=1e-6)
    assert res.pairs is not None and res.pairs["n_pairs"] == 30 and res.pairs["seed"] == seed
    assert full.pairs is None
    # fewer pairs to order: never a larger scale (here all pairs may not even be separable), and a different answer
    assert res.separable
    if full.separable:
        assert np.all(res.min_penalty <= full.min_penalty + 1e-6)
        assert np.any(res.min_penalty < full.min_penalty - 1e-3)
    else:
        assert np.all(np.isnan(full.min_penalty)) and np.all(np.isfinite(res.min_penalty))
    t = res.table()
    assert "the 30 sampled pairs the likelihood uses" in t
    assert "every cross-group pair (as the likelihood uses)" in full.table()
    assert res.to_dict()["pairs"]["used"].startswith("sampled pairs")


def test_all_pairs_preferences_keep_the_group_analysis():
    ds = make_problem(20, violation_rate=0.4, seed=3).dataset
    a = identify(ds, preferences=Preferences.from_groups(ds.group, None))
    b = identify(ds)
    np.testing.assert_array_equal(a.min_penalty, b.min_penalty)
    assert a.pairs is None


def test_infer_attaches_the_identification_of_its_pairs():
    import pbicrl

    ds = make_problem(20, violation_rate=0.4, seed=2).dataset
    post = pbicrl.infer(ds, likelihood="pairwise", pairs=5, pairs_seed=7, iterations=200, chains=1, seed=0,
                        progress=False)
    assert post.identified["pairs"]["n_pairs"] == 15 and post.identified["pairs"]["seed"] == 7
    assert "one of the 15 sampled pairs the likelihood uses" in post.table(width=400)
    prefs = Preferences.from_groups(ds.group, None, protocol=5, seed=7)
    np.testing.assert_allclose(post.min_penalty(), _brute_min_penalty(ds, prefs), rtol=1e-5, atol=1e-6)


def test_identify_command_analyses_the_pairs_of_pairs_seed(tmp_path, capsys):
    import json

    from pbicrl.cli import main

    ds = make_problem(20, violation_rate=0.4, seed=2).dataset
    path = tmp_path / "d.npz"
    ds.save(path)
    assert main(["identify", str(path), "--likelihood", "pairwise", "--pairs", "5", "--pairs-seed", "7",
                 "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["pairs"]["n_pairs"] == 15 and out["pairs"]["seed"] == 7
    prefs = Preferences.from_groups(ds.group, None, protocol=5, seed=7)
    got = [out["features"][n]["min_penalty"] for n in ds.feature_names]
    np.testing.assert_allclose(got, _brute_min_penalty(ds, prefs), rtol=1e-5, atol=1e-6)
    assert main(["identify", str(path), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["pairs"] == {"used": "all cross-group pairs"}
