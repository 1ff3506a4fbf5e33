"""Resumable SAC trainer: smoke run, resume, interruption, warm start, validation, CLI."""

from __future__ import annotations

import json
import os
import signal
import threading

import numpy as np
import pytest

gym = pytest.importorskip("gymnasium")
pytest.importorskip("torch")
pytest.importorskip("stable_baselines3")

from pbicrl.demonstrators.sac import load_policy, train_sac

TINY = {"net_arch": (16, 16), "buffer_size": 1000, "batch_size": 32, "learning_starts": 100,
        "checkpoint_every": 100, "log_every": 100, "progress": False}


def _pendulum():
    return gym.make("Pendulum-v1", max_episode_steps=100)


def test_smoke_run_writes_policy_budget_and_log(tmp_path):
    out = tmp_path / "run"
    path = train_sac(_pendulum, 300, out, seed=1, metadata={"env": "Pendulum-v1"}, **TINY)
    assert path == out / "policy.zip" and path.is_file()
    assert (out / "final_model.zip").is_file()
    budget = json.loads((out / "budget.json").read_text())
    assert budget["requested_steps"] == 300 and budget["done_steps"] == 300
    assert budget["status"] == "complete"
    assert budget["hyperparameters"]["net_arch"] == [16, 16]
    assert budget["hyperparameters"]["learning_rate"] == 3e-4
    assert budget["metadata"] == {"env": "Pendulum-v1"}
    assert "torch" in budget["versions"] and "stable_baselines3" in budget["versions"]
    assert budget["wall_time_s"] > 0
    log = (out / "progress.log").read_text().splitlines()
    assert any("steps 300/300" in line for line in log)
    # the shipped policy has no replay buffer and acts on observations
    assert path.stat().st_size < (out / "final_model.zip").stat().st_size
    policy = load_policy(path)
    env = _pendulum()
    obs, _ = env.reset(seed=0)
    a, _ = policy.predict(obs, deterministic=True)
    assert a.shape == (1,) and env.action_space.contains(a.astype(np.float32))
    # a whole-model zip (a checkpoint) loads to a policy acting exactly as the shipped one
    full = load_policy(out / "final_model.zip")
    b, _ = full.predict(obs, deterministic=True)
    np.testing.assert_array_equal(a, b)
    env.close()


def test_resume_continues_from_checkpoint(tmp_path):
    out = tmp_path / "run"
    train_sac(_pendulum, 200, out, seed=2, **TINY)
    first = json.loads((out / "checkpoint" / "state.json").read_text())
    assert first["num_timesteps"] == 200
    train_sac(_pendulum, 350, out, seed=2, **TINY)
    budget = json.loads((out / "budget.json").read_text())
    assert budget["done_steps"] == 350
    assert [(s["start_step"], s["end_step"]) for s in budget["sessions"]] == [(0, 200), (200, 350)]
    assert "resume from checkpoint at step 200" in (out / "progress.log").read_text()


def test_sigterm_writes_checkpoint_then_resume_finishes(tmp_path):
    out = tmp_path / "run"
    done_waiting = threading.Event()

    def send_sigterm_once_training_runs():
        # the handler is installed before the first progress line: only then is SIGTERM safe
        log = out / "progress.log"
        while not done_waiting.wait(0.05):
            if log.is_file() and "steps 200/" in log.read_text():
                os.kill(os.getpid(), signal.SIGTERM)
                return

    thread = threading.Thread(target=send_sigterm_once_training_runs, daemon=True)
    thread.start()
    try:
        with pytest.raises(KeyboardInterrupt, match="interrupted at step"):
            train_sac(_pendulum, 200_000, out, seed=3, **TINY)
    finally:
        done_waiting.set()
        thread.join()
    budget = json.loads((out / "budget.json").read_text())
    assert budget["status"] == "interrupted"
    done = budget["done_steps"]
    assert 0 < done < 200_000
    assert json.loads((out / "checkpoint" / "state.json").read_text())["num_timesteps"] == done
    assert not (out / "policy.zip").exists()
    train_sac(_pendulum, done + 20, out, seed=3, **TINY)
    assert json.loads((out / "budget.json").read_text())["status"] == "complete"
    assert (out / "policy.zip").is_file()


def test_deadline_finalises_policy_early_and_resume_extends(tmp_path):
    import time

    out = tmp_path / "run"
    train_sac(_pendulum, 200_000, out, seed=6, deadline=time.time() + 1.0, **TINY)
    budget = json.loads((out / "budget.json").read_text())
    assert budget["status"] == "deadline"
    done = budget["done_steps"]
    assert 0 <= done < 200_000  # 0 only if building the model took longer than the deadline
    assert (out / "policy.zip").is_file()
    train_sac(_pendulum, done + 30, out, seed=6, **TINY)
    budget = json.loads((out / "budget.json").read_text())
    assert budget["status"] == "complete" and budget["done_steps"] == done + 30
    with pytest.raises(ValueError, match="deadline"):
        train_sac(_pendulum, 10, tmp_path / "r", deadline=float("nan"), **TINY)


def test_warm_start_copies_networks(tmp_path):
    src = tmp_path / "src"
    train_sac(_pendulum, 150, src, seed=4, **TINY)

    dst = tmp_path / "dst"
    # zero training updates after the warm start: learning_starts > total steps
    train_sac(_pendulum, 50, dst, seed=5, init_from=src / "final_model.zip",
              **{**TINY, "learning_starts": 1000})
    a = load_policy(src / "final_model.zip").state_dict()
    b = load_policy(dst / "final_model.zip").state_dict()
    for k in a:
        np.testing.assert_array_equal(a[k].numpy(), b[k].numpy())
    assert json.loads((dst / "budget.json").read_text())["done_steps"] == 50


@pytest.mark.parametrize("kw, name", [({"total_steps": 0}, "total_steps"), ({"batch_size": 0}, "batch_size"),
                                      ({"learning_rate": -1.0}, "learning_rate"), ({"net_arch": ()}, "net_arch")])
def test_bad_options_name_the_option(tmp_path, kw, name):
    args = {"total_steps": 10, **kw}
    total = args.pop("total_steps")
    with pytest.raises(ValueError, match=name):
        train_sac(_pendulum, total, tmp_path / "r", **{**TINY, **args})


def test_init_from_missing_file(tmp_path):
    with pytest.raises(ValueError, match="init_from"):
        train_sac(_pendulum, 10, tmp_path / "r", init_from=tmp_path / "nope.zip", **TINY)


def test_load_policy_missing_file(tmp_path):
    with pytest.raises(FileNotFoundError, match="policy"):
        load_policy(tmp_path / "missing.zip")


def test_cli_parser_mounts_and_validates():
    import argparse

    from pbicrl.cli.wall import add_subcommands, build_parser

    parent = argparse.ArgumentParser(prog="pbicrl")
    sub = parent.add_subparsers(dest="cmd")
    add_subcommands(sub)
    args = parent.parse_args(["train-wall", "--env", "ant", "--mode", "good", "--steps", "100", "--out", "x"])
    assert args.env == "ant" and args.steps == 100 and callable(args.func) and args.deadline is None
    args = parent.parse_args(["train-wall", "--env", "ant", "--mode", "good", "--steps", "100", "--out", "x",
                              "--deadline", "2026-11-22T02:10:00Z"])
    assert args.deadline == 1795313400.0
    with pytest.raises(SystemExit):
        build_parser().parse_args(["train-wall", "--env", "ant", "--mode", "good", "--steps", "1", "--out", "x",
                                   "--deadline", "soon"])
    with pytest.raises(SystemExit):
        build_parser().parse_args(["train-wall", "--env", "hopper", "--mode", "good", "--steps", "1", "--out", "x"])
    with pytest.raises(SystemExit):
        build_parser().parse_args(["train-wall", "--env", "ant", "--mode", "good", "--steps", "0", "--out", "x"])


def test_checkpoint_swap_is_atomic_follows_the_umask_and_a_killed_swap_is_undone(tmp_path, monkeypatch):
    """Checkpoints are written with pbicrl._atomic: complete or absent, permissions of a plain mkdir/open under
    the umask, and a swap killed between its two renames leaves the previous checkpoint, put back on resume."""
    from pbicrl._atomic import temporary_prefix, umask
    from pbicrl.demonstrators import sac_files
    from pbicrl.demonstrators.sac import _find_checkpoint, _save_checkpoint

    class Model:  # stands for an SB3 model; the writers below record its tag
        def __init__(self, tag):
            self.tag = tag

    monkeypatch.setattr(sac_files, "save_model", lambda m, path: path.write_text(f"model {m.tag}"))
    monkeypatch.setattr(sac_files, "save_replay_buffer", lambda m, path: path.write_text(f"buffer {m.tag}"))

    out = tmp_path / "run"
    out.mkdir()
    _save_checkpoint(Model(1), out, {"num_timesteps": 100})
    _save_checkpoint(Model(2), out, {"num_timesteps": 200})
    ckpt = out / "checkpoint"
    assert sorted(p.name for p in out.iterdir()) == ["checkpoint"]  # no temporaries, no .old left
    assert json.loads((ckpt / "state.json").read_text()) == {"num_timesteps": 200}
    assert (ckpt / "model.zip").read_text() == "model 2"
    assert ckpt.stat().st_mode & 0o777 == 0o777 & ~umask()
    assert (ckpt / "state.json").stat().st_mode & 0o777 == 0o666 & ~umask()
    # killed after moving the previous checkpoint aside, before the new one took its place: a dead writer's
    # ".old-" temporary holds it (pid 2**22 + 1 is above Linux's pid_max: no such process)
    aside = out / (temporary_prefix(ckpt, "old").rsplit(".", 2)[0] + f".{2**22 + 1}.x")
    aside.mkdir()
    os.replace(ckpt, aside / "old")
    found = _find_checkpoint(out)
    assert found == ckpt and json.loads((ckpt / "state.json").read_text()) == {"num_timesteps": 200}
    assert sorted(p.name for p in out.iterdir()) == ["checkpoint"]
    # the swap of earlier versions (checkpoint.old) still resumes, and the next checkpoint removes it
    os.replace(ckpt, out / "checkpoint.old")
    assert _find_checkpoint(out) == out / "checkpoint.old"
    _save_checkpoint(Model(3), out, {"num_timesteps": 300})
    assert sorted(p.name for p in out.iterdir()) == ["checkpoint"]


def test_a_checkpoint_without_its_replay_buffer_is_refused_not_overwritten(tmp_path):
    """A model and state without replay_buffer.npz cannot be resumed; starting afresh would replace the model
    at the first save, so the run is refused with the folder named and the files left as they were."""
    from pbicrl.demonstrators.sac import _find_checkpoint

    ckpt = tmp_path / "run" / "checkpoint"
    ckpt.mkdir(parents=True)
    (ckpt / "model.zip").write_text("a model someone trained for days")
    (ckpt / "state.json").write_text('{"num_timesteps": 100}')
    with pytest.raises(ValueError, match="without its replay buffer") as err:
        _find_checkpoint(tmp_path / "run")
    assert str(ckpt) in str(err.value)
    assert (ckpt / "model.zip").read_text() == "a model someone trained for days"
    assert _find_checkpoint(tmp_path / "elsewhere") is None  # no checkpoint at all: a fresh run


def test_prefill_fills_the_warm_start_buffer_with_the_loaded_policy_before_training(tmp_path):
    src = tmp_path / "src"
    train_sac(_pendulum, 150, src, seed=4, **TINY)
    from pbicrl.demonstrators.sac_files import read_model, read_replay_buffer

    dst = tmp_path / "dst"
    # no gradient step (learning_starts > steps): the buffer holds the prefill, then the run's own steps
    train_sac(_pendulum, 50, dst, seed=5, init_from=src / "final_model.zip", prefill_steps=240,
              target_entropy=-3.0, **{**TINY, "learning_starts": 1000})
    model = read_model(dst / "checkpoint" / "model.zip", _pendulum())
    read_replay_buffer(model, dst / "checkpoint" / "replay_buffer.npz")
    assert model.replay_buffer.size() == 240 + 50
    # pendulum episodes here last 100 steps: the prefill crossed two time limits, stored as truncations
    dones = model.replay_buffer.dones[:240, 0]
    assert np.flatnonzero(dones).tolist() == [99, 199]
    assert model.replay_buffer.timeouts[:240, 0].sum() == 2
    # stored actions are in the policy's scaled space [-1, 1] (Pendulum acts in [-2, 2])
    acts = model.replay_buffer.actions[:240, 0, 0]
    assert np.abs(acts).max() <= 1.0 and np.abs(acts).max() > 0.5
    budget = json.loads((dst / "budget.json").read_text())
    assert budget["done_steps"] == 50  # the prefill is not counted as training steps
    assert budget["hyperparameters"]["prefill_steps"] == 240
    assert budget["hyperparameters"]["target_entropy"] == -3.0 and model.target_entropy == -3.0
    assert "prefilled with 240 steps" in (dst / "progress.log").read_text()


@pytest.mark.parametrize("kw, match", [({"prefill_steps": 10}, "prefill_steps: needs init_from"),
                                       ({"prefill_steps": -1}, "prefill_steps"),
                                       ({"target_entropy": float("nan")}, "target_entropy")])
def test_prefill_and_target_entropy_are_validated(tmp_path, kw, match):
    with pytest.raises(ValueError, match=match):
        train_sac(_pendulum, 10, tmp_path / "r", **{**TINY, **kw})
    assert not (tmp_path / "r").exists()


def test_cli_parses_the_training_only_options():
    from pbicrl.cli.wall import build_parser

    base = ["train-wall", "--env", "ant", "--mode", "good", "--steps", "100", "--out", "x"]
    args = build_parser().parse_args(base)
    assert (args.reach_bonus, args.prefill_steps, args.target_entropy, args.start_spread) == (0.0, 0, "auto", 0.0)
    args = build_parser().parse_args(base + ["--reach-bonus", "3", "--prefill-steps", "50000",
                                             "--target-entropy", "-16", "--start-spread", "9"])
    assert (args.reach_bonus, args.prefill_steps, args.target_entropy, args.start_spread) == (3.0, 50000, -16.0, 9.0)
    for bad in ("high", "nan"):
        with pytest.raises(SystemExit):
            build_parser().parse_args(base + ["--target-entropy", bad])


def test_a_resumed_checkpoint_restores_networks_optimisers_entropy_and_buffer(tmp_path):
    """The pbicrl model file and replay-buffer .npz carry everything SB3's pickles carried for a resume."""
    import torch

    from pbicrl.demonstrators.sac_files import read_model, read_replay_buffer, save_model, save_replay_buffer

    out = tmp_path / "run"
    train_sac(_pendulum, 250, out, seed=7, **TINY)
    model = read_model(out / "final_model.zip", _pendulum())
    read_replay_buffer(model, out / "checkpoint" / "replay_buffer.npz")
    assert model.num_timesteps == 250 and model.replay_buffer.size() == 250
    assert model.actor.optimizer.state_dict()["state"]  # Adam moments restored, not fresh
    assert float(model.log_ent_coef.detach()) != 0.0  # the learned temperature (starts at log 1 = 0)
    save_model(model, tmp_path / "again.zip")
    save_replay_buffer(model, tmp_path / "again.npz")
    twin = read_model(tmp_path / "again.zip", _pendulum())
    read_replay_buffer(twin, tmp_path / "again.npz")
    for k, v in model.policy.state_dict().items():
        assert torch.equal(v, twin.policy.state_dict()[k]), k
    np.testing.assert_array_equal(model.replay_buffer.observations, twin.replay_buffer.observations)
    assert (twin.batch_size, twin.tau, twin.gamma) == (32, model.tau, model.gamma)
