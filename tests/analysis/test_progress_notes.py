"""Progress that says what it waits for (issue 30 item 13): the first margin-tuning run also compiles the samplers
(the bar sat at 0/64 for two minutes saying nothing), and each run shows its own sampling progress."""

from __future__ import annotations

import warnings

from pbicrl.analysis.margins import COMPILING_NOTE, tune_margins
from pbicrl.errors import PbicrlWarning
from pbicrl.inference.synthetic import make_problem


def test_tuning_margins_says_compiling_and_shows_progress_within_runs(capsys):
    ds = make_problem(6, seed=1).dataset
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", PbicrlWarning)
        tune_margins(ds, [1.0, 2.0], gap_grid=(0.0, 1.0), iterations=1000, chains=1, jobs=1, seed=0, progress=True)
    err = capsys.readouterr().err
    assert f"tuning margins ({COMPILING_NOTE})" in err  # until the first run ends
    assert "sampling" in err  # each run's own bar (the sampler's), under the candidates'


def test_a_sweep_bar_says_compiling_until_the_first_run_ends(tmp_path, capsys):
    from pbicrl.experiments.sweep import run_tasks
    from pbicrl.experiments.tasks import Task

    data = make_problem(5, seed=2).dataset.save(tmp_path / "d.npz")
    tasks = [Task("infer", {"data": str(data), "iterations": 1000, "chains": 1, "seed": s}) for s in (0, 1)]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", PbicrlWarning)
        run_tasks(tasks, tmp_path / "out", "serial", progress=True)
    err = capsys.readouterr().err
    assert f"sweep ({COMPILING_NOTE})" in err and "sweep: 100%" in err
