"""The ICRL benchmark's five virtual tasks (pbicrl.envs.icrl_benchmark): rewards, costs, observations, lengths."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("gymnasium")
pytest.importorskip("mujoco")

import gymnasium as gym  # noqa: E402

from pbicrl.envs import register_envs  # noqa: E402
from pbicrl.envs.icrl_benchmark import (  # noqa: E402
    ICRL_TASKS,
    BiasedPendulumEnv,
    BlockedAntEnv,
    BlockedHalfCheetahEnv,
    BlockedSwimmerEnv,
    BlockedWalkerEnv,
    icrl_task,
    pendulum_reward,
)

CLASSES = {"halfcheetah": BlockedHalfCheetahEnv, "ant": BlockedAntEnv, "pendulum": BiasedPendulumEnv,
           "walker": BlockedWalkerEnv, "swimmer": BlockedSwimmerEnv}
LENGTHS = {"halfcheetah": 1000, "ant": 500, "walker": 500, "swimmer": 500, "pendulum": 100}


def _env(name: str, **kw):
    env = CLASSES[name](**kw)
    env.reset(seed=0)
    return env


def _set(env, x: float | None = None, **qpos_at: float):
    """Put the model at its initial state, at rest, with qpos[0] = x and the given qpos entries."""
    q = env.init_qpos.copy()
    if x is not None:
        q[0] = x
    for k, v in qpos_at.items():
        q[int(k[1:])] = v
    env.set_state(q, np.zeros(env.model.nv))
    return q


def test_registered_ids_make_the_tasks():
    register_envs()
    for name, task in ICRL_TASKS.items():
        env = gym.make(task.env_id)
        assert isinstance(env.unwrapped, CLASSES[name])
        obs, _ = env.reset(seed=1)
        assert obs.shape == (task.obs_dim,) == env.observation_space.shape
        assert env.action_space.shape == (task.act_dim,)
        env.close()
    assert icrl_task("pbicrl/BlockedAnt-v0") is ICRL_TASKS["ant"]
    with pytest.raises(ValueError, match="task: unknown"):
        icrl_task("hopper")


@pytest.mark.parametrize("name", sorted(CLASSES))
def test_obs0_is_the_global_x(name):
    env = _env(name)
    _set(env, x=0.0123 if name == "pendulum" else 1.234)
    obs = env._get_obs()
    assert obs[0] == pytest.approx(0.0123 if name == "pendulum" else 1.234)
    obs, _, _, _, info = env.step(np.zeros(env.action_space.shape))
    assert obs[0] == info["x_position"] == env.data.qpos[0]
    # qpos then qvel, nothing dropped
    assert obs.shape == (env.model.nq + env.model.nv,)
    np.testing.assert_array_equal(obs, np.concatenate([env.data.qpos, env.data.qvel]))


@pytest.mark.parametrize("name", sorted(CLASSES))
def test_episode_length(name):
    env = _env(name)
    _set(env)
    env._elapsed = LENGTHS[name] - 2
    _, _, term, trunc, _ = env.step(np.zeros(env.action_space.shape))
    assert not term and not trunc
    _, _, term, trunc, _ = env.step(np.zeros(env.action_space.shape))
    assert not term and trunc
    env.reset(seed=3)
    assert env._elapsed == 0
    env = _env(name, time_limit_terminal=True)  # the original's convention: the time limit is terminal
    _set(env)
    env._elapsed = LENGTHS[name] - 1
    _, _, term, trunc, _ = env.step(np.zeros(env.action_space.shape))
    assert term and not trunc


def test_halfcheetah_runs_its_full_1000_steps():
    env = _env("halfcheetah")
    rng = np.random.default_rng(0)
    n = 0
    while True:
        _, _, term, trunc, _ = env.step(rng.uniform(-1, 1, 6))
        n += 1
        assert not term
        if trunc:
            break
    assert n == 1000


def test_halfcheetah_reward_is_absolute_speed_minus_clipped_control():
    env = _env("halfcheetah")
    _set(env, x=0.5)
    env.set_state(env.data.qpos.copy(), np.r_[-15.0, np.zeros(8)])  # running backwards
    a = np.array([2.0, 0.5, 0, 0, 0, -4.0])  # clipped to [1, 0.5, 0, 0, 0, -1]
    obs, r, _, _, info = env.step(a)
    dx = obs[0] - 0.5
    assert dx < -0.3  # it did move backwards ...
    ctrl = 0.1 * (1 + 0.25 + 1)
    assert r == pytest.approx(abs(dx) / 0.05 - ctrl)  # ... and is paid for it
    assert info["reward_ctrl"] == pytest.approx(-ctrl)
    assert env.dt == pytest.approx(0.05)


def test_swimmer_reward():
    env = _env("swimmer")
    _set(env, x=0.0)
    env.set_state(env.data.qpos.copy(), np.r_[-1.0, np.zeros(4)])
    obs, r, term, _, _ = env.step(np.array([3.0, -0.5]))
    assert not term
    assert r == pytest.approx(abs(obs[0]) / 0.04 - 1e-4 * (1 + 0.25))
    assert env.dt == pytest.approx(0.04)


def test_walker_reward_termination_raw_velocities_and_legacy_model():
    env = _env("walker")
    assert env.dt == pytest.approx(0.008)
    # the legacy walker2d.xml: the feet have frictions 0.9 and 1.9 (v5's model gives both 1.9)
    feet = [env.model.geom(n).friction[0] for n in ("foot_geom", "foot_left_geom")]
    assert sorted(feet) == pytest.approx([0.9, 1.9])
    q = _set(env, x=0.2)
    env.set_state(q, np.r_[-3.0, 0.0, 0.0, 50.0, np.zeros(5)])
    assert env._get_obs()[9 + 3] == 50.0  # not clipped to 10
    obs, r, term, _, info = env.step(np.array([2.0, 0, 0, 0, 0, 0]))
    assert not term
    assert r == pytest.approx(abs(obs[0] - 0.2) / 0.008 + 1.0 - 1e-3 * 1.0)
    # falling ends the episode, and the +1 is still paid on that step
    _set(env, x=0.0, q1=0.5)
    obs, r, term, _, info = env.step(np.zeros(6))
    assert term
    assert r == pytest.approx(info["reward_run"] + 1.0)
    _set(env, x=0.0, q2=1.2)  # torso angle out of (-1, 1)
    assert env.step(np.zeros(6))[2]


def test_ant_reward_is_distance_plus_healthy_minus_control_and_never_terminates():
    env = _env("ant")
    assert env.observation_space.shape == (29,)
    _set(env, x=3.0, q1=4.0)
    obs, r, term, _, info = env.step(np.full(8, 2.0))  # clipped to 1
    xy = env.data.body("torso").xpos[:2]
    assert np.allclose(xy, obs[:2])
    assert r == pytest.approx(float(np.hypot(*xy)) + 1.0 - 0.5 * 8)
    assert info["reward_contact"] == 0.0 and not term
    # unhealthy (torso too high): no +1, and no termination
    _set(env, x=-1.0, q2=1.5)
    obs, r, term, _, info = env.step(np.zeros(8))
    assert not term and info["reward_survive"] == 0.0
    assert r == pytest.approx(float(np.hypot(*env.data.qpos[:2])))


def test_pendulum_biased_ramp_and_termination():
    assert pendulum_reward(-0.5) == 1.0
    assert pendulum_reward(-0.01) == 1.0
    assert pendulum_reward(0.0) == 0.1
    assert pendulum_reward(0.3) == 0.1
    assert pendulum_reward(-0.005) == pytest.approx(0.55)
    assert pendulum_reward(-0.0025) == pytest.approx(0.1 + 0.9 * 0.25)
    env = _env("pendulum")
    assert env.dt == pytest.approx(0.04)
    _set(env, x=-0.004)
    obs, r, term, _, _ = env.step(np.zeros(1))
    assert not term
    assert r == pytest.approx(pendulum_reward(obs[0])) and 0.1 < r < 1.0
    _set(env, x=0.0, q1=0.25)
    obs, r, term, _, _ = env.step(np.zeros(1))
    assert term
    # action box [-3, 3]: a larger push is clipped, so it moves the cart exactly as 3 does
    e1, e2 = _env("pendulum"), _env("pendulum")
    _set(e1, x=0.0)
    _set(e2, x=0.0)
    assert e1.step(np.array([3.0]))[0][0] == e2.step(np.array([30.0]))[0][0]


@pytest.mark.parametrize(("name", "inside", "outside"), [
    ("halfcheetah", -2.5, -3.5), ("ant", -2.0, -4.0), ("walker", -2.8, -3.2), ("swimmer", 0.3, 0.8),
    ("pendulum", -0.005, -0.03)])
def test_cost_is_the_post_step_wall_indicator(name, inside, outside):
    env = _env(name)
    for x, expected in ((inside, 0.0), (outside, 1.0)):
        _set(env, x=x)
        obs, _, _, _, info = env.step(np.zeros(env.action_space.shape))
        assert info["cost"] == expected == env.task.cost(obs[0])


def test_wall_cost_is_strict():
    hc, sw, pend = ICRL_TASKS["halfcheetah"], ICRL_TASKS["swimmer"], ICRL_TASKS["pendulum"]
    assert hc.cost(-3.0) == 0.0
    assert hc.cost(np.nextafter(-3.0, -np.inf)) == 1.0
    assert sw.cost(0.5) == 0.0 and sw.cost(np.nextafter(0.5, np.inf)) == 1.0 and sw.cost(-10.0) == 0.0
    assert pend.cost(-0.015) == 0.0 and pend.cost(-0.0151) == 1.0
    np.testing.assert_array_equal(hc.cost(np.array([-4.0, -3.0, 0.0, 5.0])), [1.0, 0.0, 0.0, 0.0])
    # the cost reads the state *after* the step: starting just inside the wall and moving out is a violation
    env = _env("halfcheetah")
    q = _set(env, x=-2.99)
    env.set_state(q, np.r_[-10.0, np.zeros(8)])
    obs, _, _, _, info = env.step(np.zeros(6))
    assert obs[0] < -3.0 and info["cost"] == 1.0


@pytest.mark.parametrize("name", sorted(CLASSES))
def test_features_are_the_reward_terms(name):
    env = _env(name)
    task = env.task
    rng = np.random.default_rng(1)
    for _ in range(5):
        a = rng.uniform(-2, 2, env.action_space.shape)
        _, r, term, _, info = env.step(a)
        phi = info["features"]
        assert phi.shape == (len(task.feature_names),)
        assert r == pytest.approx(float(np.dot(task.nominal_weights, phi)))
        sq = float(np.sum(np.clip(a, env.action_space.low, env.action_space.high) ** 2))
        if "action_sq_norm" in task.feature_names:
            assert phi[task.feature_names.index("action_sq_norm")] == pytest.approx(sq)
        if term:
            env.reset(seed=2)
