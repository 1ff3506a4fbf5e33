"""One vocabulary at every layer: ``sampler``, ``iterations``, ``chains``, ``jobs`` from ``InferConfig`` down to
``SamplerSettings``, ``sample``, ``run_sbc``, ``Posterior`` and ``summary.json``; the old names still work until
pbicrl 0.3 with a :class:`~pbicrl.errors.PbicrlWarning`."""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np
import pytest

from pbicrl.config import ConfigError
from pbicrl.errors import PbicrlWarning
from pbicrl.inference.likelihood import PreferenceLikelihood
from pbicrl.inference.priors import IndicatorPrior, WeightPrior
from pbicrl.inference.samplers import SamplerSettings, build_kernel, sample
from pbicrl.inference.synthetic import make_problem


def test_sampler_settings_use_the_names_of_infer_config():
    names = {f.name for f in dataclasses.fields(SamplerSettings)}
    assert {"sampler", "iterations"} <= names and not {"method", "n_iterations"} & names
    s = SamplerSettings(sampler="bpl", iterations=800)
    assert s.to_dict()["sampler"] == "bpl" and s.to_dict()["iterations"] == 800 and "method" not in s.to_dict()


def test_the_old_names_of_sampler_settings_work_with_a_warning():
    with pytest.warns(PbicrlWarning, match="'method' is deprecated.*use 'sampler'"):
        old = SamplerSettings(method="paper", n_iterations=500)
    assert old == SamplerSettings(sampler="paper", iterations=500)
    with pytest.warns(PbicrlWarning, match="SamplerSettings.n_iterations is deprecated.*SamplerSettings.iterations"):
        assert old.n_iterations == 500
    with pytest.warns(PbicrlWarning, match="'n_iterations' is deprecated"):
        assert old.replace(n_iterations=900).iterations == 900
    with pytest.warns(PbicrlWarning, match="'method' is deprecated"):
        assert dataclasses.replace(old, method="bpl") == SamplerSettings(sampler="bpl", iterations=500)
    with pytest.raises(ConfigError, match="'method': deprecated name of 'sampler', which is given too"):
        SamplerSettings(method="paper", sampler="bpl")


@pytest.mark.parametrize("settings", [
    SamplerSettings(sampler="bpl", iterations=100),
    SamplerSettings(sampler="authors", iterations=1000, thin=3, init_range=(-10.0, -2.0),
                    weight_prior=WeightPrior("flat", -5, 0), indicator_prior=IndicatorPrior(0.3)),
    SamplerSettings(iterations=500, candidates=(0, 2), p_joint=0.2, log_moves=False, sigma_theta=0.7),
])
def test_from_dict_reads_to_dict_back(settings):
    d = settings.to_dict()
    back = SamplerSettings.from_dict(d | {"beta": 2.0, "constraints": None})  # a run's record has more keys
    assert back.to_dict() == d
    assert back.weight_prior == settings.weight_prior and back.indicator_prior == settings.indicator_prior


def test_from_dict_reads_the_settings_of_a_schema_2_run_without_a_warning():
    d = SamplerSettings(sampler="paper", iterations=300).to_dict()
    d["method"] = d.pop("sampler")
    with warnings.catch_warnings():
        warnings.simplefilter("error", PbicrlWarning)
        assert SamplerSettings.from_dict(d).sampler == "paper"


def test_sample_takes_chains_and_jobs_and_the_old_names_with_a_warning():
    prob = make_problem(6, labels="violations", violation_rate=0.4, seed=2)
    lik = PreferenceLikelihood.from_dataset(prob.dataset)
    settings = SamplerSettings(iterations=400)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", PbicrlWarning)  # short chains
        new = sample(lik, settings, chains=2, jobs=1, seed=4, progress=False)
    with pytest.warns(PbicrlWarning, match="'n_chains' is deprecated.*'chains'"):
        old = sample(lik, settings, n_chains=2, n_jobs=1, seed=4, progress=False)
    assert new.n_chains == old.n_chains == 2
    np.testing.assert_array_equal(new.penalty_weights, old.penalty_weights)
    with pytest.warns(PbicrlWarning, match="'method' is deprecated"):
        assert build_kernel(lik, method="bpl").settings.sampler == "bpl"


def test_run_sbc_takes_chains_and_iterations():
    from pbicrl.analysis.calibration import SBCProblem, run_sbc

    with pytest.warns(PbicrlWarning, match="run_sbc\\(\\) argument 'n_iterations' is deprecated"):
        old = run_sbc(SBCProblem(per_group=3), n_replicates=1, L=8, bins=3, n_chains=2, n_iterations=400, seed=1)
    new = run_sbc(SBCProblem(per_group=3), n_replicates=1, L=8, bins=3, chains=2, iterations=400, seed=1)
    assert new.settings["chains"] == 2 and new.settings["iterations"] == 400
    np.testing.assert_array_equal(new.ranks, old.ranks)
    with pytest.raises(TypeError, match="unexpected keyword argument 'n_draws'"):
        run_sbc(n_draws=3)


def test_infer_parses_the_margins_once(monkeypatch):
    import pbicrl
    from pbicrl.inference.preferences import Margins

    raw: list = []
    parse = Margins.parse.__func__

    def counting(cls, value, n_groups):
        if value is not None and not isinstance(value, Margins):
            raw.append(value)  # real parsing work: a list or array turned into a matrix
        return parse(cls, value, n_groups)

    monkeypatch.setattr(Margins, "parse", classmethod(counting))
    prob = make_problem(6, labels="violations", violation_rate=0.4, seed=2)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", PbicrlWarning)
        post = pbicrl.infer(prob.dataset, margins=[0.5, 1.0], iterations=300, chains=1, jobs=1, progress=False)
    assert raw == [[0.5, 1.0]]
    assert post.extra["margins"] == {"m12": 0.5, "m13": 1.5, "m23": 1.0}
