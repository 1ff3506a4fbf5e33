"""HalfCheetah/Ant wall wrappers: features, penalties and observations on scripted rollouts."""

from __future__ import annotations

import numpy as np
import pytest

gym = pytest.importorskip("gymnasium")
pytest.importorskip("mujoco")

from pbicrl.envs.mujoco_wall import (
    FEATURE_NAMES,
    NOMINAL_WEIGHTS,
    WALL_SPECS,
    WallPenaltyWrapper,
    make_wall_env,
    rollout_wall_env,
)


def _teleport_x(env, x: float) -> None:
    """Move the robot to forward coordinate x (keeping everything else) and resync the wrapper."""
    u = env.unwrapped
    qpos, qvel = u.data.qpos.copy(), u.data.qvel.copy()
    qpos[0] = x
    u.set_state(qpos, qvel)
    wrapper = env
    while not isinstance(wrapper, WallPenaltyWrapper):
        wrapper = wrapper.env
    wrapper._x = x


def test_lazy_package_import_and_specs():
    from pbicrl import envs
    assert envs.make_wall_env is make_wall_env
    assert WALL_SPECS["halfcheetah"].wall_x == 8.0 and WALL_SPECS["halfcheetah"].penalty == -50.0
    assert WALL_SPECS["ant"].wall_x == 10.0 and WALL_SPECS["ant"].penalty == -100.0
    assert FEATURE_NAMES == ("forward_displacement", "action_sq_norm")
    assert NOMINAL_WEIGHTS == (20.0, -0.1)


def test_unknown_env_and_bad_options():
    with pytest.raises(ValueError, match="env"):
        make_wall_env("hopper", constrained=True)
    with pytest.raises(ValueError, match="max_episode_steps"):
        make_wall_env("halfcheetah", constrained=True, max_episode_steps=0)
    base = gym.make("HalfCheetah-v5")
    with pytest.raises(ValueError, match="penalty"):
        WallPenaltyWrapper(base, 8.0, 5.0, constrained=True)
    with pytest.raises(ValueError, match="nominal_weights"):
        WallPenaltyWrapper(base, 8.0, -5.0, constrained=True, nominal_weights=[1.0])
    base.close()


def test_halfcheetah_features_match_hand_computation_and_gymnasium_reward():
    env = make_wall_env("halfcheetah", constrained=True, max_episode_steps=20)
    obs, info = env.reset(seed=3)
    # x is observed (first entry of qpos) so that the good policy can stop before the wall
    assert env.observation_space.shape == (18,)
    assert obs[0] == pytest.approx(info["x_position"])
    x = info["x_position"]
    action = np.array([0.5, -0.5, 0.5, -0.5, 0.5, 2.0])  # last entry is clipped to 1.0
    for _ in range(5):
        _, r, _, _, info = env.step(action)
        dx = info["x_position"] - x
        assert info["x_position_before"] == pytest.approx(x)
        assert info["features"][0] == pytest.approx(dx)
        assert info["features"][1] == pytest.approx(5 * 0.25 + 1.0)  # clipped action
        assert r == pytest.approx(20 * dx - 0.1 * 2.25)  # far from the wall: no penalty
        assert not info["in_wall"] and info["wall_penalty"] == 0.0
        x = info["x_position"]
    # with in-range actions the paper's nominal reward equals Gymnasium's HalfCheetah
    # reward (velocity = 20 * displacement since dt = 0.05; control cost 0.1)
    for a in (np.full(6, 0.3), np.linspace(-1, 1, 6)):
        _, r, _, _, info = env.step(a)
        assert info["base_reward"] == pytest.approx(info["nominal_reward"], abs=1e-6)
        assert r == pytest.approx(info["nominal_reward"])
    env.close()


@pytest.mark.parametrize("constrained", [True, False])
def test_halfcheetah_wall_penalty_only_in_constrained_mode(constrained):
    env = make_wall_env("halfcheetah", constrained=constrained, max_episode_steps=20)
    env.reset(seed=0)
    _teleport_x(env, 8.5)
    obs, r, _, _, info = env.step(np.zeros(6))
    assert obs[0] == pytest.approx(info["x_position"])
    assert info["x_position"] >= 8.0 and info["in_wall"]
    assert info["wall_penalty"] == -50.0
    assert info["features"][1] == 0.0
    expected = 20 * info["features"][0] + (-50.0 if constrained else 0.0)
    assert r == pytest.approx(expected)
    # just below the wall: no penalty
    _teleport_x(env, 7.0)
    _, r, _, _, info = env.step(np.zeros(6))
    assert not info["in_wall"] and r == pytest.approx(20 * info["features"][0])
    env.close()


def test_ant_alive_bonus_and_penalty():
    env = make_wall_env("ant", constrained=True, max_episode_steps=20)
    obs, info = env.reset(seed=1)
    assert env.observation_space.shape == (29,)  # x, y observed; contact forces dropped
    assert obs[0] == pytest.approx(info["x_position"])
    _, r, term, _, info = env.step(np.zeros(8))
    assert not term
    assert r == pytest.approx(20 * info["features"][0] + 1.0)
    _teleport_x(env, 10.25)
    _, r, term, _, info = env.step(np.full(8, 0.5))
    assert info["in_wall"] and not term
    assert info["features"][1] == pytest.approx(8 * 0.25)
    assert r == pytest.approx(20 * info["features"][0] - 0.1 * 2.0 + 1.0 - 100.0)
    env.close()


def test_reach_bonus_pays_only_in_the_half_metre_before_the_wall():
    env = make_wall_env("ant", constrained=True, max_episode_steps=20, position_bonus=1.0, reach_bonus=3.0)
    env.reset(seed=1)
    for x, bonus in ((9.2, 0.0), (9.7, 3.0), (10.3, 0.0)):
        _teleport_x(env, x)
        _, r, _, _, info = env.step(np.zeros(8))
        xa = info["x_position"]
        assert (9.5 <= xa < 10.0) is (bonus > 0)
        expected = 20 * info["features"][0] + 1.0 + min(xa, 10.0) + bonus + (-100.0 if xa >= 10 else 0.0)
        assert r == pytest.approx(expected)
    env.close()
    # the violating demonstrator's reward never carries it; a negative bonus is refused
    env = make_wall_env("ant", constrained=False, max_episode_steps=20, reach_bonus=3.0)
    env.reset(seed=1)
    _teleport_x(env, 9.7)
    _, r, _, _, info = env.step(np.zeros(8))
    assert r == pytest.approx(20 * info["features"][0] + 1.0)
    env.close()
    with pytest.raises(ValueError, match="reach_bonus"):
        make_wall_env("ant", constrained=True, reach_bonus=-1.0)


def test_start_spread_moves_seeded_starts_forward_and_the_observation_with_them():
    plain = make_wall_env("ant", constrained=True, max_episode_steps=20)
    spread = make_wall_env("ant", constrained=True, max_episode_steps=20, start_spread=9.0)
    shifts = []
    for seed in range(8):
        _, info0 = plain.reset(seed=seed)
        obs, info = spread.reset(seed=seed)
        shifts.append(info["x_position"] - info0["x_position"])
        assert obs[0] == info["x_position"]  # the policy observes where it starts
        _, _, _, _, step = spread.step(np.zeros(8))
        assert step["x_position_before"] == info["x_position"]  # the first displacement starts there too
        assert abs(step["features"][0]) < 0.05
    assert 0.0 <= min(shifts) and max(shifts) <= 9.0 and max(shifts) - min(shifts) > 3.0
    assert spread.reset(seed=3)[1]["x_position"] - plain.reset(seed=3)[1]["x_position"] == shifts[3]  # seeded
    plain.close()
    spread.close()
    with pytest.raises(ValueError, match="start_spread"):
        make_wall_env("ant", constrained=True, start_spread=float("nan"))


def test_rollout_shapes_and_time_limit():
    env = make_wall_env("halfcheetah", constrained=False, max_episode_steps=30)
    rng = np.random.default_rng(0)
    ro = rollout_wall_env(env, lambda obs: rng.uniform(-1, 1, 6), seed=5, n_steps=100)
    assert ro["features"].shape == (30, 2)  # stopped by the 30-step time limit
    assert ro["x"].shape == (30,) and ro["actions"].shape == (30, 6)
    # displacements telescope to the total progress
    assert ro["features"][:, 0].sum() == pytest.approx(ro["x"][-1] - float(ro["x0"]))
    np.testing.assert_allclose(ro["features"][:, 1], np.sum(ro["actions"] ** 2, axis=1))
    env.close()


def _set_torso_quat(env, quat) -> None:
    u = env.unwrapped
    qpos, qvel = u.data.qpos.copy(), u.data.qvel.copy()
    qpos[3:7] = quat
    u.set_state(qpos, qvel)


def test_terminate_when_flipped_ends_an_upside_down_ant_episode_only_when_asked():
    """An ant on its back stays 'healthy' for Gymnasium (torso height in range); the training option ends it."""
    upside_down = [0.0, 1.0, 0.0, 0.0]  # half a turn about x: the torso's up axis points down
    for flag in (False, True):
        env = make_wall_env("ant", constrained=True, max_episode_steps=20, terminate_when_flipped=flag)
        env.reset(seed=0)
        _, _, terminated, _, info = env.step(np.zeros(env.action_space.shape))
        assert not terminated and not info["flipped"]  # upright after reset
        _set_torso_quat(env, upside_down)
        _, reward, terminated, _, info = env.step(np.zeros(env.action_space.shape))
        assert info["flipped"] is flag and terminated is flag
        env.close()
    with pytest.raises(ValueError, match="terminate_when_flipped"):
        make_wall_env("halfcheetah", constrained=True, terminate_when_flipped=True)


def test_torso_up_axis_from_the_quaternion():
    env = make_wall_env("ant", constrained=True)
    env.reset(seed=1)
    wrapper = env.env
    for quat, up in (([1.0, 0.0, 0.0, 0.0], 1.0), ([0.0, 0.0, 1.0, 0.0], -1.0),
                     ([np.cos(np.pi / 4), np.sin(np.pi / 4), 0.0, 0.0], 0.0)):  # a quarter turn: on its side
        _set_torso_quat(env, quat)
        assert wrapper.torso_up_z() == pytest.approx(up, abs=1e-12)
    env.close()
    cheetah = make_wall_env("halfcheetah", constrained=True)
    with pytest.raises(ValueError, match="torso_up_z"):
        cheetah.env.torso_up_z()
    cheetah.close()
