"""The dataset keys of labelling: group 0, group_names of empty groups, gap_relation, skipped, env_id."""

from __future__ import annotations

import numpy as np
import pytest

import pbicrl
from pbicrl.cli import main
from pbicrl.config import ConfigError
from pbicrl.inference.data import Dataset, DatasetError, load_dataset


def _trajs(n: int = 6) -> list[np.ndarray]:
    return [np.full((2 + i % 3, 2), float(i)) for i in range(n)]


def _pool(group, **kw) -> Dataset:
    return Dataset.from_trajectories(_trajs(len(group)), group, allow_unlabelled=True, **kw)


def test_roundtrip_of_every_new_key(tmp_path):
    ds = _pool([1, 0, 3, 0, 1, 0], group_names=["good", "bad", "very bad"], gap_relation=[1.0, 4.0],
               skipped=[False, True, False, False, False, False], env_id="point_mass")
    back = load_dataset(ds.save(tmp_path / "l.npz"), allow_unlabelled=True)
    assert back.group.tolist() == [1, 0, 3, 0, 1, 0]
    assert back.group_names == ("good", "bad", "very bad") and back.defined_groups == (1, 2, 3)
    assert back.gap_relation.tolist() == [1.0, 4.0]
    assert back.skipped.tolist() == [False, True, False, False, False, False]
    assert back.env_id == "point_mass" and back.n_unlabelled == 3
    assert back.group_name(2) == "bad" and back.group_name(0) == "unlabelled"
    assert back.group_labels.tolist() == [1, 3] and back.n_groups == 2
    assert "skipped=1" in repr(back) and "env_id='point_mass'" in repr(back)


def test_strict_loading_rejects_unlabelled_with_the_count(tmp_path):
    path = _pool([1, 0, 2, 0], skipped=[False, True, False, False]).save(tmp_path / "p.npz")
    with pytest.raises(DatasetError, match=r"group: .*2 of 4 trajectories have group 0 \(unlabelled, 1 of them "
                                           r"marked skipped\)"):
        load_dataset(path)
    assert main(["infer", str(path), "--out", str(tmp_path / "run")]) == 2
    with pytest.raises(ConfigError, match="2 trajectories are unlabelled"):
        pbicrl.infer(load_dataset(path, allow_unlabelled=True), n_iterations=100, progress=False)


def test_a_pool_may_be_all_unlabelled_and_strict_files_load_the_same_leniently(tmp_path):
    pool = _pool([0] * 6)
    assert pool.n_groups == 0 and pool.defined_groups == () and pool.group_counts() == {0: 6}
    strict = Dataset.from_trajectories(_trajs(), [1, 1, 3, 3, 5, 5], group_names=["a", "b", "c"], gap_relation=[2, 1])
    lenient = load_dataset(strict.save(tmp_path / "s.npz"), allow_unlabelled=True)
    assert lenient.defined_groups == strict.defined_groups == (1, 3, 5)
    assert [lenient.group_name(k) for k in (1, 3, 5)] == ["a", "b", "c"]
    assert lenient.gap_relation.tolist() == [2.0, 1.0]


def test_labelled_drops_unlabelled_and_empty_groups_and_merges_the_gap_relation():
    ds = _pool([1, 0, 3, 3, 1, 0], group_names=["good", "bad", "very bad"], gap_relation=[1.0, 4.0],
               skipped=[False, True, False, False, False, False])
    lab = ds.labelled()
    assert not lab.allow_unlabelled and lab.n_trajectories == 4
    assert lab.group_names == ("good", "very bad") and lab.gap_relation.tolist() == [5.0]
    with pytest.raises(DatasetError, match="at least two non-empty groups; 2 labelled trajectories in 1 group"):
        _pool([1, 0, 0, 1, 0, 0]).labelled()
    # a subset keeps the empty named groups of a labelling file
    sub = ds.subset([0, 1])
    assert sub.group_names == ("good", "bad", "very bad") and sub.gap_relation.tolist() == [1.0, 4.0]


@pytest.mark.parametrize("kw, match", [
    (dict(group=[1, -1, 0, 0, 0, 0]), "group: labels must be 0 \\(unlabelled\\) or positive"),
    (dict(group=[1, 4, 0, 0, 0, 0], group_names=["a", "b", "c"]), "group_names: 3 names, but a trajectory has group 4"),
    (dict(group=[1, 2, 0, 0, 0, 0], group_names=["a"]), "group_names: expected 2 names"),
    (dict(group=[1, 2, 0, 0, 0, 0], group_names=["a", "a", "b"]), "group_names: names must be unique"),
    (dict(group=[1, 2, 0, 0, 0, 0], gap_relation=[1, 2]), "gap_relation: 2 groups need 1 relative gap"),
    (dict(group=[1, 2, 0, 0, 0, 0], gap_relation=[0.0]), "gap_relation: relative gap sizes must be positive"),
    (dict(group=[1, 2, 0, 0, 0, 0], gap_relation=[np.nan]), "gap_relation: relative gap sizes must be positive"),
    (dict(group=[1, 2, 0, 0, 0, 0], gap_relation=[[1.0]]), "gap_relation: expected a 1-D array"),
    (dict(group=[1, 2, 0, 0, 0, 0], gap_relation=["x"]), "gap_relation: values must be numbers"),
    (dict(group=[1, 1, 0, 0, 0, 0], gap_relation=[1.0]), "gap_relation: relates the gaps .* defines 1 group"),
    (dict(group=[1, 2, 0, 0, 0, 0], skipped=[True] + [False] * 5),
     "skipped: trajectory 0 is marked skipped but has group 1"),
    (dict(group=[1, 2, 0, 0, 0, 0], skipped=[False] * 5), "skipped: expected shape \\(6,\\)"),
    (dict(group=[1, 2, 0, 0, 0, 0], skipped=[0, 0, 2, 0, 0, 0]), "skipped: expected booleans"),
    (dict(group=[1, 2, 0, 0, 0, 0], env_id="  "), "env_id: empty"),
    (dict(group=[1, 2, 0, 0, 0, 0], env_id="a\nb"), "env_id: contains control characters"),
    (dict(group=[1, 2, 0, 0, 0, 0], env_id="x" * 201), "env_id: 201 characters"),
    (dict(group=[1, 2, 0, 0, 0, 0], env_id=3), "env_id: expected a string"),
])
def test_each_key_is_validated_with_its_name(kw, match):
    group = kw.pop("group")
    with pytest.raises(DatasetError, match=match):
        _pool(group, **kw)


def test_strict_datasets_keep_their_rules():
    with pytest.raises(DatasetError, match="group_names: expected 2 names"):
        Dataset.from_trajectories(_trajs(4), [1, 2, 1, 2], group_names=["a", "b", "c"])
    with pytest.raises(DatasetError, match="group: need at least two non-empty groups"):
        Dataset.from_trajectories(_trajs(4), [1, 1, 1, 1])
    ds = Dataset.from_trajectories(_trajs(4), [1, 2, 1, 2], skipped=[0, 0, 0, 0], env_id="grid")
    assert ds.skipped.dtype == bool and not ds.skipped.any() and ds.env_id == "grid"


def test_env_id_loads_from_a_string_array(tmp_path):
    base = Dataset.from_trajectories(_trajs(4), [1, 2, 1, 2])
    p = tmp_path / "e.npz"
    np.savez(p, features=base.features, offsets=base.offsets, group=base.group, env_id=np.array(["ant"]))
    assert load_dataset(p).env_id == "ant"
    np.savez(p, features=base.features, offsets=base.offsets, group=base.group, env_id=np.array([1.0]))
    with pytest.raises(DatasetError, match="env_id: expected one string"):
        load_dataset(p)
