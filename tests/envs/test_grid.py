import numpy as np
import pytest

from pbicrl.envs.grid import (
    GRID_COLOURS,
    GRID_GOAL,
    GRID_PATHS,
    GRID_START,
    cell_features,
    grid_dataset,
    grid_path_actions,
)


def test_grid_dataset_matches_paper_example():
    ds = grid_dataset()
    assert ds.n_trajectories == 3 and ds.n_features == 3
    assert ds.group.tolist() == [1, 2, 3]  # tau_1 > tau_2 > tau_3
    assert ds.feature_names == ("grey", "orange", "red")
    # every visited cell one-hot; tau_1 grey only, tau_2 one orange, tau_3 one red
    assert np.all(ds.features.sum(axis=1) == 1.0)
    sums = np.add.reduceat(ds.features, ds.offsets[:-1], axis=0)
    np.testing.assert_array_equal(sums, [[5, 0, 0], [4, 1, 0], [4, 0, 1]])
    for i in range(3):
        s = ds.trajectory_states(i).astype(int)
        assert tuple(s[0]) == GRID_START and tuple(s[-1]) == GRID_GOAL
        assert np.all(np.abs(np.diff(s, axis=0)).sum(axis=1) == 1)  # 4-neighbour moves
        np.testing.assert_array_equal(ds.trajectory(i), [cell_features(r, c) for r, c in s])


def test_cell_features_validation():
    np.testing.assert_array_equal(cell_features(1, 1), [0, 1, 0])
    np.testing.assert_array_equal(cell_features(0, 2), [0, 0, 1])
    with pytest.raises(ValueError, match="cell"):
        cell_features(3, 0)


def test_grid_env_walks_the_three_paths():
    pytest.importorskip("gymnasium")
    from pbicrl.envs.grid import GridEnv

    env = GridEnv()
    for name, cells in GRID_PATHS.items():
        obs, info = env.reset(seed=0)
        assert obs == 0
        visited, ret = [GRID_START], 0.0
        for a in grid_path_actions(name):
            obs, r, term, trunc, info = env.step(a)
            visited.append(divmod(obs, 3))
            ret += r
        assert tuple(visited) == cells and term and not trunc
        colours = [GRID_COLOURS[r][c] for r, c in cells[1:]]
        assert ret == pytest.approx(-1.0 * colours.count("orange") - 2.0 * colours.count("red"))
    env.reset()
    _, _, term, _, _ = env.step(3)  # left at the border: stays at the start
    assert not term
    with pytest.raises(ValueError, match="action"):
        env.step(7)
