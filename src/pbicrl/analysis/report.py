"""How a posterior reads: the text table, the notebook HTML table and the data frame of its summaries.

:meth:`pbicrl.inference.posterior.Posterior.table`, ``_repr_html_`` and ``to_dataframe`` call :func:`table`,
:func:`to_html` and :func:`to_dataframe`; :func:`records` is their common content, one record per feature and per
constraint parameter.
"""

from __future__ import annotations

import html
import math
import textwrap
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import numpy as np

from pbicrl.inference.draws import INDICATOR_LABELS, SELECTION_THRESHOLD
from pbicrl.inference.summary import is_real

if TYPE_CHECKING:
    from pbicrl.analysis.diagnostics import Diagnostics

__all__ = ["records", "to_dataframe", "to_html", "table", "footer", "INDICATOR_COLUMNS"]

def records(post: Any) -> list[dict[str, Any]]:
    """The rows of :func:`table` as records: one per feature, then one per constraint parameter."""
    cs = post.conditional_summary()
    pdriven = post.prior_driven()
    mins = post.min_penalty()
    skip = post.not_identifiable()
    diag = post.diagnostics()
    p = post.p_constraint
    meaning = post.indicator_meaning
    model = post.in_model()

    def f(x: Any) -> float:
        return float(x) if is_real(x) else float("nan")

    def indicator_cells(j: int) -> dict[str, Any]:
        """The columns that say what c_j means for this sampler (:data:`INDICATOR_MEANINGS`)."""
        if meaning == "posterior":
            return {"p_constraint": float(p[j]), "selected": bool(p[j] > SELECTION_THRESHOLD)}
        if meaning == "chain_frequency":
            return {"frequency_on": float(p[j]), "map_indicator": bool(post.map_indicators[j])}
        return {"in_model": bool(model[j])}

    rows: list[dict[str, Any]] = []
    for j, n in enumerate(post.feature_names):
        v = diag.worst_of(("penalty", "indicator"), n)
        rows.append({"name": n, "kind": "feature", **indicator_cells(j),
                     "min_penalty": float("nan") if n in skip or not model[j] else f(mins[j]),
                     "median": f(cs["median"][j]), "mean": f(cs["mean"][j]),
                     "ci90_low": f(cs["low"][j]), "ci90_high": f(cs["high"][j]),
                     "prior_driven": pdriven[j], "active_draws": int(cs["active_draws"][j]),
                     "rhat": f(v["rhat"]), "ess_bulk": f(v["ess_bulk"]), "ess_tail": f(v["ess_tail"]),
                     "identifiable": n not in skip, "identified_range": None})
    owner = tuple(post.parameter_owner)
    for k, (n, v) in enumerate(post.parameter_summary().items()):
        dv = diag.worst_of(("parameter",), n)
        j = owner[k] if len(owner) == len(post.parameter_names) else None
        lo, hi = v["ci90"]
        own = {k: (float("nan") if isinstance(x, float) else None) for k, x in indicator_cells(0).items()} \
            if j is None else indicator_cells(j)
        rows.append({"name": n, "kind": "parameter", **own,
                     "min_penalty": float("nan"), "median": f(v["median"]), "mean": f(v["mean"]),
                     "ci90_low": f(lo), "ci90_high": f(hi), "prior_driven": v["prior_driven"],
                     "active_draws": int(v["active_draws"]), "rhat": f(dv["rhat"]),
                     "ess_bulk": f(dv["ess_bulk"]), "ess_tail": f(dv["ess_tail"]), "identifiable": True,
                     "identified_range": v["identified_range"]})
    return rows


def to_dataframe(post: Any) -> Any:
    r"""The content of :func:`table` as a :class:`pandas.DataFrame`, one row per feature and parameter.

    Index ``name``; columns ``kind`` (``feature`` / ``parameter``), then what the indicators mean for the
    sampler (:data:`~pbicrl.inference.draws.INDICATOR_MEANINGS`): ``p_constraint``
    (:math:`P(c_j = 1 \mid \mathcal{D})`, of the owning constraint for a parameter) and ``selected`` for
    ``pbicrl``; ``frequency_on`` (share of kept draws with :math:`c_j = 1`) and ``map_indicator`` for
    ``paper`` / ``authors``; ``in_model`` for ``bpl``;
    ``min_penalty`` (identification), ``median``, ``mean``, ``ci90_low``, ``ci90_high`` (of :math:`w_{p,j}`
    given :math:`c_j = 1`; of :math:`\vartheta_k` while its constraint is on), ``prior_driven``,
    ``active_draws``, ``rhat``, ``ess_bulk``, ``ess_tail`` (the worse of penalty and indicator), ``identifiable``
    and ``identified_range``. Undefined numbers are NaN.

    Raises
    ------
    ImportError
        If pandas is not installed (``pip install pandas``).
    """
    try:
        import pandas as pd
    except ImportError as exc:
        raise ImportError(f"Posterior.to_dataframe needs pandas ({exc}): pip install pandas "
                          "(or pip install \"pbicrl[diag]\")") from exc
    return pd.DataFrame.from_records(records(post)).set_index("name")


def to_html(post: Any) -> str:
    """An HTML table of :func:`table`'s content (for notebooks); every text is escaped."""
    e = html.escape
    c1, c2 = INDICATOR_COLUMNS[post.indicator_meaning]
    head = ["feature", c1, c2, "min|w_p|", "med | c=1", "90% interval | c=1", "R-hat", "ESS bulk", "ESS tail"]
    out = [f"<div><p><b>{e(repr(post))}</b></p>", "<table>",
           "<thead><tr>" + "".join(f"<th>{e(h)}</th>" for h in head) + "</tr></thead>", "<tbody>"]
    for r in records(post):
        star = "*" if r["prior_driven"] else ""
        iv = ("-" if not (math.isfinite(r["ci90_low"]) and math.isfinite(r["ci90_high"]))
              else f"[{_num(r['ci90_low'], 9)}, {_num(r['ci90_high'], 9)}]{star}")
        a, b = _indicator_cells(r, post.indicator_meaning)
        cells = [r["name"] if r["kind"] == "feature" else f"parameter {r['name']}",
                 a if r["kind"] == "feature" else "", b,
                 "n/a" if not r["identifiable"] else _num(r["min_penalty"], 8), _num(r["median"], 9), iv,
                 _num(r["rhat"], 6), _num(r["ess_bulk"], 8), _num(r["ess_tail"], 8)]
        out.append("<tr>" + "".join(f"<td>{e(str(c))}</td>" for c in cells) + "</tr>")
    out += ["</tbody></table>", "<ul>"]
    out += [f"<li>{e(line)}</li>" for line in footer(post)]
    out.append("</ul></div>")
    return "\n".join(out)


def table(post: Any, width: int = 100) -> str:
    """A readable table: per feature P(c=1), selected, the identified smallest penalty and the median and
    90% interval of :math:`w_{p,j}` given :math:`c_j = 1`; then parameters; footers; warnings.

    ``*`` marks an interval end that comes from the prior (see :meth:`~pbicrl.inference.posterior.Posterior.prior_driven`).
    """
    rows = [r for r in records(post) if r["kind"] == "feature"]  # the numbers; here only how they are shown
    nw = min(24, max(8, max(len(r["name"]) for r in rows)))
    ends = post.end_flags()
    sens = post.prior_sensitivity()
    diag = post.diagnostics()
    meaning = post.indicator_meaning
    c1, c2 = INDICATOR_COLUMNS[meaning]
    w1, w2 = max(6, len(c1)), max(3, len(c2))
    model = post.in_model()
    head = (f"{'feature':<{nw}}  {c1:>{w1}}  {c2:>{w2}}  {'min|w_p|':>8}  {'med|c=1':>9}  "
            f"{'90% interval | c=1':^24}  {'R-hat':>6}  {'ESS':>6}")
    lines = [head, "-" * len(head)]
    for j, r in enumerate(rows):
        n = r["name"]
        a, b = _indicator_cells(r, meaning)
        if meaning != "fixed" and sens.flags["p_constraint"][j]:
            a += "*"
        mp = "n/a" if not r["identifiable"] else _num(r["min_penalty"], 8) if model[j] else "-"
        lo_d, med_d, hi_d = ends[j]
        iv = _interval(r["ci90_low"], r["ci90_high"], marks=(bool(lo_d), bool(hi_d)))
        med = _num(r["median"], 8) + ("*" if med_d and math.isfinite(r["median"]) else "")
        lines.append(f"{_cut(n, nw):<{nw}}  {a:>{w1}}  {b:>{w2}}  {mp:>8}  "
                     f"{med:>9}  {iv}  {diag.cells('feature', n, compact=True)}")
    psum = post.parameter_summary()
    if psum:
        pw = min(24, max(10, max(len(n) for n in psum)))
        lines += ["", f"{'parameter':<{pw}}  {'med|on':>9}  {'90% interval | on':^24}  {'identified range':^21}  "
                      f"{'R-hat':>6}  {'ESS':>6}"]
        for n, v in psum.items():
            lo, hi = (np.nan if x is None else x for x in v["ci90"])
            iv = _interval(lo, hi, marks=(bool(v["prior_driven"]), bool(v["prior_driven"])))
            rng = v["identified_range"]
            rs = "-" if rng is None else f"[{_num(rng[0], 9)}, {_num(rng[1], 9)}]"
            lines.append(f"{_cut(n, pw):<{pw}}  {_num(v['median'], 9):>9}  {iv}  {rs:^21}  "
                         f"{diag.cells('parameter', n, compact=True)}")
    for line in footer(post, psum, diag=diag):
        lines.extend(textwrap.wrap(line, width=width, subsequent_indent="  ", break_on_hyphens=False) or [""])
    return "\n".join(lines)


def footer(post: Any, psum: dict[str, dict[str, Any]] | None = None, pd: list[bool | None] | None = None,
           skip: dict[str, str] | None = None, diag: "Diagnostics | None" = None) -> list[str]:
    """The lines under :func:`table`'s rows: selection, legend, prior-driven ends, run facts, warnings."""
    names = list(post.feature_names)
    psum = post.parameter_summary() if psum is None else psum
    pd = post.prior_driven() if pd is None else pd
    skip = post.not_identifiable() if skip is None else skip
    diag = post.diagnostics() if diag is None else diag
    foot = [_indicator_footer(post)]
    if post.identified is not None:
        a = post.identified.get("alpha")
        sampled = isinstance(post.identified.get("pairs"), Mapping) and post.identified["pairs"].get("n_pairs")
        foot.append("min|w_p|: smallest penalty with which the rankings order every "
                    + (f"one of the {sampled:,} sampled pairs the likelihood uses" if sampled else "cross-group pair")
                    + (f" with probability >= {1 - a:g}" if is_real(a) else "")
                    + " (identification); '-' = none")
    else:
        foot.append("min|w_p|: '-' (no identification attached)")
    driven = [n for n, x in zip(names, pd) if x] + [n for n, v in psum.items() if v["prior_driven"]]
    sens = post.prior_sensitivity()
    if sens.measured:
        foot.append(f"* prior-driven (measured: {sens.basis}): "
                    + (", ".join(driven) if driven else "none of the intervals")
                    + "; summary.json flags every reported number (posterior.prior_driven)")
    elif driven:
        src = "the identification" if post.identified is not None else \
            "heuristic: interval end beyond the prior's own 5%/95% quantile"
        foot.append(f"* prior-driven ({src}; not measured: the {post.sampler} sampler ignores the prior or it "
                    f"cannot be reweighted): {', '.join(driven)}: the data leave this end open, so it, "
                    "the median and the mean move with the prior")
    if skip:
        foot.append("not identifiable (no R-hat/ESS): " + "; ".join(f"{n} ({r})" for n, r in skip.items()))
    if post.sampler in ("authors", "paper"):
        st = post.authors_statistic()
        foot.append(f"authors' statistic (mean of c*w_p over the last {st['last_iterations']} iterations, mean of "
                    "chains) vs mean over all kept draws: " + "; ".join(
                        f"{n} {_num(st['value'][n], 9)} vs {_num(st['posterior_mean'][n], 9)}" for n in names))
    acc = ", ".join(f"{k} {v:.1%}" for k, v in post.acceptance_rate().items())
    foot.append(f"sampler {post.sampler}; {post.n_chains} chains x {post.settings['iterations']:,} iterations "
                f"({post.n_draws} kept each); acceptance {acc}; {post.runtime_s:.2f} s")
    foot.append(diag.footer(compact=True))
    foot += [f"warning: {m}" for m in post.warnings()]
    return foot


def _indicator_footer(post: Any) -> str:
    """The first footer line: the selection, or what the indicator column is when it is not a selection."""
    mfs = post.most_frequent_set()
    most = (f"{{{', '.join(mfs['features'])}}} in {(mfs['frequency'] or 0.0):.1%} of kept draws")
    if post.indicator_meaning == "posterior":
        return f"selected (P(c=1) > 0.5): {', '.join(post.selected()) or 'none'}; most frequent set: {most}"
    if post.indicator_meaning == "chain_frequency":
        on = [n for n, c in zip(post.feature_names, post.map_indicators) if c]
        return (f"freq on: {INDICATOR_LABELS['chain_frequency']} (share of kept draws with c_j = 1). The "
                f"{post.sampler} sampler's indicator moves (Algorithm 1: likelihood-ratio acceptance, latent "
                "weights) do not target a posterior, so this is not P(c=1) and no set is selected from it. MAP: "
                f"indicators of the highest-density visited draw, as the paper reports: {{{', '.join(on)}}}; "
                f"most frequent set in the chain: {most}")
    model = [n for n, m in zip(post.feature_names, post.in_model()) if m]
    return (f"model: bpl samples the penalties of the candidates ({', '.join(model) or 'none'}) with no "
            "indicators, so there is no P(c=1) and no selection; features that are not candidates are fixed "
            "at w_p = 0 and show '-'")


INDICATOR_COLUMNS = {"posterior": ("P(c=1)", "sel"), "chain_frequency": ("freq on", "MAP"), "fixed": ("model", "")}
"""Headers of the two indicator columns of :func:`table` per :data:`~pbicrl.inference.draws.INDICATOR_MEANINGS`."""


def _indicator_cells(r: Mapping[str, Any], meaning: str) -> tuple[str, str]:
    """The two indicator cells of a table row (a :func:`records` record)."""
    if meaning == "posterior":
        sel = r.get("selected")
        return _prob(r.get("p_constraint")), "-" if sel is None else ("yes" if sel else "no")
    if meaning == "chain_frequency":
        on = r.get("map_indicator")
        return _prob(r.get("frequency_on")), "-" if on is None else ("on" if on else "off")
    m = r.get("in_model")
    return "-" if m is None else ("yes" if m else "no"), ""


def _prob(x: Any) -> str:
    return f"{float(x):.3f}" if is_real(x) and math.isfinite(float(x)) else "-"


def _num(x: Any, width: int) -> str:
    """A number in at most ``width`` characters (4 significant digits), ``-`` for none / NaN."""
    if x is None or not isinstance(x, (int, float, np.integer, np.floating)) or not math.isfinite(float(x)):
        return "-"
    x = float(x)
    s = f"{x:.4g}" if 1e-3 <= abs(x) < 1e4 or x == 0 else f"{x:.2e}"
    return s if len(s) <= width else f"{x:.1e}"


def _interval(lo: float, hi: float, *, marks: tuple[bool, bool] = (False, False)) -> str:
    """``[  lo , hi ]`` in 24 characters; ``*`` after each end that is prior-driven (``marks``)."""
    mark_lo = "*" if marks[0] else " "
    mark_hi = "*" if marks[1] else " "
    if not (math.isfinite(lo) and math.isfinite(hi)):
        return f"{'-':^24}"
    return f"[{_num(lo, 9):>9}{mark_lo}, {_num(hi, 9):>9}{mark_hi}]"


def _cut(name: str, width: int) -> str:
    return name if len(name) <= width else name[: width - 1] + "~"

