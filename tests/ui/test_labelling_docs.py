"""docs/labelling.md's pool example runs as written (issue 30 item 1): a pool drawn from a shipped dataset keeps
its env_id, so the labelling page draws the goal and the regions."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import numpy as np

import pbicrl
from pbicrl.cli import main
from pbicrl.inference.data import load_dataset
from pbicrl.ui.scenes import scene_for

DOC = Path(__file__).resolve().parents[2] / "docs" / "labelling.md"


def _blocks(lang: str) -> list[str]:
    text = DOC.read_text()
    section = text[text.index("## Making a pool"):text.index("## The data format")]
    return re.findall(rf"```{lang}\n(.*?)```", section, flags=re.S)


def test_the_shell_example_makes_a_pool_that_keeps_env_id(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    (shell,) = _blocks("bash")
    pool_line = next(ln for ln in shell.splitlines() if ln.startswith("pbicrl pool"))
    argv = shlex.split(pool_line.split("#")[0])[1:]
    assert main(argv) == 0 and "env_id 'point_mass'" in capsys.readouterr().out
    pool = load_dataset(tmp_path / "pool.npz", allow_unlabelled=True)
    assert pool.n_trajectories == 40 and pool.n_unlabelled == 40 and pool.env_id == "point_mass"
    scene = scene_for(pool)
    assert scene["kind"] == "navigation" and {r["name"] for r in scene["regions"]} >= {"goal", "red"}
    # the demonstrations are the shipped ones (features and states kept), in the shipped order
    pm = pbicrl.load_dataset("point_mass")
    first = pool.trajectory(0)
    assert any(np.array_equal(first, pm.trajectory(i)) for i in range(pm.n_trajectories))
    assert main(argv) == 2 and "--overwrite" in capsys.readouterr().err  # never replaced silently


def test_the_python_example_runs(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (code,) = _blocks("python")
    exec(compile(code, str(DOC), "exec"), {})
    back = load_dataset(tmp_path / "pool.npz", allow_unlabelled=True)
    assert back.env_id == "point_mass" and back.n_trajectories == 40


def test_shipped_datasets_carry_their_environment():
    for name in ("point_mass", "fetch_reach", "grid", "halfcheetah", "ant"):
        assert pbicrl.load_dataset(name).env_id == name
    assert pbicrl.load_dataset("example").env_id is None  # synthetic: no environment
