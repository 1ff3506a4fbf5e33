"""argparse value types shared by every ``pbicrl`` subcommand: each rejects a bad value with a message."""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Callable, Sequence
from typing import Any

__all__ = ["DeprecatedFlag", "standalone_parser", "finite_float_or_auto", "floats", "iterations", "margins",
           "nonneg_float", "nonneg_int", "open_unit", "pairs", "port", "positive_float", "positive_int", "power",
           "probability", "rhat_target"]


def floats(text: str) -> list[float]:
    """Comma- or space-separated numbers."""
    try:
        return [float(x) for x in text.replace(",", " ").split()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, got {text!r}") from None


def margins(text: str) -> list:
    """'0,2.9' (gaps) or '0,0,6;0,0,2.9;0,0,0' (matrix rows separated by ';')."""
    if ";" in text:
        return [floats(row) for row in text.split(";")]
    return floats(text)


def pairs(text: str) -> str | int:
    """``all`` or a positive number of pairs."""
    if text == "all":
        return "all"
    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected 'all' or a positive integer, got {text!r}") from None
    if n < 1:
        raise argparse.ArgumentTypeError(f"expected 'all' or a positive integer, got {text!r}")
    return n


def _number(text: str, cast: type, ok: Callable[[Any], bool], expected: str) -> Any:
    """``cast(text)`` if it parses and ``ok`` accepts it; else an argparse error saying what was ``expected``."""
    try:
        x = cast(text.replace("_", "") if cast is int else text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected {expected}, got {text!r}") from None
    if not ok(x):
        raise argparse.ArgumentTypeError(f"expected {expected}, got {text!r}")
    return x


def power(text: str) -> float | str:
    """A likelihood power in (0, 1], or ``pairs``."""
    if text == "pairs":
        return text
    return _number(text, float, lambda x: 0 < x <= 1, "a number in (0, 1] or 'pairs'")


def positive_int(text: str) -> int:
    """An integer >= 1 (``1_000`` allowed)."""
    return _number(text, int, lambda n: n >= 1, "a positive integer")


def nonneg_int(text: str) -> int:
    """An integer >= 0 (``1_000`` allowed)."""
    return _number(text, int, lambda n: n >= 0, "a non-negative integer")


def positive_float(text: str) -> float:
    """A finite number > 0 (NaN is not)."""
    return _number(text, float, lambda x: 0 < x < float("inf"), "a positive number")


def nonneg_float(text: str) -> float:
    """A finite number >= 0 (NaN is not)."""
    return _number(text, float, lambda x: 0 <= x < float("inf"), "a finite number >= 0")


def open_unit(text: str) -> float:
    """A number in the open interval (0, 1)."""
    return _number(text, float, lambda x: 0.0 < x < 1.0, "a number in (0, 1)")


def finite_float_or_auto(text: str) -> float | str:
    """``auto``, or a finite number (NaN and infinities are not)."""
    if text == "auto":
        return text
    return _number(text, float, math.isfinite, "auto or a finite number")


def iterations(text: str) -> int | str:
    """``auto`` (run until converged) or a positive integer."""
    if text == "auto":
        return text
    return _number(text, int, lambda n: n >= 1, "'auto' or a positive integer")


def rhat_target(text: str) -> float:
    """A finite number > 1 (an R-hat target)."""
    return _number(text, float, lambda x: 1.0 < x < float("inf"), "a number > 1")


def probability(text: str) -> float:
    """A number in [0, 1]."""
    return _number(text, float, lambda x: 0.0 <= x <= 1.0, "a number in [0, 1]")


def port(text: str) -> int:
    """A TCP port, 0 (any free port) to 65535."""
    return _number(text, int, lambda v: 0 <= v <= 65535, "a port from 0 to 65535")


class DeprecatedFlag(argparse.Action):
    """An old spelling of an option, accepted until pbicrl 0.3: stores like the new one and says so on stderr.

    ``p.add_argument("--protocol", dest="pairs", action=DeprecatedFlag, new="--pairs", choices=...)``. The
    command line does not print library warnings (:mod:`pbicrl.cli`), so the note is printed here.
    """

    def __init__(self, option_strings: Sequence[str], dest: str, *, new: str, **kwargs: Any) -> None:
        kwargs.setdefault("help", f"deprecated: use {new}")
        super().__init__(option_strings, dest, **kwargs)
        self.new = new

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any,
                 option_string: str | None = None) -> None:
        print(f"pbicrl: warning: {option_string} is deprecated and will be removed in pbicrl 0.3: use {self.new}",
              file=sys.stderr)
        setattr(namespace, self.dest, values)


def standalone_parser(prog: str, description: str, add_subcommands: Callable[[Any], None]) -> argparse.ArgumentParser:
    """A parser for ``python -m <package>`` holding the subcommands a module also mounts under ``pbicrl``."""
    parser = argparse.ArgumentParser(prog=prog, description=description)
    add_subcommands(parser.add_subparsers(dest="command", required=True))
    return parser
