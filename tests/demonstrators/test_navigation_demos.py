"""SAC smoke run, rollouts, demonstration generation, plotting, CLI and Minari round trip."""

import json

import numpy as np
import pytest

pytest.importorskip("gymnasium")

from pbicrl.errors import PbicrlWarning
from pbicrl.inference.data import Dataset
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
    from pbicrl.cli.navigation import main

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

    from pbicrl.envs.minari_io import episodes_to_minari, minari_to_dataset
    from pbicrl.io.minari import from_minari, load_minari
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
    ds = from_minari(mds, feature_names=FEATURE_NAMES, actions=False)  # the one converter
    with pytest.warns(PbicrlWarning, match="minari_to_dataset is deprecated.*from_minari"):
        old = minari_to_dataset(mds, feature_names=FEATURE_NAMES)
    assert old.content_hash() == ds.content_hash()  # the deprecated name gives the same dataset
    with_actions = from_minari(mds, feature_names=FEATURE_NAMES)
    first_actions = with_actions.actions[with_actions.offsets[0]:with_actions.offsets[1]]
    np.testing.assert_allclose(first_actions[:-1], eps[0].actions, rtol=1e-6)  # the final state has no action
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
    from pbicrl.demonstrators.navigation import relabelled_warm_start, train_nav_policy
    from pbicrl.demonstrators.sac_files import read_buffer_arrays

    src = smoke_policy.parent  # a nominal-reward run
    out = tmp_path / "true"
    ckpt = relabelled_warm_start(src, "point_mass", "true", out, shaping_scale=0.0, tau=0.05)
    old = read_buffer_arrays(src / "checkpoint" / "replay_buffer.npz")
    new = read_buffer_arrays(ckpt / "replay_buffer.npz")
    n = int(old["pos"])
    assert int(new["pos"]) == n and n > 0
    expected = POINT_MASS_TASK.features(old["next_observations"][:n, 0].astype(float)) @ np.array([1.0, -10, -100, -1])
    np.testing.assert_allclose(new["rewards"][:n, 0], expected, rtol=1e-5, atol=1e-5)
    np.testing.assert_array_equal(new["actions"][:n], old["actions"][:n])
    with pytest.raises(ValueError, match="out_dir"):
        relabelled_warm_start(src, "point_mass", "true", out)
    train_nav_policy("point_mass", "true", out, 50, shaping_scale=0.0, learning_starts=0, checkpoint_every=1000,
                     log_every=25, progress=False)
    budget = json.loads((out / "budget.json").read_text())
    assert budget["metadata"]["warm_start"]["source_run"] == str(src) and budget["done_steps"] == 50


# ------------------------------------------------------------------ paper protocol
def test_group_feature_balance_matches_hand_computation():
    from pbicrl.demonstrators.navigation import group_feature_balance

    # two features, nominal weight only on the first; trajectory means 1, 3 (G1) and 2, 6 (G2)
    trajs = [np.array([[1.0, 0], [1.0, 1]]), np.array([[3.0, 0]]), np.array([[2.0, 1]]), np.array([[6.0, 0], [6.0, 0]])]
    ds = Dataset.from_trajectories(trajs, [1, 1, 2, 2], feature_names=("a", "b"), nominal_weights=[1.0, 0.0])
    fb = group_feature_balance(ds)
    assert fb["features"] == ["a"]
    assert fb["mean"]["a"] == {"G1": 2.0, "G2": 4.0}
    sd1, sd2 = np.std([1, 3], ddof=1), np.std([2, 6], ddof=1)
    assert fb["sd"]["a"]["G2"] == pytest.approx(sd2)
    assert fb["smd"]["a"]["G1-G2"] == pytest.approx(-2.0 / np.sqrt((sd1**2 + sd2**2) / 2))
    assert fb["max_abs_smd"] == pytest.approx(abs(fb["smd"]["a"]["G1-G2"]))
    assert fb["length"]["G1"]["mean"] == 1.5
    assert group_feature_balance(ds, ["b"])["mean"]["b"] == {"G1": 0.25, "G2": 0.5}
    with pytest.raises(ValueError, match="features"):
        group_feature_balance(ds, ["c"])


def test_paper_protocol_keeps_every_rollout_and_labels_from_states(smoke_policy, tmp_path):
    from pbicrl.demonstrators.navigation import generate_paper_protocol_demos

    # an untrained policy rarely reaches the goal: keep all rollouts to exercise the bookkeeping
    ds, report, eps = generate_paper_protocol_demos("point_mass", smoke_policy, smoke_policy, tmp_path / "p.npz",
                                                    p_good=0.5, n_per_group=2, max_episodes=30, batch=10,
                                                    require_goal=False, return_episodes=True, progress=False,
                                                    command="cmd")
    assert report["total_rollouts"] <= 30 and report["total_rollouts"] % 10 == 0
    assert ds.n_trajectories == report["total_rollouts"]  # nothing dropped
    roll = report["rollouts"]
    assert roll["good"]["episodes"] + roll["violating"]["episodes"] == report["total_rollouts"]
    assert 0 < roll["good"]["episodes"] < report["total_rollouts"]  # both policies used at p = 0.5
    assert report["filters"]["goal_reached"] == {"applied": False, "rejected": 0,
                                                 "rejected_per_policy": {"good": 0, "violating": 0}}
    for i in range(ds.n_trajectories):
        s = ds.trajectory_states(i)
        assert ds.group[i] == POINT_MASS_TASK.group(s)
        x, y = s[0]
        assert (0 <= x <= 1 and 9 <= y <= 19) or (9 <= x <= 19 and 0 <= y <= 1)  # the env's start edges
    assert list(ds.group) == sorted(ds.group)  # stored by group
    assert report["trajectory_policy"] == "".join(e.policy[0] for e in eps)
    assert report["command"] == "cmd" and report["p_good"] == 0.5 and report["deterministic"] is False
    saved = json.loads((tmp_path / "p.json").read_text())
    assert saved["group_counts"] == {f"G{k}": v for k, v in Dataset.load(tmp_path / "p.npz").group_counts().items()}
    # the same seed gives the same rollouts (stochastic actions included)
    ds2, _ = generate_paper_protocol_demos("point_mass", smoke_policy, smoke_policy, None, p_good=0.5, n_per_group=2,
                                           max_episodes=30, batch=10, require_goal=False, progress=False)
    np.testing.assert_array_equal(ds.states, ds2.states)


def test_paper_protocol_mix_extremes_and_goal_filter(smoke_policy):
    from pbicrl.demonstrators.navigation import generate_paper_protocol_demos

    kw = dict(n_per_group=1, max_episodes=10, batch=10, progress=False)
    with pytest.raises(RuntimeError, match="groups"):  # one step never reaches the goal: every rollout rejected
        generate_paper_protocol_demos("point_mass", smoke_policy, smoke_policy, p_good=0.0,
                                      env_kwargs={"max_steps": 1}, **kw)
    _, rep = generate_paper_protocol_demos("point_mass", smoke_policy, smoke_policy, p_good=1.0, require_goal=False, **kw)
    assert rep["rollouts"]["good"]["episodes"] == 10 and rep["rollouts"]["violating"]["episodes"] == 0
    with pytest.raises(ValueError, match="p_good"):
        generate_paper_protocol_demos("point_mass", smoke_policy, smoke_policy, p_good=1.5, **kw)


def test_paper_protocol_filter_counts_rejections():
    pytest.importorskip("stable_baselines3")
    from pbicrl.demonstrators.navigation import generate_paper_protocol_demos
    from pbicrl.cli.navigation import shipped_policy

    # the shipped point-mass policies need ~17-25 steps: an 18-step limit makes many of them miss the goal
    ds, rep = generate_paper_protocol_demos("point_mass", shipped_policy("point_mass", "good"),
                                            shipped_policy("point_mass", "violating"), p_good=0.5, n_per_group=1,
                                            max_episodes=40, batch=20, env_kwargs={"max_steps": 18}, progress=False)
    rej = rep["filters"]["goal_reached"]
    assert rej["rejected"] > 0 and rej["rejected"] + ds.n_trajectories == rep["total_rollouts"]
    assert rej["rejected_per_policy"]["good"] == sum(rep["rollouts"]["good"]["rejected_goal_not_reached_per_group"].values())
    assert rep["env_kwargs"] == {"max_steps": 18}
    for i in range(ds.n_trajectories):
        assert POINT_MASS_TASK.reached(ds.trajectory_states(i)[-1:])[0]


def test_cli_paper_protocol(tmp_path, capsys):
    pytest.importorskip("stable_baselines3")
    from pbicrl.cli.navigation import main

    out = tmp_path / "pm.npz"
    assert main(["demos", "--env", "point_mass", "--paper-protocol", "-n", "2", "--p-good", "0.2",
                 "--out", str(out)]) == 0
    rep = json.loads(out.with_suffix(".json").read_text())
    assert rep["p_good"] == 0.2 and rep["deterministic"] is False and rep["env_kwargs"] == {"start": "balanced"}
    assert min(Dataset.load(out).group_counts().values()) >= 2
    assert rep["command"] == (f"python -m pbicrl.envs demos --env point_mass --paper-protocol --p-good 0.2 --stochastic "
                              f"--start balanced -n 2 --seed 0 --max-episodes 50000 --out {out}")
    capsys.readouterr()
    for argv, flag in ((["--p-good", "0.5"], "--p-good"), (["--paper-protocol", "--start", "wide"], "--start"),
                       (["--paper-protocol", "--g1-from-violating"], "--g1-from-violating"),
                       (["--deterministic"], "--deterministic")):
        assert main(["demos", "--env", "point_mass", *argv, "--out", str(tmp_path / "x.npz")]) == 2
        assert flag in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["demos", "--env", "point_mass", "--paper-protocol", "--p-good", "2", "--out", str(tmp_path / "x.npz")])
