"""The command line end to end, and its errors."""

import json
import subprocess
import sys

import numpy as np
import pytest

from pbicrl.cli import main
from pbicrl.inference.synthetic import make_problem


@pytest.fixture(scope="module")
def data_path(tmp_path_factory):
    p = tmp_path_factory.mktemp("data") / "demo.npz"
    make_problem(20, labels="violations", violation_rate=0.4, seed=2).dataset.save(p)
    return p


def test_infer_end_to_end(data_path, tmp_path, capsys):
    out = tmp_path / "run"
    rc = main(["infer", str(data_path), "--out", str(out), "--iterations", "4000", "--chains", "2",
               "--seed", "5", "--margins", "0.5,1.0", "--no-progress"])
    assert rc == 0
    s = json.loads((out / "summary.json").read_text())
    for key in ("indicators", "penalty_weights", "effective_penalty"):
        assert set(s["map"][key]) == {"feature0", "constraint1", "constraint2", "feature3"}
    for key in ("mean_effective_penalty", "p_constraint", "ci90"):
        assert key in s["posterior"]
    assert s["iterations"] == 4000 and s["chains"] == 2 and s["seed"] == 5 and s["runtime_s"] > 0
    assert set(s["acceptance_rate"]) >= {"flip", "weight"}
    assert s["extra"]["margins"] == {"m12": 0.5, "m13": 1.5, "m23": 1.0}
    z = np.load(out / "chains.npz")
    assert z["indicators"].shape[:2] == (2, s["draws_per_chain"])
    assert "P(c=1)" in capsys.readouterr().out


def test_config_file_and_cli_override(data_path, tmp_path):
    cfg = tmp_path / "c.toml"
    cfg.write_text('sampler = "bpl"\niterations = 2000\nchains = 1\nmargins = [[0, 0, 6.0], [0, 0, 2.9], [0, 0, 0]]\n')
    out = tmp_path / "run"
    assert main(["infer", str(data_path), "--out", str(out), "--config", str(cfg), "--seed", "1", "--no-progress"]) == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["sampler"] == "bpl" and s["iterations"] == 2000 and s["seed"] == 1
    assert s["extra"]["margins"]["m13"] == 6.0


@pytest.mark.parametrize("args, message", [
    (["--iterations", "0"], "expected 'auto' or a positive integer"),
    (["--iterations", "forever"], "expected 'auto' or a positive integer"),
    (["--target-rhat", "0.99"], "a number > 1"),
    (["--max-time", "-5"], "a positive number"),
    (["--target-ess", "nan"], "a positive number"),
    (["--margins", "1,2,3"], "3 groups need 2 consecutive gaps"),
    (["--nominal-weights", "1,2"], "nominal_weights: expected 4 values"),
    (["--sampler", "gibbs"], "invalid choice"),
    (["--pairs", "some"], "expected 'all' or a positive integer"),
    (["--burn-in", "5000", "--iterations", "100"], "burn_in: must lie in"),
    (["--candidates", "nope"], "candidates: unknown feature 'nope'"),
    (["--prior-bounds", "5,1"], "need low < high"),
    (["--beta", "-1"], "expected a positive number"),
])
def test_bad_options_fail_cleanly(data_path, tmp_path, args, message, capsys):
    out = tmp_path / "run"
    try:
        rc = main(["infer", str(data_path), "--out", str(out), "--no-progress", *args])
    except SystemExit as exc:  # argparse rejects malformed values itself
        rc = exc.code
    err = capsys.readouterr().err
    assert rc == 2
    assert message in err
    assert "Traceback" not in err
    assert not out.exists()
    assert not list(tmp_path.glob(".run*"))


def test_bad_config_and_data(tmp_path, data_path, capsys):
    cfg = tmp_path / "c.toml"
    cfg.write_text("iteratons = 5\n")
    assert main(["infer", str(data_path), "--out", str(tmp_path / "o"), "--config", str(cfg)]) == 2
    assert "config key 'iteratons': unknown" in capsys.readouterr().err
    cfg.write_text('iterations = "many"\n')
    assert main(["infer", str(data_path), "--out", str(tmp_path / "o"), "--config", str(cfg)]) == 2
    assert "config key 'iterations': expected a number of iterations or \"auto\"" in capsys.readouterr().err
    bad = tmp_path / "bad.npz"
    np.savez(bad, features=np.ones((3, 2)), offsets=np.array([0, 1, 3]), group=np.array([1, 1]))
    assert main(["infer", str(bad), "--out", str(tmp_path / "o")]) == 2
    assert "group: need at least two non-empty groups" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_existing_output_is_not_clobbered(data_path, tmp_path, capsys):
    out = tmp_path / "run"
    out.mkdir()
    (out / "keep.txt").write_text("x")
    assert main(["infer", str(data_path), "--out", str(out), "--iterations", "100", "--no-progress"]) == 2
    assert "already exists" in capsys.readouterr().err
    assert (out / "keep.txt").exists()


def test_console_script_runs():
    r = subprocess.run([sys.executable, "-m", "pbicrl.cli", "--version"], capture_output=True, text=True)
    assert r.returncode == 0 and "pbicrl" in r.stdout


@pytest.mark.parametrize("flag,value", [("--prior-bounds", "-50,50"), ("--nominal-weights", "-1,0,0,-1"),
                                        ("--margins", "-0.5,1")])
def test_negative_first_value_is_accepted(data_path, tmp_path, flag, value, capsys):
    """``--prior-bounds -50,50`` (space, not '=') used to fail with 'expected one argument'."""
    from pbicrl.cli.app import _join_negative_values

    assert _join_negative_values([flag, value, "--x", "y"]) == [f"{flag}={value}", "--x", "y"]
    if flag == "--nominal-weights":
        value = ",".join(["-1"] * np.load(data_path)["features"].shape[1])
    out = tmp_path / "run"
    code = main(["infer", str(data_path), "--out", str(out), flag, value, "--iterations", "400", "--chains", "1",
                 "--no-progress"])
    err = capsys.readouterr().err
    assert "expected one argument" not in err
    assert code in (0, 2)  # a value the model rejects is a clean error, never an argparse failure


# ------------------------------------------------------------------------------------------------ extensions
def _fake_extension(tmp_path, monkeypatch, name, body):
    (tmp_path / f"{name}.py").write_text(body)
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.delitem(sys.modules, name, raising=False)


def test_a_subcommand_whose_extra_is_missing_names_the_pip_install(tmp_path, monkeypatch, capsys):
    from pbicrl.cli import app as cli
    _fake_extension(tmp_path, monkeypatch, "fake_ui_ext", "import starlette_missing_for_the_test\n")
    monkeypatch.setitem(cli._EXTRAS, "starlette_missing_for_the_test", "ui")
    monkeypatch.setattr(cli, "_EXTENSIONS", {"fake_ui_ext": ("label-fake",)})
    assert "label-fake" in cli.build_parser().format_help()  # still listed, not dropped
    assert main(["label-fake", "anything", "--port", "1"]) == 2
    err = capsys.readouterr().err
    assert 'pbicrl label-fake needs starlette_missing_for_the_test' in err and 'pip install "pbicrl[ui]"' in err


def test_any_other_import_error_of_a_subcommand_surfaces(tmp_path, monkeypatch):
    from pbicrl.cli import app as cli
    _fake_extension(tmp_path, monkeypatch, "fake_broken_ext", "from pbicrl.inference.results import no_such_name\n")
    monkeypatch.setattr(cli, "_EXTENSIONS", {"fake_broken_ext": ("broken",)})
    with pytest.raises(ImportError, match="no_such_name"):
        cli.build_parser()


def test_every_extension_mounts_the_subcommands_it_declares():
    from pbicrl.cli import app as cli
    sub = next(a for a in cli.build_parser()._subparsers._group_actions if a.dest == "command")
    declared = {c for commands in cli._EXTENSIONS.values() for c in commands}
    assert declared <= set(sub.choices)
    assert {"infer", "identify", "info", "synthetic", "tune-margins", "check"} <= set(sub.choices)


def test_deprecated_names_in_a_config_file_are_reported_once(data_path, tmp_path, capsys):
    cfg = tmp_path / "old.toml"
    cfg.write_text("method = \"paper\"\nn_iterations = 500\nn_chains = 1\n")
    assert main(["infer", str(data_path), "--out", str(tmp_path / "run"), "--config", str(cfg), "--no-progress",
                 "--json"]) == 0
    err = capsys.readouterr().err
    assert "pbicrl: warning: config key 'method' is deprecated and will be removed in pbicrl 0.3: use 'sampler'" in err
    assert err.count("'n_iterations' is deprecated") == 1 and "Traceback" not in err
    s = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert s["sampler"] == "paper" and s["iterations"] == 500 and s["chains"] == 1


def test_identify_prints_each_warning_once_and_short(capsys):
    """issue 30 item 8: identify printed every warning twice (in its output and again on stderr), each a paragraph
    of 5-8 lines; now one short line per feature, once, and the long text in --json's explanations."""
    assert main(["identify", "example"]) == 0
    out, err = capsys.readouterr()
    lines = [ln for ln in out.splitlines() if ln.startswith("warning: ")]
    assert lines and len(lines) == len(set(lines)) and "warning" not in err
    assert all(len(ln) <= 100 for ln in lines)
    assert any("identified; magnitude beyond that is the prior's" in ln for ln in lines)
    assert main(["identify", "example", "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert [f"warning: {m}" for m in d["warnings"]] == lines
    assert all(len(t) > 200 for t in d["explanations"].values()) and "min|w_p|" in d["explanation"]


def test_identify_companions_on_and_off(capsys):
    """issue 31 item 9: --no-companions leaves out the per-feature sparsest directions (the flags and scales stay),
    --companions asks for them whatever the size."""
    assert main(["identify", "example", "--json", "--companions"]) == 0
    full = json.loads(capsys.readouterr().out)
    assert main(["identify", "example", "--json", "--no-companions"]) == 0
    bare = json.loads(capsys.readouterr().out)
    assert full["companions"] is True and bare["companions"] is False
    unb = [n for n, f in full["features"].items() if f["unbounded"]]
    assert unb and all(full["features"][n]["recession"] for n in unb)
    assert all(bare["features"][n]["recession"] == [] and bare["features"][n]["unbounded"] for n in unb)
    assert [f["min_penalty"] for f in bare["features"].values()] == \
        pytest.approx([f["min_penalty"] for f in full["features"].values()])
    assert main(["identify", "example", "--no-companions"]) == 0
    assert "not computed for the 4 unbounded penalties" in capsys.readouterr().out


def test_identify_out_of_memory_names_what_to_reduce(capsys, monkeypatch):
    """The replay of session 15: identify out of memory advised 'fewer chains/draws', which identify has not."""
    import pbicrl.analysis.identify as ident

    def boom(*a, **k):
        raise MemoryError

    monkeypatch.setattr(ident, "identify", boom)
    assert main(["identify", "example"]) == 2
    err = capsys.readouterr().err
    assert "out of memory" in err and "--candidates" in err and "chains" not in err, err
