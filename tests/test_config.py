"""TOML configuration edge cases: nothing is silently ignored or silently converted; each error names the key."""

from __future__ import annotations

from pathlib import Path

import pytest

from pbicrl.config import ConfigError, InferConfig, load_config


def _cfg(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "c.toml"
    p.write_text(text)
    return p


def test_top_level_keys_or_an_infer_table_both_load(tmp_path):
    top = load_config(_cfg(tmp_path, "iterations = 5000\nchains = 2\n"))
    inside = load_config(_cfg(tmp_path, "[infer]\niterations = 5000\nchains = 2\n"))
    assert top == inside == InferConfig(iterations=5000, chains=2)
    with_constraints = load_config(_cfg(tmp_path, "[infer]\nchains = 2\n[[infer.constraints]]\n"
                                                  "family = 'axis_halfspace'\ndims = [0]\n"))
    assert with_constraints.constraints == [{"family": "axis_halfspace", "dims": [0]}]


@pytest.mark.parametrize("text, needles", [
    ("iterations = 5000\n[infer]\nchains = 2\n", ["'iterations'", "outside the [infer] table"]),
    ("[infer]\nchains = 2\n[[constraints]]\nfamily = 'axis_halfspace'\ndims = [0]\n", ["[constraints]", "outside"]),
    ("[mcmc]\nmethod = 'paper'\n", ["unknown table(s) [mcmc]"]),
    ("[sampler]\nmethod = 'paper'\n", ["config key 'sampler': expected str"]),
    ("[infer]\nchains = 2\n[infer.extra]\nx = 1\n", ["unknown table(s) [extra]"]),
    ("[infer]\nchains = 2\n[plots]\ndpi = 3\n", ["[plots]", "outside"]),
    ("infer = 3\n", ["'infer' must be a table"]),
])
def test_misplaced_or_unknown_tables_are_errors(tmp_path, text, needles):
    with pytest.raises(ConfigError) as exc:
        load_config(_cfg(tmp_path, text))
    for n in needles:
        assert n in str(exc.value), str(exc.value)


@pytest.mark.parametrize("dims, needle", [
    ("[true]", "non-negative integers"), ("[0.5]", "non-negative integers"), ("[-1]", "non-negative integers"),
    ("[]", "non-negative integers"), ("'x'", "non-negative integers"), ("true", "non-negative integers"),
])
def test_constraint_dims_must_be_column_indices(tmp_path, dims, needle):
    text = f"[[constraints]]\nfamily = 'box'\ndims = {dims}\nname = 'zone'\n"
    with pytest.raises(ConfigError, match=needle) as exc:
        load_config(_cfg(tmp_path, text))
    assert "'zone'" in str(exc.value) and "'dims'" in str(exc.value)


def test_repeated_dims_are_an_error(tmp_path):
    with pytest.raises(ConfigError, match="repeats a column"):
        load_config(_cfg(tmp_path, "[[constraints]]\nfamily = 'box'\ndims = [0, 0]\n"))
    ok = load_config(_cfg(tmp_path, "[[constraints]]\nfamily = 'box'\ndims = [0, 1]\n"))
    assert ok.constraints[0]["dims"] == [0, 1]


@pytest.mark.parametrize("key, value, low", [("jobs", 0, 1), ("chains", 0, 1), ("iterations", -5, 1),
                                             ("thin", 0, 1), ("f_s", 0, 1), ("burn_in", -1, 0), ("seed", -3, 0)])
def test_integers_out_of_range_are_errors(tmp_path, key, value, low):
    with pytest.raises(ConfigError, match=rf"config key '{key}': expected an integer >= {low}, got {value}"):
        load_config(_cfg(tmp_path, f"{key} = {value}\n"))


def test_booleans_are_not_numbers_and_bad_files_are_named(tmp_path):
    with pytest.raises(ConfigError, match="config key 'chains': expected int, got True"):
        load_config(_cfg(tmp_path, "chains = true\n"))
    with pytest.raises(ConfigError, match="is a directory"):
        load_config(tmp_path)
    with pytest.raises(ConfigError, match="no such file"):
        load_config(tmp_path / "nope.toml")
    (tmp_path / "bin.toml").write_bytes(b"\xff\xfe\x00")
    with pytest.raises(ConfigError, match="not UTF-8|not valid TOML"):
        load_config(tmp_path / "bin.toml")


def test_the_command_line_reports_config_errors_in_one_line(tmp_path, capsys):
    from pbicrl.cli import main

    cfg = _cfg(tmp_path, "jobs = 0\n")
    assert main(["infer", "point_mass", "--out", str(tmp_path / "run"), "--config", str(cfg)]) == 2
    err = capsys.readouterr().err
    assert "pbicrl: error: config key 'jobs'" in err and "Traceback" not in err
    assert main(["infer", "point_mass", "--out", str(tmp_path / "run"), "--config", str(tmp_path)]) == 2
    assert "is a directory" in capsys.readouterr().err
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize("value", [-0.1, 1.0, 1.5, "nan"])
def test_p_joint_outside_zero_one_is_named(tmp_path, value):
    text = "p_joint = nan\n" if value == "nan" else f"p_joint = {value}\n"
    with pytest.raises(ConfigError, match=r"config key 'p_joint': expected a number in \[0, 1\)"):
        load_config(_cfg(tmp_path, text))


def test_p_joint_from_toml_and_the_command_line(tmp_path, capsys):
    from pbicrl.cli import main

    assert load_config(_cfg(tmp_path, "p_joint = 0.3\n")).p_joint == 0.3
    assert load_config(_cfg(tmp_path, "[infer]\np_joint = 0\n")).p_joint == 0
    with pytest.raises(ConfigError, match="config key 'p_joint': expected int or float, got True"):
        load_config(_cfg(tmp_path, "p_joint = true\n"))
    # --p-joint goes through the same record; out of range is one line naming the setting, and nothing is written
    out = tmp_path / "run"
    assert main(["infer", "point_mass", "--out", str(out), "--p-joint", "1.2", "--iterations", "50",
                 "--chains", "1", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "pbicrl: error: p_joint: expected a number in [0, 1)" in err and "Traceback" not in err
    assert not out.exists()
    assert main(["infer", "point_mass", "--out", str(out), "--p-joint", "0.2", "--sampler", "paper",
                 "--iterations", "50", "--chains", "1", "--no-progress"]) == 2
    assert "p_joint: the joint weight step belongs to the pbicrl and bpl samplers" in capsys.readouterr().err
    assert not out.exists()
