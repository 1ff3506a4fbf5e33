import numpy as np
import pytest

pytest.importorskip("gymnasium")

from pbicrl.envs.point_mass import MAX_STEPS, POINT_MASS_TASK, PointMassEnv


def test_dynamics_adds_clipped_action_and_clamps():
    np.testing.assert_allclose(PointMassEnv.dynamics([5.0, 5.0], [0.5, -0.25]), [5.5, 4.75])
    np.testing.assert_allclose(PointMassEnv.dynamics([5.0, 5.0], [3.0, -7.0]), [6.0, 4.0])  # action clipped
    np.testing.assert_allclose(PointMassEnv.dynamics([19.5, -0.5], [1.0, -1.0]), [20.0, -1.0])  # box clamp


def test_features_at_hand_computed_states():
    f = POINT_MASS_TASK.features([[20.0, 17.0],   # distance 3 to the goal: reached (closed disc)
                                  [20.0, 16.9],   # distance 3.1: not reached
                                  [5.5, 14.5],    # orange centre
                                  [5.5, 17.5],    # distance exactly 3 from orange: outside (strict)
                                  [14.5, 7.0],    # inside red
                                  [0.0, 0.0]])
    np.testing.assert_allclose(f[:, 0], [1 / 3, 1 / 3.1, 1 / np.hypot(14.5, 5.5), 1 / np.hypot(14.5, 2.5),
                                         1 / np.hypot(5.5, 13.0), 1 / np.hypot(20, 20)])
    np.testing.assert_array_equal(f[:, 1:], [[0, 0, 0], [0, 0, 1], [1, 0, 1], [0, 0, 1], [0, 1, 1], [0, 0, 1]])


def test_reward_is_weights_dot_features_of_next_state():
    for which, w in (("true", [1, -10, -100, -1]), ("nominal", [1, 0, 0, -1])):
        env = PointMassEnv(reward_weights=which)
        env.reset(seed=0, options={"position": [13.5, 5.0]})
        _, r, term, trunc, info = env.step([1.0, 0.5])  # -> (14.5, 5.5): red centre
        phi = [1 / np.hypot(5.5, 14.5), 0, 1, 1]
        np.testing.assert_allclose(info["features"], phi)
        assert r == pytest.approx(float(np.dot(w, phi)))
        assert not term and not trunc


def test_terminates_on_reaching_goal():
    env = PointMassEnv()
    env.reset(seed=0, options={"position": [16.0, 16.0]})
    _, _, term, trunc, info = env.step([1.0, 1.0])  # (17, 17): distance 4.24
    assert not term
    _, r, term, trunc, info = env.step([1.0, 1.0])  # (18, 18): distance 2.83 <= 3
    assert term and not trunc and info["reached"]
    assert info["features"][3] == 0.0
    assert r == pytest.approx(1 / np.hypot(2, 2))


def test_truncates_after_max_steps():
    env = PointMassEnv()
    env.reset(seed=3)
    for t in range(MAX_STEPS):
        _, _, term, trunc, _ = env.step([0.0, 0.0])
        assert not term
        assert trunc == (t == MAX_STEPS - 1)


def test_start_distribution_edges():
    env = PointMassEnv()
    edges = []
    for s in range(200):
        obs, info = env.reset(seed=s)
        x, y = obs
        if info["start_edge"] == "left":
            assert 0 <= x <= 1 and 9 <= y <= 19
        else:
            assert 9 <= x <= 19 and 0 <= y <= 1
        assert POINT_MASS_TASK.group([obs]) == 1  # no start inside a region
        edges.append(info["start_edge"])
    assert 70 < edges.count("left") < 130
    obs, info = env.reset(seed=0, options={"start_edge": "bottom"})
    assert info["start_edge"] == "bottom"
    with pytest.raises(ValueError, match="start_edge"):
        env.reset(seed=0, options={"start_edge": "top"})
    with pytest.raises(ValueError, match="reward_weights"):
        PointMassEnv(reward_weights="nope")


def test_balanced_start_strips():
    env = PointMassEnv(start="balanced")
    starts, edges = [], []
    for s in range(400):
        obs, info = env.reset(seed=s)
        x, y = (float(v) for v in obs)
        if info["start_edge"] == "left":
            assert 0 <= x <= 2.5 and 5 <= y <= 19
        else:
            assert 5 <= x <= 19 and 0 <= y <= 2.5
        assert POINT_MASS_TASK.group([obs]) == 1  # the strips touch no region
        starts.append((x, y))
        edges.append(info["start_edge"])
    along = np.array([y if e == "left" else x for (x, y), e in zip(starts, edges)])
    assert along.min() < 6 and along.max() > 18 and 140 < edges.count("left") < 260
    # the default edges are unchanged (same draws as before "balanced" existed)
    a, _ = PointMassEnv().reset(seed=3)
    b, _ = PointMassEnv(start="random").reset(seed=3)
    np.testing.assert_array_equal(a, b)
    with pytest.raises(ValueError, match="start: expected one of"):
        PointMassEnv(start="top")


def test_reset_is_seeded():
    a, _ = PointMassEnv().reset(seed=11)
    b, _ = PointMassEnv().reset(seed=11)
    np.testing.assert_array_equal(a, b)


def test_every_start_is_19_to_20_steps_of_chebyshev_distance_from_the_goal():
    # with actions in [-1, 1]^2 the fewest steps to the goal centre is the Chebyshev distance:
    # the same from every start, so where a start lies does not decide how far a run has to go
    env = PointMassEnv()
    starts = np.array([env.reset(seed=s)[0] for s in range(300)], dtype=np.float64)
    cheb = np.abs(starts - np.array(POINT_MASS_TASK.goal.centre)).max(axis=1)
    assert np.all((cheb >= 19.0) & (cheb <= 20.0))
