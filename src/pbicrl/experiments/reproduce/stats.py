"""Statistics over a reproduction's seeds: mean and spread, and the wall experiments' CMSE rows."""

from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np

__all__ = ["mean_std", "wall_row"]


def mean_std(values: Sequence[float]) -> tuple[float, float]:
    v = np.asarray(values, dtype=float)
    return float(v.mean()), float(v.std())


def wall_row(rr: list[dict], wall: float) -> dict[str, Any]:
    """CMSE of one model at one size: the MAP location (the paper's convention) and the posterior median of the
    wall given the wall is on (pbicrl's point estimate), with the seeds whose estimate has no wall counted apart."""
    from pbicrl.analysis.metrics import cmse_location

    def cm(thetas: list[Any]) -> tuple[tuple[float, float], int]:
        errs = [cmse_location(t, wall) for t in thetas if t is not None and math.isfinite(t)]
        return (mean_std(errs) if errs else (math.inf, math.inf)), int(len(thetas) - len(errs))

    map_t = [r["map_parameters"][0] if r["map_parameters"] else None for r in rr]
    sel_t = [r["selected_parameters"][0] if r["selected_parameters"] else None for r in rr]
    cm_map, off_map = cm(map_t)
    cm_sel, off_sel = cm(sel_t)
    ident = [r.get("identified_parameters", {}).get("wall.threshold") for r in rr]
    return {"cmse": cm_map, "theta": map_t, "wall_off_seeds": off_map,
            "cmse_selected": cm_sel, "theta_selected": sel_t, "wall_off_seeds_selected": off_sel,
            "theta_ci90": [r.get("parameter_ci90", [[None, None]])[0] for r in rr],
            "p_wall": [r["p_constraint"][-1] for r in rr], "identified": ident,
            "penalty": [r["map_effective_penalty"][-1] for r in rr],
            "penalty_selected": [r["selected_effective_penalty"][-1] for r in rr],
            "runtime_s": mean_std([r["runtime_s"] for r in rr]), "n_pairs": rr[0]["n_pairs"]}
