"""CSV / Parquet import: round trips, row order, and the errors users will hit."""

from __future__ import annotations

import numpy as np
import pytest

from pbicrl.cli import main
from pbicrl.inference.data import Dataset, load_dataset
from pbicrl.io import TableError, columns_to_dataset, read_csv, read_parquet, read_table, write_csv


@pytest.fixture()
def dataset():
    rng = np.random.default_rng(0)
    lengths = [3, 5, 2, 4]
    return Dataset.from_trajectories([rng.normal(size=(T, 2)) for T in lengths], [1, 2, 1, 3],
                                     states=[rng.normal(size=(T, 3)) for T in lengths],
                                     feature_names=["speed", "in_red"], nominal_weights=[1.0, 0.0])


def assert_same(a: Dataset, b: Dataset) -> None:
    np.testing.assert_array_equal(a.offsets, b.offsets)
    np.testing.assert_array_equal(a.group, b.group)
    np.testing.assert_array_equal(a.features, b.features)  # repr() keeps every bit
    assert a.feature_names == b.feature_names


def test_csv_round_trip(dataset, tmp_path):
    path = write_csv(dataset, tmp_path / "demos.csv")
    back = read_csv(path, feature_cols="speed,in_red", state_cols=["state0", "state1", "state2"],
                    nominal_weights=[1.0, 0.0])
    assert_same(dataset, back)
    np.testing.assert_array_equal(back.states, dataset.states)
    np.testing.assert_array_equal(back.nominal_weights, [1.0, 0.0])
    # default feature columns: everything that is not id/group/state
    assert read_csv(path, state_cols="state0,state1,state2").feature_names == ("speed", "in_red")


def test_rows_in_any_order_with_step_column(tmp_path):
    p = tmp_path / "t.csv"
    p.write_text("step,traj,g,f\n"
                 "1,b,2,20\n0,a,1,1\n\n1,a,1,2\n0,b,2,10\n2,a,1,3\n")
    ds = read_csv(p, id_col="traj", group_col="g", step_col="step")
    assert ds.n_trajectories == 2 and list(ds.group) == [2, 1]  # order of first appearance
    np.testing.assert_array_equal(ds.trajectory(0)[:, 0], [10, 20])
    np.testing.assert_array_equal(ds.trajectory(1)[:, 0], [1, 2, 3])
    assert ds.feature_names == ("f",)


@pytest.mark.parametrize("text, kwargs, message", [
    ("trajectory,group,a\n1,1,0\n", {"feature_cols": "a,b"}, "--feature-cols: column(s) ['b'] not found"),
    ("traj,group,a\n1,1,0\n2,2,1\n", {}, "--id-col: column(s) ['trajectory'] not found; columns are ['traj', 'group', 'a']"),
    ("trajectory,group,a\nx,1,0\nx,2,1\ny,3,0\n", {}, "trajectory 'x' has rows in more than one group: 1 (row 1 (line 2)), 2 (row 2 (line 3))"),
    ("trajectory,group,a\nx,1,0\ny,2,abc\n", {}, "column 'a', row 2 (line 3): 'abc' is not a number"),
    ("trajectory,group,a\nx,1,0\ny,2,\n", {}, "column 'a', row 2 (line 3): an empty value is not a number"),
    ("trajectory,group,a\nx,1,0\ny,2,nan\n", {}, "column 'a', row 2 (line 3): 'nan' is not a finite number"),
    ("trajectory,group,a\nx,1,0\ny,0,1\n", {}, "group labels must be positive integers"),
    ("trajectory,group,a\nx,1.5,0\ny,2,1\n", {}, "group labels must be positive integers (1 = best), got '1.5'"),
    ("trajectory,group,a\nx,1,0\ny,1,1\n", {}, "need at least two groups"),
    ("trajectory,group,a\nx,1,0\ny,2\n", {}, "line 3: 2 values, the header has 3 columns"),
    ("trajectory,group,a,a\nx,1,0,0\n", {}, "repeated column names ['a']"),
    ("", {}, "empty file"),
    ("trajectory,group,a\n", {}, "no data rows"),
    ("trajectory,group\nx,1\ny,2\n", {}, "no feature columns"),
    ("trajectory,group,a\nx,1,0\ny,2,1\n", {"feature_cols": "a,group"}, "also used as id/group"),
])
def test_clear_errors(tmp_path, text, kwargs, message):
    p = tmp_path / "bad.csv"
    p.write_text(text)
    with pytest.raises(TableError) as err:
        read_csv(p, **kwargs)
    assert message in str(err.value)
    assert str(p) in str(err.value)


def test_missing_file_and_unknown_format(tmp_path):
    with pytest.raises(FileNotFoundError):
        read_csv(tmp_path / "none.csv")
    (tmp_path / "x.xlsx").write_text("")
    with pytest.raises(TableError, match="unknown table format 'xlsx'"):
        read_table(tmp_path / "x.xlsx")


def test_columns_to_dataset_from_arrays():
    ds = columns_to_dataset({"trajectory": np.array([0, 0, 1]), "group": np.array([2, 2, 1]),
                             "f": np.array([1.0, 2.0, 3.0])})
    assert list(ds.group) == [2, 1] and ds.lengths.tolist() == [2, 1]


def test_parquet_round_trip_and_errors(dataset, tmp_path):
    pa = pytest.importorskip("pyarrow")
    pq = pytest.importorskip("pyarrow.parquet")
    rows = np.repeat(np.arange(dataset.n_trajectories), dataset.lengths)
    table = pa.table({"trajectory": [f"t{i}" for i in rows], "group": dataset.group[rows],
                      "speed": dataset.features[:, 0], "in_red": dataset.features[:, 1]})
    pq.write_table(table, tmp_path / "d.parquet")
    assert_same(dataset, read_table(tmp_path / "d.parquet"))
    bad = table.set_column(2, "speed", pa.array(["fast"] + [str(x) for x in dataset.features[1:, 0]]))
    pq.write_table(bad, tmp_path / "bad.parquet")
    with pytest.raises(TableError, match=r"column 'speed', row 1: 'fast' is not a number"):
        read_parquet(tmp_path / "bad.parquet")


def test_cli_import_csv(dataset, tmp_path, capsys):
    src = write_csv(dataset, tmp_path / "demos.csv")
    out = tmp_path / "demos.npz"
    rc = main(["import", "csv", str(src), "--out", str(out), "--feature-cols", "speed,in_red",
               "--state-cols", "state0,state1,state2", "--nominal-weights", "1,0"])
    assert rc == 0
    assert_same(dataset, load_dataset(out))
    assert main(["import", "csv", str(src), "--out", str(out)]) == 2
    assert "already exists" in capsys.readouterr().err
    bad = tmp_path / "bad.csv"
    bad.write_text("trajectory,group,a\nx,1,0\nx,2,1\ny,3,0\n")
    assert main(["import", "csv", str(bad), "--out", str(tmp_path / "b.npz")]) == 2
    err = capsys.readouterr().err
    assert "more than one group" in err and "Traceback" not in err
    assert not (tmp_path / "b.npz").exists()
