"""Active query selection (pbicrl.analysis.suggest): group probabilities, information gain, the CLI."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest

import pbicrl
from pbicrl.cli import main
from pbicrl.inference.data import Dataset, DatasetError
from pbicrl.inference.likelihood import PreferenceLikelihood
from pbicrl.inference.preferences import Preferences
from pbicrl.analysis.suggest import group_probabilities, information_gain, suggest
from pbicrl.inference.synthetic import make_problem


def _hand_dataset() -> Dataset:
    """Two features (a nominal one and a candidate constraint), three groups of two."""
    feats = [np.array([[1.0, 0.0]] * 3), np.array([[0.9, 0.0]] * 4),   # G1: no constraint
             np.array([[1.0, 1.0]] * 3), np.array([[0.8, 0.5]] * 2),   # G2: in the region part of the time
             np.array([[0.3, 0.0]] * 2), np.array([[0.2, 1.0]] * 5)]   # G3: slow
    return Dataset.from_trajectories(feats, [1, 1, 2, 2, 3, 3], feature_names=["speed", "region"],
                                     nominal_weights=[4.0, 0.0])


def _brute_probabilities(W, ds, X, margins=None):
    """p_s(k) from the grouped likelihood of the data with the candidate added to group k (no shortcut)."""
    K = ds.n_groups
    out = np.empty((W.shape[0], X.shape[0], K))
    for m in range(X.shape[0]):
        F = np.vstack([ds.mean_features, X[m]])
        for k, label in enumerate(ds.group_labels):
            prefs = Preferences.from_groups(np.append(ds.group, label), margins)
            lik = PreferenceLikelihood(F, prefs, np.zeros(ds.n_features), kind="grouped")
            for s in range(W.shape[0]):
                out[s, m, k] = lik(W[s])
    out = np.exp(out - out.max(axis=2, keepdims=True))
    return out / out.sum(axis=2, keepdims=True)


def _brute_mi(P, codes):
    """I(Y; Z) from the joint p(y, z) = (1/S) sum_s [z_s = z] p_s(y), written out term by term."""
    S, M, K = P.shape
    out = np.zeros(M)
    zs = sorted(set(codes))
    for m in range(M):
        joint = np.zeros((K, len(zs)))
        for s in range(S):
            joint[:, zs.index(codes[s])] += P[s, m] / S
        py, pz = joint.sum(axis=1), joint.sum(axis=0)
        for y in range(K):
            for z in range(len(zs)):
                if joint[y, z] > 0:
                    out[m] += joint[y, z] * math.log(joint[y, z] / (py[y] * pz[z]))
    return out


def test_gain_is_zero_for_a_certain_group_and_positive_for_an_ambiguous_one():
    S = 8
    c = np.array([[0, 1]] * 4 + [[0, 0]] * 4)
    P = np.zeros((S, 3, 3))
    P[:, 0] = [1.0, 0.0, 0.0]                                    # certain: always the best group
    P[:4, 1], P[4:, 1] = [0.1, 0.8, 0.1], [0.7, 0.2, 0.1]        # its group depends on c
    P[:, 2] = [0.4, 0.3, 0.3]                                    # uncertain, but the same under every c
    gain = information_gain(P, c)
    assert gain[0] == pytest.approx(0.0, abs=1e-12)
    assert gain[2] == pytest.approx(0.0, abs=1e-12)
    assert gain[1] > 0.1
    assert gain == pytest.approx(_brute_mi(P, [tuple(r) for r in c]), abs=1e-12)
    # per-feature target: the first indicator never varies, so the sum equals the gain about c_2
    assert information_gain(P, c, target="selected") == pytest.approx(gain, abs=1e-12)


def test_group_probabilities_match_the_grouped_likelihood_by_brute_force():
    ds = _hand_dataset()
    rng = np.random.default_rng(3)
    W = np.c_[rng.uniform(2.0, 6.0, 6), rng.uniform(-8.0, 0.0, 6)]
    X = np.array([[0.95, 0.0], [0.85, 0.4], [0.5, 0.2], [0.1, 0.9], [3.0, 0.0], [-2.0, 1.0]])
    for margins in (None, [0.5, 1.5]):
        fast = group_probabilities(W, ds, X, margins=margins)
        assert fast.shape == (6, 6, 3)
        assert fast.sum(axis=2) == pytest.approx(np.ones((6, 6)))
        assert fast == pytest.approx(_brute_probabilities(W, ds, X, margins), abs=1e-4)


def test_information_gain_oracle_on_a_hand_problem():
    """Draws with and without the constraint: a candidate that is in the region is informative (its group
    depends on c), a fast, region-free one is not (best group under every draw)."""
    ds = _hand_dataset()
    c = np.array([[0, 1]] * 5 + [[0, 0]] * 5)
    wp = np.array([[0.0, -6.0]] * 10)
    W = ds.nominal_weights + c * wp
    X = np.array([[30.0, 0.0],       # far better than everything: group 1 for every draw
                  [0.95, 0.8]])      # fast but mostly in the region: group 1 without, group 2/3 with the penalty
    P = _brute_probabilities(W, ds, X)
    expected = _brute_mi(P, [tuple(r) for r in c])
    got = information_gain(group_probabilities(W, ds, X), c)
    assert got == pytest.approx(expected, abs=1e-4)
    assert got[0] < 1e-6 < 0.05 < got[1]


def test_suggest_ranks_the_ambiguous_candidate_first_and_reports_probabilities():
    ds = _hand_dataset()
    c = np.array([[0, 1]] * 5 + [[0, 0]] * 5, dtype=np.int8)
    post = _FakeRun(c[None], np.array([[0.0, -6.0]] * 10)[None] * np.ones((1, 1, 1)), ("speed", "region"))
    pool = Dataset.from_trajectories([np.array([[30.0, 0.0]] * 2), np.array([[0.95, 0.8]] * 2),
                                      np.array([[0.9, 0.0]] * 2)], [0, 0, 1], feature_names=["speed", "region"],
                                     allow_unlabelled=True)
    res = suggest(post, ds, pool, 5)
    assert res.indices == [1, 0]            # the labelled pool trajectory is not a candidate
    assert res.n_candidates == 2 and res.n_draws == 10
    assert sum(res.ranking[0].group_probabilities) == pytest.approx(1.0)
    d = res.to_dict()
    assert d["groups"] == ["G1", "G2", "G3"] and d["suggestions"][0]["index"] == 1
    assert "gain (nats)" in res.table()


@dataclasses.dataclass
class _FakeRun:
    indicators: np.ndarray
    penalty_weights: np.ndarray
    feature_names: tuple
    settings: dict = dataclasses.field(default_factory=dict)
    extra: dict = dataclasses.field(default_factory=dict)


def test_suggest_rejects_bad_input():
    ds = _hand_dataset()
    post = _FakeRun(np.zeros((1, 4, 2), np.int8), np.zeros((1, 4, 2)), ("speed", "region"))
    with pytest.raises(DatasetError, match="group: the pool has no unlabelled"):
        suggest(post, ds, ds, 3)
    other = Dataset.from_trajectories([np.ones((2, 2))] * 2, [0, 0], feature_names=["a", "b"], allow_unlabelled=True)
    with pytest.raises(DatasetError, match="feature_names"):
        suggest(post, ds, other, 3)
    with pytest.raises(ValueError, match="n: expected a positive integer"):
        suggest(post, ds, ds, 0)
    with pytest.raises(ValueError, match="candidates: indices"):
        suggest(post, ds, ds, 2, candidates=[99])


@pytest.fixture(scope="module")
def run_and_pool(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("suggest")
    prob = make_problem(20, noise=1.0, violation_rate=0.4, seed=2)
    data = prob.dataset.save(tmp / "labelled.npz")
    post = pbicrl.infer(prob.dataset, n_iterations=3000, n_chains=1, n_jobs=1, progress=False, seed=1)
    post.extra["data"]["path"] = str(data)
    post.save(tmp / "run")
    pool = make_problem(10, noise=1.0, violation_rate=0.4, seed=3).dataset
    pool = dataclasses.replace(pool, group=np.zeros(pool.n_trajectories, dtype=np.int64), group_names=(),
                               allow_unlabelled=True)
    return tmp, pool.save(tmp / "pool.npz")


def test_cli_suggest_json(run_and_pool, capsys):
    tmp, pool = run_and_pool
    assert main(["suggest", str(tmp / "run"), "--pool", str(pool), "--n", "4", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["n_candidates"] == 30 and out["target"] == "indicators" and out["unit"] == "nats"
    gains = [s["information_gain"] for s in out["suggestions"]]
    assert len(gains) == 4 and gains == sorted(gains, reverse=True) and min(gains) >= 0
    assert all(0 <= s["index"] < 30 for s in out["suggestions"])
    assert all(sum(s["group_probabilities"].values()) == pytest.approx(1.0) for s in out["suggestions"])
    assert main(["suggest", str(tmp / "run"), "--pool", str(pool), "--n", "2"]) == 0
    assert "candidates scored" in capsys.readouterr().out


def test_cli_suggest_errors(run_and_pool, capsys, tmp_path):
    tmp, pool = run_and_pool
    assert main(["suggest", str(tmp / "run"), "--pool", str(tmp / "labelled.npz")]) == 2
    assert "group: the pool has no unlabelled" in capsys.readouterr().err
    assert main(["suggest", str(tmp_path / "nope"), "--pool", str(pool)]) == 2
    assert "run:" in capsys.readouterr().err
    bad = tmp_path / "bad.npz"
    bad.write_text("not a zip")
    assert main(["suggest", str(tmp / "run"), "--pool", str(bad)]) == 2
    assert "not a readable .npz" in capsys.readouterr().err


def test_additive_margins_go_in_as_offsets_with_the_same_numbers_as_the_matrix():
    from pbicrl.analysis.suggest import Z_HIGH, Z_LOW, Z_STEP, _slot_logits
    from pbicrl.inference.preferences import Margins

    rng = np.random.default_rng(3)
    K = 7
    a = rng.normal(size=20)
    gitems = rng.permutation(20).astype(np.int64)
    goff = np.array([0, 3, 5, 9, 12, 14, 17, 20], dtype=np.int64)
    m = Margins.from_gaps(rng.uniform(0.0, 2.0, K - 1))
    ac = rng.normal(size=5)
    by_matrix, by_offsets = np.empty((5, K)), np.empty((5, K))
    _slot_logits(a, gitems, goff, np.ascontiguousarray(m.matrix), np.zeros(0), ac, Z_LOW, Z_HIGH, Z_STEP, by_matrix)
    _slot_logits(a, gitems, goff, np.zeros((0, 0)), m.offsets, ac, Z_LOW, Z_HIGH, Z_STEP, by_offsets)
    np.testing.assert_array_equal(by_offsets, by_matrix)  # o_l - o_k is exactly the matrix entry


def test_a_run_over_many_groups_suggests_from_its_recorded_gaps_without_a_k_by_k_matrix(monkeypatch):
    """600 single-trajectory groups: the run records only the 599 consecutive gaps (``Margins.as_dict`` beyond 64
    groups); suggest reads them back as gaps and never builds the 600 x 600 matrix (checked by refusing it)."""
    import pbicrl.analysis.suggest  # noqa: F401 - the module under test, compiled before the patch
    from pbicrl.inference.preferences import Margins

    K = 600
    rng = np.random.default_rng(0)
    F = np.column_stack([np.linspace(2.0, 0.0, K), rng.uniform(size=K)])
    ds = Dataset.from_trajectories([f[None, :] for f in F], np.arange(1, K + 1), feature_names=["speed", "region"],
                                   nominal_weights=[1.0, 0.0])
    gaps = np.full(K - 1, 0.01)
    recorded = Margins.from_gaps(gaps).as_dict()
    assert len(recorded) == K - 1
    post = _FakeRun(np.array([[[0, 0], [0, 1]]], dtype=np.int8), np.array([[[0.0, 0.0], [0.0, -3.0]]]),
                    ("speed", "region"), {"beta": 1.0, "nominal_weights": [1.0, 0.0]}, {"margins": recorded})
    pool = Dataset.from_trajectories([np.array([[1.0, 0.0]]), np.array([[1.0, 1.0]])], [0, 0],
                                     feature_names=["speed", "region"], allow_unlabelled=True)
    expected = group_probabilities(post.penalty_weights.reshape(-1, 2) * post.indicators.reshape(-1, 2) + [1.0, 0.0],
                                   ds, pool.mean_features, margins=gaps)

    def no_matrix(self):
        raise AssertionError("the K x K margin matrix was built")

    monkeypatch.setattr(Margins, "matrix", property(no_matrix))
    got = suggest(post, ds, pool, n=2)
    assert got.n_candidates == 2 and len(got.groups) == K
    by_index = {s.index: s.group_probabilities for s in got.ranking}
    for i in range(2):  # the mean over the draws of the same probabilities as with the gaps given directly
        np.testing.assert_allclose(by_index[i], expected[:, i].mean(axis=0), rtol=1e-12, atol=1e-15)



def test_demonstrations_already_labelled_are_never_suggested(run_and_pool, capsys):
    """issue 30 item 7: a pool drawn from the run's own data (group set to 0, order shuffled) used to get its
    labelled demonstrations suggested; they are matched by content and left out."""
    from pbicrl.inference.data import load_dataset

    tmp, pool_path = run_and_pool
    labelled = load_dataset(tmp / "labelled.npz")
    fresh = load_dataset(pool_path, allow_unlabelled=True)
    both = Dataset.from_trajectories(
        [labelled.trajectory(i) for i in range(labelled.n_trajectories)]
        + [fresh.trajectory(i) for i in range(fresh.n_trajectories)],
        np.zeros(labelled.n_trajectories + fresh.n_trajectories, dtype=np.int64),
        feature_names=labelled.feature_names, allow_unlabelled=True)
    order = np.random.default_rng(0).permutation(both.n_trajectories)
    mixed = Dataset.from_trajectories([both.trajectory(int(i)) for i in order], both.group,
                                      feature_names=both.feature_names, allow_unlabelled=True)
    was_labelled = order < labelled.n_trajectories  # position in the mixed pool -> from the run's data
    path = mixed.save(tmp / "mixed.npz")
    assert main(["suggest", str(tmp / "run"), "--pool", str(path), "--n", "50", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    picked = [s["index"] for s in out["suggestions"]]
    assert len(picked) == fresh.n_trajectories and not was_labelled[picked].any()
    assert sorted(out["already_labelled"]) == np.flatnonzero(was_labelled).tolist()
    assert out["n_candidates"] == fresh.n_trajectories
    assert main(["suggest", str(tmp / "run"), "--pool", str(path)]) == 0
    assert f"left out {labelled.n_trajectories} pool trajectories already in the labelled data" in capsys.readouterr().out
    only_known = Dataset.from_trajectories([labelled.trajectory(i) for i in range(3)], [0, 0, 0],
                                           feature_names=labelled.feature_names, allow_unlabelled=True)
    assert main(["suggest", str(tmp / "run"), "--pool", str(only_known.save(tmp / "known.npz"))]) == 2
    assert "already labelled in the run's data" in capsys.readouterr().err
