"""The ``pbicrl`` command line: every argparse parser lives in this package.

``app`` is the top-level command (``pbicrl infer``, ``reproduce``, ``sweep``, ...); ``posterior``
(``check``, ``export``, ``import``, ...), ``envs``, ``navigation`` and ``wall`` (``pbicrl envs ...``) and
``label`` (``pbicrl label``, ``pbicrl suggest``) add their subcommands to it; ``argtypes`` holds the shared
argument types.
"""

from pbicrl.cli.app import build_parser, main

__all__ = ["build_parser", "main"]
