"""The shared argument types of the command line: what each accepts and the message for what it refuses."""

import argparse
import re

import pytest

from pbicrl.cli import argtypes


@pytest.mark.parametrize("fn, good, bad, message", [
    (argtypes.positive_int, {"1": 1, "1_000": 1000}, ["0", "-3", "1.5", "x"], "a positive integer"),
    (argtypes.nonneg_int, {"0": 0, "7": 7}, ["-1", "nan"], "a non-negative integer"),
    (argtypes.positive_float, {"0.5": 0.5, "1e3": 1000.0}, ["0", "-1", "inf", "nan"], "a positive number"),
    (argtypes.nonneg_float, {"0": 0.0, "2.5": 2.5}, ["-0.1", "inf", "nan", "x"], "a finite number >= 0"),
    (argtypes.open_unit, {"0.5": 0.5, "0.99": 0.99}, ["0", "1", "nan", "x"], "a number in (0, 1)"),
    (argtypes.probability, {"0": 0.0, "1": 1.0, "0.25": 0.25}, ["1.01", "-0.1", "nan", "p"], "a number in [0, 1]"),
    (argtypes.port, {"0": 0, "8000": 8000, "65535": 65535}, ["65536", "-1", "80.5", "http"], "a port from 0 to 65535"),
    (argtypes.power, {"pairs": "pairs", "0.5": 0.5, "1": 1.0}, ["0", "1.5", "all"], "a number in (0, 1]"),
])
def test_accepts_and_refuses_with_a_message(fn, good, bad, message):
    for text, value in good.items():
        assert fn(text) == value
    for text in bad:
        with pytest.raises(argparse.ArgumentTypeError, match=re.escape(message)) as exc:
            fn(text)
        assert repr(text) in str(exc.value)  # names what it got


def test_label_and_demos_use_them(capsys):
    from pbicrl.cli.app import build_parser

    parser = build_parser()
    for argv in (["label", "x.npz", "--out", "y.npz", "--port", "70000"],
                 ["envs", "demos", "--env", "point_mass", "--paper-protocol", "--p-good", "2", "--out", "d.npz"]):
        with pytest.raises(SystemExit):
            parser.parse_args(argv)
    err = capsys.readouterr().err
    assert "expected a port from 0 to 65535, got '70000'" in err
    assert "expected a number in [0, 1], got '2'" in err
