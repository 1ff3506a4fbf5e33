"""Minari import with a user feature function (a local dataset, nothing downloaded)."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest

minari = pytest.importorskip("minari")
gym = pytest.importorskip("gymnasium")

from pbicrl.cli import main  # noqa: E402
from pbicrl.inference.data import DatasetError, load_dataset  # noqa: E402
from pbicrl.io import from_minari  # noqa: E402

DATASET_ID = "pbicrltest/walk/ranked-v0"


def speed_and_height(episode):
    """Per-state features of an episode: x-velocity and height (observations are [x, y])."""
    obs = np.asarray(episode.observations)
    vel = np.diff(obs[:, 0], prepend=obs[0, 0])
    return np.column_stack([vel, obs[:, 1]])


@pytest.fixture(scope="module")
def root(tmp_path_factory):
    from minari.data_collector.episode_buffer import EpisodeBuffer

    root = tmp_path_factory.mktemp("minari")
    rng = np.random.default_rng(0)
    buffers = []
    for i in range(6):
        T = 4 + i
        obs = np.cumsum(rng.normal(size=(T + 1, 2)), axis=0).astype(np.float32)
        buffers.append(EpisodeBuffer(id=i, seed=i, observations=obs, actions=rng.normal(size=(T, 1)).astype(np.float32),
                                     rewards=list(rng.normal(size=T)), terminations=[False] * (T - 1) + [True],
                                     truncations=[False] * T, infos={}))
    space = gym.spaces.Box(-np.inf, np.inf, (2,), np.float32)
    import os

    old = os.environ.get("MINARI_DATASETS_PATH")
    os.environ["MINARI_DATASETS_PATH"] = str(root)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            minari.create_dataset_from_buffers(DATASET_ID, buffers, observation_space=space,
                                               action_space=gym.spaces.Box(-1, 1, (1,), np.float32),
                                               algorithm_name="random", author="pbicrl tests")
    finally:
        if old is None:
            os.environ.pop("MINARI_DATASETS_PATH", None)
        else:
            os.environ["MINARI_DATASETS_PATH"] = old
    return root


def test_feature_function_and_groups(root):
    groups = {0: 1, 1: 2, 2: 1, 3: 3, 4: 2, 5: 3}
    ds = from_minari(DATASET_ID, speed_and_height, groups=groups, root=root, feature_names=["speed", "height"])
    assert ds.n_trajectories == 6 and list(ds.group) == [1, 2, 1, 3, 2, 3]
    assert ds.lengths.tolist() == [5, 6, 7, 8, 9, 10]  # one feature row per observation
    assert ds.states is not None and ds.states.shape == (ds.lengths.sum(), 2)
    np.testing.assert_allclose(ds.trajectory_states(3)[:, 1], ds.trajectory(3)[:, 1])  # height == obs[:, 1]
    # per-step features (T rows) keep the states before each action
    ds2 = from_minari(DATASET_ID, lambda ep: speed_and_height(ep)[1:], groups=lambda ep: 1 + ep.id % 2, root=root)
    assert ds2.lengths.tolist() == [4, 5, 6, 7, 8, 9] and list(ds2.group) == [1, 2, 1, 2, 1, 2]


def test_errors_name_the_episode(root):
    with pytest.raises(DatasetError, match=r"episode 0 has no infos\['group'\]"):
        from_minari(DATASET_ID, speed_and_height, root=root)
    with pytest.raises(DatasetError, match=r"episode 0 has no infos\['features'\]"):
        from_minari(DATASET_ID, groups=[1, 2, 1, 2, 1, 2], root=root)
    with pytest.raises(DatasetError, match="episode 2: expected an array"):
        from_minari(DATASET_ID, lambda ep: np.zeros((0, 2)) if ep.id == 2 else speed_and_height(ep),
                    groups=[1, 2, 1, 2, 1, 2], root=root)
    with pytest.raises(DatasetError, match="episode 1: labels must be positive integers"):
        from_minari(DATASET_ID, speed_and_height, groups=[1, 0, 1, 2, 1, 2], root=root)
    with pytest.raises(DatasetError, match="episode 0: 3 feature rows but 5 observations"):
        from_minari(DATASET_ID, lambda ep: speed_and_height(ep)[:3], groups=[1, 2, 1, 2, 1, 2], root=root)


def test_cli_import_minari(root, tmp_path, capsys):
    fn = tmp_path / "feats.py"
    fn.write_text("import numpy as np\n\ndef features(ep):\n    o = np.asarray(ep.observations)\n"
                  "    return o[:, :1] ** 2\n")
    groups = tmp_path / "groups.json"
    groups.write_text(json.dumps({str(i): 1 + (i >= 3) for i in range(6)}))
    out = tmp_path / "d.npz"
    rc = main(["import", "minari", DATASET_ID, "--root", str(root), "--features", f"{fn}:features",
               "--groups", str(groups), "--out", str(out), "--feature-names", "x_sq"])
    assert rc == 0, capsys.readouterr().err
    ds = load_dataset(out)
    assert ds.feature_names == ("x_sq",) and ds.group_counts() == {1: 3, 2: 3}
    assert main(["import", "minari", DATASET_ID, "--root", str(root), "--features", f"{fn}:nope",
                 "--groups", str(groups), "--out", str(tmp_path / "e.npz")]) == 2
    assert "has no function 'nope'" in capsys.readouterr().err
