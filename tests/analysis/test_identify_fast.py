"""The fast identifiability analysis (issue 31 item 9) against the one it replaced and against brute force.

``identify_reference.py`` beside this file is the analysis as it was before (one max-t LP and one sparsest-direction LP
per unbounded feature, one LP per end of every penalty, probes seeded one matrix product at a time, a p x p null-space
projector); the current one must give the same answers on small random problems of every kind: separable or not,
unbounded penalties or not, either sign, margins, single-trajectory groups, affinely dependent candidates.

One change of definition is applied to both (marked in the reference): the sparsest direction asks for half the best
improvement t* (the max-t LP's optimal value), where it asked for half the improvement of whichever optimal vertex the
solver returned, so it no longer depends on the solver's path. Where the sparsest-direction LP itself has several
optimal vertices (e.g. two candidates with the same standardised column) any of them is right: a direction that differs
from the reference's must then be a recession direction on the data, improve the ranking and cost no more than the
reference's in that LP's objective.
"""

import importlib.util
import math
import sys
from pathlib import Path

import numpy as np
import pytest

import pbicrl.analysis.identify as identify_module
from pbicrl.analysis.identify import _GroupLP, _flat_partners, identify
from pbicrl.inference.data import Dataset

pytest.importorskip("scipy")

_spec = importlib.util.spec_from_file_location("identify_reference", Path(__file__).with_name("identify_reference.py"))
ref = importlib.util.module_from_spec(_spec)
sys.modules.setdefault("identify_reference", ref)  # dataclasses look their module up
_spec.loader.exec_module(ref)


def _problem(seed: int) -> tuple[Dataset, dict]:
    """A small random ranked dataset: a few features that tell the groups apart (cleanly or not), noise features,
    sometimes a duplicated (affinely dependent) one, groups of one trajectory or of several."""
    rng = np.random.default_rng(seed)
    K = int(rng.integers(2, 5))
    sizes = rng.integers(1, 6, K) if rng.random() < 0.3 else rng.integers(3, 9, K)
    group = np.repeat(np.arange(1, K + 1), sizes)
    n = group.size
    n_sig, n_noise = int(rng.integers(1, 4)), int(rng.integers(0, 5))
    cols = [rng.uniform(0, 1, n)]  # the nominal feature
    for _ in range(n_sig):  # grows with the group index: a cost that explains the ranking, with some overlap
        overlap = rng.choice([0.0, 0.3, 1.5])
        cols.append(np.clip((group - 1) / K + overlap * rng.uniform(-0.5, 0.5, n) / K, 0, None) * (rng.random(n) < 0.8))
    cols += [rng.uniform(0, 1, n) for _ in range(n_noise)]
    if rng.random() < 0.25:
        cols.append(2.0 * cols[1] + 0.5)  # affinely dependent on the first signal
    F = np.column_stack(cols)
    if rng.random() < 0.3:
        flip = rng.random(n) < 0.15
        group = group.copy()
        group[flip] = rng.integers(1, K + 1, int(flip.sum()))
        group[:K] = np.arange(1, K + 1)  # keep every group
    names = [f"f{j}" for j in range(F.shape[1])]
    ds = Dataset(features=F, offsets=np.arange(n + 1), group=group, feature_names=names,
                 nominal_weights=np.r_[rng.uniform(0, 2), np.zeros(F.shape[1] - 1)])
    kw = {"penalty_sign": "negative" if rng.random() < 0.7 else "any", "beta": float(rng.choice([0.5, 1.0, 4.0])),
          "candidates": names[1:]}
    if rng.random() < 0.4:
        kw["margins"] = list(rng.uniform(0, 1, len(np.unique(group)) - 1))
    return ds, kw


def _same_direction(a: dict, b: dict) -> bool:
    keys = set(a) | set(b)
    return all(abs(a.get(k, 0.0) - b.get(k, 0.0)) <= 1e-6 for k in keys)


def _cost(ds: Dataset, name: str, d: dict) -> float:
    """The sparsest-direction LP's objective of ``d`` for feature ``name``: sum of |delta_i| over the other features
    in standardised units (unit range), with |delta| = 1 on ``name``."""
    F = ds.mean_features
    s = F.max(axis=0) - F.min(axis=0)
    idx = {n: j for j, n in enumerate(ds.feature_names)}
    std = {n: abs(v) * s[idx[n]] for n, v in d.items()}
    return sum(v for n, v in std.items() if n != name) / std[name]


def _is_recession_direction(ds: Dataset, d: dict) -> bool:
    """Along ``d`` no cross-group pair's return difference decreases and some increase (checked on the data)."""
    delta = np.array([d.get(n, 0.0) for n in ds.feature_names])
    r = ds.mean_features @ delta
    labels = ds.group_labels
    lo = np.array([r[ds.group == k].min() for k in labels])
    hi = np.array([r[ds.group == k].max() for k in labels])
    tol = 1e-6 * (1.0 + np.abs(r).max())
    ordered = all(lo[k] >= hi[k + 1:].max() - tol for k in range(labels.size - 1))
    return ordered and r[ds.group == labels[0]].mean() - r[ds.group == labels[-1]].mean() > tol


def _same_scale_and_ends(f, g) -> None:
    """The separation scale and the ends of S_alpha of two entries agree (to the LP tolerance; infinite ends exactly)."""
    if g.min_penalty is None:
        assert f.min_penalty is None
        return
    assert f.min_penalty == pytest.approx(g.min_penalty, rel=1e-6, abs=1e-7)
    for x, y in zip(f.penalty_range, g.penalty_range):
        assert x == y if math.isinf(y) else x == pytest.approx(y, rel=1e-6, abs=1e-7)


def _companions_removed(reason: str) -> str:
    return reason.split(";")[0].split(" together with")[0].split(" on its own")[0]


@pytest.mark.parametrize("warm", [False, True], ids=["linprog", "highspy"])
@pytest.mark.parametrize("seed", range(40))
def test_the_fast_analysis_gives_the_reference_answers(seed, warm, monkeypatch):
    if warm:
        pytest.importorskip("highspy")
    monkeypatch.setattr(identify_module, "_WARM", warm)
    ds, kw = _problem(seed)
    new, old = identify(ds, **kw), ref.identify(ds, **kw)
    assert new.separable == old.separable
    for f, g in zip(new.features, old.features):
        assert (f.name, f.candidate, f.identifiable, f.unbounded, f.direction) == \
            (g.name, g.candidate, g.identifiable, g.unbounded, g.direction), (seed, f, g)
        if f.reason.split(";")[0] != g.reason.split(";")[0]:  # only the companions may differ, see below
            assert _companions_removed(f.reason) == _companions_removed(g.reason), (seed, f.reason, g.reason)
            assert f.recession != g.recession
        _same_scale_and_ends(f, g)
        assert len(f.recession) == len(g.recession)
        for d_new, d_old in zip(f.recession, g.recession):
            # the sparsest direction is a vertex of an LP; where there are several, any is right: check it is one
            if not _same_direction(d_new, d_old):
                assert _is_recession_direction(ds, d_new), (seed, f.name, d_new)
                assert _cost(ds, f.name, d_new) <= _cost(ds, f.name, d_old) * (1 + 1e-6) + 1e-6, (seed, d_new, d_old)


def _full_pair_ends(ds: Dataset, kw: dict, name: str) -> list[float]:
    """The ends of ``name``'s penalty over S_alpha from one LP over every cross-group pair row (no box)."""
    from scipy.optimize import linprog

    from pbicrl.inference.preferences import Margins

    F, wn, labels = ds.mean_features, ds.nominal_weights, ds.group_labels
    cand = [ds.feature_names.index(n) for n in kw["candidates"]]
    M = Margins.parse(kw.get("margins"), labels.size).matrix
    L = math.log(0.95 / 0.05)
    rows, rhs = [], []
    for k in range(labels.size):
        for l in range(k + 1, labels.size):
            for i in np.flatnonzero(ds.group == labels[k]):
                for j in np.flatnonzero(ds.group == labels[l]):  # beta (phi_i - phi_j) @ (w_n + w) >= m_kl + L
                    rows.append(-(F[i] - F[j])[cand])
                    rhs.append((F[i] - F[j]) @ wn - (M[k, l] + L) / kw["beta"])
    box = [(None, 0.0) if kw["penalty_sign"] == "negative" else (None, None)] * len(cand)
    a = cand.index(ds.feature_names.index(name))
    out = []
    for sgn in (-1.0, 1.0):
        obj = np.zeros(len(cand))
        obj[a] = -sgn
        r = linprog(obj, A_ub=np.array(rows), b_ub=np.array(rhs), bounds=box, method="highs")
        out.append(float(r.x[a]) if r.status == 0 else sgn * math.inf)
    return out


@pytest.mark.parametrize("warm", [False, True], ids=["linprog", "highspy"])
@pytest.mark.parametrize("seed", [53, 345, 375])
def test_ends_where_companions_reach_the_box_match_the_full_pair_lp(seed, warm, monkeypatch):
    """Problems where the LP for an end of S_alpha has optimal vertices with a companion at the 1e10 box: such a vertex
    lost digits (seed 53: -45.78 instead of -46.10, which the reference still gives when its solver path lands there);
    the ends are now found under boxes that stay inactive, so they are the full pair LP's."""
    if warm:
        pytest.importorskip("highspy")
    monkeypatch.setattr(identify_module, "_WARM", warm)
    ds, kw = _problem(seed)
    res = identify(ds, **kw)
    checked = 0
    for f in res.features:
        if f.penalty_range is None or not f.candidate:
            continue
        want = _full_pair_ends(ds, kw, f.name)
        for got, exact in zip(f.penalty_range, want):
            if math.isinf(exact):
                assert got == exact, (f.name, f.penalty_range, want)
            else:
                checked += 1
                assert got == pytest.approx(exact, rel=1e-7, abs=1e-9), (f.name, f.penalty_range, want)
    assert checked > 0


def test_the_column_seeding_adds_the_extremes_the_probes_added():
    rng = np.random.default_rng(5)
    X = rng.uniform(-1, 1, (40, 6))
    X[3] = X[7]  # ties: the first member wins, as np.argmin
    c = rng.uniform(0, 1, 40)
    starts = np.array([0, 1, 10, 25, 26, 40])
    lp = _GroupLP(X, c, starts, shift=np.zeros(5), base=0.1)
    old = ref._GroupLP(X, c, starts, shift=np.zeros(5), base=0.1)
    assert lp.work == old.work and np.array_equal(lp.in_work, old.in_work)


@pytest.mark.parametrize("n, p", [(30, 5), (8, 20)])
def test_affine_dependence_without_a_p_by_p_projector(n, p):
    rng = np.random.default_rng(n)
    X = rng.standard_normal((n, p))
    X[:, 2] = X[:, 0] - 3 * X[:, 1]  # dependent: 0, 1, 2 (and, with p > n, everything)
    X -= X.mean(axis=0)
    got = _flat_partners(X)
    # the p x p projector on the null space, as the analysis used to build it
    _, sv, vt = np.linalg.svd(X)
    tol = sv.max() * max(X.shape) * np.finfo(float).eps
    Z = vt[np.r_[sv, np.zeros(p - sv.size)] <= tol].T
    linked = np.abs(Z @ Z.T) > 1e-8
    want = {a: list(np.flatnonzero(linked[a])) for a in range(p) if linked[a, a]}
    assert set(got) == set(want)
    for a, (bs, more) in got.items():
        assert bs == want[a][:20] and more == (len(want[a]) > 20)
    if n > p:
        assert set(got) == {0, 1, 2}


def test_without_highspy_every_lp_goes_to_scipy_with_the_same_answers(monkeypatch):
    """``highspy`` is optional (``pbicrl[lp]``): when it cannot be imported the analysis falls back to
    :func:`scipy.optimize.linprog` for every LP, silently, with the same answers."""
    import sys

    ds, kw = _problem(53)  # separable, finite and infinite ends, unbounded penalties
    monkeypatch.setitem(sys.modules, "highspy", None)  # `import highspy` raises ImportError
    assert not identify_module._LPSolver().warm
    with pytest.raises(ImportError):
        identify_module._LPSolver(warm=True)
    cold = identify(ds, **kw)
    monkeypatch.delitem(sys.modules, "highspy")
    pytest.importorskip("highspy")
    assert identify_module._LPSolver().warm
    warm = identify(ds, **kw)
    assert cold.separable and warm.separable
    finite = 0
    for f, g in zip(cold.features, warm.features):
        assert (f.unbounded, f.direction, f.identifiable) == (g.unbounded, g.direction, g.identifiable)
        if g.penalty_range is not None:
            for x, y in zip(f.penalty_range, g.penalty_range):
                finite += math.isfinite(y)
                assert x == y if math.isinf(y) else x == pytest.approx(y, rel=1e-7, abs=1e-9)
    assert finite > 0


def test_the_warm_solver_prints_nothing(capfd):
    """HiGHS >= 1.16 prints a licence banner on stdout when a model object is made, before any option can be
    set; identify must not (it would corrupt `pbicrl identify --json` and the labelling page's child pipe)."""
    pytest.importorskip("highspy")
    ds, kw = _problem(53)
    capfd.readouterr()
    solver = identify_module._LPSolver()
    assert solver.warm
    identify(ds, **kw)
    out, err = capfd.readouterr()
    assert "HiGHS" not in out and "HiGHS" not in err, out + err


@pytest.mark.parametrize("seed", range(40))
def test_without_companions_the_same_unbounded_penalties_and_ends(seed):
    """identify(companions=False) decides unboundedness from the shared LPs alone (w_p <= 0: a direction that moves a
    penalty plus the improving one is unbounded); every flag, scale and end must be the reference's, and only the
    directions are left out."""
    ds, kw = _problem(seed)
    new, old = identify(ds, **kw, companions=False), ref.identify(ds, **kw)
    assert new.companions == (kw["penalty_sign"] == "any")  # "any": the deciding LP is the companions' LP
    for f, g in zip(new.features, old.features):
        assert (f.identifiable, f.unbounded, f.direction) == (g.identifiable, g.unbounded, g.direction), (seed, f, g)
        _same_scale_and_ends(f, g)
        if kw["penalty_sign"] == "negative":
            assert f.recession == ()
            if f.unbounded and f.identifiable:
                assert "companions were not computed" in f.reason
                assert "companions were not computed" in new.explanations()[f.name]


def _dense(n: int, p: int, seed: int = 0) -> Dataset:
    """``n`` trajectories of 4 states in 3 groups; two features tell the groups apart, ``p - 2`` uniform ones."""
    rng = np.random.default_rng(seed)
    group = np.repeat([1, 2, 3], -(-n // 3))[:n]
    g = np.repeat(group, 4)
    F = rng.random((4 * n, p))
    F[:, 0] = (g == 2) * (rng.random(4 * n) < 0.5)
    F[:, 1] = (g == 3) * (rng.random(4 * n) < 0.5)
    F[::4, 0], F[::4, 1] = group == 2, group == 3
    return Dataset(features=F, offsets=np.arange(0, 4 * n + 1, 4), group=group,
                   feature_names=[f"f{j}" for j in range(p)])


def test_many_unbounded_penalties_skip_the_companions_by_default():
    """Above the default's size (more than 200 unbounded penalties) no per-feature LP runs: the same flags and scales
    as with companions, a handful of LPs instead of one per feature, and the reason says how to get them."""
    ds = _dense(60, 240)
    auto, full = identify(ds), identify(ds, companions=True)
    assert full.companions and not auto.companions and auto.to_dict()["companions"] is False
    assert auto.n_lp < 40 < full.n_lp
    assert int(auto.unbounded.sum()) == int(full.unbounded.sum()) > identify_module._COMPANION_MAX
    np.testing.assert_allclose(auto.min_penalty, full.min_penalty, rtol=1e-6, atol=1e-7)
    for f, g in zip(auto.features, full.features):
        assert (f.unbounded, f.direction, f.identifiable) == (g.unbounded, g.direction, g.identifiable)
        assert (f.penalty_range is None) == (g.penalty_range is None)
        if f.penalty_range is not None:
            np.testing.assert_allclose(f.penalty_range, g.penalty_range, rtol=1e-6, atol=1e-7)
        assert f.recession == () and (not g.unbounded or g.recession)
    small = identify(_dense(60, 20))
    assert small.companions and all(f.recession for f in small.features if f.unbounded)


def test_the_zero_rounds_settle_upper_ends_exactly():
    """w_p <= 0: upper ends at 0 come from points of S_alpha with zeros (the smallest sum |w|, then the same over the
    features not yet settled) instead of one LP per feature; every end must equal its own LP's."""
    ds = _dense(45, 60, seed=3)
    new = identify(ds, alpha=0.2)
    X = ds.mean_features
    from scipy.optimize import linprog

    labels = ds.group_labels
    L = math.log(0.8 / 0.2)
    rows, rhs = [], []
    for k in range(labels.size):
        for l in range(k + 1, labels.size):
            for i in np.flatnonzero(ds.group == labels[k]):
                for j in np.flatnonzero(ds.group == labels[l]):
                    rows.append(-(X[i] - X[j]))
                    rhs.append(-L)
    assert new.separable
    checked = 0
    for a, f in enumerate(new.features):
        obj = np.zeros(X.shape[1])
        obj[a] = -1.0  # the highest w_a
        r = linprog(obj, A_ub=np.array(rows), b_ub=np.array(rhs), bounds=[(None, 0.0)] * X.shape[1], method="highs")
        assert r.status == 0
        assert f.penalty_range[1] == pytest.approx(r.x[a], abs=1e-6 * (1 + abs(r.x[a]))), (f.name, r.x[a])
        checked += f.penalty_range[1] < 0
    assert checked >= 1  # some penalty is required (its upper end below 0), the rest are settled at 0


def test_progress_shows_while_one_lp_takes_long(monkeypatch, capfd):
    """issue 31 item 9: with many dense features one LP takes 15 s; the bar must appear (and its clock run) during
    it, not after it."""
    monkeypatch.setattr(identify_module, "_PROGRESS_DELAY_S", 0.1)
    slow = identify_module._LPSolver.solve
    during = []

    def solve(self, *a, **k):
        if not during:
            import time

            time.sleep(2.5)
            during.append(capfd.readouterr().err)  # what stderr showed while this LP ran
        return slow(self, *a, **k)

    monkeypatch.setattr(identify_module._LPSolver, "solve", solve)
    ds, kw = _problem(3)
    capfd.readouterr()
    identify(ds, **kw, progress=True)
    assert "identify: unbounded penalties" in during[0], during
    assert during[0].count("\r") >= 2, during  # drawn, then redrawn with its clock one second on


def _instances(monkeypatch, cls) -> list:
    """Every instance of ``cls`` made while the test runs, in order."""
    made = []
    init = cls.__init__

    def keep(self, *a, **k):
        init(self, *a, **k)
        made.append(self)

    monkeypatch.setattr(cls, "__init__", keep)
    return made


def test_each_phase_frees_its_lp_models(monkeypatch):
    """The replay of session 15: with 10,000 dense features every HiGHS model (a copy of 6 million non-zeros) stayed
    alive to the end and the analysis passed a 4 GB address-space cap; a phase's models are now freed when it ends."""
    pytest.importorskip("highspy")
    monkeypatch.setattr(identify_module, "_WARM", True)
    made = _instances(monkeypatch, identify_module._LPSolver)
    res = identify(_dense(45, 60, seed=3), alpha=0.2, companions=True)
    assert res.separable and res.unbounded.any()
    left = set(made[0]._models)
    assert not left & {"support", "sparsest", "zeros"}, left


def test_an_interrupted_analysis_leaves_no_bar_redrawing(monkeypatch, capfd):
    """Ctrl-C (or any error) in the middle of identify: the bar's redraw thread must stop with it, not print to the
    terminal every second for the rest of the session (a notebook keeps the interrupted frame alive)."""
    monkeypatch.setattr(identify_module, "_PROGRESS_DELAY_S", 0.0)
    made = _instances(monkeypatch, identify_module._Progress)
    slow = identify_module._LPSolver.solve
    calls = []

    def solve(self, *a, **k):
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return slow(self, *a, **k)

    monkeypatch.setattr(identify_module._LPSolver, "solve", solve)
    ds, kw = _problem(3)
    with pytest.raises(KeyboardInterrupt):
        identify(ds, **kw, progress=True)
    assert made and all(p._ticker is None or not p._ticker.is_alive() for p in made)
