"""``python -m pbicrl.experiments.close_loop`` (or ``python -m pbicrl.cli.close_loop``): the command line of
:func:`pbicrl.experiments.close_loop.run`."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from pbicrl.experiments import close_loop as _experiment
from pbicrl.experiments.close_loop import CloseLoopConfig, default_config, run

__all__ = ["main"]

_DESCRIPTION = (_experiment.__doc__ or "").splitlines()[0]


def main(argv: list[str] | None = None) -> int:
    """Command line: ``python -m pbicrl.experiments.close_loop --out DIR [--docs docs] ...``."""
    p = argparse.ArgumentParser(prog="python -m pbicrl.experiments.close_loop", description=_DESCRIPTION)
    p.add_argument("--out", type=Path, required=True, help="cache and results directory")
    p.add_argument("--docs", type=Path, help="also write figures and results JSON to DIR/figures")
    p.add_argument("--pm-steps", type=int, default=100_000)
    p.add_argument("--hc-steps", type=int, default=200_000)
    p.add_argument("--seeds", type=int, default=3, help="point-mass training seeds")
    p.add_argument("--hc-seeds", type=int, default=3, help="HalfCheetah training seeds")
    p.add_argument("--pm-cost-limit", type=float, default=0.1)
    p.add_argument("--hc-cost-limit", type=float, default=1.0)
    p.add_argument("--no-hc-probability", action="store_true", help="skip the inferred-probability HalfCheetah policy")
    p.add_argument("--episodes", type=int, default=100)
    p.add_argument("--iterations", type=int, default=40_000)
    p.add_argument("--envs", default="point_mass,halfcheetah")
    a = p.parse_args(argv)
    import warnings

    from pbicrl.errors import PbicrlWarning

    warnings.simplefilter("ignore", PbicrlWarning)  # the runs' summary.json keep them
    for name in ("pm_steps", "hc_steps", "seeds", "hc_seeds", "episodes", "iterations"):
        if getattr(a, name) < 1:
            p.error(f"--{name.replace('_', '-')}: must be >= 1")
    cfg = default_config(a.pm_steps, a.hc_steps, a.seeds, a.hc_seeds, a.pm_cost_limit, a.hc_cost_limit,
                         not a.no_hc_probability, a.episodes, a.iterations)
    envs = [e.strip() for e in a.envs.split(",") if e.strip()]
    bad = [e for e in envs if e not in ("point_mass", "halfcheetah")]
    if bad or not envs:
        p.error(f"--envs: expected point_mass and/or halfcheetah, got {a.envs!r}")
    cfg = CloseLoopConfig(tuple(pl for pl in cfg.plans if pl.env in envs), cfg.episodes, cfg.iterations, cfg.chains)
    try:
        run(cfg, a.out, a.docs)
    except KeyboardInterrupt:
        print("close_loop: interrupted; checkpoints kept, rerun the same command to resume", file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
