"""Identifiability analysis (pbicrl.analysis.identify): oracles by brute force and by the full all-pairs LP."""

import json
import math
import warnings

import numpy as np
import pytest

from pbicrl.inference.constraints import AxisHalfspace, Ball
from pbicrl.inference.data import Dataset
from pbicrl.errors import PbicrlWarning
from pbicrl.analysis.identify import IdentifyError, identify, threshold_interval
from pbicrl.inference.likelihood import log_likelihood
from pbicrl.inference.preferences import Margins, PreferenceError, Preferences

L95 = math.log(0.95 / 0.05)


def _dataset(rows, group, names, wn, lengths=None):
    """Trajectories whose every state equals ``rows[i]`` (so the mean features are ``rows``)."""
    lengths = lengths if lengths is not None else [1] * len(rows)
    return Dataset.from_trajectories([np.tile(np.asarray(r, float), (t, 1)) for r, t in zip(rows, lengths)], group,
                                     feature_names=names, nominal_weights=wn)


def _regions(extra_cols=(), lengths=None):
    """The point-mass structure in miniature: G1 clean, G2 enters orange, G3 enters red.

    Features (a, orange, red) with w_n = (1, 0, 0); candidates orange and red. By hand, with gaps
    g_kl = (m_kl + logit(1-alpha)) / beta:  |w_o| >= 10 (g12 + 0.1) and |w_r| >= 5 |w_o| + 10 (g23 + 0.1).
    """
    rows, group = [], []
    for a in (0.0, 0.1):
        rows.append([a, 0, 0]); group.append(1)
        for lvl in (0.1, 0.5):
            rows.append([a, lvl, 0]); group.append(2)
            rows.append([a, 0, lvl]); group.append(3)
    rows = [r + list(extra_cols) for r in rows]
    names = ["a", "orange", "red"] + [f"x{i}" for i in range(len(extra_cols))]
    return _dataset(rows, group, names, [1.0, 0, 0] + [0.0] * len(extra_cols), lengths=lengths)


def _by_hand(gaps=(0.0, 0.0), beta=1.0, alpha=0.05):
    m = Margins.from_gaps(gaps).matrix
    L = math.log((1 - alpha) / alpha)
    g = (m + L) / beta
    wo = 10 * (g[0, 1] + 0.1)
    wr = max(5 * wo + 10 * (g[1, 2] + 0.1), 10 * (g[0, 2] + 0.1))
    return wo, wr


def _pair_gap(ds, W, margins=None, beta=1.0, alpha=0.05, wn=None):
    """Brute force: min over ALL cross-group pairs of beta (r_i - r_j) - m - logit(1-alpha), for each row of W."""
    prefs = Preferences.from_groups(ds.group, margins)
    I, J, M = prefs.to_pair_list()
    wn = ds.nominal_weights if wn is None else wn
    W = np.atleast_2d(W)
    out = np.empty(W.shape[0])
    for s in range(0, W.shape[0], 2000):  # chunks keep the (grid x pairs) array small
        r = (wn + W[s:s + 2000]) @ ds.mean_features.T
        out[s:s + 2000] = np.min(beta * (r[:, I] - r[:, J]) - M - math.log((1 - alpha) / alpha), axis=1)
    return out


# ------------------------------------------------------------------------------------------------ oracles
def test_min_penalty_by_hand_and_by_grid():
    ds = _regions()
    res = identify(ds, candidates=["orange", "red"])
    wo, wr = _by_hand()
    assert res.separable
    assert res["orange"].min_penalty == pytest.approx(wo, rel=1e-7)
    assert res["red"].min_penalty == pytest.approx(wr, rel=1e-7)
    assert res["a"].candidate is False and res["a"].min_penalty is None
    # Grid over (w_o, w_r): no grid point beats the LP, and the best one is within the grid's resolution (the
    # red bound moves 5x as fast as w_o, hence 6 steps).
    step = 0.25
    go, gr = np.meshgrid(np.arange(-2 * wo, 0 + step, step), np.arange(-1.5 * wr, 0 + step, step), indexing="ij")
    W = np.zeros((go.size, 3))
    W[:, 1], W[:, 2] = go.ravel(), gr.ravel()
    ok = _pair_gap(ds, W) >= -1e-9
    assert ok.any()
    for j, lp, res_ in ((1, wo, step), (2, wr, 6 * step)):
        best = np.abs(W[ok, j]).min()
        assert lp - 1e-6 <= best <= lp + res_ + 1e-9
    # The separating set's upper ends are -min_penalty; the lower ends are -inf (both unbounded).
    assert res["orange"].penalty_range == (-math.inf, pytest.approx(-wo))
    assert res["red"].penalty_range == (-math.inf, pytest.approx(-wr))


def test_unbounded_directions_by_hand_and_along_rays():
    ds = _regions()
    res = identify(ds, candidates=["orange", "red"])
    assert res["red"].unbounded and res["red"].direction == "-inf"
    assert res["red"].recession == ({"red": -1.0},)
    # Orange can only run off with red at least five times as fast (G2 must stay above G3).
    (d_o,) = res["orange"].recession
    assert set(d_o) == {"orange", "red"} and d_o["red"] == -1.0 and d_o["orange"] == pytest.approx(-0.2)
    dirs = sorted(res.unbounded_directions, key=len)
    assert len(dirs) == 2 and dirs[0] == {"red": -1.0} and dirs[1] == {"orange": pytest.approx(-0.2), "red": -1.0}
    # Brute force: along each reported direction no pair gets worse and the log-likelihood rises.
    I, J, _ = Preferences.from_groups(ds.group).to_pair_list()
    w0 = np.array([0.0, -40.0, -200.0])
    for dvec in res.unbounded_directions:
        delta = np.array([dvec.get(n, 0.0) for n in ds.feature_names])
        diff = ds.mean_features @ delta
        assert np.all(diff[I] - diff[J] >= -1e-12) and np.any(diff[I] - diff[J] > 0)
        ll = [log_likelihood(ds, w0 + t * delta) for t in (0, 10, 100, 1000, 10_000)]
        assert np.all(np.diff(ll) >= 0) and ll[-1] > ll[0]
    # Orange alone is not a recession direction: the likelihood eventually falls.
    assert log_likelihood(ds, w0 + 1e4 * np.array([0, -1.0, 0])) < log_likelihood(ds, w0)


def _random_problem(seed, n=8):
    rng = np.random.default_rng(seed)
    rows, group = [], []
    for k in (1, 2, 3):
        for _ in range(n):
            f1 = rng.uniform(0.4, 1.0) if k == 2 else rng.uniform(0.0, 0.1 if k == 1 else 0.3)
            f2 = rng.uniform(0.6, 1.0) if k == 3 else rng.uniform(0.0, 0.1 if k == 1 else 0.05)
            rows.append([rng.uniform(0, 1), f1, f2]); group.append(k)
    return _dataset(rows, group, ["a", "f1", "f2"], [1.0, 0.0, 0.0])


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_random_data_against_grid_and_direction_scan(seed):
    ds = _random_problem(seed)
    margins = [0.5, 1.0]
    res = identify(ds, candidates=["f1", "f2"], margins=margins)
    assert res.separable
    mp = np.array([res["f1"].min_penalty, res["f2"].min_penalty])
    # Grid oracle for the separation scales (explicit pairs, no group-extreme shortcut).
    lim = 2 * mp.max() + 10
    step = lim / 250
    g1, g2 = np.meshgrid(np.arange(-lim, step, step), np.arange(-lim, step, step), indexing="ij")
    W = np.column_stack([np.zeros(g1.size), g1.ravel(), g2.ravel()])
    ok = _pair_gap(ds, W, margins) >= -1e-9
    for a, j in enumerate((1, 2)):
        best = np.abs(W[ok, j]).min()
        assert mp[a] - 1e-6 <= best <= mp[a] + 5 * step
    # Direction scan for unboundedness: delta = -(cos t, sin t) over the admissible quadrant.
    I, J, _ = Preferences.from_groups(ds.group).to_pair_list()
    th = np.linspace(0, np.pi / 2, 4001)
    D = -np.column_stack([np.zeros_like(th), np.cos(th), np.sin(th)])
    diff = ds.mean_features @ D.T
    inside = np.all(diff[I] - diff[J] >= -1e-12, axis=0) & np.any(diff[I] - diff[J] > 1e-12, axis=0)
    for a, j in enumerate((1, 2)):
        assert res.features[j].unbounded == bool(np.any(inside & (D[:, j] < -1e-9)))


def test_cutting_planes_match_the_full_pair_lp():
    from scipy.optimize import linprog

    rng = np.random.default_rng(7)
    n = 40
    group = np.repeat([1, 2, 3], n)
    lo = np.array([[0, 0, 0], [0.5, 0, 0], [0, 0.5, 0]])[group - 1]    # f1 marks G2, f2 marks G3, f3 is noise
    hi = np.array([[0.2, 0.05, 1], [1, 0.05, 1], [0.2, 1, 1]])[group - 1]
    rows = np.column_stack([rng.uniform(0, 1, 3 * n), rng.uniform(lo, hi)])
    ds = _dataset(rows.tolist(), group, ["a", "f1", "f2", "f3"], [1.0, 0, 0, 0])
    res = identify(ds, candidates=["f1", "f2", "f3"], penalty_sign="any", margins=[1.0, 0.5], beta=2.0)
    # Strict separation by f1, f2 leaves room to add some f3 either way: every penalty is unbounded.
    assert res.separable and res["f3"].direction == "both" and res["f2"].direction == "-inf"
    assert sum(math.isfinite(e) for n in ("f1", "f2", "f3") for e in res[n].penalty_range) == 2
    I, J, M = Preferences.from_groups(group, [1.0, 0.5]).to_pair_list()
    F, c = ds.mean_features, ds.mean_features @ ds.nominal_weights
    # beta (c_i - c_j + (F_i - F_j) w) >= m + L   <=>   -beta (F_i - F_j) w <= beta (c_i - c_j) - m - L
    A = -2.0 * (F[I] - F[J])[:, 1:]
    b = 2.0 * (c[I] - c[J]) - M - L95
    for a, name in enumerate(("f1", "f2", "f3")):
        f = res[name]
        for sgn, end in ((-1, f.penalty_range[0]), (1, f.penalty_range[1])):
            obj = np.zeros(3)
            obj[a] = -sgn
            out = linprog(obj, A_ub=A, b_ub=b, bounds=[(-1e6, 1e6)] * 3, method="highs")
            assert out.status == 0
            full = out.x[a]
            if math.isinf(end):
                assert abs(full) > 1e5  # runs into the box: unbounded in the full LP too
            else:
                assert end == pytest.approx(full, rel=1e-6, abs=1e-6)


# ------------------------------------------------------------------------------------------------ cases
def test_noisy_rankings_are_not_separable_but_a_clean_feature_stays_unbounded():
    ds = _regions()
    rows = ds.mean_features.tolist() + [[0.05, 0.0, 0.0], [0.05, 0.0, 0.0]]
    group = ds.group.tolist() + [1, 2]  # the same trajectory in G1 and G2: no weight orders that pair
    noisy = _dataset(rows, group, list(ds.feature_names), ds.nominal_weights)
    res = identify(noisy, candidates=["orange", "red"])
    assert not res.separable
    assert res["orange"].min_penalty is None and res["red"].min_penalty is None
    assert res["red"].unbounded  # red still separates G3 from everything: its scale is still not fixed
    assert "separable: no" in res.table()
    msgs = res.warnings()
    assert any(m.startswith("red:") and "not separable" in m for m in msgs)
    assert json.loads(json.dumps(res.to_dict(), allow_nan=False))["separable"] is False


def test_overlapping_groups_are_bounded():
    # G2 trajectories sometimes look like G1 ones: a finite penalty balances the pairs, nothing runs off.
    rows = [[0.0, 0.0], [0.0, 0.2], [0.0, 0.6], [0.0, 0.1], [0.0, 0.7], [0.0, 0.9]]
    group = [1, 1, 1, 2, 2, 2]
    ds = _dataset(rows, group, ["a", "f"], [1.0, 0.0])
    res = identify(ds, candidates=["f"])
    assert not res.separable and not res["f"].unbounded and res["f"].identifiable
    assert res.warnings() == []


def test_constant_and_zero_features_are_not_identifiable():
    base = identify(_regions(), candidates=["orange", "red"])
    # Lengths differ so the "constant" means differ in the last bit (0.1 summed 3 vs 7 times).
    ds = _regions(extra_cols=(0.1, 0.0), lengths=[3, 7, 2, 5, 1, 4, 6, 3, 2, 5])
    res = identify(ds, candidates=["orange", "red", "x0", "x1"])
    const, zero = res["x0"], res["x1"]
    assert const.identifiable is False and "constant" in const.reason
    assert zero.identifiable is False and "all zeros" in zero.reason
    for f in (const, zero):
        assert f.min_penalty is None and not f.unbounded and f.recession == ()
    assert all("x0" not in d and "x1" not in d for d in res.unbounded_directions)
    for n in ("orange", "red"):
        assert res[n].min_penalty == pytest.approx(base[n].min_penalty, rel=1e-6)
    msgs = res.warnings()
    assert sum(m.startswith("x0: not identifiable") for m in msgs) == 1
    assert sum(m.startswith("x1: not identifiable") for m in msgs) == 1


def test_collinear_candidates_are_not_identifiable():
    ds = _regions()
    F = ds.mean_features
    dup = _dataset(np.column_stack([F, 2 * F[:, 2] + 1]).tolist(), ds.group, ["a", "orange", "red", "red2"],
                   [1.0, 0, 0, 0])
    res = identify(dup, candidates=["orange", "red", "red2"], penalty_sign="any")
    assert res["red"].identifiable is False and "red2" in res["red"].reason
    assert res["red2"].identifiable is False and res["orange"].identifiable
    # With free signs, red can run to -inf and, compensated by red2, to +inf.
    assert res["red"].direction == "both"


def test_sign_handling():
    # G1 has MORE of the feature: only a bonus (w > 0) orders the groups.
    ds = _dataset([[0.5], [0.6], [0.1], [0.2]], [1, 1, 2, 2], ["b"], [0.0])
    neg = identify(ds)
    assert not neg.separable and not neg["b"].unbounded
    anys = identify(ds, penalty_sign="any")
    assert anys.separable
    assert anys["b"].min_penalty == pytest.approx(L95 / 0.3)
    assert anys["b"].direction == "+inf" and anys["b"].recession == ({"b": 1.0},)
    assert anys["b"].penalty_range == (pytest.approx(L95 / 0.3), math.inf)
    assert anys.warnings() == [f"b: |w_p| >= {L95 / 0.3:.4g} identified; magnitude beyond that is the prior's"]
    assert "(w_p -> +inf)" in anys.explanations()["b"]


def test_margins_beta_alpha_move_the_scale_not_the_unboundedness():
    ds = _regions()
    ref = identify(ds, candidates=["orange", "red"])
    for gaps, beta, alpha in (([1.0, 2.0], 1.0, 0.05), ([0.0, 3.0], 2.0, 0.05), ([0.0, 0.0], 1.0, 0.01)):
        res = identify(ds, candidates=["orange", "red"], margins=gaps, beta=beta, alpha=alpha)
        wo, wr = _by_hand(gaps, beta, alpha)
        assert res["orange"].min_penalty == pytest.approx(wo, rel=1e-7)
        assert res["red"].min_penalty == pytest.approx(wr, rel=1e-7)
        assert [f.unbounded for f in res.features] == [f.unbounded for f in ref.features]
        assert res.unbounded_directions == ref.unbounded_directions
    assert identify(ds, candidates=["orange", "red"], margins=[1.0, 2.0])["red"].min_penalty > ref["red"].min_penalty
    # A K x K matrix and the equivalent gaps agree.
    a = identify(ds, candidates=["orange", "red"], margins=Margins.from_gaps([1.0, 2.0]).matrix)
    assert a["red"].min_penalty == pytest.approx(_by_hand([1.0, 2.0])[1])


def test_nominal_weights_override():
    ds = _regions()
    res = identify(ds, candidates=["orange", "red"], nominal_weights=[0.0, 0.0, 0.0])
    # Without the nominal term the a-spread no longer matters: |w_o| >= 10 L, |w_r| >= 5 |w_o| + 10 L.
    assert res["orange"].min_penalty == pytest.approx(10 * L95)
    assert res["red"].min_penalty == pytest.approx(60 * L95)


def test_to_dict_table_and_warnings():
    res = identify(_regions(), candidates=["orange", "red"])
    d = json.loads(json.dumps(res.to_dict(), allow_nan=False))
    assert d["separable"] is True and d["alpha"] == 0.05
    assert set(d["features"]["red"]) >= {"min_penalty", "unbounded", "direction", "identifiable", "reason"}
    assert d["features"]["red"]["penalty_range"][0] is None  # -inf
    assert d["unbounded_directions"][0] in ({"red": -1.0}, {"orange": pytest.approx(-0.2), "red": -1.0})
    assert d["parameters"] == {}
    msgs = res.warnings()
    assert len(msgs) == 2
    red = next(m for m in msgs if m.startswith("red:"))
    assert red == f"red: |w_p| >= {res['red'].min_penalty:.4g} identified; magnitude beyond that is the prior's"
    long = res.explanations()["red"]  # the full text, once: summary.json's identified.explanations
    assert f"{res['red'].min_penalty:.4g}" in long and "Margins move the lower bound only" in long
    assert "not an estimate of the true penalty" in long
    assert d["warnings"] == msgs and d["explanations"]["red"] == long and "min|w_p|" in d["explanation"]
    table = res.table()
    assert "separable: yes" in table and "red" in table
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert res.issue_warnings() == msgs
    assert [str(w.message) for w in caught] == msgs and all(w.category is PbicrlWarning for w in caught)
    assert caught[0].filename == __file__  # attributed to the caller
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        overlap = _dataset([[0.0, 0.0], [0.0, 0.6], [0.0, 0.1], [0.0, 0.7]], [1, 1, 2, 2], ["a", "f"], [1.0, 0.0])
        assert identify(overlap, candidates=["f"]).issue_warnings() == []


# ------------------------------------------------------------------------------------------------ parameters
def _wall_data():
    reach = {1: [7.5, 6.0, 7.0], 2: [8.2, 9.0, 8.5], 3: [7.0, 10.0]}
    trajs, group = [], []
    for k, rs in reach.items():
        for r in rs:
            trajs.append(np.linspace(0.0, r, 6)[:, None])
            group.append(k)
    return Dataset.from_trajectories([np.ones((len(t), 1)) for t in trajs], group, states=trajs,
                                     feature_names=["living"], nominal_weights=[-1.0])


def test_wall_interval_both_directions_against_brute_force():
    ds = _wall_data()
    ge = AxisHalfspace(0, direction=">=", name="wall")
    iv = threshold_interval(ds, ge)
    assert (iv.low, iv.high, iv.low_closed, iv.high_closed) == (7.5, 8.2, False, True)
    assert iv.n_violating == 4 and iv.n_worse == 5 and iv.violating_per_group == {2: 3, 3: 1}
    assert iv.text() == "(7.5, 8.2]"
    # Brute force: theta in the interval <=> no G1 state inside and every violating trajectory touches the wall.
    best = ds.group == 1
    viol = np.array([False, False, False, True, True, True, False, True])
    for th in np.concatenate([np.linspace(6, 11, 501), [7.5, 8.2, np.nextafter(7.5, 9), np.nextafter(8.2, 9)]]):
        ins = np.array([ge.inside(ds.trajectory_states(i), [th]).any() for i in range(ds.n_trajectories)])
        ok = not ins[best].any() and ins[viol].all()
        assert ok == (7.5 < th <= 8.2), th
    # Mirror image: x <= theta on -x.
    neg = Dataset.from_trajectories([np.ones((t, 1)) for t in ds.lengths], ds.group,
                                    states=[-ds.trajectory_states(i) for i in range(ds.n_trajectories)])
    iv2 = threshold_interval(neg, AxisHalfspace(0, direction="<=", name="floor"))
    assert (iv2.low, iv2.high, iv2.low_closed, iv2.high_closed) == (-8.2, -7.5, True, False)
    assert iv2.text() == "[-8.2, -7.5)"


def test_parameters_in_identify_and_other_families():
    ds = _wall_data()
    res = identify(ds, constraints=[AxisHalfspace(0, name="wall"), Ball((0,), name="disc")])
    d = res.to_dict()
    assert d["parameters"]["wall.threshold"] == [7.5, 8.2]
    assert d["parameters"]["disc.centre0"] is None and d["parameters"]["disc.radius"] is None
    assert "only axis half-spaces" in d["parameter_details"]["disc.radius"]["reason"]
    assert res["living"].candidate is False  # with parametric constraints, as in infer: only they are candidates
    assert "wall.threshold" in res.table()
    # A wall nobody crosses: no interval, with the reason.
    flat = Dataset.from_trajectories([np.ones((2, 1))] * 2, [1, 2], states=[np.zeros((2, 1)), np.zeros((2, 1))])
    iv = threshold_interval(flat, AxisHalfspace(0))
    assert iv.interval is None and "does not place" in iv.reason


# ------------------------------------------------------------------------------------------------ errors
@pytest.mark.parametrize("kwargs, exc, field", [
    ({"alpha": 0.0}, IdentifyError, "alpha"),
    ({"alpha": 0.7}, IdentifyError, "alpha"),
    ({"alpha": "x"}, IdentifyError, "alpha"),
    ({"beta": 0.0}, IdentifyError, "beta"),
    ({"beta": math.nan}, IdentifyError, "beta"),
    ({"nominal_weights": [1.0, 2.0]}, IdentifyError, "nominal_weights"),
    ({"nominal_weights": [1.0, math.inf, 0.0]}, IdentifyError, "nominal_weights"),
    ({"candidates": ["nope"]}, IdentifyError, "candidates"),
    ({"candidates": [7]}, IdentifyError, "candidates"),
    ({"candidates": []}, IdentifyError, "candidates"),
    ({"candidates": ["red", 2]}, IdentifyError, "candidates"),
    ({"candidates": "red"}, IdentifyError, "candidates"),
    ({"penalty_sign": "positive"}, IdentifyError, "penalty_sign"),
    ({"margins": [1.0, 2.0, 3.0]}, PreferenceError, "margins"),
    ({"constraints": [AxisHalfspace(0)]}, ValueError, "constraints"),
    ({"constraints": [3]}, IdentifyError, "constraints"),
])
def test_bad_input_names_the_field(kwargs, exc, field):
    with pytest.raises(exc, match=field):
        identify(_regions(), **kwargs)


def test_bad_dataset():
    with pytest.raises(IdentifyError, match="dataset"):
        identify(np.zeros((3, 2)))


# ------------------------------------------------------------------------------------------------ many groups
def _full_pair_lp(ds, margins, beta, alpha, cand, neg):
    """Brute force over every cross-group pair (no group extremes, no adjacent-gap reduction): separability, the
    ends of each candidate's penalty over S_alpha, and the signs in which it is unbounded."""
    from scipy.optimize import linprog

    I, J, M = Preferences.from_groups(ds.group, margins).to_pair_list()
    F, c = ds.mean_features, ds.mean_features @ ds.nominal_weights
    L = math.log((1 - alpha) / alpha)
    D = (F[I] - F[J])[:, cand]
    A, b = -beta * D, beta * (c[I] - c[J]) - M - L    # beta (c_i - c_j + D w) >= m + L
    p = len(cand)
    box = [(-1e6, 0.0 if neg else 1e6)] * p
    feasible = linprog(np.zeros(p), A_ub=A, b_ub=b, bounds=box, method="highs").status == 0
    ends, ways = {}, {}
    for a in range(p):
        if feasible:
            e = []
            for sgn in (-1.0, 1.0):
                obj = np.zeros(p)
                obj[a] = -sgn
                x = linprog(obj, A_ub=A, b_ub=b, bounds=box, method="highs").x[a]
                e.append(sgn * math.inf if abs(x) > 1e5 else x)
            ends[a] = (e[0], min(e[1], 0.0) if neg else e[1])
        ways[a] = []
        for sgn in ((-1.0,) if neg else (-1.0, 1.0)):
            # max t  s.t.  D delta >= 0 (no pair worse), sgn delta_a >= t, sum D delta >= t (not flat), |delta| <= 1
            obj = np.zeros(p + 1)
            obj[p] = -1.0
            lead = np.zeros(p + 1)
            lead[a], lead[p] = -sgn, 1.0
            rows = np.vstack([np.c_[-D, np.zeros(len(D))], lead, np.r_[-D.sum(axis=0), 1.0]])
            bnd = [((-1.0, 0.0) if neg else (-1.0, 1.0))] * p + [(0.0, 1.0)]
            x = linprog(obj, A_ub=rows, b_ub=np.zeros(len(rows)), bounds=bnd, method="highs").x
            if x[p] > 1e-6:
                ways[a].append(int(sgn))
    return feasible, ends, ways


def _ranked(n, K, *, seed=0, sizes=None, wn=(4.0, 0.0, 0.0)):
    """n trajectories ranked by 4 a - 6 f1 - 2 f2 and cut into K groups (equal, or ``sizes``, best first)."""
    rng = np.random.default_rng(seed)
    F = rng.uniform(0, 1, (n, 3))
    order = np.argsort(-(F @ np.array([4.0, -6.0, -2.0])))
    sizes = np.full(K, n // K) if sizes is None else np.asarray(sizes)
    sizes[-1] += n - sizes.sum()
    group = np.empty(n, dtype=np.int64)
    group[order] = np.repeat(np.arange(1, K + 1), sizes)
    return Dataset(features=F, offsets=np.arange(n + 1), group=group, feature_names=["a", "f1", "f2"],
                   nominal_weights=list(wn))


@pytest.mark.parametrize("layout", ["total", "equal", "mixed", "matrix"])
@pytest.mark.parametrize("sign", ["negative", "any"])
def test_many_groups_match_the_full_pair_lp(layout, sign):
    # total ranking (every group one trajectory: no bound variables), 10 groups of 3, groups of 1-3 (both kinds in
    # one LP), and a non-additive K x K matrix (one row per group pair) - each against every pair's row.
    sizes = {"total": np.ones(30, int), "mixed": [1, 3, 2, 1, 1, 3, 2, 2, 1, 3, 1, 2, 3, 1], "matrix": [1, 3, 2, 1, 3]}
    n = {"mixed": 40, "matrix": 15}.get(layout, 30)
    K = len(sizes.get(layout, [0] * 10))
    ds = _ranked(n, K, sizes=np.array(sizes[layout]) if layout in sizes else None)
    rng = np.random.default_rng(1)
    cases = [(None, 1000.0, ["f1", "f2"]), (Margins.from_gaps(np.linspace(0.0, 0.3, K - 1)), 1000.0, ["f1", "f2"])]
    if layout == "matrix":
        m = np.triu(rng.uniform(0.0, 0.2, (K, K)), 1)
        assert Margins(m).offsets is None  # not additive: the dense form
        cases = [(Margins(m), 1000.0, ["f1", "f2"])]
    neg = sign == "negative"
    seen_finite = 0
    for margins, beta, cands in cases:
        res = identify(ds, candidates=cands, beta=beta, margins=margins, penalty_sign=sign)
        cand = [ds.feature_names.index(c) for c in cands]
        feasible, ends, ways = _full_pair_lp(ds, margins, beta, 0.05, cand, neg)
        assert res.separable == feasible
        for a, name in enumerate(cands):
            f = res[name]
            assert sorted(ways[a]) == ({"-inf": [-1], "+inf": [1], "both": [-1, 1]}[f.direction] if f.direction else [])
            if feasible:
                for got, want in zip(f.penalty_range, ends[a]):
                    if math.isinf(want):
                        assert got == want
                    else:
                        seen_finite += 1
                        assert got == pytest.approx(want, rel=1e-7, abs=1e-7)
    assert seen_finite >= 4  # the comparison covered finite ends, not only infinite ones
    # Zero nominal weights and every feature a candidate: some direction orders every pair strictly, so every
    # penalty is unbounded - in the full LP too.
    free = Dataset(features=ds.mean_features, offsets=ds.offsets, group=ds.group, feature_names=ds.feature_names,
                   nominal_weights=[0.0, 0.0, 0.0])
    res = identify(free, penalty_sign="any")
    feasible, ends, ways = _full_pair_lp(free, None, 1.0, 0.05, [0, 1, 2], False)
    assert res.separable and feasible
    for a, name in enumerate(free.feature_names):
        f = res[name]
        assert f.unbounded and sorted(ways[a]) == {"-inf": [-1], "+inf": [1], "both": [-1, 1]}[f.direction]


def test_twenty_thousand_groups_in_modest_memory(monkeypatch):
    # A total ranking of 20,000 trajectories: the old LP had K(K-1)/2 = 2e8 ordering rows and the result a
    # K x K margin matrix (3.2 GB). Dataset itself caps the groups (another module's limit); lifted here.
    import tracemalloc

    import pbicrl.inference.data as data_mod

    monkeypatch.setattr(data_mod, "MAX_GROUPS", 10**6)
    n = 20_000
    rng = np.random.default_rng(3)
    F = rng.uniform(0, 1, (n, 2))
    ret = F @ np.array([-3.0, 1.0]) + 0.05 * rng.standard_normal(n)  # noisy: not separable, finite scale
    group = np.empty(n, dtype=np.int64)
    group[np.argsort(-ret)] = np.arange(1, n + 1)
    ds = Dataset(features=F, offsets=np.arange(n + 1), group=group, feature_names=["f", "g"],
                 nominal_weights=[0.0, 1.0])
    tracemalloc.start()
    try:
        res = identify(ds, candidates=["f"])
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 200e6, f"peak {peak / 1e6:.0f} MB"
    assert len(res.group_labels) == n and res.margins.n_groups == n and res.margins.offsets is not None
    assert not res.separable and not res["f"].unbounded  # the noise leaves no direction that orders every pair
    d = res.to_dict()
    assert len(d["margins"]) == n - 1  # consecutive gaps, not K(K-1)/2 entries
    assert "(19999 in all)" in res.table()
