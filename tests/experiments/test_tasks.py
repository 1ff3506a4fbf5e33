"""Task kinds and the results cache: the one inference kind, renamed settings, cache versions, workers."""

from __future__ import annotations

import json
import os
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest

from pbicrl.api import infer
from pbicrl.inference.data import load_dataset
from pbicrl.errors import PbicrlWarning
from pbicrl.experiments import tasks
from pbicrl.experiments.sweep import run_tasks
from pbicrl.experiments.tasks import (CACHE_VERSION, RESULT_FILE, Task, TaskError, adopt_older_runs, execute_task,
                                      find_done, in_task_worker, infer_config_of_reproduce_run, prepare_infer,
                                      read_result, run_infer, summarize_infer, task_jobs, task_worker, write_shipped)
from pbicrl.inference.priors import WeightPrior
from pbicrl.inference.posterior import Posterior
from pbicrl.inference.synthetic import make_problem

ITER = 600


@pytest.fixture(scope="module")
def demo(tmp_path_factory) -> Path:
    p = tmp_path_factory.mktemp("data") / "demo.npz"
    make_problem(15, labels="violations", violation_rate=0.4, seed=3).dataset.save(p)
    return p


def _draws(run_dir: Path) -> tuple[np.ndarray, np.ndarray]:
    post = Posterior.load(run_dir, issue_warnings=False)
    return post.indicators, post.penalty_weights


# ------------------------------------------------------------------------------------------------ one inference kind
# Configs of the retired `reproduce-run` kind (version 2), as pbicrl reproduce wrote them, and the call its
# `run_unit` made for each: the `infer` kind must give the same chains for the renamed settings.
_LEGACY = [
    ({"method": "paper", "n_per_group": 10, "sample_seed": 1, "iterations": ITER, "seed": 1, "sigma": 0.1, "f_s": 4,
      "pairs": 10, "prior": "improper", "label": "x"},
     dict(sampler="paper", likelihood="pairwise", pairs=10, pairs_seed=1, weight_prior=WeightPrior("improper", sign="any"))),
    ({"method": "pbicrl", "n_per_group": 12, "sample_seed": 2, "iterations": ITER, "seed": 2, "sigma": 0.1, "f_s": 4,
      "pairs": "all", "prior": "flat", "margins": [0.0, 1.0]},
     dict(sampler="pbicrl", likelihood="pairwise", pairs="all", pairs_seed=2, margins=[0.0, 1.0],
          weight_prior=WeightPrior("flat", -1000.0, 1000.0, sign="any"))),
    ({"method": "pbicrl", "n_per_group": 12, "sample_seed": 0, "iterations": ITER, "seed": 3, "sigma": 0.1, "f_s": 4,
      "likelihood": "grouped", "prior": "default", "pairs": None},
     dict(sampler="pbicrl", likelihood="grouped", pairs=None, pairs_seed=0, weight_prior=WeightPrior())),
]


@pytest.mark.parametrize("legacy, call", _LEGACY)
def test_a_reproduce_run_config_renamed_gives_the_same_chains(legacy, call, demo, tmp_path):
    config = infer_config_of_reproduce_run({"dataset": str(demo)} | legacy)
    assert "label" not in config and config["demos_seed"] == config["pairs_seed"] == legacy["sample_seed"]
    result = run_infer(prepare_infer(config), tmp_path / "new")
    ds = load_dataset(demo).sample_per_group(legacy["n_per_group"], seed=legacy["sample_seed"])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", PbicrlWarning)
        old = infer(ds, iterations=ITER, chains=1, jobs=1, seed=legacy["seed"], sigma=0.1, f_s=4, progress=False, **call)
    ind, pw = _draws(tmp_path / "new")
    np.testing.assert_array_equal(ind, old.indicators)
    np.testing.assert_array_equal(pw, old.penalty_weights)
    assert result["p_constraint"] == old.p_constraint.tolist()
    assert result["map_effective_penalty"] == old.map_effective_penalty.tolist()


def test_the_infer_result_is_recomputed_exactly_from_the_saved_run(demo, tmp_path):
    config = prepare_infer({"data": str(demo), "iterations": ITER, "chains": 2, "sampler": "paper",
                            "likelihood": "pairwise", "demos_per_group": 12})
    result = run_infer(config, tmp_path)
    assert summarize_infer(config, tmp_path) == result
    assert set(result) >= {"features", "p_constraint", "selected_effective_penalty", "group_means_map",
                           "parameter_ci90", "map_log_posterior", "max_rhat", "acceptance", "n_pairs", "warnings"}
    assert "runtime_s" not in result  # machine-dependent: result.json holds it beside the result


def test_old_setting_names_are_the_same_run_with_a_warning(demo):
    new = Task("infer", {"data": str(demo), "sampler": "paper", "iterations": 500, "chains": 2})
    with pytest.warns(PbicrlWarning, match="'method' is deprecated.*use 'sampler'"):
        old = Task("infer", {"data": str(demo), "method": "paper", "n_iterations": 500, "n_chains": 2})
    assert old == new and old.config == new.config and "method" not in old.config
    with pytest.raises(TaskError, match="'method': deprecated name of 'sampler', which is given too"):
        Task("infer", {"data": str(demo), "method": "paper", "sampler": "bpl"})
    with pytest.raises(TaskError, match="infer config key 'chains': expected an integer >= 1, got 0"):
        Task("infer", {"data": str(demo), "chains": 0})


# ------------------------------------------------------------------------------------------------ cache versions
def _age(run_dir: Path, root: Path, *, version: int, kind: str | None = None, config: dict | None = None) -> Path:
    """Make a finished run look as if an older pbicrl wrote it: older version, hash and directory name."""
    rec = read_result(run_dir)
    rec.update(cache_version=version, config_hash="0" * 64)
    if kind is not None:
        rec["kind"] = kind
    if config is not None:
        rec["config"] = config
    rec["result"] = {"from": "the old version"}
    old = root / f"old-{version}-{'0' * 12}"
    os.rename(run_dir, old)
    (old / RESULT_FILE).write_text(json.dumps(rec))
    return old


def test_the_cache_version_is_in_the_hash(demo, monkeypatch):
    task = Task("infer", {"data": str(demo)})
    monkeypatch.setattr(tasks, "CACHE_VERSION", CACHE_VERSION + 1)
    assert Task("infer", {"data": str(demo)}) != task


def test_runs_of_a_renaming_version_are_adopted_and_others_reported(demo, tmp_path, capsys):
    cfg = {"data": str(demo), "iterations": ITER, "chains": 1, "sampler": "paper", "likelihood": "pairwise"}
    task = Task("infer", cfg)
    first = run_tasks([task], tmp_path, "serial", progress=False, manifest=False)
    fresh = first.records[0].result
    draws = _draws(find_done(task, tmp_path))
    old = _age(find_done(task, tmp_path), tmp_path, version=2)
    assert find_done(task, tmp_path) is None  # not found under its old name and version

    # a version-2 run of the same settings (version 3 only renamed settings) is taken over, not run again
    res = run_tasks([task], tmp_path, "serial", progress=True, manifest=True)
    rec = res.records[0]
    assert rec.status == "cached" and not old.exists() and Path(rec.out_dir) == task.out_dir(tmp_path)
    record = read_result(task.out_dir(tmp_path))
    assert record["cache_version"] == CACHE_VERSION and record["config_hash"] == task.config_hash
    assert record["adopted_from"]["cache_version"] == 2
    assert rec.result == fresh  # recomputed from its files by the kind, not the stored numbers
    np.testing.assert_array_equal(_draws(task.out_dir(tmp_path))[1], draws[1])
    assert "taken over" in capsys.readouterr().err
    assert json.loads((tmp_path / "sweep.json").read_text())["older_cache_versions"]["adopted"] == [rec.task.dir_name]

    # a version-1 run (numbers that may differ) is kept, reported and never reused
    v1 = _age(task.out_dir(tmp_path), tmp_path, version=1)
    res = run_tasks([task], tmp_path, "serial", progress=True)
    assert res.records[0].status == "ran" and v1.exists()
    assert "made by cache version 1" in capsys.readouterr().err
    listed = json.loads((tmp_path / "sweep.json").read_text())["older_cache_versions"]["not_reused"]
    assert [e["dir"] for e in listed] == [v1.name] and "cache version 1" in listed[0]["reason"]


def test_a_reproduce_run_of_version_2_becomes_the_infer_run_of_the_new_names(demo, tmp_path):
    legacy = {"dataset": str(demo), "method": "paper", "n_per_group": 10, "sample_seed": 1, "iterations": ITER,
              "seed": 1, "sigma": 0.1, "f_s": 4, "pairs": "all", "prior": "improper", "label": "x", "n": 10}
    new_cfg = {"data": str(demo), "sampler": "paper", "demos_per_group": 10, "demos_seed": 1, "pairs_seed": 1,
               "iterations": ITER, "seed": 1, "likelihood": "pairwise", "pairs": "all", "chains": 1,
               "prior": "improper", "penalty_sign": "any"}
    task = Task("infer", new_cfg)
    run_tasks([task], tmp_path, "serial", progress=False, manifest=False)
    fresh = read_result(task.out_dir(tmp_path))["result"]
    sha = read_result(task.out_dir(tmp_path))["config"]["data_sha256"]
    _age(task.out_dir(tmp_path), tmp_path, version=2, kind="reproduce-run", config=legacy | {"dataset_sha256": sha})
    dry = adopt_older_runs(tmp_path, dry_run=True)
    assert dry.adopted == [task.out_dir(tmp_path)] and not task.out_dir(tmp_path).exists()  # a dry run moves nothing
    older = adopt_older_runs(tmp_path)
    assert older.adopted == [task.out_dir(tmp_path)] and not older.not_reused
    assert find_done(task, tmp_path) == task.out_dir(tmp_path)
    assert read_result(task.out_dir(tmp_path))["result"] == fresh


def test_an_older_run_whose_dataset_changed_is_not_adopted(demo, tmp_path):
    data = tmp_path / "data.npz"
    shutil.copy(demo, data)
    root = tmp_path / "runs"
    task = Task("infer", {"data": str(data), "iterations": ITER, "chains": 1})
    run_tasks([task], root, "serial", progress=False, manifest=False)
    old = _age(task.out_dir(root), root, version=2)
    make_problem(15, labels="violations", violation_rate=0.4, seed=4).dataset.save(data, overwrite=True)
    older = adopt_older_runs(root)
    assert not older.adopted and [p for p, _ in older.not_reused] == [old]
    assert "data_sha256" in older.not_reused[0][1] and old.exists()


# ------------------------------------------------------------------------------------------------ workers
def test_task_worker_marks_the_process_and_restores_it():
    assert not in_task_worker() and task_jobs() == 1
    with task_worker(3):
        assert in_task_worker() and task_jobs() == 3
        with task_worker(1):
            assert task_jobs() == 1
        assert task_jobs() == 3
    assert not in_task_worker() and task_jobs() == 1


def test_a_failing_task_is_reported_and_leaves_nothing(tmp_path):
    out = execute_task(Task("selftest", {"fail": "boom"}), tmp_path)
    assert out["status"] == "failed" and out["error"] == "RuntimeError: boom" and "Traceback" in out["traceback"]
    assert list(tmp_path.iterdir()) == []


def test_shipped_outcomes_are_written_like_local_ones(tmp_path):
    task = Task("selftest", {"value": {"a": [1, 2]}})
    outcome = execute_task(task, None)  # as a Ray worker: files come back with the outcome
    assert outcome["files"] == {"value.json": b'{"a": [1, 2]}\n'}
    written = write_shipped(task, tmp_path, outcome)
    assert "files" not in written and Path(written["out_dir"]) == find_done(task, tmp_path)
    assert json.loads((find_done(task, tmp_path) / "value.json").read_text()) == {"a": [1, 2]}
    assert oct((find_done(task, tmp_path)).stat().st_mode & 0o777) == oct(0o777 & ~_umask())


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask
