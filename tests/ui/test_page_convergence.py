"""The labelling page runs until converged by default and says NOT CONVERGED (never folded away) when it is not."""

from pathlib import Path

import pytest

import pbicrl
from pbicrl.inference.synthetic import make_problem

pytest.importorskip("starlette")

from pbicrl.ui.inference import InferenceSettings, summarise  # noqa: E402


def test_page_default_is_until_converged():
    assert InferenceSettings().iterations == "auto"
    assert InferenceSettings.from_json({"iterations": "auto"}).iterations == "auto"
    assert InferenceSettings.from_json({"iterations": 3000}).iterations == 3000
    with pytest.raises(ValueError, match="iterations"):
        InferenceSettings.from_json({"iterations": "forever"})


def test_summary_of_an_unconverged_run_says_so(tmp_path: Path):
    ds = make_problem(15, labels="violations", violation_rate=0.4, seed=3).dataset
    with pytest.warns(pbicrl.errors.PbicrlWarning):
        post = pbicrl.infer(ds, target_ess=1e6, max_time=1, progress=False)
    post.save(tmp_path / "run")
    res = summarise(pbicrl.load_run(tmp_path / "run", issue_warnings=False), ds)
    assert res["converged"] is False
    assert res["convergence"]["failing"] and res["convergence"]["target_ess"] == 1e6


def test_the_page_script_shows_not_converged_unfolded():
    js = (Path(pbicrl.__file__).parent / "ui" / "static" / "app.js").read_text()
    assert "res.converged === false" in js and "NOT CONVERGED" in js and 'role", "alert"' in js
