"""The split modules: old import paths keep working, moved command lines are deprecated aliases, kinds apart
from the engine."""

import subprocess
import sys
from importlib import import_module

import pytest

from pbicrl.errors import PbicrlWarning


@pytest.mark.parametrize("module, name, new", [
    ("pbicrl.experiments.reproduce", "add_subcommands", "pbicrl.cli.reproduce"),
    ("pbicrl.experiments.sweep", "add_subcommands", "pbicrl.cli.sweep"),
    ("pbicrl.experiments.safe_rl", "add_subcommands", "pbicrl.cli.train_safe"),
    ("pbicrl.experiments.close_loop", "main", "pbicrl.cli.close_loop"),
])
def test_a_moved_command_line_is_a_deprecated_alias(module, name, new):
    with pytest.warns(PbicrlWarning, match=f"{module}.{name} is deprecated.*use {new}.{name}"):
        old = getattr(import_module(module), name)
    assert old is getattr(import_module(new), name)
    with pytest.raises(AttributeError, match="no attribute 'nothing'"):
        getattr(import_module(module), "nothing")


def test_python_m_close_loop_still_parses_its_flags_and_exit_codes(tmp_path):
    def run(*args):
        return subprocess.run([sys.executable, "-m", "pbicrl.experiments.close_loop", *args], capture_output=True,
                              text=True, timeout=120)

    ok = run("--help")
    assert ok.returncode == 0 and ok.stdout.startswith("usage: python -m pbicrl.experiments.close_loop")
    assert "--hc-cost-limit" in ok.stdout and "Close the loop" in ok.stdout
    bad = run("--out", str(tmp_path / "o"), "--envs", "moon")
    assert bad.returncode == 2 and "--envs: expected point_mass and/or halfcheetah, got 'moon'" in bad.stderr
    assert run("--out", str(tmp_path / "o"), "--seeds", "0").returncode == 2
    assert not (tmp_path / "o").exists()  # refused before anything is written


def test_the_built_in_kinds_live_apart_from_the_engine():
    from pbicrl.experiments import kinds, registry, tasks

    assert {k: tasks.get_task_kind(k).target for k in ("infer", "selftest")} == {
        "infer": "pbicrl.experiments.kinds:run_infer", "selftest": "pbicrl.experiments.kinds:run_selftest"}
    assert tasks.get_task_kind("reproduce-icl").target == "pbicrl.baselines.icl:run_icl_task"
    # the names stay importable where they were, as the same objects
    assert tasks.run_infer is kinds.run_infer and tasks.prepare_infer is kinds.prepare_infer
    assert tasks.register_task is registry.register_task and tasks.TaskError is registry.TaskError
    # a task naming the old path of a kind's function still runs it
    assert tasks.Task("pbicrl.experiments.tasks:run_selftest", {}).target == "pbicrl.experiments.tasks:run_selftest"
