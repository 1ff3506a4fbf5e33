"""``pbicrl envs ...``: environments and demonstrators (train SAC, roll out demonstrations, plot them).

Mounts :mod:`pbicrl.cli.navigation` (point mass, Fetch-Reach, grid) and :mod:`pbicrl.cli.wall`
(HalfCheetah / Ant with a wall) under one subcommand; optional dependencies load only when a command runs.
"""

from __future__ import annotations

from typing import Any

__all__ = ["add_subcommands"]


def add_subcommands(sub: Any) -> None:
    from pbicrl.cli import wall as wall_cli
    from pbicrl.cli import navigation as nav_cli

    p = sub.add_parser("envs", help="environments and SAC demonstrators: train, demos, plot (extras envs, rl)",
                       description="Train SAC demonstrators, roll out and label demonstrations, plot them.")
    inner = p.add_subparsers(dest="envs_command", required=True, metavar="COMMAND")
    nav_cli.add_subcommands(inner)
    wall_cli.add_subcommands(inner)
