"""``pbicrl train-safe``: settings checks, a smoke training run, resume, the CLI, and the episode-cost budget."""

from __future__ import annotations

import json
import os
import signal
import threading

import numpy as np
import pytest

pytest.importorskip("torch")
pytest.importorskip("gymnasium")

from pbicrl.baselines.ppo_lagrangian import PPOLagConfig, PPOLagrangian  # noqa: E402
from pbicrl.cli import main  # noqa: E402
from pbicrl.envs.point_mass import PointMassEnv  # noqa: E402
from pbicrl.envs.regions import FEATURE_NAMES as NAV  # noqa: E402
from pbicrl.experiments.safe_rl import evaluate_policy, load_policy, ppo_config, train_safe  # noqa: E402

SMALL = {"n_envs": 2, "n_steps": 64, "n_epochs": 2, "minibatch_size": 64}


@pytest.fixture
def nav_run(tmp_path):
    """Point-mass posterior: orange and red selected in every draw."""
    d = tmp_path / "run"
    d.mkdir()
    ind = np.zeros((1, 8, 4), dtype=np.int8)
    ind[..., 1:3] = 1
    np.savez(d / "chains.npz", indicators=ind, penalty_weights=-50.0 * ind, log_likelihood=np.zeros((1, 8)),
             feature_names=np.array(NAV))
    (d / "summary.json").write_text(json.dumps({"schema_version": 1, "feature_names": list(NAV), "settings": {}}))
    return d


def test_episode_cost_sum_budget_and_backward_compatible_config():
    assert "episode_cost" not in PPOLagConfig().to_dict()  # old configs (and hashes keyed on them) unchanged
    assert PPOLagConfig(episode_cost="sum").to_dict()["episode_cost"] == "sum"
    with pytest.raises(ValueError, match="ppo.episode_cost"):
        PPOLagConfig(episode_cost="mean").validate()
    cfg = PPOLagConfig(n_envs=2, n_steps=64, n_epochs=1, minibatch_size=64, cost_budget=1.0, lagrange_lr=0.1,
                       episode_cost="sum")
    p = PPOLagrangian(lambda: PointMassEnv(max_steps=10), lambda o, i: np.asarray(o)[:2], lambda c: np.ones(len(c)),
                      cfg, seed=0)
    p.learn(128)
    p.close()
    assert p.history[0]["ep_cost"] == pytest.approx(10.0)  # 10 steps of cost 1, undiscounted
    assert p.lam == pytest.approx(0.1 * (10.0 - 1.0))


def test_train_safe_smoke_resume_and_files(nav_run, tmp_path):
    out = tmp_path / "safe"
    s = train_safe(out, "point_mass", 256, 0.5, run=nav_run, seed=1, ppo=SMALL, eval_episodes=3, progress=False)
    assert s["steps"] == 256 and s["cost_limit"] == 0.5 and s["lambda"] >= 0
    assert [t["name"] for t in s["cost_description"]["terms"]] == ["in_orange", "in_red"]
    assert s["evaluation"]["episodes"] == 3 and 0 <= s["evaluation"]["violation_rate"] <= 1
    budget = json.loads((out / "budget.json").read_text())
    assert budget["status"] == "complete" and budget["requested_steps"] == 256 and budget["done_steps"] == 256
    assert budget["ppo"]["episode_cost"] == "sum" and budget["ppo"]["cost_budget"] == 0.5
    assert len(s["history"]) == 2  # one update per 2 x 64 steps
    # same command again: nothing to do; a larger total: continues from the checkpoint
    again = train_safe(out, "point_mass", 256, 0.5, run=nav_run, seed=1, ppo=SMALL, eval_episodes=3, progress=False)
    assert again["steps"] == 256 and again["runtime_s"] == s["runtime_s"]
    more = train_safe(out, "point_mass", 384, 0.5, run=nav_run, seed=1, ppo=SMALL, eval_episodes=0, progress=False)
    assert more["steps"] == 384 and len(more["history"]) == 3 and more["sessions"] == 2
    assert "resume: 256 of 384 steps done" in (out / "progress.log").read_text()
    with pytest.raises(ValueError, match=r"out: .* different settings \(seed\)"):
        train_safe(out, "point_mass", 512, 0.5, run=nav_run, seed=2, ppo=SMALL, progress=False)
    # the final policy acts; a deterministic evaluation is reproducible
    pol = load_policy(out)
    a = evaluate_policy(pol, "point_mass", 2, seed=5)
    b = evaluate_policy(pol, "point_mass", 2, seed=5)
    np.testing.assert_array_equal(a.true_return, b.true_return)
    assert a.violation_rate == a.violation_steps.sum() / a.steps.sum()


def test_train_safe_reference_costs(tmp_path):
    none = train_safe(tmp_path / "none", "point_mass", 128, run=None, cost="none", ppo=SMALL, eval_episodes=0,
                      progress=False)
    assert none["lambda"] == 0.0 and all(h["ep_cost"] in (0.0, None) or np.isnan(h["ep_cost"]) for h in none["history"])
    true = train_safe(tmp_path / "true", "point_mass", 128, run=None, cost="true", ppo=SMALL, eval_episodes=2,
                      progress=False)
    assert true["cost_description"] == {"cost": "true"}
    # evaluated with the true cost, the episode cost is the number of violating steps
    ev = true["evaluation"]
    assert ev["cost"] == pytest.approx(ev["violation_rate"] * ev["mean_steps"])


def test_warmup_keeps_the_cost_off(tmp_path):
    """A posterior whose constraint is 'goal_not_reached' costs every step: off during the warm-up only."""
    d = tmp_path / "run"
    d.mkdir()
    ind = np.zeros((1, 4, 4), dtype=np.int8)
    ind[..., 3] = 1
    np.savez(d / "chains.npz", indicators=ind, penalty_weights=-1.0 * ind, log_likelihood=np.zeros((1, 4)),
             feature_names=np.array(NAV))
    (d / "summary.json").write_text(json.dumps({"feature_names": list(NAV)}))
    s = train_safe(tmp_path / "w", "point_mass", 512, 0.0, run=d, ppo=SMALL | {"n_steps": 128}, warmup_steps=256,
                   eval_episodes=0, progress=False)
    h = s["history"]
    assert [x["steps"] for x in h] == [256, 512, 768, 1024][:len(h)] and len(h) == 2
    assert h[0]["ep_cost"] in (0.0, None) or np.isnan(h[0]["ep_cost"])
    assert h[0]["lam_next"] == 0.0
    assert h[1]["ep_cost"] > 0 and h[1]["lam_next"] > 0  # every step costs 1 once the warm-up is over
    assert "warm-up over at 256 steps" in (tmp_path / "w" / "progress.log").read_text()
    with pytest.raises(ValueError, match="warmup_steps: must be an integer >= 0"):
        train_safe(tmp_path / "v", "point_mass", 512, run=d, warmup_steps=-1, progress=False)


def test_sigterm_writes_a_checkpoint_then_a_rerun_resumes(tmp_path):
    out = tmp_path / "sig"
    done_waiting = threading.Event()

    def send_sigterm_once_training_runs() -> None:
        # the handler is installed before the first update's progress line: only then is SIGTERM safe
        log = out / "progress.log"
        while not done_waiting.wait(0.05):
            if log.is_file() and "steps 128/" in log.read_text():
                os.kill(os.getpid(), signal.SIGTERM)
                return

    before = signal.getsignal(signal.SIGTERM)
    thread = threading.Thread(target=send_sigterm_once_training_runs, daemon=True)
    thread.start()
    try:
        with pytest.raises(KeyboardInterrupt, match="train-safe interrupted at"):
            train_safe(out, "point_mass", 10**7, run=None, cost="none", ppo=SMALL, eval_episodes=0, progress=False,
                       log_every_s=0.0)
    finally:
        done_waiting.set()
        thread.join()
    assert signal.getsignal(signal.SIGTERM) == before  # the run's handler is gone again
    budget = json.loads((out / "budget.json").read_text())
    done = budget["done_steps"]
    assert budget["status"] == "interrupted" and 128 <= done < 10**7
    assert f"interrupted at {done} steps; checkpoint written" in (out / "progress.log").read_text()
    s = train_safe(out, "point_mass", done + 128, run=None, cost="none", ppo=SMALL, eval_episodes=0, progress=False)
    assert s["steps"] == done + 128 and s["sessions"] == 2


def test_bad_settings_write_nothing(nav_run, tmp_path):
    out = tmp_path / "x"
    cases = [({"env": "grid"}, "env: expected one of"), ({"cost": "maybe"}, "cost: expected one of"),
             ({"steps": 0}, "steps: must be an integer"), ({"cost_limit": -1.0}, "cost_limit: must be"),
             ({"run": None}, "run: required with cost 'inferred'"),
             ({"mode": "max"}, "mode: expected one of"), ({"constraints": ["wall"]}, "constraints: 'wall' not in"),
             ({"ppo": {"n_env": 2}}, r"ppo: unknown option\(s\) \['n_env'\]"),
             ({"env": "halfcheetah"}, "env: the wall environment's features")]
    for over, msg in cases:
        kw = {"env": "point_mass", "steps": 64, "cost_limit": 1.0, "run": nav_run, "progress": False} | over
        with pytest.raises(ValueError, match=msg):
            train_safe(out, kw.pop("env"), kw.pop("steps"), kw.pop("cost_limit"), **kw)
        assert not out.exists()
    (tmp_path / "busy").mkdir()
    (tmp_path / "busy" / "notes.txt").write_text("mine")
    with pytest.raises(ValueError, match="out: .* not empty and holds no train-safe checkpoint"):
        train_safe(tmp_path / "busy", "point_mass", 64, run=nav_run, progress=False)


def test_cli(nav_run, tmp_path, capsys):
    out = tmp_path / "cli"
    rc = main(["train-safe", str(nav_run), "--env", "point_mass", "--steps", "200", "--cost-limit", "0",
               "--out", str(out), "--eval-episodes", "1", "--quiet"])
    assert rc == 0
    printed = json.loads(capsys.readouterr().out)
    assert printed["cost_limit"] == 0.0 and printed["steps"] == 1024  # one rollout: 4 envs x 256 steps
    assert (out / "policy.pt").is_file() and (out / "summary.json").is_file()
    rc = main(["train-safe", "--env", "point_mass", "--steps", "200", "--out", str(tmp_path / "y")])
    assert rc == 2 and "run: required with cost 'inferred'" in capsys.readouterr().err
    assert not (tmp_path / "y").exists()
    with pytest.raises(SystemExit):
        main(["train-safe", str(nav_run), "--env", "point_mass", "--steps", "200", "--out", str(tmp_path / "z"),
              "--cost-limit", "-1"])
    assert "expected a finite number >= 0" in capsys.readouterr().err


def test_ppo_config_defaults():
    c = ppo_config("halfcheetah", 2.0)
    assert (c.n_envs, c.n_steps, c.cost_budget, c.episode_cost) == (4, 512, 2.0, "sum")
    assert ppo_config("point_mass").cost_budget == 1.0


def test_evaluate_policy_on_the_wall():
    """A still HalfCheetah never reaches the wall: no violation, true return = nominal return, max x near 0."""
    r = evaluate_policy(lambda obs: np.zeros(6), "halfcheetah", 1, seed=0)
    assert r.steps.tolist() == [500] and r.violation_rate == 0.0
    assert r.true_return[0] == pytest.approx(r.nominal_return[0])
    assert r.max_x is not None and abs(r.max_x[0]) < 1.0
    assert "max_x" in r.to_dict() and evaluate_policy(lambda obs: np.zeros(2), "point_mass", 1).max_x is None
    with pytest.raises(ValueError, match="episodes: must be >= 1"):
        evaluate_policy(lambda obs: np.zeros(2), "point_mass", 0)


@pytest.mark.slow
def test_close_loop_smoke(tmp_path):
    """The evaluation script end to end on a tiny budget (about a minute): cached, resumable, identical costs flagged."""
    from pbicrl.cli.close_loop import main as close_loop

    args = ["--out", str(tmp_path / "cl"), "--pm-steps", "1024", "--hc-steps", "1024", "--seeds", "1", "--episodes", "2",
            "--iterations", "2000"]
    assert close_loop(args) == 0
    res = json.loads((tmp_path / "cl" / "results.json").read_text())
    assert set(res["envs"]) == {"point_mass", "halfcheetah"}
    assert res["envs"]["point_mass"]["identical_to_true"] == {"inferred": True}  # selected set = true regions
    assert set(res["envs"]["halfcheetah"]["policies"]) == {"nominal", "true", "inferred", "inferred-conservative",
                                                           "inferred-probability"}
    table = (tmp_path / "cl" / "table.md").read_text()
    assert table.count("\n") == 2 + 3 + 5
    assert close_loop(args) == 0  # everything cached: nothing retrained
    from pbicrl.experiments.kinds import shipped_data_tag

    tag = shipped_data_tag("point_mass")
    assert res["envs"]["point_mass"]["posterior"]["data"] == tag
    assert (tmp_path / "cl" / "infer" / tag / "summary.json").is_file()
    assert (tmp_path / "cl" / "train" / "point_mass" / f"inferred-{tag}" / "seed0").is_dir()
    assert (tmp_path / "cl" / "train" / "point_mass" / "true" / "seed0").is_dir()  # does not depend on the data


def test_close_loop_names_data_dependent_stages_by_the_file_content():
    import hashlib

    from pbicrl.experiments.close_loop import _stage
    from pbicrl.experiments.kinds import shipped_data_tag
    from pbicrl.inference.data import resolve_dataset_path

    for name in ("point_mass", "halfcheetah"):
        sha = hashlib.sha256(resolve_dataset_path(name).read_bytes()).hexdigest()
        assert shipped_data_tag(name) == f"{name}-{sha[:12]}"
    assert _stage("inferred-probability", "hc-1") == "inferred-probability-hc-1"
    assert _stage("true", "hc-1") == "true" and _stage("nominal", "hc-1") == "nominal"


@pytest.fixture
def every_step_run(tmp_path):
    """A posterior whose only constraint is 'goal_not_reached': every step before the goal costs 1."""
    d = tmp_path / "every"
    d.mkdir()
    ind = np.zeros((1, 4, 4), dtype=np.int8)
    ind[..., 3] = 1
    np.savez(d / "chains.npz", indicators=ind, penalty_weights=-1.0 * ind, log_likelihood=np.zeros((1, 4)),
             feature_names=np.array(NAV))
    (d / "summary.json").write_text(json.dumps({"feature_names": list(NAV)}))
    return d


def test_summary_says_whether_the_cost_limit_was_met(every_step_run, tmp_path):
    from pbicrl.errors import PbicrlWarning

    with pytest.warns(PbicrlWarning, match="did NOT meet the cost limit"):
        s = train_safe(tmp_path / "over", "point_mass", 128, 0.0, run=every_step_run, ppo=SMALL, eval_episodes=2,
                       progress=False)
    ev = s["evaluation"]
    assert ev["cost"] > 0 and s["cost_limit_met"] is False
    assert s["cost_limit_check"] == {"evaluation_cost": ev["cost"], "cost_limit": 0.0,
                                     "violation_rate": ev["violation_rate"],
                                     "violating_episodes": ev["violating_episodes"]}
    assert json.loads((tmp_path / "over" / "summary.json").read_text())["cost_limit_met"] is False
    assert "WARNING: the final policy did NOT meet" in (tmp_path / "over" / "progress.log").read_text()
    ok = train_safe(tmp_path / "ok", "point_mass", 128, 0.0, run=None, cost="none", ppo=SMALL, eval_episodes=2,
                    progress=False)
    assert ok["cost_limit_met"] is True and ok["cost_limit_check"]["evaluation_cost"] == 0.0
    assert "cost limit met" in (tmp_path / "ok" / "progress.log").read_text()
    none = train_safe(tmp_path / "noeval", "point_mass", 128, 0.0, run=None, cost="none", ppo=SMALL, eval_episodes=0,
                      progress=False)
    assert none["cost_limit_met"] is None


def test_cli_learning_rates_and_limit_warning(every_step_run, tmp_path, capsys):
    out = tmp_path / "lr"
    rc = main(["train-safe", str(every_step_run), "--env", "point_mass", "--steps", "200", "--cost-limit", "0",
               "--out", str(out), "--eval-episodes", "1", "--quiet", "--lr", "0.001", "--lagrange-lr", "0.2"])
    assert rc == 0
    cap = capsys.readouterr()
    assert json.loads(cap.out)["cost_limit_met"] is False
    assert "warning: the final policy did not meet --cost-limit 0" in cap.err
    budget = json.loads((out / "budget.json").read_text())
    assert budget["ppo"]["lr"] == 0.001 and budget["ppo"]["lagrange_lr"] == 0.2
    assert budget["mode"] == "indicator"  # features only: the default mode is indicator
    with pytest.raises(SystemExit):
        main(["train-safe", str(every_step_run), "--env", "point_mass", "--steps", "200", "--out", str(tmp_path / "n"),
              "--lr", "0"])
    assert "expected a positive number" in capsys.readouterr().err
