"""What the labelling page draws for each kind of dataset (pbicrl.ui.scenes; no server needed)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import pbicrl
from pbicrl.inference.data import Dataset
from pbicrl.inference.synthetic import make_region_problem, make_wall_problem
from pbicrl.ui.scenes import MAX_THUMBNAIL_POINTS, normalise_env_id, scene_for, thumbnail_payload, trajectory_payload


@pytest.mark.parametrize("raw, env", [
    ("point_mass", "point_mass"), ("pbicrl/PointMass-v0", "point_mass"), ("pbicrl/FetchReachConstrained-v0", "fetch_reach"),
    ("HalfCheetah-v5", "halfcheetah"), ("Ant-v5", "ant"), ("pbicrl/Grid3x3-v0", "grid"), ("my_robot", None), (None, None)])
def test_env_ids_are_normalised(raw, env):
    assert normalise_env_id(raw) == env


def test_navigation_grid_wall_scenes():
    pytest.importorskip("gymnasium", reason="region geometry lives in pbicrl.envs (extra envs)")
    fetch = scene_for(pbicrl.load_dataset("fetch_reach"), "fetch_reach")
    assert fetch["kind"] == "navigation" and fetch["projection"] == "top-down (x, y)"
    boxes = {r["name"]: r for r in fetch["regions"]}
    assert boxes["orange"]["shape"] == "box" and boxes["orange"]["low"] == [0.7, 0.7]
    x0, x1, y0, y1 = fetch["bounds"]
    assert x0 < 0.7 and x1 > 1.1 and y0 < 0.7 and y1 > 1.1
    grid = scene_for(pbicrl.load_dataset("grid"), "grid")
    assert grid["kind"] == "grid" and grid["cells"][0][2]["name"] == "red"
    wall = scene_for(make_wall_problem(5).dataset, "halfcheetah")
    assert wall["kind"] == "wall" and wall["wall_x"] == 8.0 and wall["x_range"][1] > 8.0


def test_unknown_environments_fall_back_to_paths_or_features():
    prob, _ = make_region_problem(4, length=12)
    sc = scene_for(prob.dataset)
    # issue 30 item 1: no env_id used to give an undrawn scene silently; the page says why and how to fix it
    assert sc["kind"] == "path2d" and sc["regions"] == [] and sc["env_id"] is None
    assert "no environment recorded (env_id)" in sc["note"] and "--env" in sc["note"] and "pbicrl pool" in sc["note"]
    named = scene_for(dataclasses.replace(prob.dataset, env_id="my_robot"))
    assert named["kind"] == "path2d" and "my_robot" in named["note"]
    one = Dataset.from_trajectories([np.ones((4, 2)) * i for i in range(4)], [1, 1, 2, 2],
                                    states=[np.arange(4.0)[:, None]] * 4, feature_names=["a", "b"])
    feats = scene_for(one)
    assert feats["kind"] == "features" and feats["feature_names"] == ["a", "b"] and feats["max_length"] == 4
    mismatch = scene_for(one, "point_mass")  # one state column cannot be a top-down path
    assert mismatch["kind"] == "features" and "do not fit" in mismatch["note"]


def test_payloads_thin_thumbnails_and_keep_every_state_in_the_detail():
    ds = make_wall_problem(3, length=200).dataset
    sc = scene_for(ds, "ant")
    thumbs = thumbnail_payload(ds, sc)
    assert len(thumbs) == 6 and all(len(t) <= MAX_THUMBNAIL_POINTS for t in thumbs)
    assert thumbs[0][-1] == ds.trajectory_states(0)[-1, :1].tolist()  # the end is kept
    detail = trajectory_payload(ds, sc, 2)
    assert detail["length"] == len(detail["series"]) == 200 and len(detail["features"][0]) == 2


def test_missing_ui_extra_names_the_pip_install(monkeypatch, tmp_path, capsys):
    import sys

    from pbicrl.cli import main

    monkeypatch.setitem(sys.modules, "uvicorn", None)  # as if not installed
    pool = Dataset.from_trajectories([np.ones((3, 2))] * 2, [0, 0], states=[np.ones((3, 2))] * 2,
                                     allow_unlabelled=True).save(tmp_path / "p.npz")
    assert main(["label", str(pool), "--out", str(tmp_path / "o.npz"), "--no-browser"]) == 2
    assert 'pip install "pbicrl[ui]"' in capsys.readouterr().err
    assert not (tmp_path / "o.npz").exists()
