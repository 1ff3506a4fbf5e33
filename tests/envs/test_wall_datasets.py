"""Shipped HalfCheetah/Ant wall demonstrations: load, validate, good stays below / violating crosses.

Also the demonstration generator and the visitation figure on small inputs.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import pbicrl
from pbicrl.inference.data import Dataset, load_dataset

DATA = Path(pbicrl.__file__).parent / "data"
WALLS = {"halfcheetah": 8.0, "ant": 10.0}


@pytest.mark.parametrize("name", sorted(WALLS))
def test_shipped_wall_dataset(name):
    path = DATA / f"{name}.npz"
    if not path.is_file():
        pytest.skip(f"{path} not generated yet (python -m pbicrl.demonstrators demos-wall --env {name} ...)")
    wall = WALLS[name]
    ds = load_dataset(path)
    assert ds.feature_names == ("forward_displacement", "action_sq_norm")
    np.testing.assert_array_equal(ds.nominal_weights, [20.0, -0.1])
    assert ds.states is not None and ds.states.shape == (ds.features.shape[0], 1)
    assert ds.actions is not None and ds.actions.shape[1] == {"halfcheetah": 6, "ant": 8}[name]
    counts = ds.group_counts()
    assert set(counts) == {1, 2} and counts[1] >= 200 and counts[2] >= 200
    assert np.all(ds.lengths == 500)
    # features are consistent with states and actions
    assert np.all(np.abs(ds.actions) <= 1.0 + 1e-12)
    # stored features are recomputed from the stored (quantised) x and actions
    np.testing.assert_allclose(ds.features[:, 1], np.sum(ds.actions ** 2, axis=1), rtol=1e-12, atol=1e-12)
    for i in range(ds.n_trajectories):
        x = ds.trajectory_states(i)[:, 0]
        dx = ds.trajectory(i)[:, 0]
        np.testing.assert_allclose(np.diff(x), dx[1:], rtol=0, atol=1e-12)
        if ds.group[i] == 1:
            assert x.max() < wall, f"good trajectory {i} reaches x={x.max():.3f} >= {wall}"
        else:
            assert x.max() >= wall, f"violating trajectory {i} never reaches the wall (max x={x.max():.3f})"


@pytest.mark.parametrize("name", sorted(WALLS))
def test_shipped_policies_keep_their_side_of_the_wall(name):
    pytest.importorskip("gymnasium")
    pytest.importorskip("mujoco")
    pytest.importorskip("stable_baselines3")
    from pbicrl.demonstrators.sac import load_policy
    from pbicrl.envs.mujoco_wall import make_wall_env, rollout_wall_env

    wall = WALLS[name]
    for mode in ("good", "violating"):
        path = DATA / "policies" / f"{name}_{mode}.zip"
        if not path.is_file():
            pytest.skip(f"{path} not shipped yet")
        policy = load_policy(path)
        env = make_wall_env(name, constrained=(mode == "good"))
        furthest, complete = [], []
        for seed in range(12345, 12349):
            ro = rollout_wall_env(env, lambda obs, p=policy: p.predict(obs, deterministic=True)[0], seed=seed)
            furthest.append(ro["x"].max())
            complete.append(ro["x"].shape == (500,))
        env.close()
        # Ant falls over in 4-30% of rollouts and which seeds fall depends on the machine's floating point
        # (chaotic contact dynamics): falls are allowed, most rollouts must last the 500 steps
        assert sum(complete) >= 2, f"{name} {mode} policy fell over in {4 - sum(complete)} of 4 rollouts"
        crossed = np.array(furthest) >= wall
        if mode == "good":
            # the Ant good policy crosses in 7.6% of its rollouts (docs/wall_demonstrations.md; seed 12345 is one)
            assert crossed.sum() <= 1, f"{name} good policy crossed the wall in {crossed.sum()} of 4: {furthest}"
        else:
            assert crossed[complete].all(), f"{name} violating policy: a complete rollout stayed below: {furthest}"


# Issue 13's target for the good demonstrations: >= 80% of them reach wall - 0.5 and the furthest comes within 0.25
# of the wall (none crosses: test above). HalfCheetah 94%, Ant 86.5% (round 5, docs/wall_demonstrations.md).
@pytest.mark.parametrize("name", ["halfcheetah", "ant"])
def test_good_demonstrations_run_up_to_the_wall(name):
    wall = WALLS[name]
    ds = load_dataset(DATA / f"{name}.npz")
    furthest = np.array([ds.trajectory_states(i)[:, 0].max() for i in np.flatnonzero(ds.group == 1)])
    assert furthest.max() >= wall - 0.25
    assert np.mean(furthest >= wall - 0.5) >= 0.8, f"{np.mean(furthest >= wall - 0.5):.1%} reach {wall - 0.5}"


def test_ant_good_demonstrations_come_within_a_quarter_of_the_wall():
    ds = load_dataset(DATA / "ant.npz")
    furthest = np.array([ds.trajectory_states(i)[:, 0].max() for i in np.flatnonzero(ds.group == 1)])
    assert 9.75 <= furthest.max() < 10.0
    assert np.median(furthest) > 9.5  # round 5: 9.84 (round 3 continued: 9.15; round 1: median 4.0, furthest 8.6)


def _toy_dataset() -> Dataset:
    rng = np.random.default_rng(0)
    feats, states, groups = [], [], []
    for g, speed in ((1, 0.01), (2, 0.03)):
        for _ in range(3):
            dx = np.full(500, speed) + rng.normal(0, 1e-3, 500)
            x = np.cumsum(dx)
            feats.append(np.column_stack([dx, rng.uniform(0, 2, 500)]))
            states.append(x[:, None])
            groups.append(g)
    return Dataset.from_trajectories(features=feats, group=groups, states=states,
                                     feature_names=["forward_displacement", "action_sq_norm"],
                                     nominal_weights=[20.0, -0.1])


def test_plot_visitation(tmp_path):
    pytest.importorskip("matplotlib")
    from pbicrl.demonstrators.wall import plot_wall_visitation

    ds = _toy_dataset()
    out = plot_wall_visitation(ds, 8.0, tmp_path / "fig" / "v.png", title="toy")
    assert out.is_file() and out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    no_states = Dataset.from_trajectories(features=[np.ones((3, 2)), np.ones((2, 2))], group=[1, 2])
    with pytest.raises(ValueError, match="states"):
        plot_wall_visitation(no_states, 8.0, tmp_path / "w.png")


def test_generate_demos_labels_and_rejects(tmp_path):
    gym = pytest.importorskip("gymnasium")  # noqa: F841
    pytest.importorskip("mujoco")
    pytest.importorskip("stable_baselines3")
    from pbicrl.demonstrators.wall import generate_wall_demos, train_wall_policy

    # an untrained policy (no gradient step: learning_starts > steps) barely moves
    pol = train_wall_policy("halfcheetah", "violating", 20, tmp_path / "p", net_arch=(8,), buffer_size=100,
                            learning_starts=1000, progress=False)
    # a 30-step rollout cannot reach x = 8: the "violating" group can never be filled
    with pytest.raises(RuntimeError, match=r"violating: only 0/2 acceptable rollouts in 2 attempts"):
        generate_wall_demos("halfcheetah", pol, pol, 2, n_steps=30, max_attempts_factor=1)
    with pytest.raises(ValueError, match="mode"):
        train_wall_policy("halfcheetah", "bad", 10, tmp_path / "q")
    with pytest.raises(ValueError, match="terminate_when_flipped: only applies to env 'ant'"):
        train_wall_policy("halfcheetah", "good", 10, tmp_path / "r", terminate_when_flipped=True)
    assert not (tmp_path / "r").exists()  # refused before anything was written
    for opt in ("reach_bonus", "start_spread"):
        with pytest.raises(ValueError, match=f"{opt}: only applies to mode='good'"):
            train_wall_policy("ant", "violating", 10, tmp_path / "s", **{opt: 1.0})
    assert not (tmp_path / "s").exists()


def test_quantized_rollout_is_self_consistent():
    from pbicrl.demonstrators.wall import ACTION_QUANTUM, X_QUANTUM, _quantize_rollout

    rng = np.random.default_rng(1)
    x = np.cumsum(rng.uniform(0, 0.2, 50)) + 0.0123456789
    ro = {"x": x, "x0": np.asarray(0.0123456789), "actions": rng.uniform(-1, 1, (50, 3)),
          "features": np.zeros((50, 2))}
    q = _quantize_rollout(ro)
    assert np.max(np.abs(q["x"] - x)) <= X_QUANTUM / 2
    assert np.max(np.abs(q["actions"] - ro["actions"])) <= ACTION_QUANTUM / 2
    assert np.all(np.abs(q["actions"]) <= 1.0)
    np.testing.assert_array_equal(np.diff(q["x"]), q["features"][1:, 0])
    assert q["features"][0, 0] == q["x"][0] - float(q["x0"])
    np.testing.assert_allclose(q["features"][:, 0], np.diff(np.concatenate([[ro["x0"]], x])), atol=X_QUANTUM)
    np.testing.assert_array_equal(q["features"][:, 1], np.sum(q["actions"] ** 2, axis=1))
