"""ICRL benchmark: ranked demonstrations (groups by what an episode did), ppo_lag_inferred, and the report."""

from __future__ import annotations

import json

import numpy as np
import pytest

pytest.importorskip("torch")
pytest.importorskip("gymnasium")
pytest.importorskip("mujoco")

from pbicrl.experiments.icrl_benchmark import train_policy  # noqa: E402
from pbicrl.experiments.icrl_demos import (  # noqa: E402
    DemoRules,
    classify_episode,
    generate_ranked_demos,
)
from pbicrl.experiments.icrl_report import build_report, curve_series, plateau, seed_metrics  # noqa: E402

SMALL = dict(n_envs=2, n_steps=64, minibatch_size=64, n_epochs=1)


def test_groups_follow_the_number_of_violating_steps():
    rules = DemoRules.for_task("halfcheetah")
    assert (rules.brief_max_steps, rules.through_min_steps) == (100, 500)
    assert [classify_episode(n, rules) for n in (0, 1, 100, 101, 499, 500, 1000)] == [1, 2, 2, 0, 0, 3, 3]
    assert DemoRules.for_task("pendulum") == DemoRules(10, 50)
    with pytest.raises(ValueError, match="through_min_steps"):
        DemoRules(10, 10)
    with pytest.raises(ValueError, match="brief_max_steps"):
        DemoRules(0, 5)


@pytest.fixture(scope="module")
def pendulum_policies(tmp_path_factory):
    """Two barely trained pendulum policies (their episodes cross the wall x < -0.015 now and then)."""
    out = tmp_path_factory.mktemp("runs")
    a = train_policy("pendulum", "ppo_lag_true", 0, out, 128, config_overrides=SMALL, eval_every=1, eval_episodes=1,
                     log=None)
    b = train_policy("pendulum", "ppo", 1, out, 128, config_overrides=SMALL, eval_every=1, eval_episodes=1, log=None)
    return a / "best.pt", b / "checkpoint.pt"


def test_ranked_demos_label_by_behaviour_and_are_reproducible(pendulum_policies, tmp_path):
    from pbicrl.inference.data import load_dataset

    expert, unconstrained = pendulum_policies
    rules = DemoRules(2, 4)
    generate_ranked_demos("pendulum", expert, unconstrained, tmp_path / "d.npz", n_per_group=3, seed=5, rules=rules,
                          max_episodes=400, command="test")
    back = load_dataset(tmp_path / "d.npz")
    assert list(back.group) == [1, 1, 1, 2, 2, 2, 3, 3, 3] and back.actions is None
    assert back.states.shape[1] == 1 and back.feature_names == ("bias_reward",)
    off = back.offsets
    for i, g in enumerate(back.group):  # each stored episode's label is what its x did with the wall
        n_v = int(np.sum(back.states[off[i]:off[i + 1], 0] < -0.015))
        assert classify_episode(n_v, rules) == g
    side = json.loads((tmp_path / "d.json").read_text())
    assert side["command"] == "test" and side["policies"]["expert"]["steps"] == 128
    assert len(side["policies"]["expert"]["sha256"]) == 64
    assert side["policies"]["handover"]["sha256"] == side["policies"]["unconstrained"]["sha256"]  # the default
    assert side["groups"]["2"]["violating_steps_max"] <= 2 and side["groups"]["3"]["violating_steps_min"] >= 4
    assert sum(e["kept"] for e in side["episodes"]) == 9
    assert side["file_sha256"] and side["file_bytes"] == (tmp_path / "d.npz").stat().st_size
    _, again = generate_ranked_demos("pendulum", expert, unconstrained, None, n_per_group=3, seed=5, rules=rules,
                                     max_episodes=400, command="test")
    assert again["episodes"] == side["episodes"]  # the same seed: the same episodes
    _, other = generate_ranked_demos("pendulum", expert, unconstrained, None, handover=expert, n_per_group=3,
                                     seed=5, rules=rules, max_episodes=400)
    assert other["policies"]["handover"]["sha256"] == side["policies"]["expert"]["sha256"]
    switch = [e for e in other["episodes"] if e["source"] == "switch"]
    assert switch and switch != [e for e in side["episodes"] if e["source"] == "switch"][:len(switch)]


def test_unfilled_groups_fail_and_write_nothing(pendulum_policies, tmp_path):
    expert, unconstrained = pendulum_policies
    with pytest.raises(ValueError, match="groups: not filled after 3 episodes"):
        generate_ranked_demos("pendulum", expert, unconstrained, tmp_path / "d.npz", n_per_group=50,
                              max_episodes=3)
    assert not list(tmp_path.iterdir())
    with pytest.raises(ValueError, match="sources"):
        generate_ranked_demos("pendulum", expert, unconstrained, None, sources=["teleport"])
    with pytest.raises(ValueError, match="policy: .* is not a file"):
        generate_ranked_demos("pendulum", tmp_path / "none.pt", unconstrained, None)


def _write_run(path, names, ind, wp, params, constraints, data=None):
    path.mkdir(parents=True)
    np.savez(path / "chains.npz", indicators=np.asarray(ind, dtype=np.int8)[None],
             penalty_weights=np.asarray(wp, dtype=np.float64)[None], log_likelihood=np.zeros((1, len(ind))),
             feature_names=np.array(names), parameters=np.asarray(params, dtype=np.float64)[None],
             parameter_names=np.array(["wall.threshold"]))
    summary = {"schema_version": 1, "method": "pbicrl", "feature_names": list(names),
               "settings": {"constraints": constraints}}
    if data is not None:
        summary["extra"] = {"data": {"path": str(data)}}
    (path / "summary.json").write_text(json.dumps(summary))
    return path


def test_ppo_lag_inferred_trains_on_the_conservative_boundary(tmp_path):
    import gymnasium as gym

    from pbicrl.envs import register_envs
    from pbicrl.envs.inferred_cost import InferredConstraintCost
    from pbicrl.inference.data import Dataset

    cons = [{"family": "axis_halfspace", "dims": [0], "name": "wall", "direction": "<="}]
    # the good demonstrations reach x = -0.004; a bad one goes to -0.03 (pendulum wall: x < -0.015)
    x = np.array([0.0, -0.004, 0.002, 0.0, -0.02, -0.03])
    Dataset(features=np.ones((6, 1)), offsets=np.array([0, 3, 6]), group=np.array([1, 2]), states=x[:, None],
            feature_names=("bias_reward",)).save(tmp_path / "demos.npz")
    args = (("bias_reward", "wall"), [[0, 1]] * 3, [[0, -1.0]] * 3, [[-0.03], [-0.02], [0.005]], cons)
    run = _write_run(tmp_path / "inf", *args, data=tmp_path / "demos.npz")
    register_envs()
    icc = InferredConstraintCost(gym.make("pbicrl/BiasedPendulum-v0"), run)  # the task's own features and x
    assert icc.mode == "conservative"
    edge = float(np.nextafter(-0.004, -1))
    assert icc.conservative_location["wall"][0] == edge  # just beyond the good demonstrations' reach
    np.testing.assert_array_equal(icc.costs(states=[[-0.005], [-0.004]]), [1.0, 0.0])

    out = tmp_path / "runs"
    d = train_policy("pendulum", "ppo_lag_inferred", 0, out, 128, config_overrides=SMALL, eval_every=1,
                     eval_episodes=1, log=None, inferred_run=run)
    cfg = json.loads((d / "config.json").read_text())
    ic = cfg["inferred_cost"]
    assert ic["mode"] == "conservative" and ic["boundary"] == {"wall": [edge]} and len(ic["summary_sha256"]) == 64
    assert "good demonstrations" in cfg["inferred_boundary_source"]["wall"]
    assert (d / "done.json").exists()
    rows = [json.loads(s) for s in (d / "curve.jsonl").read_text().splitlines()]
    assert all(r["constraint"] == int(r["x_min"] < -0.015) for r in rows)  # the metrics keep the true wall
    # another posterior on the same run directory is refused
    s = json.loads((run / "summary.json").read_text())
    s["note"] = "changed"
    (run / "summary.json").write_text(json.dumps(s))
    with pytest.raises(ValueError, match="other settings.*inferred_cost"):
        train_policy("pendulum", "ppo_lag_inferred", 0, out, 256, config_overrides=SMALL, log=None,
                     inferred_run=run)
    # without the run's dataset the boundary would be the posterior's highest draw (0.005: the start): refused
    lost = _write_run(tmp_path / "lost", *args, data=tmp_path / "gone.npz")
    with pytest.raises(ValueError, match=r"not from the good demonstrations \(boundary \{'wall': 0.005\}\)"):
        train_policy("pendulum", "ppo_lag_inferred", 2, out, 128, log=None, inferred_run=lost)
    assert not (out / "pendulum" / "ppo_lag_inferred" / "seed2").exists()
    with pytest.raises(ValueError, match="inferred_run: method ppo_lag_inferred needs"):
        train_policy("pendulum", "ppo_lag_inferred", 1, out, 128, log=None)
    with pytest.raises(ValueError, match="inferred_run: only for"):
        train_policy("pendulum", "ppo", 1, out, 128, log=None, inferred_run=run)


def _fake_seed(d, evals, curve=(), done=True, steps=1000, wall_s=7200.0, config=None):
    d.mkdir(parents=True)
    rows = [{"steps": steps, "episodes": [{"reward": r, "reward_nc": rnc, "constraint": c} for r, rnc, c in ev]}
            for ev in evals]
    (d / "eval.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    (d / "curve.jsonl").write_text("".join(json.dumps({"reward": r, "reward_nc": rnc, "constraint": c}) + "\n"
                                           for r, rnc, c in curve))
    (d / ("done.json" if done else "progress.json")).write_text(json.dumps({"steps": steps, "wall_s": wall_s}))
    if config is not None:
        (d / "config.json").write_text(json.dumps(config))


def test_report_on_synthetic_runs(tmp_path):
    runs = tmp_path / "runs"
    hc = runs / "halfcheetah"
    old = [(5.0, 5.0, 0)]  # an earlier evaluation: not used
    _fake_seed(hc / "ppo" / "seed0", [old, [(100.0, 10.0, 1), (80.0, 20.0, 1)]], curve=[(1.0, 0.5, 1)] * 3)
    _fake_seed(hc / "ppo" / "seed1", [[(90.0, 30.0, 1), (70.0, 70.0, 0)]])
    _fake_seed(hc / "ppo_lag_true" / "seed0", [[(50.0, 50.0, 0), (60.0, 60.0, 0)]])
    _fake_seed(hc / "ppo_lag_inferred" / "seed0", [[(1.0, 1.0, 0)]], done=False, steps=500,
               config={"inferred_cost": {"mode": "conservative", "boundary": {"wall": [-0.4]}}})
    m = seed_metrics(hc / "ppo" / "seed0")
    assert m["violation_rate"] == 1.0 and m["feasible_reward"] == 15.0 and m["train_feasible_reward"] == 0.5
    res = build_report(runs, tmp_path / "out", tasks=["halfcheetah", "ant"], seeds_planned=3)
    ppo = res["tasks"]["halfcheetah"]["ppo"]
    assert ppo["seeds_done"] == 2
    assert ppo["violation_rate"][0] == pytest.approx(0.75)  # seeds: 1.0 and 0.5
    assert ppo["feasible_reward"] == pytest.approx((32.5, np.std([15.0, 50.0], ddof=1)))
    assert res["tasks"]["halfcheetah"]["ppo_lag_true"]["violation_rate"] == (0.0, 0.0)
    missing = {(r["task"], r["method"]) for r in res["missing"]}
    assert ("halfcheetah", "ppo_lag_inferred") in missing and ("halfcheetah", "icl") in missing
    assert {("ant", m) for m in ("ppo", "ppo_lag_true", "ppo_lag_inferred", "icl")} <= missing
    assert res["in_progress"] == [{"task": "halfcheetah", "method": "ppo_lag_inferred", "seed": "seed0", "steps": 500}]
    md = (tmp_path / "out" / "report.md").read_text()
    assert "**2 of 8 rows** (2 tasks x 4 methods)" in md and "**Missing rows**" in md
    assert "| halfcheetah | PPO-Lagrangian, pbicrl inferred cost (no finished seed); ICL baseline (no run directory) |" in md
    assert "at 500 steps" in md
    assert "| halfcheetah | PPO (no constraint) | 2 of 3 | 1,000 | 0.75 ± 0.35 | 32 ± 25 |" in md
    assert "| halfcheetah | PPO-Lagrangian, true cost | 1 of 3 | 1,000 | 0.00 | 55 |" in md  # one seed: no sd
    pytest.importorskip("matplotlib")
    assert (tmp_path / "out" / "figures" / "icrl_halfcheetah.png").stat().st_size > 1000
    assert "![halfcheetah](figures/icrl_halfcheetah.png)" in md
    # learning curves: every evaluation of every seed (finished or not), for a reader to see convergence
    assert ppo["per_seed"]["seed0"]["eval_curve"] == {"steps": [1000, 1000], "violation_rate": [0.0, 1.0],
                                                      "feasible_reward": [5.0, 15.0]}
    assert res["tasks"]["halfcheetah"]["ppo_lag_inferred"]["per_seed"]["seed0"]["eval_curve"]["steps"] == [500]
    assert (tmp_path / "out" / "figures" / "icrl_halfcheetah_curves.png").stat().st_size > 1000
    assert "![halfcheetah curves](figures/icrl_halfcheetah_curves.png)" in md and "Learning curves" in md


def test_curve_mean_is_over_finished_seeds_only():
    """A seed still training neither cuts the thick mean short nor enters it; the label counts both kinds."""
    def seed(steps, feas, done):
        return {"done": done, "eval_curve": {"steps": steps, "feasible_reward": feas,
                                             "violation_rate": [0.0] * len(steps)}}
    rows = {"ppo_lag_true": {"per_seed": {"seed0": seed([1, 2, 3], [10.0, 20.0, 30.0], True),
                                          "seed1": seed([1, 2, 3], [30.0, 40.0, 50.0], True),
                                          "seed2": seed([1], [1000.0], False)}},
            "icl": {"per_seed": {"seed0": seed([1, 2], [5.0, 6.0], False)}},
            "ppo": {"per_seed": {"seed0": {"done": False}}}}  # nothing evaluated yet: not drawn
    by = {s["method"]: s for s in curve_series(rows)}
    assert set(by) == {"ppo_lag_true", "icl"}
    assert by["ppo_lag_true"]["mean"] == {"steps": [1, 2, 3], "feasible_reward": [20.0, 30.0, 40.0],
                                          "violation_rate": [0.0, 0.0, 0.0]}
    assert len(by["ppo_lag_true"]["in_progress"]) == 1
    assert by["ppo_lag_true"]["label"] == "PPO-Lagrangian, true cost (2 seeds, 1 in progress)"
    assert by["icl"]["mean"] is None and by["icl"]["label"] == "ICL baseline (no finished seed, 1 in progress)"


def _curve(steps, feas, done=True):
    return {"done": done, "eval_curve": {"steps": list(steps), "feasible_reward": list(feas),
                                         "violation_rate": [0.0] * len(steps)}}


def test_plateau_compares_the_last_fifth_of_the_steps_with_the_fifth_before():
    steps = range(10, 101, 10)  # windows (80, 100] and (60, 80]: evaluations 90, 100 and 70, 80
    rising = _curve(steps, [1, 2, 3, 4, 5, 6, 100, 100, 120, 120])  # 120 against 100: +20%
    flat = _curve(steps, [1, 2, 3, 4, 5, 6, 100, 98, 101, 101])  # 101 against 99: +2%
    p = plateau({"seed0": rising})
    assert (p["last"], p["before"], p["seeds"]) == (120.0, 100.0, 1)
    assert p["change"] == pytest.approx(0.2) and p["stable"] is False
    p = plateau({"seed0": flat})
    assert p["change"] == pytest.approx(2 / 99) and p["stable"] is True
    # averaged over the finished seeds; a run in progress is left out
    p = plateau({"a": rising, "b": flat, "c": _curve(steps, [0] * 6 + [1, 1, 1000, 1000], done=False)})
    assert (p["last"], p["before"], p["seeds"]) == (110.5, 99.5, 2)
    assert plateau({"seed0": rising}, tol=0.25)["stable"] is True
    # a falling reward beyond the tolerance is not stable either
    assert plateau({"seed0": _curve(steps, [0] * 6 + [100, 100, 50, 50])})["stable"] is False
    # nothing to compare: a single evaluation, or nothing finished
    assert plateau({"seed0": _curve([100], [5.0])}) is None
    assert plateau({"seed0": _curve(steps, [1.0] * 10, done=False)}) is None
    assert plateau({"seed0": {"done": True}}) is None
    assert np.isnan(plateau({"seed0": _curve(steps, [0.0] * 10)})["change"])
    with pytest.raises(ValueError, match="window"):
        plateau({}, window=0.6)
    with pytest.raises(ValueError, match="tol"):
        plateau({}, tol=-1)


def test_report_says_whether_the_expert_stopped_improving(tmp_path):
    runs = tmp_path / "runs"
    for k, feas in enumerate(([10.0, 10.0, 10.0, 10.0, 20.0], [10.0, 10.0, 10.0, 12.0, 24.0])):
        d = runs / "swimmer" / "ppo_lag_true" / f"seed{k}"
        _fake_seed(d, [[(f, f, 0)] for f in feas])
        (d / "eval.jsonl").write_text("".join(json.dumps({"steps": 200 * (i + 1), "episodes": [
            {"reward": f, "reward_nc": f, "constraint": 0}]}) + "\n" for i, f in enumerate(feas)))
    res = build_report(runs, tmp_path / "out", tasks=["swimmer"], seeds_planned=2, figures=False)
    p = res["tasks"]["swimmer"]["ppo_lag_true"]["plateau"]
    assert (p["last"], p["before"], p["stable"]) == (22.0, 11.0, False)
    md = (tmp_path / "out" / "report.md").read_text()
    assert "Had the policies stopped improving?" in md
    assert "| swimmer | PPO-Lagrangian, true cost | 2 | 22 | 11 | +100.0% | no, still rising |" in md
    assert "**1 of 4 rows** (1 task x 4 methods)" in md
    _fake_seed(runs / "halfcheetah" / "ppo_lag_true" / "seed0", [[(1.0, 1.0, 0)]])
    _fake_seed(runs / "halfcheetah" / "ppo_lag_inferred" / "seed0", [[(1.0, 1.0, 0)]],
               config={"inferred_cost": {"mode": "conservative", "boundary": {"wall": [-2.8]}}})
    build_report(runs, tmp_path / "out", tasks=["halfcheetah"], methods=["ppo_lag_true", "ppo_lag_inferred"],
                 figures=False)
    md = (tmp_path / "out" / "report.md").read_text()
    assert "**2 of 2 rows** (1 task x 2 methods)" in md
    assert "| halfcheetah | -2.800 vs -3: safe side by 0.200 (met) | +0.00 (met) | 1.00 (met) | - (ICL not in this " \
           "report) |" in md


def test_report_names_the_runs_path_as_given(tmp_path, monkeypatch):
    """A committed report says where to rerun it (the relative path), not the machine's absolute path."""
    monkeypatch.chdir(tmp_path)
    _fake_seed(tmp_path / "training" / "icrl" / "halfcheetah" / "ppo" / "seed0", [[(1.0, 1.0, 0)]])
    res = build_report("training/icrl", "out", tasks=["halfcheetah"], seeds_planned=1, figures=False)
    assert res["runs"] == "training/icrl"
    md = (tmp_path / "out" / "report.md").read_text()
    assert "from the training runs in `training/icrl`." in md and str(tmp_path) not in md


def test_report_names_a_started_run_without_progress(tmp_path):
    """A run directory with nothing recorded yet is listed as started, not as 'at None steps'."""
    runs = tmp_path / "runs"
    _fake_seed(runs / "halfcheetah" / "ppo" / "seed0", [[(1.0, 1.0, 0)]])
    (runs / "halfcheetah" / "ppo_lag_true" / "seed0").mkdir(parents=True)
    (runs / "halfcheetah" / "ppo_lag_true" / "seed0" / "config.json").write_text("{}")
    res = build_report(runs, tmp_path / "out", tasks=["halfcheetah"], seeds_planned=1)
    assert res["in_progress"] == [{"task": "halfcheetah", "method": "ppo_lag_true", "seed": "seed0", "steps": None}]
    md = (tmp_path / "out" / "report.md").read_text()
    assert "halfcheetah / ppo_lag_true / seed0 started, no progress recorded yet" in md and "None" not in md


def test_report_refuses_bad_input(tmp_path):
    with pytest.raises(ValueError, match="runs: .* is not a directory"):
        build_report(tmp_path / "none", tmp_path / "out")
    (tmp_path / "r" / "halfcheetah" / "ppo" / "seed0").mkdir(parents=True)
    (tmp_path / "r" / "halfcheetah" / "ppo" / "seed0" / "eval.jsonl").write_text("{not json\n")
    with pytest.raises(ValueError, match="line 1 is not JSON"):
        build_report(tmp_path / "r", tmp_path / "out")
    assert not (tmp_path / "out").exists()
    with pytest.raises(ValueError, match="methods: unknown"):
        build_report(tmp_path / "r", tmp_path / "out", methods=["sac"])
    # empty is refused, not read as "all" (tasks) or as a report with no rows (methods)
    with pytest.raises(ValueError, match="tasks: none given"):
        build_report(tmp_path / "r", tmp_path / "out", tasks=[])
    with pytest.raises(ValueError, match="methods: none given"):
        build_report(tmp_path / "r", tmp_path / "out", methods=[])
    with pytest.raises(ValueError, match=r"methods: listed twice: \['ppo'\]"):
        build_report(tmp_path / "r", tmp_path / "out", methods=["ppo", "icl", "ppo"])
    with pytest.raises(ValueError, match=r"tasks: listed twice: \['halfcheetah'\]"):
        build_report(tmp_path / "r", tmp_path / "out", tasks=["halfcheetah", "halfcheetah"])
    assert not (tmp_path / "out").exists()


def test_cli_benchmark_icrl(tmp_path, capsys):
    from pbicrl.cli.app import main

    runs = tmp_path / "runs"
    _fake_seed(runs / "pendulum" / "ppo" / "seed0", [[(1.0, 1.0, 0)]])
    assert main(["benchmark", "icrl", "report", "--runs", str(runs), "--out", str(tmp_path / "o"), "--tasks",
                 "pendulum", "--no-figures"]) == 0
    assert "missing rows: 3" in capsys.readouterr().out
    assert main(["benchmark", "icrl", "report", "--runs", str(runs), "--out", str(tmp_path / "o"), "--tasks",
                 "pendulum", "--methods", "ppo,ppo_lag_true", "--no-figures"]) == 0
    assert "missing rows: 1" in capsys.readouterr().out
    assert main(["benchmark", "icrl", "report", "--runs", str(runs), "--methods", "sac"]) == 2
    assert "methods: unknown ['sac']" in capsys.readouterr().err
    assert main(["benchmark", "icrl", "report", "--runs", str(runs), "--methods", ","]) == 2
    assert "methods: none given" in capsys.readouterr().err
    assert main(["benchmark", "icrl", "report", "--runs", str(runs), "--tasks", " , "]) == 2
    assert "tasks: none given" in capsys.readouterr().err
    assert main(["benchmark", "icrl", "train", "--out", str(runs), "--run", "pendulum:ppo_lag_inferred:0:100"]) == 2
    assert "--inferred-run" in capsys.readouterr().err


def test_run_status_tells_done_training_stopped_and_started(tmp_path, capsys):
    import os
    import subprocess
    import sys

    from pbicrl.cli.app import main
    from pbicrl.experiments.icrl_report import run_status

    runs = tmp_path / "runs"
    _fake_seed(runs / "ant" / "ppo" / "seed0", [[(5.0, 5.0, 1)]], steps=3000, wall_s=60.0)
    for k in (1, 2):  # seed1 trains (a live process holds its lock), seed2 was stopped (its process is gone)
        d = runs / "ant" / "ppo" / f"seed{k}"
        _fake_seed(d, [[(1.0, 1.0, 0)]], done=False, steps=1000, wall_s=100.0)
        (d / "progress.json").write_text(json.dumps({"steps": 1000, "wall_s": 100.0, "total_steps_target": 4000}))
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    (runs / "ant" / "ppo" / "seed1" / "lock").write_text(str(os.getpid()))
    (runs / "ant" / "ppo" / "seed2" / "lock").write_text(str(dead.pid))
    (runs / "ant" / "icl" / "seed0").mkdir(parents=True)
    rows = {r["run"]: r for r in run_status(runs)}
    assert {k: r["state"] for k, r in rows.items()} == {
        "ant/ppo/seed0": "done", "ant/ppo/seed1": "training", "ant/ppo/seed2": "stopped", "ant/icl/seed0": "started"}
    assert rows["ant/ppo/seed1"]["eta_s"] == pytest.approx(300.0)  # 3000 steps left at 0.1 s per step
    assert rows["ant/ppo/seed2"]["eta_s"] is None and rows["ant/ppo/seed0"]["target"] == 3000
    assert rows["ant/ppo/seed0"]["violation_rate"] == 1.0 and rows["ant/icl/seed0"]["feasible_reward"] is None
    assert main(["benchmark", "icrl", "status", "--runs", str(runs)]) == 0
    out = capsys.readouterr().out
    assert "4 runs: 1 done, 1 training, 1 stopped" in out and "0.08" in out  # 300 s left = 0.08 h
    assert main(["benchmark", "icrl", "status", "--runs", str(tmp_path / "none")]) == 2
    assert "runs: " in capsys.readouterr().err


def test_shipped_halfcheetah_demos_match_their_record_and_rules():
    import hashlib

    import pbicrl
    from pbicrl.inference.data import shipped_dir

    path = shipped_dir() / "icrl_halfcheetah.npz"
    rec = json.loads(path.with_suffix(".json").read_text())
    assert hashlib.sha256(path.read_bytes()).hexdigest() == rec["file_sha256"]
    ds = pbicrl.load_dataset("icrl_halfcheetah")
    assert ds.env_id == "pbicrl/BlockedHalfCheetah-v0" and ds.feature_names == ("speed", "action_sq_norm")
    assert list(np.bincount(ds.group)[1:]) == [100, 100, 100]
    rules = DemoRules(rec["rules"]["brief_max_steps"], rec["rules"]["through_min_steps"])
    off, x = ds.offsets, ds.states[:, 0]
    n_v = np.array([np.sum(x[off[i]:off[i + 1]] < -3.0) for i in range(ds.n_trajectories)])
    assert [classify_episode(n, rules) for n in n_v] == list(ds.group)  # labelled by what each episode did
    assert n_v[ds.group == 3].min() >= 500  # group 3 really runs through the wall
    dx = np.abs(np.diff(x))  # the stored speed is |dx| / dt (dt 0.05) of the stored x, within an episode
    inner = np.setdiff1d(np.arange(1, len(x)), off[1:-1])
    np.testing.assert_array_equal(ds.features[inner, 0], dx[inner - 1] / 0.05)


@pytest.mark.parametrize("name, env_id", [("icrl_halfcheetah", "pbicrl/BlockedHalfCheetah-v0"),
                                          ("icrl_ant", "pbicrl/BlockedAnt-v0"),
                                          ("icrl_walker", "pbicrl/BlockedWalker-v0"),
                                          ("icrl_pendulum", "pbicrl/BiasedPendulum-v0"),
                                          ("icrl_swimmer", "pbicrl/BlockedSwimmer-v0")])
def test_every_shipped_wall_dataset_matches_its_record_and_rules(name, env_id):
    """Each shipped ICRL demonstration set is the file its record describes, 100 per group, each episode labelled by
    the number of its steps beyond the task's wall (x < -3 after the step; the pendulum's x < -0.015, the swimmer's
    x > 0.5), never by the policy that made it."""
    from pbicrl.envs.icrl_benchmark import icrl_task

    import hashlib

    import pbicrl
    from pbicrl.inference.data import shipped_dir

    path = shipped_dir() / f"{name}.npz"
    rec = json.loads(path.with_suffix(".json").read_text())
    assert hashlib.sha256(path.read_bytes()).hexdigest() == rec["file_sha256"]
    ds = pbicrl.load_dataset(name)
    assert ds.env_id == env_id and rec["env_id"] == env_id
    spec = icrl_task(env_id)
    assert rec["wall"]["threshold"] == spec.wall and rec["wall"]["side"] == spec.side
    assert list(np.bincount(ds.group)[1:]) == [100, 100, 100]
    rules = DemoRules(rec["rules"]["brief_max_steps"], rec["rules"]["through_min_steps"])
    off, x = ds.offsets, ds.states[:, 0]
    n_v = np.array([np.sum(spec.cost(x[off[i]:off[i + 1]])) for i in range(ds.n_trajectories)])
    assert [classify_episode(n, rules) for n in n_v] == list(ds.group)
    assert n_v[ds.group == 1].max() == 0 and n_v[ds.group == 2].min() >= 1
    assert n_v[ds.group == 3].min() >= rec["rules"]["through_min_steps"]


def test_report_checks_the_issue_targets_per_task(tmp_path):
    """The targets table: boundary on the safe side (or within 0.1), violation at most 0.05 above the true cost's,
    feasible reward at least 90% of it, and at least ICL's on both metrics."""
    runs = tmp_path / "runs"
    hc = runs / "halfcheetah"
    _fake_seed(hc / "ppo_lag_true" / "seed0", [[(100.0, 100.0, 0), (100.0, 100.0, 0)]])
    _fake_seed(hc / "ppo_lag_inferred" / "seed0", [[(85.0, 85.0, 0), (85.0, 85.0, 1)]],
               config={"inferred_cost": {"mode": "conservative", "boundary": {"wall": [-3.05]}}})
    _fake_seed(hc / "icl" / "seed0", [[(50.0, 50.0, 1), (60.0, 60.0, 0)]])
    build_report(runs, tmp_path / "out", tasks=["halfcheetah"], figures=False)
    md = (tmp_path / "out" / "report.md").read_text()
    row = next(ln for ln in md.splitlines() if ln.startswith("| halfcheetah | -3.050"))
    # -3.05 is 0.05 beyond the true x < -3 (within 0.1: met); violation 0.5 vs 0 (missed); 85 / 100 (missed);
    # against ICL 0.5 vs 0.5 and 85 vs 55 (met)
    assert row == ("| halfcheetah | -3.050 vs -3: unsafe side by 0.050 (met) | +0.50 (missed) | 0.85 (missed) | "
                   "0.50 vs 0.50, 85 vs 55 (met) |"), row


@pytest.mark.parametrize("task, bound, text", [
    ("pendulum", -0.01466, "-0.01466 vs -0.015: safe side by 0.00034 (met)"),
    ("swimmer", 0.49866, "0.4987 vs 0.5: safe side by 0.0013 (met)"),  # a wall in front: smaller is safer
    ("swimmer", 0.53, "0.5300 vs 0.5: unsafe side by 0.0300 (met)")])
def test_report_resolves_a_boundary_on_its_walls_scale(tmp_path, task, bound, text):
    """The pendulum's wall is at -0.015: three decimals would print its boundary as the wall itself."""
    runs = tmp_path / "runs"
    _fake_seed(runs / task / "ppo_lag_true" / "seed0", [[(10.0, 10.0, 0)]])
    _fake_seed(runs / task / "ppo_lag_inferred" / "seed0", [[(10.0, 10.0, 0)]],
               config={"inferred_cost": {"mode": "conservative", "boundary": {"wall": [bound]}}})
    build_report(runs, tmp_path / "out", tasks=[task], figures=False)
    md = (tmp_path / "out" / "report.md").read_text()
    assert f"| {task} | {text} | +0.00 (met) | 1.00 (met) | - (no finished ICL seed) |" in md, md
    # ICL's learned wall on the same scale
    icl = runs / task / "icl" / "seed0"
    _fake_seed(icl, [[(10.0, 10.0, 0)]])
    (icl / "done.json").write_text(json.dumps({"steps": 1000, "wall_s": 60.0, "icl_location": bound}))
    build_report(runs, tmp_path / "out", tasks=[task], figures=False)
    md = (tmp_path / "out" / "report.md").read_text()
    rel, true = ("<", "< -0.015") if task == "pendulum" else (">=", "> 0.5")
    assert f"| {task} | x {rel} {text.split(' vs ')[0]} | 1 of 1 | x {true} |" in md, md
    assert f"| {task} | {text} | +0.00 (met) | 1.00 (met) | 0.00 vs 0.00, 10 vs 10 (met) |" in md, md


def test_a_finished_run_being_extended_counts_as_in_progress(tmp_path):
    """A larger STEPS resumes a finished run: its done.json stays until the new target, while progress.json and the
    evaluations move on; the report must not mix the old step count with the new evaluations."""
    runs = tmp_path / "runs"
    d = runs / "pendulum" / "ppo_lag_true" / "seed0"
    _fake_seed(d, [[(1.0, 1.0, 1)]], steps=1000)
    (d / "progress.json").write_text(json.dumps({"steps": 1000, "wall_s": 1.0}))
    assert seed_metrics(d)["done"]  # finished: progress at the same steps
    (d / "progress.json").write_text(json.dumps({"steps": 5000, "wall_s": 9.0}))
    m = seed_metrics(d)
    assert not m["done"] and m["steps"] == 5000
    res = build_report(runs, tmp_path / "out", tasks=["pendulum"], figures=False)
    assert res["in_progress"] == [{"task": "pendulum", "method": "ppo_lag_true", "seed": "seed0", "steps": 5000}]


def test_switch_hands_over_within_the_tasks_window():
    """The switch source's hand-over point lies within ``handover_range`` of the wall: 0.01 for the pendulum
    (whose wall is at -0.015: a U(-1, 1) window would hand over at the start of every episode)."""
    from pbicrl.envs.icrl_benchmark import ICRLTask, icrl_task
    from pbicrl.experiments.icrl_demos import _Switch

    spec = icrl_task("pendulum")
    assert spec.handover_range == 0.01 and icrl_task("halfcheetah").handover_range == 1.0
    xs = np.linspace(0.02, -0.05, 701)  # the cart moving left past the wall
    points = []
    for ep in range(40):
        sw = _Switch(lambda o: np.zeros(1), lambda o: np.ones(1), spec.wall, True, 3, spec.handover_range)
        sw.reset(ep)
        acts = [float(sw(np.array([x, 0.0, 0.0, 0.0]))[0]) for x in xs]
        points.append(xs[acts.index(1.0)])
    points = np.asarray(points)
    assert np.all(np.abs(points - spec.wall) <= 0.01 + 1e-4) and np.ptp(points) > 0.01  # spread over the window
    with pytest.raises(ValueError, match="handover_range"):
        ICRLTask("t", "x/T-v0", "m:C", 10, 0.0, "behind", 1, 1, handover_range=0.0)


def test_report_reads_a_compressed_curve(tmp_path):
    """The committed snapshot gzips long curves (curve.jsonl.gz): the report reads them as the plain file."""
    import gzip

    d = tmp_path / "runs" / "pendulum" / "ppo_lag_true" / "seed0"
    _fake_seed(d, [[(10.0, 10.0, 0)]], curve=[(10.0, 10.0, 0), (12.0, 12.0, 1)])
    plain = seed_metrics(d)
    curve = d / "curve.jsonl"
    with gzip.open(d / "curve.jsonl.gz", "wt", encoding="utf-8") as fh:
        fh.write(curve.read_text(encoding="utf-8"))
    curve.unlink()
    assert seed_metrics(d) == plain and plain["train_violation_rate"] is not None
