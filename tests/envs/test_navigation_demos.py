"""SAC smoke run, rollouts, demonstration generation, plotting, CLI and Minari round trip."""

import json

import numpy as np
import pytest

pytest.importorskip("gymnasium")

from pbicrl.data import Dataset
from pbicrl.demonstrators.navigation import Episode, generate_navigation_demos, make_nav_env, rollout_episodes
from pbicrl.envs.point_mass import POINT_MASS_TASK


def _towards_goal(obs):
    return np.clip(np.array([20.0, 20.0]) - obs, -1, 1)


def test_rollouts_record_states_features_and_groups():
    env = make_nav_env("point_mass", "nominal")
    eps = rollout_episodes(env, _towards_goal, 20, seed=5, policy_name="scripted")
    for ep in eps:
        T = len(ep.rewards)
        assert ep.states.shape == (T + 1, 2) and ep.actions.shape == (T, 2) and ep.features.shape == (T + 1, 4)
        np.testing.assert_allclose(ep.features, POINT_MASS_TASK.features(ep.states))
        assert ep.group == POINT_MASS_TASK.group(ep.states)
        # the episode return is the nominal reward of the states after each action
        np.testing.assert_allclose(ep.rewards.sum(), (ep.features[1:] @ np.array([1.0, 0, 0, -1])).sum())
        assert ep.reached  # the straight-line controller always gets there within 60 steps
    groups = {ep.group for ep in eps}
    assert groups >= {2, 3}  # a straight dash crosses orange from the left, red from the bottom


@pytest.fixture(scope="module")
def smoke_policy(tmp_path_factory):
    pytest.importorskip("stable_baselines3")
    from pbicrl.demonstrators.navigation import train_nav_policy

    out = tmp_path_factory.mktemp("sac") / "pm"
    path = train_nav_policy("point_mass", "nominal", out, 300, learning_starts=100, checkpoint_every=200,
                            log_every=100, progress=False)
    return path


def test_sac_smoke_run_writes_policy_budget_and_resumes(smoke_policy):
    out = smoke_policy.parent
    budget = json.loads((out / "budget.json").read_text())
    assert budget["done_steps"] == 300 and budget["status"] == "complete"
    assert budget["hyperparameters"]["torch_threads"] == 1
    assert budget["hyperparameters"]["batch_size"] == 128 and budget["hyperparameters"]["net_arch"] == [256, 256]
    assert budget["metadata"]["env"] == "point_mass" and budget["metadata"]["potential_shaping"]["scale"] == 1.0
    assert "steps 300/300" in (out / "progress.log").read_text()
    from pbicrl.demonstrators.navigation import train_nav_policy

    # extending the budget resumes from the checkpoint instead of starting over
    train_nav_policy("point_mass", "nominal", out, 400, learning_starts=100, checkpoint_every=200,
                     log_every=100, progress=False)
    assert "resume from checkpoint at step 300" in (out / "progress.log").read_text()
    assert json.loads((out / "budget.json").read_text())["done_steps"] == 400


def test_generate_demos_labels_groups_from_states(smoke_policy, tmp_path):
    # an untrained policy rarely reaches the goal: keep all rollouts to exercise the bookkeeping
    ds, report = generate_navigation_demos("point_mass", smoke_policy, smoke_policy, tmp_path / "d.npz",
                                           n_per_group=3, max_episodes=40, batch=20, require_goal=False,
                                           progress=False)
    loaded = Dataset.load(tmp_path / "d.npz")
    assert loaded.n_trajectories == ds.n_trajectories
    for i in range(ds.n_trajectories):
        assert ds.group[i] == POINT_MASS_TASK.group(ds.trajectory_states(i))
        np.testing.assert_allclose(ds.trajectory(i), POINT_MASS_TASK.features(ds.trajectory_states(i)))
    rep = json.loads((tmp_path / "d.json").read_text())
    assert rep["group_counts"] == {f"G{k}": v for k, v in ds.group_counts().items()}
    assert rep["rollouts"]["good"]["episodes"] <= 40
    np.testing.assert_allclose(ds.nominal_weights, [1, 0, 0, -1])


def test_plot_writes_png(tmp_path):
    pytest.importorskip("matplotlib")
    from pbicrl.demonstrators.navigation import plot_navigation_demos

    env = make_nav_env("point_mass", "nominal")
    eps = rollout_episodes(env, _towards_goal, 10, seed=0)
    ds = Dataset.from_trajectories([e.features for e in eps], [e.group for e in eps], states=[e.states for e in eps])
    out = plot_navigation_demos(ds, "point_mass", tmp_path / "pm.png")
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_cli_grid_and_errors(tmp_path, capsys):
    from pbicrl.envs.cli import main

    assert main(["grid", "--out", str(tmp_path / "g.npz")]) == 0
    assert Dataset.load(tmp_path / "g.npz").group.tolist() == [1, 2, 3]
    rc = main(["demos", "--env", "point_mass", "--good-policy", str(tmp_path / "missing.zip"),
               "--out", str(tmp_path / "x.npz")])
    assert rc == 2 and "--good-policy" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["train", "--env", "moon", "--reward", "true"])


def test_minari_round_trip(tmp_path):
    pytest.importorskip("minari")
    pytest.importorskip("h5py")
    import gymnasium as gym

    from pbicrl.envs.minari_io import episodes_to_minari, load_minari, minari_to_dataset
    from pbicrl.envs.regions import FEATURE_NAMES
    from pbicrl.envs.registration import register_envs

    register_envs()
    env = gym.make("pbicrl/PointMass-v0", reward_weights="true")
    eps = rollout_episodes(env.unwrapped, _towards_goal, 6, seed=1)
    path = episodes_to_minari(eps, "pbicrl/point_mass/test-v0", env=env, root=tmp_path)
    assert path.exists()
    with pytest.raises(FileExistsError, match="dataset_id"):
        episodes_to_minari(eps, "pbicrl/point_mass/test-v0", env=env, root=tmp_path)
    mds = load_minari("pbicrl/point_mass/test-v0", root=tmp_path)
    assert mds.total_episodes == 6
    first = next(iter(mds.iterate_episodes()))
    np.testing.assert_allclose(first.actions, eps[0].actions, rtol=1e-6)
    np.testing.assert_allclose(first.rewards, eps[0].rewards)
    ds = minari_to_dataset(mds, feature_names=FEATURE_NAMES)
    assert ds.group.tolist() == [e.group for e in eps]
    assert mds.spec.env_spec.id == "pbicrl/PointMass-v0"  # users can recover the environment
    for i, e in enumerate(eps):
        np.testing.assert_allclose(ds.trajectory_states(i), e.states, rtol=1e-6)
        np.testing.assert_allclose(ds.trajectory(i), e.features)
    # overwrite replaces it
    episodes_to_minari(eps[:2], "pbicrl/point_mass/test-v0", env=env, root=tmp_path, overwrite=True)
    assert load_minari("pbicrl/point_mass/test-v0", root=tmp_path).total_episodes == 2


def test_episode_dataclass_fields():
    assert {"states", "actions", "rewards", "features", "group", "seed"} <= set(Episode.__dataclass_fields__)


def test_relabelled_warm_start_rescores_the_buffer(smoke_policy, tmp_path):
    from stable_baselines3.common.save_util import load_from_pkl

    from pbicrl.demonstrators.navigation import relabelled_warm_start, train_nav_policy

    src = smoke_policy.parent  # a nominal-reward run
    out = tmp_path / "true"
    ckpt = relabelled_warm_start(src, "point_mass", "true", out, shaping_scale=0.0, tau=0.05)
    old = load_from_pkl(src / "checkpoint" / "replay_buffer.pkl")
    new = load_from_pkl(ckpt / "replay_buffer.pkl")
    n = old.pos
    assert new.pos == n and n > 0
    expected = POINT_MASS_TASK.features(old.next_observations[:n, 0].astype(float)) @ np.array([1.0, -10, -100, -1])
    np.testing.assert_allclose(new.rewards[:n, 0], expected, rtol=1e-5, atol=1e-5)
    np.testing.assert_array_equal(new.actions[:n], old.actions[:n])
    with pytest.raises(ValueError, match="out_dir"):
        relabelled_warm_start(src, "point_mass", "true", out)
    train_nav_policy("point_mass", "true", out, 50, shaping_scale=0.0, learning_starts=0, checkpoint_every=1000,
                     log_every=25, progress=False)
    budget = json.loads((out / "budget.json").read_text())
    assert budget["metadata"]["warm_start"]["source_run"] == str(src) and budget["done_steps"] == 50
