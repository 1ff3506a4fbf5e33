"""Run directories through :mod:`pbicrl.io.runs`: one ``load_run`` giving one type, the checked record underneath,
old import paths (``pbicrl.inference.results``, ``pbicrl.runs``) kept as deprecated aliases."""

from __future__ import annotations

import importlib
import math
import warnings

import numpy as np
import pytest

import pbicrl
from pbicrl._atomic import OutputExistsError
from pbicrl.errors import PbicrlWarning
from pbicrl.inference.data import Dataset
from pbicrl.inference.posterior import Posterior
from pbicrl.inference.priors import prior_quantile
from pbicrl.io import runs

from tests.inference.test_results import make_post

IND = np.array([[[1, 0], [1, 1], [0, 1], [1, 0]], [[1, 1], [1, 0], [1, 0], [0, 1]]])
WP = np.where(IND == 1, -np.arange(1.0, 9.0).reshape(2, 4, 1), 0.0)


@pytest.fixture
def run_dir(tmp_path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", PbicrlWarning)
        return make_post(IND, WP).save(tmp_path / "run")


def test_there_is_one_load_run_and_it_gives_a_posterior(run_dir):
    assert pbicrl.load_run is runs.load_run
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", PbicrlWarning)
        post = pbicrl.load_run(run_dir)
        via_class = Posterior.load(run_dir)
    assert type(post) is Posterior and type(via_class) is Posterior
    np.testing.assert_array_equal(post.indicators, IND)
    assert post.summary()["selected"] == via_class.summary()["selected"]
    rec = runs.read_run(run_dir)  # the checked record underneath: same draws, no Posterior
    assert type(rec) is runs.RunRecord
    np.testing.assert_array_equal(rec.penalty_weights, post.penalty_weights)


def test_posterior_load_attributes_its_warnings_to_the_caller(tmp_path):
    post = make_post(IND, WP, issue_warnings=False)  # 8 draws: the diagnostics warn (bulk ESS < 400)
    run = post.save(tmp_path / "run")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", PbicrlWarning)
        Posterior.load(run)
    mine = [w for w in caught if w.category is PbicrlWarning]
    assert [str(w.message) for w in mine] == post.warnings() != []
    assert all(w.filename == __file__ for w in mine)


@pytest.mark.parametrize("name", sorted(importlib.import_module("pbicrl.inference.results").MOVED_NAMES))
def test_every_name_of_the_old_results_module_still_imports_with_a_warning(name):
    old = importlib.import_module("pbicrl.inference.results")
    with pytest.warns(PbicrlWarning, match=rf"pbicrl\.inference\.results\.{name} moved to .*deprecated"):
        value = getattr(old, name)
    assert value is getattr(importlib.import_module(old.MOVED_NAMES[name]), name)


def test_the_old_runs_module_keeps_its_record_reader(run_dir):
    old = importlib.import_module("pbicrl.runs")
    with pytest.warns(PbicrlWarning, match=r"pbicrl\.runs\.load_run moved to pbicrl\.io\.runs\.read_run"):
        load = old.load_run
    assert type(load(run_dir)) is runs.RunRecord  # what pbicrl.runs.load_run always returned
    with pytest.raises(AttributeError, match="no_such_name"):
        old.no_such_name  # noqa: B018


def test_the_old_path_of_posterior_is_the_same_class():
    with pytest.warns(PbicrlWarning, match="deprecated"):
        from pbicrl.inference.results import Posterior as Old
    assert Old is Posterior is pbicrl.Posterior


def test_dataset_save_refuses_an_existing_file_as_an_output_exists_error(tmp_path):
    ds = Dataset(features=np.ones((4, 2)), offsets=np.array([0, 2, 4]), group=np.array([1, 2]))
    path = ds.save(tmp_path / "d.npz")
    with pytest.raises(OutputExistsError, match="path: .* already exists"):
        ds.save(path, overwrite=False)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d.npz"]  # no temporary left behind


@pytest.mark.parametrize("spec, p, want", [
    # Cauchy on (-inf, 0]: P(Z <= z | Z <= 0) = 2 F(z), so the 5% quantile is tan(pi (0.025 - 1/2))
    ({"kind": "cauchy", "scale": 2.0, "support": [None, 0.0]}, 0.05, 2.0 * math.tan(math.pi * (0.025 - 0.5))),
    # t with 1 df is the Cauchy: the same number through the student_t branch
    ({"kind": "student_t", "df": 1, "mean": 1.0, "scale": 1.0}, 0.9, 1.0 + math.tan(math.pi * 0.4)),
    # half-normal: 95% quantile of |N(0, 3^2)| on [0, inf) is 3 * z_{0.975}
    ({"kind": "normal", "scale": 3.0, "support": [0.0, None]}, 0.95, 3.0 * 1.959963984540054),
])
def test_prior_quantile_is_exact_on_closed_forms(spec, p, want):
    assert prior_quantile(spec, p) == pytest.approx(want, rel=1e-9)
