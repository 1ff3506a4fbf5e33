"""One settings vocabulary: InferConfig's names, types and defaults everywhere; old names deprecated."""

from __future__ import annotations

import inspect
import warnings

import numpy as np
import pytest

from pbicrl.api import infer, infer_from_config
from pbicrl.config import DEPRECATED_NAMES, ConfigError, InferConfig, canonical_names, check_setting, load_config
from pbicrl.errors import PbicrlWarning
from pbicrl.experiments.tasks import INFER_EXTRA, prepare_infer
from pbicrl.inference.synthetic import make_problem

FIELDS = InferConfig.defaults()


@pytest.fixture(scope="module")
def dataset():
    return make_problem(12, labels="violations", violation_rate=0.4, seed=3).dataset


def test_infer_takes_every_setting_with_the_configs_default():
    from pbicrl.api import _settings

    params = inspect.signature(infer).parameters
    assert params["config"].default is None and params["overrides"].kind is inspect.Parameter.VAR_KEYWORD
    assert not (set(FIELDS) | set(DEPRECATED_NAMES)) & set(params)  # settings only through InferConfig's names
    for name, default in FIELDS.items():  # every setting is a keyword, checked and defaulted by InferConfig
        assert _settings(None, {name: default}) == InferConfig(), name
    cfg = InferConfig(sampler="bpl", chains=3)
    assert _settings(cfg, {"chains": 2}) == InferConfig(sampler="bpl", chains=2)
    assert _settings(cfg, {"chains": np.int64(2)}).chains == 2  # a NumPy integer is an integer


@pytest.mark.parametrize("key, value, message", [
    ("chains", 0, "key 'chains'"), ("iterations", "forever", "key 'iterations'"), ("beta", "1", "key 'beta'"),
    ("p_joint", 1.5, "key 'p_joint'"),
])
def test_infer_checks_its_keywords_as_a_config_file_is_checked(dataset, key, value, message):
    with pytest.raises(ConfigError, match=message):
        infer(dataset, **{key: value}, progress=False)


def test_infer_refuses_a_config_that_is_not_one(dataset):
    with pytest.raises(TypeError, match="config: expected an InferConfig"):
        infer(dataset, {"sampler": "bpl"}, progress=False)


def test_the_command_line_options_are_config_settings():
    from pbicrl.cli import build_parser

    sub = next(a for a in build_parser()._subparsers._group_actions if a.dest == "command")
    cli_only = {"help", "data", "out", "config", "check", "overwrite", "no_progress", "json", "prior_bounds"}
    dests = {a.dest for a in sub.choices["infer"]._actions} - cli_only
    assert dests <= set(FIELDS), dests - set(FIELDS)
    assert {"sampler", "iterations", "chains", "jobs", "pairs"} <= dests


def test_sweep_configs_know_exactly_the_config_settings(tmp_path, dataset):
    path = tmp_path / "d.npz"
    dataset.save(path)
    config = prepare_infer({"data": str(path)})
    assert set(config) == {"data", "data_sha256"} | set(FIELDS) | set(INFER_EXTRA)


def test_reproductions_use_only_config_settings(tmp_path, monkeypatch):
    from pbicrl.experiments import reproduce as rep

    class Stop(Exception):
        pass

    seen = []

    def capture(ctx, configs, names):
        seen.extend(configs)
        raise Stop

    monkeypatch.setattr(rep.navigation, "run_infer_tasks", capture)
    monkeypatch.setattr(rep.walls, "run_infer_tasks", capture)
    ctx = rep.Context(tmp_path, True, "all", 1, "serial", None, False, 100, None)
    for name in ("grid", "halfcheetah"):
        try:
            rep.EXPERIMENTS[name](ctx)
        except (Stop, FileNotFoundError):
            pass
    assert seen
    allowed = set(FIELDS) | set(INFER_EXTRA) | {"data"} | set(rep.configs.BOOKKEEPING)
    assert set().union(*seen) <= allowed


@pytest.mark.parametrize("old, new", sorted(DEPRECATED_NAMES.items()))
def test_old_names_warn_and_mean_the_new_one(old, new, tmp_path):
    value = "bpl" if new == "sampler" else 3
    with pytest.warns(PbicrlWarning, match=f"'{old}' is deprecated.*use '{new}'"):
        assert canonical_names({old: value}) == {new: value}
    (tmp_path / "c.toml").write_text(f"{old} = {value!r}\n".replace("'", '"'))
    with pytest.warns(PbicrlWarning, match=f"config key '{old}' is deprecated"):
        assert getattr(load_config(tmp_path / "c.toml"), new) == value
    with pytest.raises(ConfigError, match=f"'{old}': deprecated name of '{new}', which is given too"):
        canonical_names({old: value, new: value})
    with pytest.warns(PbicrlWarning):
        assert getattr(InferConfig().updated(**{old: value}), new) == value


def test_infer_with_old_names_gives_the_same_chains(dataset):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", PbicrlWarning)
        a = infer(dataset, sampler="paper", iterations=800, chains=2, jobs=1, seed=1, progress=False)
    with pytest.warns(PbicrlWarning, match="'n_iterations' is deprecated"):
        b = infer(dataset, method="paper", n_iterations=800, n_chains=2, n_jobs=1, seed=1, progress=False)
    np.testing.assert_array_equal(a.penalty_weights, b.penalty_weights)
    with pytest.raises(ConfigError, match="'method': deprecated name of 'sampler', which is given too"):
        infer(dataset, method="paper", sampler="bpl", progress=False)
    with pytest.raises(TypeError, match="unexpected keyword argument 'n_iter'"):
        infer(dataset, n_iter=5)


def test_a_config_and_its_keyword_arguments_give_the_same_chains(dataset):
    cfg = InferConfig(sampler="paper", iterations=800, chains=2, jobs=1, seed=2, prior="flat", penalty_sign="any",
                      likelihood="pairwise", pairs=5, pairs_seed=1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", PbicrlWarning)
        a = infer_from_config(dataset, cfg, progress=False)
        b = infer(dataset, **cfg.to_dict(), progress=False)
        c = infer(dataset, cfg, progress=False)
    np.testing.assert_array_equal(a.penalty_weights, b.penalty_weights)
    np.testing.assert_array_equal(a.penalty_weights, c.penalty_weights)
    assert a.settings["weight_prior"] == b.settings["weight_prior"]


def test_a_prior_given_twice_is_an_error(dataset):
    from pbicrl.inference.priors import IndicatorPrior, WeightPrior

    with pytest.raises(ConfigError, match="weight_prior: given together with prior"):
        infer(dataset, weight_prior=WeightPrior("flat"), prior="normal", progress=False)
    with pytest.raises(ConfigError, match="indicator_prior: given together with indicator_pi"):
        infer(dataset, indicator_prior=IndicatorPrior(0.3), indicator_pi=0.2, progress=False)


@pytest.mark.parametrize("key, value, message", [
    ("iteratons", 5, "unknown; known keys are"), ("chains", True, "expected int, got True"),
    ("chains", 0, "expected an integer >= 1"), ("beta", "x", "expected int or float"),
])
def test_check_setting_names_the_key(key, value, message):
    with pytest.raises(ConfigError, match=f"where key '{key}': {message}"):
        check_setting(key, value, where="where")
    check_setting("chains", None)  # None stands for the default


def test_from_mapping_and_to_dict_round_trip():
    cfg = InferConfig(sampler="bpl", margins=[0.0, 1.0], constraints=[{"family": "axis_halfspace", "dims": [0]}])
    assert InferConfig.from_mapping(cfg.to_dict()) == cfg
    d = cfg.to_dict()
    d["margins"].append(5.0)  # a copy: the record is not changed
    assert cfg.margins == [0.0, 1.0]
