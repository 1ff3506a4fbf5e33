import numpy as np
import pytest

from pbicrl.inference.preferences import Margins, PreferenceError, Preferences


def test_all_pairs_count_and_margins():
    g = np.array([1] * 3 + [2] * 4 + [3] * 5)
    p = Preferences.from_groups(g, [1.0, 2.0])
    assert p.n_pairs == 3 * 4 + 3 * 5 + 4 * 5
    i, j, m = p.to_pair_list()
    assert np.all(g[i] < g[j])
    assert set(zip(g[i].tolist(), g[j].tolist(), m.tolist())) == {(1, 2, 1.0), (1, 3, 3.0), (2, 3, 2.0)}


def test_labels_need_not_be_consecutive():
    p = Preferences.from_groups([5, 2, 9, 2], [0.5, 0.25])
    i, j, m = p.to_pair_list()
    assert sorted(zip(i.tolist(), j.tolist())) == [(0, 2), (1, 0), (1, 2), (3, 0), (3, 2)]


def test_sampled_protocol_seeded():
    g = np.repeat([1, 2, 3], 10)
    a = Preferences.from_groups(g, protocol=7, seed=1)
    b = Preferences.from_groups(g, protocol=7, seed=1)
    c = Preferences.from_groups(g, protocol=7, seed=2)
    assert a.n_pairs == 21
    np.testing.assert_array_equal(a.pair_i, b.pair_i)
    assert not np.array_equal(a.pair_i, c.pair_i) or not np.array_equal(a.pair_j, c.pair_j)
    assert np.all(g[a.pair_i] < g[a.pair_j])


def test_explicit_pairs():
    p = Preferences.from_pairs([[0, 1], [2, 1]], 3, margins=[0.5, 1.0])
    assert p.n_pairs == 2
    with pytest.raises(PreferenceError, match="preferred to itself"):
        Preferences.from_pairs([[1, 1]], 3)
    with pytest.raises(PreferenceError, match="outside"):
        Preferences.from_pairs([[0, 5]], 3)


def test_margins_forms():
    m = Margins.from_gaps([1.0, 2.0])
    np.testing.assert_allclose(m.matrix, [[0, 1, 3], [0, 0, 2], [0, 0, 0]])
    paper = Margins.from_dict({(1, 2): 0.0, (2, 3): 2.9, (1, 3): 6.0}, 3)
    assert paper.as_dict() == {"m12": 0.0, "m13": 6.0, "m23": 2.9}
    with pytest.raises(PreferenceError, match="upper triangle"):
        Margins(np.ones((2, 2)))
    with pytest.raises(PreferenceError, match="need 2 consecutive gaps"):
        Margins.parse([1.0], 3)
    with pytest.raises(PreferenceError, match="2 x 2 but the data have 3"):
        Margins.parse([[0, 1], [0, 0]], 3)
    with pytest.raises(PreferenceError, match="protocol"):
        Preferences.from_groups([1, 2], protocol=0)


def test_with_margins_keeps_pairs():
    g = np.repeat([1, 2, 3], 4)
    p = Preferences.from_groups(g, protocol=5, seed=0).with_margins(g, [1.0, 2.0])
    m = p.pair_margins
    expect = np.where((g[p.pair_i] == 1) & (g[p.pair_j] == 3), 3.0, np.where(g[p.pair_i] == 1, 1.0, 2.0))
    np.testing.assert_allclose(m, expect)


def test_groups_are_kept_for_the_grouped_likelihood():
    g = np.array([5, 2, 9, 2, 5, 9, 9])
    p = Preferences.from_groups(g, [0.5, 0.25])
    assert p.n_groups == 3
    members = [p.group_items[p.group_offsets[k]:p.group_offsets[k + 1]].tolist() for k in range(3)]
    assert members == [[1, 3], [0, 4], [2, 5, 6]]  # best (lowest label) first
    np.testing.assert_array_equal(p.group_margins, Margins.from_gaps([0.5, 0.25]).matrix)
    sampled = Preferences.from_groups(g, protocol=4, seed=0)
    assert sampled.n_groups == 3 and sampled.protocol != "all"
    assert Preferences.from_pairs([[0, 1]], 3).n_groups == 0
    p2 = p.with_margins(g, [1.0, 2.0])
    np.testing.assert_array_equal(p2.group_margins, Margins.from_gaps([1.0, 2.0]).matrix)
    np.testing.assert_array_equal(p2.group_items, p.group_items)


@pytest.mark.parametrize("field, value, message", [
    ("group_offsets", [0, 2, 2, 7], "at least one trajectory"),
    ("group_offsets", [0, 2, 9], "rise from 0"),
    ("group_items", [0, 1, 1, 3, 4, 5, 6], "distinct indices"),
    ("group_margins", np.zeros((2, 2)), "3 x 3"),
])
def test_bad_group_structure_is_rejected(field, value, message):
    p = Preferences.from_groups([1, 1, 2, 2, 3, 3, 3])
    parts = {f: getattr(p, f) for f in ("group_items", "group_offsets", "group_margins")} | {field: value}
    with pytest.raises(PreferenceError, match=message):
        Preferences(p.n_trajectories, p.block_rows, p.block_row_offsets, p.block_cols, p.block_col_offsets,
                    p.block_margins, p.pair_i, p.pair_j, p.pair_margins, protocol=p.protocol, **parts)
