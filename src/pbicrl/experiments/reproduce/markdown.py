"""The written side of a reproduction: number formats of the Markdown tables and the report files
(``report.md``, ``results.json``, the figures it links)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Callable

from pbicrl.experiments.reproduce.configs import Context

__all__ = ["fmt_mean_std", "fmt_cmse", "fmt_interval", "write_report"]


def fmt_mean_std(m: float, s: float, digits: int = 3) -> str:
    return f"{m:.{digits}g} ± {s:.{digits}g}"


def fmt_cmse(entry: dict) -> str:
    """CMSE over the seeds whose MAP has the wall, and how many seeds had none."""
    off = entry.get("wall_off_seeds", 0)
    body = "no seed found a wall" if not math.isfinite(entry["cmse"][0]) else fmt_mean_std(*entry["cmse"])
    return body + (f" ({off} seed(s) without a wall)" if off else "")


def fmt_interval(iv: Any) -> str:
    """``(lo, hi]`` rounded outward to 0.01, so that the printed interval contains the identified one
    (a lower end of 9.998 prints as 9.99, not as a misleading 10.00)."""
    if not iv or iv[0] is None:
        return "-"
    lo, hi = math.floor(round(float(iv[0]) * 100.0, 6)) / 100.0, float(iv[1])
    if math.isfinite(hi):
        hi = math.ceil(round(hi * 100.0, 6)) / 100.0
    return f"({lo:.2f}, {hi:.2f}]"


def write_report(ctx: Context, name: str, title: str, lines: list[str], results: dict, figures: Callable[[Path], list[str]] | None) -> Path:
    d = ctx.out / name
    d.mkdir(parents=True, exist_ok=True)
    figs: list[str] = []
    if figures is not None:
        try:
            figs = figures(d)
        except ImportError as exc:
            lines.append(f"\n_Figures skipped: {exc}_")
    body = [f"# {title}", "", *lines, ""]
    for f in figs:
        body += [f"![{f}]({f})", ""]
    from pbicrl._atomic import write_json, write_text

    write_text(d / "report.md", "\n".join(body))
    write_json(d / "results.json", results, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o))
    return d / "report.md"
