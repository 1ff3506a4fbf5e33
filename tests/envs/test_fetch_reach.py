import numpy as np
import pytest

pytest.importorskip("gymnasium")
pytest.importorskip("mujoco")
pytest.importorskip("gymnasium_robotics")

from pbicrl.envs import _mujoco_compat
from pbicrl.envs.fetch_reach import (
    FETCH_REACH_TASK,
    START_BOXES,
    START_HIGH,
    START_LOW,
    FetchReachConstrainedEnv,
    make_fetch_reach_base,
)


@pytest.fixture(scope="module")
def env():
    e = FetchReachConstrainedEnv()
    yield e
    e.close()


def test_shim_fixes_the_joint_type_assertion():
    import mujoco
    from gymnasium_robotics.utils import mujoco_utils

    base = make_fetch_reach_base()  # would raise AssertionError inside gym.make without the shim
    model, data = base.model, base.data
    if _mujoco_compat.needs_joint_type_patch():
        original = _mujoco_compat.original_joint_helpers()["set_joint_qpos"]
        with pytest.raises(AssertionError):  # the upstream bug is real on this mujoco
            original(model, data, "robot0:slide0", 0.1)
    mujoco_utils.set_joint_qpos(model, data, "robot0:slide0", 0.123)
    jid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, "robot0:slide0")
    assert data.qpos[model.jnt_qposadr[jid]] == pytest.approx(0.123)
    assert mujoco_utils.get_joint_qpos(model, data, "robot0:slide0") == pytest.approx([0.123])
    mujoco_utils.set_joint_qvel(model, data, "robot0:slide0", -0.5)
    assert mujoco_utils.get_joint_qvel(model, data, "robot0:slide0") == pytest.approx([-0.5])
    with pytest.raises(ValueError, match="not part of the model"):
        mujoco_utils.get_joint_qpos(model, data, "no_such_joint")
    assert _mujoco_compat.patch_gymnasium_robotics() is True  # idempotent


def test_features_at_hand_computed_states():
    f = FETCH_REACH_TASK.features([[0.95, 0.90, 0.769],  # distance 0.049 from the target: reached
                                   [0.95, 0.90, 0.78],   # distance 0.06
                                   [0.9, 0.8, 0.8],      # inside orange
                                   [1.1, 0.85, 0.7],     # orange corner (bounds inclusive)
                                   [0.9, 1.05, 0.9],     # inside red
                                   [0.9, 1.05, 0.65]])   # below the red box
    np.testing.assert_allclose(f[:, 0], 1 / np.linalg.norm(np.array([[0.95, 0.90, 0.769], [0.95, 0.90, 0.78],
                                                                     [0.9, 0.8, 0.8], [1.1, 0.85, 0.7],
                                                                     [0.9, 1.05, 0.9], [0.9, 1.05, 0.65]])
                                                           - [0.95, 0.90, 0.72], axis=1))
    np.testing.assert_array_equal(f[:, 1:], [[0, 0, 0], [0, 0, 1], [1, 0, 1], [1, 0, 1], [0, 1, 1], [0, 0, 1]])
    np.testing.assert_allclose(FETCH_REACH_TASK.weights("true"), [0.1, -20, -100, -5])


def test_reset_places_gripper_in_start_box(env):
    for seed in range(3):
        obs, info = env.reset(seed=seed)
        assert obs.shape == (3,)
        assert np.all(obs >= np.array(START_LOW) - 0.01) and np.all(obs <= np.array(START_HIGH) + 0.01)
        assert FETCH_REACH_TASK.group([obs]) == 1
    obs, _ = env.reset(seed=0, options={"position": [1.3, 0.75, 0.8]})
    np.testing.assert_allclose(obs, [1.3, 0.75, 0.8], atol=0.01)


def test_reaching_the_target_terminates_with_true_reward(env):
    obs, _ = env.reset(seed=1, options={"position": [1.25, 0.92, 0.75]})
    target = np.array(FETCH_REACH_TASK.goal.centre)
    for t in range(env.max_steps):
        obs, r, term, trunc, info = env.step(np.clip((target - obs) / 0.05, -1, 1))
        np.testing.assert_allclose(info["features"], FETCH_REACH_TASK.features(obs.astype(np.float64))[0], rtol=1e-6)
        assert r == pytest.approx(float(env.w @ info["features"]))
        if term:
            break
    assert term and not trunc and info["reached"] and t < 20
    assert np.linalg.norm(env.position - target) <= 0.05


def test_moving_through_orange_sets_the_indicator_and_zero_action_truncates(env):
    obs, _ = env.reset(seed=2, options={"position": [1.2, 0.78, 0.8]})
    seen = []
    for _ in range(6):  # move -x into the orange box (x <= 1.1)
        obs, r, term, trunc, info = env.step([-1.0, 0.0, 0.0])
        seen.append(info["features"][1])
    assert max(seen) == 1.0 and r == pytest.approx(float(env.w @ info["features"]))
    env.reset(seed=3)
    for t in range(env.max_steps):
        _, _, term, trunc, _ = env.step([0.0, 0.0, 0.0])
        assert not term
    assert trunc


def test_equidistant_start_box_keeps_the_chebyshev_distance_fixed():
    import itertools

    lo, hi = (np.array(b) for b in START_BOXES["equidistant"])
    wlo, whi = (np.array(b) for b in START_BOXES["wide"])
    assert np.all(lo >= wlo) and np.all(hi <= whi)  # inside the box the shipped policies were trained on
    np.testing.assert_allclose(START_BOXES["wide"], (START_LOW, START_HIGH))
    goal = np.array(FETCH_REACH_TASK.goal.centre)
    d = np.abs(np.array(list(itertools.product(*zip(lo, hi)))) - goal)
    # every start is 0.30-0.35 m from the goal along x and at most that along y and z (box corners suffice)
    assert np.all((d[:, 0] >= 0.30 - 1e-12) & (d[:, 0] <= 0.35 + 1e-12))
    assert np.all(d[:, 1:].max(axis=1) <= 0.30 + 1e-12)
    e = FetchReachConstrainedEnv(start="equidistant")
    try:
        for seed in range(3):
            obs, _ = e.reset(seed=seed)
            assert np.all(obs >= lo - 0.01) and np.all(obs <= hi + 0.01)
    finally:
        e.close()
    with pytest.raises(ValueError, match="start"):
        FetchReachConstrainedEnv(start="moon")


def test_balanced_start_box_lies_where_the_policies_were_trained_and_touches_no_region():
    import itertools

    lo, hi = (np.array(b) for b in START_BOXES["balanced"])
    wlo, whi = (np.array(b) for b in START_BOXES["wide"])
    assert np.all(lo >= wlo) and np.all(hi <= whi)
    corners = np.array(list(itertools.product(*zip(lo, hi))))
    assert FETCH_REACH_TASK.group(corners) == 1 and not FETCH_REACH_TASK.reached(corners).any()
    # the y range spans the corridor between the boxes and both boxes' y ranges (reaches cross either or none)
    assert lo[1] < 0.70 and hi[1] > 1.10
    e = FetchReachConstrainedEnv(start="balanced")
    try:
        obs, _ = e.reset(seed=0)
        assert np.all(obs >= lo - 0.01) and np.all(obs <= hi + 0.01)
    finally:
        e.close()
