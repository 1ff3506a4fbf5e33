import numpy as np
import pytest

from pbicrl.inference.data import Dataset, DatasetError, load_dataset


def _ok(**kw):
    base = dict(features=np.ones((5, 2)), offsets=np.array([0, 2, 5]), group=np.array([1, 2]))
    base.update(kw)
    return Dataset(**base)


def test_roundtrip(tmp_path):
    ds = Dataset.from_trajectories([np.arange(6.0).reshape(3, 2), np.ones((2, 2))], [1, 2],
                                   states=[np.zeros((3, 1)), np.ones((2, 1))], actions=[np.zeros((3, 2)), np.ones((2, 2))],
                                   feature_names=["a", "b"], nominal_weights=[1.0, -1.0])
    path = ds.save(tmp_path / "d.npz")
    back = load_dataset(path)
    np.testing.assert_array_equal(back.features, ds.features)
    np.testing.assert_array_equal(back.offsets, [0, 3, 5])
    assert back.feature_names == ("a", "b")
    np.testing.assert_array_equal(back.nominal_weights, [1.0, -1.0])
    np.testing.assert_allclose(back.mean_features, [[2.0, 3.0], [1.0, 1.0]])
    assert back.states.shape == (5, 1) and back.actions.shape == (5, 2)
    assert not list(tmp_path.glob(".tmp-*"))


@pytest.mark.parametrize("kw, field", [
    (dict(features=np.ones((5, 2, 1))), "features"),
    (dict(features=np.array([[1.0, np.nan]] * 5)), "features"),
    (dict(features=np.array([[1.0, np.inf]] * 5)), "features"),
    (dict(offsets=np.array([1, 2, 5])), "offsets: must start at 0"),
    (dict(offsets=np.array([0, 3, 2, 5]), group=np.array([1, 2, 2])), "offsets: must be strictly increasing"),
    (dict(offsets=np.array([0, 2, 2, 5]), group=np.array([1, 2, 2])), "empty"),
    (dict(offsets=np.array([0, 2, 4])), "offsets: must end"),
    (dict(offsets=np.array([0.5, 2, 5])), "offsets: must be integers"),
    (dict(group=np.array([1, 2, 3])), "group: expected shape"),
    (dict(group=np.array([0, 1])), "group: labels must be positive"),
    (dict(group=np.array([1.5, 2])), "group: labels must be positive integers"),
    (dict(group=np.array([2, 2])), "at least two non-empty groups"),
    (dict(nominal_weights=np.ones(3)), "nominal_weights: expected 2"),
    (dict(nominal_weights=np.array([1.0, np.nan])), "nominal_weights: contains NaN"),
    (dict(states=np.ones((4, 1))), "states: expected 5 rows"),
    (dict(actions=np.ones((6, 1))), "actions: expected 5 rows"),
    (dict(feature_names=("a",)), "feature_names: expected 2"),
    (dict(feature_names=("a", "a")), "feature_names: names must be unique"),
    (dict(features=np.array([["a", "b"]] * 5)), "features: values must be numeric"),
])
def test_bad_input_names_field(kw, field):
    with pytest.raises(DatasetError, match=field.replace("(", r"\(")):
        _ok(**kw)


def test_load_rejects_pickles_and_missing_fields(tmp_path):
    p = tmp_path / "obj.npz"
    np.savez(p, features=np.ones((2, 1)), offsets=np.array([0, 1, 2]), group=np.array([1, 2]),
             feature_names=np.array([object()], dtype=object))
    with pytest.raises(DatasetError, match="pickle"):
        load_dataset(p)
    q = tmp_path / "missing.npz"
    np.savez(q, features=np.ones((2, 1)), offsets=np.array([0, 1, 2]))
    with pytest.raises(DatasetError, match="missing required field.*group"):
        load_dataset(q)
    r = tmp_path / "garbage.npz"
    r.write_bytes(b"not a zip")
    with pytest.raises(DatasetError, match="not a readable"):
        load_dataset(r)
    with pytest.raises(DatasetError, match="no such file"):
        load_dataset(tmp_path / "nope.npz")


def test_from_trajectories_errors():
    with pytest.raises(DatasetError, match="trajectory 1 is empty"):
        Dataset.from_trajectories([np.ones((2, 2)), np.ones((0, 2))], [1, 2])
    with pytest.raises(DatasetError, match="trajectory 1 has 3 features"):
        Dataset.from_trajectories([np.ones((2, 2)), np.ones((2, 3))], [1, 2])
    with pytest.raises(DatasetError, match="states: trajectory 0 must have 2 rows"):
        Dataset.from_trajectories([np.ones((2, 2)), np.ones((2, 2))], [1, 2], states=[np.ones((3, 1)), np.ones((2, 1))])


def test_subset_and_sampling():
    feats = [np.full((i + 1, 1), float(i)) for i in range(9)]
    ds = Dataset.from_trajectories(feats, [1, 1, 1, 2, 2, 2, 3, 3, 3])
    sub = ds.subset([8, 0])
    np.testing.assert_allclose(sub.mean_features[:, 0], [8.0, 0.0])
    assert sub.group.tolist() == [3, 1]
    s1 = ds.sample_per_group(2, seed=3)
    s2 = ds.sample_per_group(2, seed=3)
    assert s1.group_counts() == {1: 2, 2: 2, 3: 2}
    np.testing.assert_array_equal(s1.features, s2.features)
