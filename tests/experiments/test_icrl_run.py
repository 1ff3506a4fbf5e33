"""The one-call ICRL benchmark (pbicrl.experiments.icrl_run): plan, walls, runs on each executor, resume, report."""

import json
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("gymnasium")
pytest.importorskip("mujoco")
pytest.importorskip("torch")

from pbicrl.experiments.icrl_run import (
    BUDGETS,
    Job,
    plan_jobs,
    run_benchmark,
    wall_config_text,
)

SMALL = {"n_envs": 2, "n_steps": 64, "minibatch_size": 64, "n_epochs": 1}
TINY = {"pendulum": {"ppo": 128, "ppo_lag_true": 128, "ppo_lag_inferred": 128}}
DOCS = Path(__file__).resolve().parents[2] / "docs" / "benchmarks" / "icrl"


def test_plan_is_seed_major_at_the_documented_budgets():
    jobs, skipped = plan_jobs(["pendulum", "ant"], seeds=2)
    assert [j.name for j in jobs[:8]] == [
        "pendulum:ppo:0:3000000", "pendulum:ppo_lag_true:0:2000000", "pendulum:ppo_lag_inferred:0:2000000",
        "pendulum:icl:0:2000000",
        "ant:ppo:0:3000000", "ant:ppo_lag_true:0:3000000", "ant:ppo_lag_inferred:0:3000000", "ant:icl:0:2500000"]
    assert len(jobs) == 16 and {j.seed for j in jobs[8:]} == {1} and skipped == []
    all_jobs, _ = plan_jobs(seeds=5)
    assert len(all_jobs) == 5 * 5 * 4
    assert sum(j.steps for j in all_jobs) == 5 * sum(sum(b.values()) for b in BUDGETS.values())
    assert [j.name for j in plan_jobs(["pendulum"], 1, ["ppo"], budgets=TINY)[0]] == ["pendulum:ppo:0:128"]


@pytest.mark.parametrize("kwargs, match", [
    ({"tasks": ["moon"]}, "unknown ICRL benchmark task"),
    ({"tasks": ["ant", "ant"]}, "tasks: listed twice"),
    ({"methods": ["sac"]}, "methods: unknown"),
    ({"seeds": 0}, "seeds: must be"),
    ({"methods": ["ppo", "ppo"]}, "methods: listed twice"),
    ({"tasks": ["ant", "pbicrl/BlockedAnt-v0"]}, r"tasks: listed twice: \['ant'\]"),
    ({"tasks": []}, "tasks: none given"),  # not "all five": --tasks "," must not start every run
    ({"methods": []}, "methods: none given"),
])
def test_plan_refuses_bad_input(kwargs, match):
    with pytest.raises(ValueError, match=match):
        plan_jobs(**kwargs)


def test_plan_skips_icl_on_a_task_without_icl_environment(monkeypatch):
    from pbicrl.experiments import icrl_benchmark

    monkeypatch.delitem(icrl_benchmark.ICL_TASKS, "pendulum")
    jobs, skipped = plan_jobs(["pendulum", "swimmer"], seeds=1, methods=["icl"])
    assert [j.name for j in jobs] == ["swimmer:icl:0:2000000"]
    assert skipped == ["pendulum/icl: no ICL environment for this task "
                       "(ICL runs on halfcheetah, ant, walker, swimmer)"]
    with pytest.raises(ValueError, match="nothing to run: pendulum/icl: no ICL environment"):
        plan_jobs(["pendulum"], seeds=1, methods=["icl"])


def test_job_is_validated():
    with pytest.raises(ValueError, match="steps: must be"):
        Job("ant", "ppo", 0, 0)
    with pytest.raises(ValueError, match="method: unknown"):
        Job("ant", "sac", 0, 10)
    with pytest.raises(ValueError, match="seed: must be"):
        Job("ant", "ppo", -1, 10)


@pytest.mark.parametrize("task", list(BUDGETS))
def test_wall_config_is_the_documented_one(task):
    """The TOML the command writes says what the committed configs say, on the side of the task's wall."""
    from pbicrl.envs.icrl_benchmark import icrl_task

    mine = tomllib.loads(wall_config_text(task))["constraints"]
    side = icrl_task(task).side
    assert mine == tomllib.loads((DOCS / f"wall_{side}.toml").read_text())["constraints"]
    assert mine[0]["direction"] == ("<=" if side == "behind" else ">=")


def _fake_wall(run):
    """A pbicrl infer run directory of a pendulum wall at x <= -0.004 (the good demonstrations' reach)."""
    from pbicrl.inference.data import Dataset

    run.mkdir(parents=True)
    x = np.array([0.0, -0.004, 0.002, 0.0, -0.02, -0.03])
    Dataset(features=np.ones((6, 1)), offsets=np.array([0, 3, 6]), group=np.array([1, 2]), states=x[:, None],
            feature_names=("bias_reward",)).save(run / "demos.npz")
    np.savez(run / "chains.npz", indicators=np.asarray([[0, 1]] * 3, dtype=np.int8)[None],
             penalty_weights=np.asarray([[0, -1.0]] * 3)[None], log_likelihood=np.zeros((1, 3)),
             feature_names=np.array(["bias_reward", "wall"]), parameters=np.asarray([[-0.03], [-0.02], [0.005]])[None],
             parameter_names=np.array(["wall.threshold"]))
    cons = [{"family": "axis_halfspace", "dims": [0], "name": "wall", "direction": "<="}]
    (run / "summary.json").write_text(json.dumps({
        "schema_version": 1, "method": "pbicrl", "feature_names": ["bias_reward", "wall"],
        "settings": {"constraints": cons}, "extra": {"data": {"path": str(run / "demos.npz")}}}))
    return run


@pytest.mark.parametrize("executor", ["serial", "local", pytest.param("ray", marks=pytest.mark.slow)])
def test_run_benchmark_trains_resumes_and_reports(tmp_path, executor):
    pytest.importorskip("matplotlib")
    if executor == "ray":
        pytest.importorskip("ray")  # a local instance, started and shut down by the call
    _fake_wall(tmp_path / "runs" / "infer" / "pendulum_wall")
    lines = []
    kw = {"tasks": ["pendulum"], "seeds": 1, "methods": ["ppo", "ppo_lag_true", "ppo_lag_inferred"],
          "executor": executor, "workers": 2, "budgets": TINY, "eval_every": 1, "config_overrides": SMALL}
    res = run_benchmark(tmp_path / "runs", report_dir=tmp_path / "rep", log=lines.append, **kw)
    assert [(o["job"], o["status"]) for o in res["jobs"]] == [
        ("pendulum:ppo:0:128", "done"), ("pendulum:ppo_lag_true:0:128", "done"),
        ("pendulum:ppo_lag_inferred:0:128", "done")]
    assert res["walls"] == {"pendulum": str(tmp_path / "runs" / "infer" / "pendulum_wall")}
    assert any("reusing" in s for s in lines)
    for m in ("ppo", "ppo_lag_true", "ppo_lag_inferred"):
        assert (tmp_path / "runs" / "pendulum" / m / "seed0" / "done.json").is_file()
    cfg = json.loads((tmp_path / "runs" / "pendulum" / "ppo_lag_inferred" / "seed0" / "config.json").read_text())
    assert cfg["inferred_cost"]["boundary"] == {"wall": [float(np.nextafter(-0.004, -1))]}
    md = (tmp_path / "rep" / "report.md").read_text()
    assert "| pendulum | PPO-Lagrangian, pbicrl inferred cost | 1 of 1 |" in md
    # the same command again: every run is already done, nothing retrains
    before = (tmp_path / "runs" / "pendulum" / "ppo" / "seed0" / "checkpoint.pt").stat().st_mtime_ns
    again = run_benchmark(tmp_path / "runs", log=None, **kw)
    assert {o["status"] for o in again["jobs"]} == {"done"} and again["report"] is None
    assert (tmp_path / "runs" / "pendulum" / "ppo" / "seed0" / "checkpoint.pt").stat().st_mtime_ns == before


def test_run_benchmark_leaves_a_locked_run_to_its_process_and_reports_failures(tmp_path, request):
    d = tmp_path / "runs" / "pendulum" / "ppo" / "seed0"
    d.mkdir(parents=True)
    other = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(120)"])
    request.addfinalizer(other.kill)
    (d / "lock").write_text(str(other.pid))  # a live process trains it
    kw = {"tasks": ["pendulum"], "seeds": 1, "executor": "serial", "budgets": TINY, "eval_every": 1, "log": None}
    res = run_benchmark(tmp_path / "runs", methods=["ppo"], config_overrides=SMALL, **kw)
    (o,) = res["jobs"]
    assert o["status"] == "busy" and "being trained by process" in o["error"]
    assert not (d / "checkpoint.pt").exists() and (d / "lock").read_text() == str(other.pid)  # left alone
    res = run_benchmark(tmp_path / "runs", methods=["ppo_lag_true"], config_overrides={"n_envs": 0}, **kw)
    (o,) = res["jobs"]
    assert o["status"] == "failed" and "n_envs" in o["error"]


def test_run_benchmark_refuses_bad_settings(tmp_path):
    with pytest.raises(ValueError, match="executor: unknown"):
        run_benchmark(tmp_path, executor="dask")
    with pytest.raises(ValueError, match="workers: must be"):
        run_benchmark(tmp_path, workers=0)


def test_an_unconverged_wall_is_not_used(tmp_path):
    from pbicrl.experiments.icrl_run import infer_wall

    run = _fake_wall(tmp_path / "pendulum_wall")
    assert infer_wall("pendulum", tmp_path) == run  # reused as it is
    summary = json.loads((run / "summary.json").read_text())
    (run / "summary.json").write_text(json.dumps({**summary, "converged": False}))
    with pytest.raises(RuntimeError, match="did not converge"):
        infer_wall("pendulum", tmp_path)
    with pytest.raises(RuntimeError, match="did not converge"):
        run_benchmark(tmp_path / "runs", tasks=["pendulum"], seeds=1, methods=["ppo_lag_inferred"],
                      infer_dir=tmp_path, budgets=TINY, log=None)
    assert not (tmp_path / "runs" / "pendulum").exists()  # refused before any training


def test_cli_run_dry_run_lists_the_plan(capsys):
    from pbicrl.cli.app import main

    assert main(["benchmark", "icrl", "run", "--out", "unused", "--tasks", "swimmer", "--seeds", "2", "--dry-run"]) == 0
    out = capsys.readouterr().out
    assert "swimmer:ppo_lag_inferred:1:2000000" in out and "swimmer:icl:1:2000000" in out
    assert "8 runs, 18.0 M environment steps in all" in out and "left out" not in out
    assert not Path("unused").exists()
    assert main(["benchmark", "icrl", "run", "--out", "x", "--methods", "sac", "--dry-run"]) == 2
    assert "methods: unknown" in capsys.readouterr().err
    assert main(["benchmark", "icrl", "run", "--out", "x", "--tasks", ",", "--dry-run"]) == 2
    assert "tasks: none given" in capsys.readouterr().err
    assert not Path("x").exists()


@pytest.mark.slow
def test_infer_wall_on_the_shipped_ant_demonstrations(tmp_path):
    """The real inference: the conservative boundary is the good demonstrations' reach, 0.047 short of -3."""
    from pbicrl.experiments.icrl_run import infer_wall

    run = infer_wall("ant", tmp_path, jobs=1)
    s = json.loads((run / "summary.json").read_text())
    assert s["converged"] is True
    assert (tmp_path / "ant_wall.toml").read_text() == wall_config_text("ant")
    assert infer_wall("ant", tmp_path) == run  # reused, not inferred again


def test_a_wall_with_unusable_draws_is_not_saved(tmp_path, monkeypatch):
    """The library path refuses NaN draws as the command line does (nothing written under the infer directory)."""
    import dataclasses
    import warnings

    import pbicrl.api
    from pbicrl.experiments.icrl_run import infer_wall
    from pbicrl.inference.posterior import Posterior

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        post = Posterior.load(_fake_wall(tmp_path / "fake"), issue_warnings=False)
    w = np.array(post.penalty_weights, dtype=np.float64)
    w[0, 1, 1] = np.nan
    bad = dataclasses.replace(post, penalty_weights=w)
    assert bad.converged is not False
    monkeypatch.setattr(pbicrl.api, "infer_from_config", lambda *a, **k: bad)
    with pytest.raises(ValueError, match="penalty_weights: 1 of 6 values .* NaN or infinite"):
        infer_wall("pendulum", tmp_path / "infer")
    assert not (tmp_path / "infer" / "pendulum_wall").exists()
    post.require_usable_draws()  # the same draws without the NaN pass
