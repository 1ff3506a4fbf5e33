"""The ICRL benchmark's training driver (pbicrl.experiments.icrl_benchmark): metrics, checkpoints, resume."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

pytest.importorskip("torch")
pytest.importorskip("gymnasium")
pytest.importorskip("mujoco")

import gymnasium as gym  # noqa: E402

from pbicrl.baselines.ppo_lagrangian import PPOLagConfig, lagrange_adam_update, lagrange_update  # noqa: E402
from pbicrl.experiments.icrl_benchmark import (  # noqa: E402
    BENCHMARK_NU0,
    EpisodeRecorder,
    episode_metrics,
    expert_config,
    load_run_checkpoint,
    train_policy,
)
from pbicrl.cli.icrl_benchmark import main  # noqa: E402

SMALL = dict(n_envs=2, n_steps=64, minibatch_size=64, n_epochs=1)


def test_episode_metrics_on_a_hand_made_episode():
    m = episode_metrics([1.0, 2.0, 3.0, 4.0, 5.0], [0, 0, 1, 0, 1])
    assert m == {"reward": 15.0, "reward_nc": 3.0, "constraint": 1, "cost_sum": 2.0, "length": 5}
    clean = episode_metrics([1.0, -2.0, 3.0], [0, 0, 0])
    assert clean["reward_nc"] == clean["reward"] == 2.0 and clean["constraint"] == 0
    first = episode_metrics([7.0, 1.0], [1, 0])  # violating on the first step: nothing is feasible
    assert first["reward_nc"] == 0.0 and first["constraint"] == 1
    with pytest.raises(ValueError, match="3 rewards but 2 costs"):
        episode_metrics([1, 2, 3], [0, 0])


class _Scripted(gym.Env):
    """Emits scripted rewards and costs; obs[0] counts the steps."""

    observation_space = gym.spaces.Box(-np.inf, np.inf, (1,))
    action_space = gym.spaces.Box(-1, 1, (1,))

    def __init__(self, rewards, costs):
        self.rewards, self.costs = rewards, costs

    def reset(self, *, seed=None, options=None):
        self.t = 0
        return np.zeros(1), {}

    def step(self, action):
        r, c = self.rewards[self.t], self.costs[self.t]
        self.t += 1
        return np.array([float(self.t)]), r, False, self.t == len(self.rewards), {"cost": c}


def test_episode_recorder_logs_each_finished_episode():
    sink: list = []
    env = EpisodeRecorder(_Scripted([1.0, 1.0, 10.0, 1.0], [0.0, 0.0, 1.0, 0.0]), sink)
    for _ in range(2):
        env.reset()
        done = False
        while not done:
            *_, term, trunc, _ = env.step(np.zeros(1))
            done = term or trunc
    assert len(sink) == 2
    assert sink[0] == {"reward": 13.0, "reward_nc": 2.0, "constraint": 1, "cost_sum": 1.0, "length": 4,
                       "x_min": 1.0, "x_max": 4.0}


def test_expert_config_follows_the_note():
    hc = expert_config("halfcheetah", "ppo_lag_true")
    assert (hc.n_envs, hc.n_steps, hc.lr, hc.n_epochs, hc.minibatch_size, hc.clip) == (5, 2048, 3e-4, 10, 64, 0.2)
    assert hc.lagrange_init == hc.lagrange_min == 1.0 and hc.lagrange_lr == 0.1 and hc.cost_budget == 0.0
    ant = expert_config("ant", "ppo_lag_true")
    assert (ant.lr, ant.n_epochs, ant.minibatch_size, ant.gae_lambda, ant.lagrange_min) == (3e-5, 20, 128, 0.9, 0.1)
    assert hc.lagrange_optimizer == "adam" and hc.scale_cost and hc.episode_cost == "step"
    ppo = expert_config("halfcheetah", "ppo")
    assert ppo.lagrange_init == ppo.lagrange_min == 0.0
    # nu_0 departs from the benchmark's for the pendulum and the swimmer only (their experts never met the wall)
    nu0 = {t: expert_config(t, "ppo_lag_true").lagrange_min for t in BENCHMARK_NU0}
    assert {t for t in nu0 if nu0[t] != BENCHMARK_NU0[t]} == {"pendulum", "swimmer"}
    assert (nu0["pendulum"], nu0["swimmer"]) == (10.0, 30.0)
    assert expert_config("pendulum", "ppo").lagrange_init == 0.0  # the unconstrained runs are unchanged
    with pytest.raises(ValueError, match="method: unknown"):
        expert_config("halfcheetah", "sac")


def test_ppolag_lower_bound_keeps_old_hashes():
    d = PPOLagConfig().to_dict()  # configs made before the options hash as before
    assert not {"lagrange_min", "lagrange_optimizer", "scale_cost"} & set(d)
    with pytest.raises(ValueError, match="lagrange_optimizer"):
        PPOLagConfig(lagrange_optimizer="rmsprop").validate()
    assert PPOLagConfig(lagrange_min=0.5, lagrange_init=0.5).to_dict()["lagrange_min"] == 0.5
    assert lagrange_update(1.0, 0.0, 0.5, 0.1) == pytest.approx(0.95)
    assert lagrange_update(1.0, 0.0, 0.5, 10.0, lam_min=0.7) == 0.7
    with pytest.raises(ValueError, match="lagrange_min"):
        PPOLagConfig(lagrange_min=200.0).validate()
    with pytest.raises(ValueError, match="episode_cost"):
        PPOLagConfig(episode_cost="mean").validate()


def _lines(path):
    return [json.loads(s) for s in path.read_text().splitlines()]


def test_short_run_checkpoints_and_resumes(tmp_path):
    out = tmp_path / "runs"
    run = train_policy("pendulum", "ppo_lag_true", 3, out, 256, config_overrides=SMALL, checkpoint_every=1,
                       eval_every=2, eval_episodes=3, log=None)
    assert run == out / "pendulum" / "ppo_lag_true" / "seed3"
    ck = load_run_checkpoint(run / "checkpoint.pt")  # torch.load(weights_only=True)
    assert ck["agent"]["num_steps"] == 256 and ck["agent"]["num_updates"] == 2
    assert ck["agent"]["lam"] >= 0.1  # never below nu_0
    first = _lines(run / "curve.jsonl")
    assert first and [r["episode"] for r in first] == list(range(1, len(first) + 1))
    for r in first:  # the metrics are consistent with each other (pendulum rewards are positive)
        assert r["constraint"] == int(r["cost_sum"] > 0)
        assert r["reward_nc"] <= r["reward"] + 1e-12
        assert (r["reward_nc"] == r["reward"]) or r["constraint"] == 1
    ev = _lines(run / "eval.jsonl")
    assert len(ev) == 1 and len(ev[0]["episodes"]) == 3 and ev[0]["steps"] == 256
    assert ev[0]["violation_rate"] == np.mean([e["constraint"] for e in ev[0]["episodes"]])
    assert (run / "done.json").exists() and (run / "best.pt").exists()

    # a crash after some lines were logged but before the next checkpoint: the resumed run drops them
    with open(run / "curve.jsonl", "a") as fh:
        fh.write('{"episode": 999999}\n')
    train_policy("pendulum", "ppo_lag_true", 3, out, 512, config_overrides=SMALL, checkpoint_every=1, eval_every=2,
                 eval_episodes=3, log=None)
    ck = load_run_checkpoint(run / "checkpoint.pt")
    assert ck["agent"]["num_steps"] == 512 and ck["agent"]["num_updates"] == 4
    rows = _lines(run / "curve.jsonl")
    assert rows[:len(first)] == first
    assert [r["episode"] for r in rows] == list(range(1, len(rows) + 1)) and len(rows) > len(first)
    assert min(r["steps"] for r in rows[len(first):]) > 256
    assert [e["steps"] for e in _lines(run / "eval.jsonl")] == [256, 512]

    # the same target again: nothing to do
    before = (run / "checkpoint.pt").read_bytes()
    train_policy("pendulum", "ppo_lag_true", 3, out, 512, config_overrides=SMALL, checkpoint_every=1, eval_every=2,
                 eval_episodes=3, log=None)
    assert (run / "checkpoint.pt").read_bytes() == before

    # other settings on the same directory are refused, naming what differs
    with pytest.raises(ValueError, match="other settings.*ppo"):
        train_policy("pendulum", "ppo_lag_true", 3, out, 768, config_overrides={**SMALL, "lr": 1e-3}, log=None)
    assert not (run / "lock").exists()  # released on the refusal: the right settings go on


def test_interrupted_run_resumes_from_its_checkpoint(tmp_path):
    run = train_policy("swimmer", "ppo", 0, tmp_path, 10_000, config_overrides=SMALL, checkpoint_every=1,
                       eval_every=100, eval_episodes=1, log=None, max_seconds=0.0)  # stops after one update
    assert not (run / "done.json").exists()
    assert load_run_checkpoint(run / "checkpoint.pt")["agent"]["num_steps"] == 128
    train_policy("swimmer", "ppo", 0, tmp_path, 384, config_overrides=SMALL, checkpoint_every=1, eval_every=100,
                 eval_episodes=1, log=None)
    ck = load_run_checkpoint(run / "checkpoint.pt")
    assert ck["agent"]["num_steps"] == 384 and ck["agent"]["lam"] == 0.0
    assert (run / "done.json").exists()


def test_a_busy_run_directory_is_refused(tmp_path):
    run = tmp_path / "halfcheetah" / "ppo" / "seed0"
    run.mkdir(parents=True)
    (run / "lock").write_text(str(os.getppid()))  # a live process
    with pytest.raises(RuntimeError, match="being trained by process"):
        train_policy("halfcheetah", "ppo", 0, tmp_path, 128, config_overrides=SMALL, log=None)
    assert sorted(p.name for p in run.iterdir()) == ["lock"]  # refused before writing config.json


def test_unsafe_checkpoint_is_refused(tmp_path):
    bad = tmp_path / "checkpoint.pt"
    bad.write_bytes(b"not a checkpoint")
    with pytest.raises(ValueError, match="cannot be loaded safely"):
        load_run_checkpoint(bad)


def test_cli_rejects_bad_jobs(capsys, tmp_path):
    assert main(["--out", str(tmp_path), "--run", "halfcheetah:ppo:0"]) == 2
    assert "TASK:METHOD:SEED:STEPS" in capsys.readouterr().err
    assert main(["--out", str(tmp_path), "--run", "hopper:ppo:0:100"]) == 2
    assert "unknown ICRL benchmark task" in capsys.readouterr().err


def test_adam_multiplier_on_the_softplus_preactivation():
    def softplus(t):
        return float(np.log1p(np.exp(t)))

    st: dict = {}
    theta0 = float(np.log(np.expm1(1.0)))
    lam = lagrange_adam_update(1.0, 0.3, 0.0, 0.1, st, lam_min=1.0)
    assert lam == pytest.approx(softplus(theta0 + 0.1), rel=1e-6)  # Adam's first step: lr * sign
    assert st["t"] == 1 and st["m"] < 0
    lam2 = lagrange_adam_update(lam, 0.001, 0.0, 0.1, st, lam_min=1.0)  # a tiny cost still raises it (Adam scales)
    assert lam2 > lam + 0.03  # a plain gradient step would add 0.1 * 0.001 * sigmoid(theta) < 1e-4
    down = lagrange_adam_update(1.05, 0.0, 0.5, 0.1, {}, lam_min=1.0)  # under budget: falls, but not below nu_0
    assert down == 1.0
    assert lagrange_adam_update(5.0, 1.0, 0.0, 10.0, {}, lam_max=6.0) == 6.0


def test_adam_multiplier_and_cost_scale_survive_a_checkpoint(tmp_path):
    run = train_policy("pendulum", "ppo_lag_true", 0, tmp_path, 256, config_overrides=SMALL, checkpoint_every=1,
                       eval_every=100, eval_episodes=1, log=None)
    ag = load_run_checkpoint(run / "checkpoint.pt")["agent"]
    assert ag["lam_adam"]["t"] == 2 and ag["cost_rms"]["count"] > 1
    assert ag["config"]["lagrange_optimizer"] == "adam" and ag["config"]["scale_cost"] is True


def test_fused_optimizer_is_the_same_algorithm_and_resumes_either_way():
    from pbicrl.baselines.ppo_lagrangian import PPOLagrangian
    from pbicrl.envs.point_mass import PointMassEnv

    cfg = PPOLagConfig(n_envs=2, n_steps=64, n_epochs=2, minibatch_size=64)

    def make(fused):
        return PPOLagrangian(lambda: PointMassEnv(max_steps=10), lambda o, i: np.asarray(o)[:2],
                             lambda c: np.zeros(len(c)), cfg, seed=0, fused_optimizer=fused)

    plain, fused = make(False), make(True)
    plain.learn(256)
    fused.learn(256)
    for p, q in zip(plain.ac.parameters(), fused.ac.parameters()):
        np.testing.assert_allclose(p.detach().numpy(), q.detach().numpy(), atol=1e-5)
    if fused.fused_optimizer:
        again = make(True)
        again.load_state_dict(plain.state_dict())  # a checkpoint of the default optimiser
        assert again.opt.param_groups[0]["fused"] is True
        again.learn(384)
        assert again.num_steps == 384
    back = make(False)
    back.load_state_dict(fused.state_dict())
    back.learn(384)
    assert back.num_steps == 384


def test_checkpoint_policy_rollouts_and_a_ranked_dataset(tmp_path):
    from pbicrl.experiments.icrl_benchmark import CheckpointPolicy, demonstrations_dataset, rollout_episodes
    from pbicrl.inference.data import load_dataset

    run = train_policy("swimmer", "ppo_lag_true", 0, tmp_path, 128, config_overrides=SMALL, checkpoint_every=1,
                       eval_every=1, eval_episodes=1, log=None)
    pol = CheckpointPolicy(run / "best.pt")
    assert pol.steps == 128
    a = rollout_episodes("swimmer", pol, 2, seed=7)
    b = rollout_episodes("swimmer", CheckpointPolicy(run / "checkpoint.pt"), 2, seed=7)
    np.testing.assert_array_equal(a[0]["x"], b[0]["x"])  # deterministic, same weights, same seeds
    ep = a[0]
    assert ep["features"].shape == (500, 2) and ep["obs"].shape == (501, 10)
    np.testing.assert_array_equal(ep["x"], ep["obs"][1:, 0])
    np.testing.assert_allclose(ep["rewards"], ep["features"] @ np.array([1.0, -1e-4]))
    assert ep["constraint"] == int(np.any(ep["x"] > 0.5)) and ep["reward"] == pytest.approx(ep["rewards"].sum())
    noisy = rollout_episodes("swimmer", CheckpointPolicy(run / "best.pt", deterministic=False, seed=1), 1, seed=7)
    assert not np.array_equal(noisy[0]["x"], ep["x"])
    ds = demonstrations_dataset("swimmer", {1: a[:1], 3: a[1:]})
    assert ds.feature_names == ("speed", "action_sq_norm") and ds.env_id == "pbicrl/BlockedSwimmer-v0"
    assert list(ds.group) == [1, 3] and ds.states.shape == (1000, 1)
    path = ds.save(tmp_path / "demos.npz")
    back = load_dataset(path)
    np.testing.assert_array_equal(back.states, ds.states)
    with pytest.raises(ValueError, match="at least two groups"):
        demonstrations_dataset("swimmer", {1: a})
    with pytest.raises(ValueError, match=r"obs: expected shape \(10,\)"):
        pol(np.zeros(3))


def test_icl_method_resumes_and_its_run_is_reported(tmp_path):
    """A smoke-sized ICL seed on Blocked Half-Cheetah's good demonstrations: stopped after its first update,
    resumed to the end, evaluated as the other methods are, and read by the report."""
    from pbicrl.experiments.icrl_benchmark import icl_config
    from pbicrl.experiments.icrl_report import build_report

    small = {"ppo": {"n_envs": 2}, "policy_episodes": 1, "eval_episodes": 1}
    cfg = icl_config("halfcheetah", 3072, "smoke", small)  # smoke: 2 rounds; scaled to 2048 + 1024 steps
    assert (cfg.rounds, cfg.first_round_steps, cfg.round_steps, cfg.total_steps) == (2, 2048, 1024, 3072)
    assert icl_config("ant", 2_500_000).to_dict() == icl_config("ant", 2_500_000, "default").to_dict()
    kw = dict(icl_budget="smoke", config_overrides=small, eval_episodes=1, log=None)
    run = train_policy("halfcheetah", "icl", 0, tmp_path, 3072, max_seconds=0.0, **kw)  # stops after one update
    assert run == tmp_path / "halfcheetah" / "icl" / "seed0"
    assert not (run / "done.json").exists() and json.loads((run / "budget.json").read_text())["status"] == "interrupted"
    assert json.loads((run / "progress.json").read_text())["steps"] == 512
    with open(run / "curve.jsonl", "a") as fh:  # logged after the checkpoint by a run that then died: cut on resume
        fh.write('{"episode": 99, "steps": 999999}\n')
    train_policy("halfcheetah", "icl", 0, tmp_path, 3072, **kw)
    done = json.loads((run / "done.json").read_text())
    assert done["steps"] == 3072 and done["rounds"] == 2 and done["true_location"] == -3.0
    curve = _lines(run / "curve.jsonl")  # after the resume (fresh resets) 2 environments x 1280 steps: 1 episode each
    assert [r["episode"] for r in curve] == [1, 2] and all(512 < r["steps"] <= 3072 and r["length"] == 1000
                                                           for r in curve)
    for r in curve:  # the true cost, which the learner never saw, is what the logs record
        assert r["constraint"] == int(r["cost_sum"] > 0) == int(r["x_min"] < -3.0)
    ev = _lines(run / "eval.jsonl")
    assert len(ev) == 1 and ev[0]["steps"] == 3072 and len(ev[0]["episodes"]) == 1
    assert ev[0]["violation_rate"] == ev[0]["episodes"][0]["constraint"]
    c = json.loads((run / "config.json").read_text())
    assert c["method"] == "icl" and c["expert_data"] == "icrl_halfcheetah" and c["n_expert"] == 100
    before = (run / "checkpoint.pt").read_bytes()
    train_policy("halfcheetah", "icl", 0, tmp_path, 3072, **kw)  # finished: nothing to do
    assert (run / "checkpoint.pt").read_bytes() == before
    with pytest.raises(ValueError, match="other settings.*icl"):
        train_policy("halfcheetah", "icl", 0, tmp_path, 4096, **kw)
    assert not (run / "lock").exists()

    res = build_report(tmp_path, tmp_path / "report", tasks=["halfcheetah", "pendulum"], figures=False)
    row = res["tasks"]["halfcheetah"]["icl"]
    assert row["seeds_done"] == 1 and row["violation_rate"][0] == ev[0]["violation_rate"]
    assert row["feasible_reward"][0] == pytest.approx(ev[0]["episodes"][0]["reward_nc"])
    missing = {(m["task"], m["method"]): m["why"] for m in res["missing"]}
    assert ("halfcheetah", "icl") not in missing and missing["pendulum", "icl"] == "no run directory"
    md = (tmp_path / "report" / "report.md").read_text()
    assert "| halfcheetah | ICL baseline | 1 of 5 | 3,072 |" in md and "ICL's learned wall" in md


@pytest.mark.parametrize("task, wall, side", [("pendulum", -0.015, "behind"), ("swimmer", 0.5, "infront")])
def test_icl_method_runs_on_the_pendulum_and_the_swimmer(tmp_path, task, wall, side):
    """A smoke-sized ICL seed on the tasks that gained ICL environments last: the true cost is what the logs
    record (x beyond the wall on the wall's side), and ICL's wall, where it finds one, is beyond the good
    demonstrations' reach (scanned from their nearest approach)."""
    small = {"ppo": {"n_envs": 2}, "policy_episodes": 1, "eval_episodes": 1}
    run = train_policy(task, "icl", 0, tmp_path, 3072, icl_budget="smoke", config_overrides=small,
                       eval_episodes=1, log=None)
    done = json.loads((run / "done.json").read_text())
    assert done["steps"] == 3072 and done["true_location"] == wall
    assert json.loads((run / "config.json").read_text())["expert_data"] == f"icrl_{task}"
    loc = done["icl_location"]
    if loc is not None:  # the good demonstrations reach -0.01466 (pendulum) and 0.4987 (swimmer)
        assert (loc <= -0.01466) if side == "behind" else (loc >= 0.4986)
    curve = _lines(run / "curve.jsonl")
    assert curve
    for r in curve:
        beyond = r["x_min"] < wall if side == "behind" else r["x_max"] > wall
        assert r["constraint"] == int(r["cost_sum"] > 0) == int(beyond)


def test_icl_method_refuses_tasks_without_an_icl_environment(capsys, tmp_path, monkeypatch):
    from pbicrl.experiments import icrl_benchmark
    from pbicrl.experiments.icrl_benchmark import icl_config

    # every task has one; the pendulum and the swimmer use Ant's 6 rounds, scaled to 2 M steps
    cfg = icl_config("pendulum", 2_000_000)
    assert (cfg.rounds, cfg.total_steps) == (6, 2_000_000) and icl_config("swimmer", 2_000_000).to_dict() == cfg.to_dict()
    monkeypatch.delitem(icrl_benchmark.ICL_TASKS, "pendulum")
    assert main(["--out", str(tmp_path), "--run", "pendulum:icl:0:100000"]) == 2
    assert "method icl runs on ['ant', 'halfcheetah', 'swimmer', 'walker'] only" in capsys.readouterr().err
    assert main(["--out", str(tmp_path), "--run", "halfcheetah:icl:0:100"]) == 2
    assert "too small for ICL's 8 rounds" in capsys.readouterr().err
    with pytest.raises(ValueError, match="icl_config"):
        expert_config("halfcheetah", "icl")
