r"""``pbicrl benchmark icrl report``: the ICRL benchmark's table and figures from training run directories.

Reads ``<runs>/<task>/<method>/seed<k>/`` written by :func:`pbicrl.experiments.icrl_benchmark.train_policy`
(an ICL run in the same layout under the method ``icl``) and writes ``report.md``, ``results.json`` and one
figure per task (``figures/icrl_<task>.png``: violation rate against feasible cumulative reward, methods as
points with error bars of one standard deviation over seeds) and its learning curves
(``figures/icrl_<task>_curves.png``: both metrics of every evaluation against the training steps, per seed and
method, so a reader sees whether a row's policies had converged). ``report.md`` also checks issue 28's targets
per task from the rows' means (boundary, violation, feasible reward, against ICL), and whether each
PPO-Lagrangian row had stopped improving at its budget (:func:`plateau`).

Metrics, as the benchmark defines them (``shared/notes/icrl-benchmark.md`` section 2), per seed, from the
**evaluation episodes of the stochastic policy** at the run's last evaluation (``eval.jsonl``: 10 episodes, 100
for the pendulum, on fresh environments, the true cost):

* violation rate = share of the episodes with at least one violating step (:math:`x` beyond the wall after a
  step);
* feasible cumulative reward = mean over the episodes of the reward summed over the steps before the first
  violating step (the whole episode's reward when it never violates).

A row gives mean :math:`\pm` standard deviation (``ddof=1``; 0 with one seed) over seeds. The same two metrics
over the last 100 *training* episodes (``curve.jsonl``, the benchmark's own plotting window) are given beside
them. A run counts as done when its ``done.json`` is there; runs still training are listed separately and are
not in the table. Rows without any finished seed are listed as missing.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["PLATEAU_TOL", "PLATEAU_WINDOW", "REPORT_METHODS", "build_report", "curve_series", "plateau",
           "run_status", "seed_metrics"]

REPORT_METHODS: tuple[str, ...] = ("ppo", "ppo_lag_true", "ppo_lag_inferred", "icl")
_LABELS = {"ppo": "PPO (no constraint)", "ppo_lag_true": "PPO-Lagrangian, true cost",
           "ppo_lag_inferred": "PPO-Lagrangian, pbicrl inferred cost", "icl": "ICL baseline"}
_COLOURS = {m: f"C{i}" for i, m in enumerate(REPORT_METHODS)}  # one colour per method in every figure
PLATEAU_WINDOW = 0.2
"""Share of a run's steps in each of the two windows :func:`plateau` compares (the last fifth and the one
before)."""
PLATEAU_TOL = 0.05
"""Largest relative change of the feasible reward between those windows that :func:`plateau` calls stable."""


def _read_jsonl(path: Path) -> list[dict[str, Any]]:
    """The rows of a JSON-lines file, or of ``<path>.gz`` where only that exists (the committed snapshot of a long
    run compresses its curve: the pendulum's 100,000 episodes are 25 MB of text)."""
    rows: list[dict[str, Any]] = []
    gz = path.with_name(path.name + ".gz")
    if path.is_file():
        text = path.read_text(encoding="utf-8")
    elif gz.is_file():
        import gzip

        with gzip.open(gz, "rt", encoding="utf-8") as fh:
            text = fh.read()
    else:
        return rows
    for i, line in enumerate(text.splitlines(), 1):
        if line.strip():
            try:
                rows.append(json.loads(line))
            except json.JSONDecodeError:
                raise ValueError(f"runs: {path} line {i} is not JSON") from None
    return rows


def seed_metrics(seed_dir: str | os.PathLike[str], *, training: bool = True) -> dict[str, Any]:
    """The metrics of one seed's run directory (see the module docstring).

    Returns
    -------
    dict
        ``done`` (bool), ``steps``, ``violation_rate``, ``feasible_reward``, ``reward`` and ``eval_episodes`` of
        the last evaluation (None without one), ``train_violation_rate`` and ``train_feasible_reward`` of the
        last 100 training episodes (None without any), ``wall_s``, ``inferred_cost`` (from ``config.json``;
        ``ppo_lag_inferred`` runs), and for a finished ``icl`` run ``icl_location`` (from ``done.json``: where ICL's
        learned constraint first reaches 0.5, None if nowhere).
    """
    d = Path(seed_dir)
    evals = _read_jsonl(d / "eval.jsonl")
    # every training episode: the largest file of a run (25 MB for a pendulum run), read only when asked for
    curve = _read_jsonl(d / "curve.jsonl")[-100:] if training else []

    def read(name: str) -> dict[str, Any]:
        return json.loads((d / name).read_text(encoding="utf-8")) if (d / name).is_file() else {}

    fin, prog = read("done.json"), read("progress.json")
    # a finished run being extended (a larger STEPS) is in progress again: its done.json is older than its evaluations
    done = bool(fin) and not (prog.get("steps") or 0) > (fin.get("steps") or 0)
    info = fin if done else prog
    out: dict[str, Any] = {"done": done, "steps": info.get("steps"), "wall_s": info.get("wall_s"),
                           "violation_rate": None, "feasible_reward": None, "reward": None, "eval_episodes": 0,
                           "train_violation_rate": None, "train_feasible_reward": None}
    if done and "icl_location" in info:
        out["icl_location"] = info["icl_location"]
    if evals:
        eps = evals[-1].get("episodes") or []
        if not eps:
            raise ValueError(f"runs: the last evaluation in {d / 'eval.jsonl'} has no episodes")
        for k in ("constraint", "reward_nc", "reward"):
            if any(k not in e for e in eps):
                raise ValueError(f"runs: an episode of the last evaluation in {d / 'eval.jsonl'} has no {k!r}")
        out.update(violation_rate=float(np.mean([e["constraint"] for e in eps])),
                   feasible_reward=float(np.mean([e["reward_nc"] for e in eps])),
                   reward=float(np.mean([e["reward"] for e in eps])), eval_episodes=len(eps),
                   eval_steps=evals[-1].get("steps"))
        rows = [r for r in evals if r.get("episodes") and r.get("steps") is not None]
        out["eval_curve"] = {  # every evaluation, for the learning curves
            "steps": [int(r["steps"]) for r in rows],
            "violation_rate": [float(np.mean([e.get("constraint", np.nan) for e in r["episodes"]])) for r in rows],
            "feasible_reward": [float(np.mean([e.get("reward_nc", np.nan) for e in r["episodes"]])) for r in rows]}
        if out["steps"] is None:
            out["steps"] = evals[-1].get("steps")
    if curve:
        out.update(train_violation_rate=float(np.mean([e["constraint"] for e in curve])),
                   train_feasible_reward=float(np.mean([e["reward_nc"] for e in curve])))
    cfg = d / "config.json"
    if cfg.is_file():
        c = json.loads(cfg.read_text(encoding="utf-8"))
        if "inferred_cost" in c:
            out["inferred_cost"] = c["inferred_cost"]
            out["inferred_run"] = c.get("inferred_run")
    return out


def run_status(runs: str | os.PathLike[str]) -> list[dict[str, Any]]:
    """Where every run under ``runs`` stands (``<runs>/<task>/<method>/seed<k>``), for a benchmark that trains
    for hours: what is done, what trains now, what was stopped and would resume.

    Returns
    -------
    list of dict
        Per run, in path order: ``run`` (``task/method/seed<k>``), ``state`` (``"done"``; ``"training"``: its
        lock names a live process; ``"stopped"``: progress recorded, no live process, rerun to resume;
        ``"started"``: nothing recorded yet), ``steps``, ``target`` (the steps asked for, None if unknown),
        ``violation_rate`` and ``feasible_reward`` of the last evaluation (None without one), ``wall_s``, and
        ``eta_s`` for a training run (the steps left at its average pace so far; None otherwise).
    """
    from pbicrl._atomic import pid_alive

    root = Path(runs)
    if not root.is_dir():
        raise ValueError(f"runs: {root} is not a directory (the --out of the training runs)")
    out = []
    for d in sorted(root.glob("*/*/seed*")):
        if not d.is_dir():
            continue
        m = seed_metrics(d, training=False)
        prog = d / "progress.json"
        target = json.loads(prog.read_text(encoding="utf-8")).get("total_steps_target") if prog.is_file() else None
        lock = d / "lock"
        try:
            pid = int(lock.read_text(encoding="utf-8").strip() or "0") if lock.is_file() else 0
        except (OSError, ValueError):
            pid = 0
        if m["done"]:
            state, target = "done", m["steps"]
        elif pid and pid_alive(pid):
            state = "training"
        elif m["steps"]:
            state = "stopped"
        else:
            state = "started"
        eta = None
        if state == "training" and target and m["steps"] and m["wall_s"]:
            eta = max(0.0, (int(target) - int(m["steps"])) * float(m["wall_s"]) / int(m["steps"]))
        out.append({"run": d.relative_to(root).as_posix(), "state": state, "steps": m["steps"], "target": target,
                    "violation_rate": m["violation_rate"], "feasible_reward": m["feasible_reward"],
                    "wall_s": m["wall_s"], "eta_s": eta})
    return out


def _decimals(wall: float) -> int:
    """Decimals that resolve a boundary on the wall's own scale: 3 for |wall| >= 1, 4 for the swimmer's 0.5, 5 for
    the pendulum's 0.015 (whose good demonstrations stop 0.0003 short of it)."""
    return 3 + max(0, -math.floor(math.log10(abs(wall)))) if wall else 3


def _mean_sd(vals: Sequence[float]) -> tuple[float, float]:
    a = np.asarray(vals, dtype=np.float64)
    return float(a.mean()), float(a.std(ddof=1)) if a.size > 1 else 0.0


def _fmt(ms: tuple[float, float] | None, digits: int, n: int = 2) -> str:
    if ms is None:
        return "-"
    return f"{ms[0]:.{digits}f}" if n < 2 else f"{ms[0]:.{digits}f} ± {ms[1]:.{digits}f}"  # no sd of one seed


def build_report(runs: str | os.PathLike[str], out_dir: str | os.PathLike[str], *,
                 tasks: Sequence[str] | None = None, methods: Sequence[str] = REPORT_METHODS,
                 seeds_planned: int = 5, figures: bool = True) -> dict[str, Any]:
    """Write ``report.md``, ``results.json`` and ``figures/icrl_<task>.png`` into ``out_dir``.

    Parameters
    ----------
    runs : path
        Root of the training runs (``<runs>/<task>/<method>/seed<k>``).
    out_dir : path
        Where the report goes (created).
    tasks : sequence of str, optional
        Tasks to report (default: all five, in the benchmark's order; absent ones are reported missing). Not empty,
        no task twice.
    methods : sequence of str
        Methods (rows) per task (default :data:`REPORT_METHODS`). Not empty, no method twice.
    seeds_planned : int
        Seeds each row should have (stated against the seeds found).
    figures : bool
        Draw the figures (needs matplotlib; without it the report says so).

    Returns
    -------
    dict
        What ``results.json`` holds: per task and method the per-seed metrics and the aggregates, and the lists
        of missing rows and runs in progress.
    """
    from pbicrl._atomic import write_json, write_text
    from pbicrl.envs.icrl_benchmark import ICRL_TASKS, icrl_task
    from pbicrl.experiments.icrl_benchmark import ICL_TASKS, selection

    root = Path(runs)
    if not root.is_dir():
        raise ValueError(f"runs: {root} is not a directory (the --out of the training runs)")
    names = selection("tasks", tasks, list(ICRL_TASKS), canonical=lambda t: icrl_task(t).name)
    methods = selection("methods", methods, REPORT_METHODS)
    if int(seeds_planned) != seeds_planned or seeds_planned < 1:
        raise ValueError(f"seeds_planned: must be an integer >= 1, got {seeds_planned!r}")
    # as given: a committed report names the path a reader can rerun it on, not this machine's absolute one
    results: dict[str, Any] = {"runs": str(runs), "tasks": {}, "missing": [], "in_progress": [],
                               "metric_source": "last evaluation in eval.jsonl: stochastic-policy episodes, true cost"}
    for t in names:
        rows: dict[str, Any] = {}
        for m in methods:
            mdir = root / t / m
            seeds = sorted((p for p in mdir.glob("seed*") if p.is_dir() and p.name[4:].isdigit()),
                           key=lambda p: int(p.name[4:])) if mdir.is_dir() else []
            per = {p.name: seed_metrics(p) for p in seeds}
            done = {k: v for k, v in per.items() if v["done"] and v["violation_rate"] is not None}
            for k, v in per.items():
                if k not in done:
                    results["in_progress"].append({"task": t, "method": m, "seed": k, "steps": v["steps"]})
            agg: dict[str, Any] = {"seeds_done": len(done), "seeds_found": len(per), "per_seed": per}
            if done:
                for key in ("violation_rate", "feasible_reward", "reward", "train_violation_rate",
                            "train_feasible_reward", "steps", "wall_s"):
                    vals = [v[key] for v in done.values() if v.get(key) is not None]
                    agg[key] = _mean_sd(vals) if vals else None
                inf = [v["inferred_cost"] for v in done.values() if "inferred_cost" in v]
                if inf:
                    agg["inferred_boundary"] = inf[0].get("boundary")
                    agg["inferred_mode"] = inf[0].get("mode")
                agg["plateau"] = plateau(done)
                locs = [v["icl_location"] for v in done.values() if "icl_location" in v]
                if locs:
                    found = [float(x) for x in locs if x is not None]
                    agg["icl_location"] = _mean_sd(found) if found else None
                    agg["icl_location_seeds"] = [len(found), len(locs)]
            else:
                why = "no run directory" if not per else "no finished seed"
                if m == "icl" and not per and t not in ICL_TASKS:
                    tasks = sorted(ICL_TASKS)
                    why = f"not run: the icl method has {', '.join(tasks[:-1])} and {tasks[-1]} only"
                results["missing"].append({"task": t, "method": m, "why": why})
            rows[m] = agg
        results["tasks"][t] = rows

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    fig_note = ""
    drawn: dict[str, str] = {}
    curves: dict[str, str] = {}
    if figures:
        try:
            drawn, curves = _figures(results, out / "figures")
        except ImportError:
            fig_note = 'Figures not drawn: matplotlib is not installed (pip install "pbicrl[plot]").'
    write_text(out / "report.md", _markdown(results, names, methods, seeds_planned, drawn, curves, fig_note))
    write_json(out / "results.json", results)
    return results


def _markdown(res: dict[str, Any], names: Sequence[str], methods: Sequence[str], seeds_planned: int,
              drawn: dict[str, str], curves: dict[str, str], fig_note: str) -> str:
    from pbicrl.envs.icrl_benchmark import icrl_task

    intro = ("Per seed: violation rate (share of episodes with at least one step beyond the wall) and feasible "
             "cumulative reward (reward before the first violating step) over the **evaluation episodes of the "
             "stochastic policy** at the run's last evaluation (10 episodes, 100 for the pendulum; true cost). "
             "Mean ± sd over the finished seeds (the value alone for one seed). `train` columns: the same metrics "
             "over the last 100 training episodes (the benchmark's own plotting window).")
    lines = ["# ICRL benchmark (Liu et al., ICLR 2023): results", "",
             "Generated by `pbicrl benchmark icrl report` from the training runs in `" + res["runs"] + "`.", "",
             intro, ""]
    n_rows = len(names) * len(methods)
    have = (f"**{n_rows - len(res['missing'])} of {n_rows} rows** ({len(names)} task{'s' * (len(names) != 1)} x "
            f"{len(methods)} method{'s' * (len(methods) != 1)}) "
            f"have at least one finished seed; {seeds_planned} seeds are planned per row.")
    lines += [have, ""]
    if res["missing"]:
        lines += ["**Missing rows** (not in the table):", "", "| task | missing |", "|---|---|"]
        for t in names:
            miss = [m for m in res["missing"] if m["task"] == t]
            if miss:
                lines.append(f"| {t} | " + "; ".join(f"{_LABELS[m['method']]} ({m['why']})" for m in miss) + " |")
        lines.append("")
    else:
        lines += ["No row is missing.", ""]
    if res["in_progress"]:
        lines += ["**Runs still training** (not counted): " + "; ".join(
            f"{r['task']} / {r['method']} / {r['seed']} " + (f"at {r['steps']} steps" if r["steps"] is not None
                                                             else "started, no progress recorded yet")
            for r in res["in_progress"]) + ".", ""]
    header = ("| task | method | seeds | steps | violation rate | feasible reward | reward | train violation rate | "
              "train feasible reward | wall time per seed (h) |")
    lines += [header, "|---|---|---|---|---|---|---|---|---|---|"]
    for t in names:
        for m in methods:
            a = res["tasks"][t][m]
            if not a["seeds_done"]:
                continue
            steps = a["steps"][0] if a.get("steps") else math.nan
            wall = a.get("wall_s")
            n = a["seeds_done"]
            lines.append(f"| {t} | {_LABELS[m]} | {n} of {seeds_planned} | {steps:,.0f} | "
                         f"{_fmt(a['violation_rate'], 2, n)} | {_fmt(a['feasible_reward'], 0, n)} | "
                         f"{_fmt(a['reward'], 0, n)} | {_fmt(a.get('train_violation_rate'), 2, n)} | "
                         f"{_fmt(a.get('train_feasible_reward'), 0, n)} | "
                         f"{'-' if not wall else f'{wall[0] / 3600:.2f}'} |")
    thr = [(t, res["tasks"][t]["ppo_lag_inferred"]) for t in names if "ppo_lag_inferred" in res["tasks"][t]
           and res["tasks"][t]["ppo_lag_inferred"].get("inferred_boundary")]
    if thr:
        lines += ["", "Inferred wall against the true one (the boundary the `ppo_lag_inferred` cost used):", "",
                  "| task | mode | inferred boundary | true wall |", "|---|---|---|---|"]
        for t, a in thr:
            spec = icrl_task(t)
            b = ", ".join(f"{k} {'<=' if spec.side == 'behind' else '>='} {v[0]:.{_decimals(spec.wall)}f}"
                          for k, v in a["inferred_boundary"].items())
            lines.append(f"| {t} | {a.get('inferred_mode')} | {b} | x {'<' if spec.side == 'behind' else '>'} "
                         f"{spec.wall:g} |")
    lines += _target_lines(res, names)
    lines += _plateau_lines(res, names, methods)
    icl = [(t, res["tasks"][t]["icl"]) for t in names if "icl" in res["tasks"][t]
           and res["tasks"][t]["icl"].get("icl_location_seeds")]
    if icl:
        lines += ["", "ICL's learned wall against the true one (where its constraint c first reaches 0.5, scanning "
                  "from the good demonstrations' nearest approach to the wall; mean ± sd over the seeds where it "
                  "does):", "", "| task | ICL wall | seeds with a wall | true wall |", "|---|---|---|---|"]
        for t, a in icl:
            spec = icrl_task(t)
            n_found, n_all = a["icl_location_seeds"]
            loc = a.get("icl_location")
            rel = "<" if spec.side == "behind" else ">="
            wall = "none" if loc is None else f"x {rel} {_fmt(loc, _decimals(spec.wall), n_found)}"
            lines.append(f"| {t} | {wall} | {n_found} of {n_all} | x {'<' if spec.side == 'behind' else '>'} "
                         f"{spec.wall:g} |")
    if drawn:
        lines += [""] + [f"![{t}]({p})" for t, p in drawn.items()]
        if curves:
            lines += ["", "Learning curves: both metrics at every evaluation (10 stochastic episodes, 100 for the "
                      "pendulum) against the training steps; thin lines are seeds (dashed: still training), "
                      "the thick line of each method the mean over its finished seeds at the steps they all reached. "
                      "The `ppo_lag_true` curves are the reference expert's: a row's numbers mean something once its "
                      "curve has flattened.", ""]
            lines += [f"![{t} curves]({p})" for t, p in curves.items()]
    if fig_note:
        lines += ["", fig_note]
    return "\n".join(lines) + "\n"


def _target_lines(res: dict[str, Any], names: Sequence[str]) -> list[str]:
    """The issue's targets per task, from the rows' means: the inferred boundary on the safe side of the true wall or
    within 0.1 of it; violation rate with the inferred cost at most 0.05 above the true cost's; feasible reward at
    least 90% of the true cost's; at least ICL's on both metrics. '-' where a row has no finished seed."""
    from pbicrl.envs.icrl_benchmark import icrl_task
    from pbicrl.experiments.icrl_benchmark import ICL_TASKS

    out = ["", "Targets (means over the finished seeds; a row with fewer seeds than planned is provisional):", "",
           "| task | boundary: safe side or within 0.1 | violation: inferred - true <= 0.05 | "
           "feasible reward: inferred / true >= 0.9 | inferred vs ICL: violation <= and feasible >= |",
           "|---|---|---|---|---|"]
    any_row = False
    for t in names:
        rows = res["tasks"][t]
        inf, tru, icl = (rows.get(m, {}) for m in ("ppo_lag_inferred", "ppo_lag_true", "icl"))
        if not inf.get("seeds_done") and not inf.get("inferred_boundary"):
            continue
        any_row = True
        spec = icrl_task(t)
        b = next(iter((inf.get("inferred_boundary") or {}).values()), None)
        if b:
            gap = (spec.wall - b[0]) if spec.side == "infront" else (b[0] - spec.wall)  # > 0: on the safe side
            d = _decimals(spec.wall)
            side = "safe side" if gap >= 0 else "unsafe side"
            bound = f"{b[0]:.{d}f} vs {spec.wall:g}: {side} by {abs(gap):.{d}f}" + (
                " (met)" if gap >= 0 or abs(gap) <= 0.1 else " (missed)")
        else:
            bound = "-"
        have = bool(inf.get("seeds_done")) and bool(tru.get("seeds_done"))
        if have:
            dv = inf["violation_rate"][0] - tru["violation_rate"][0]
            viol = f"{dv:+.2f} ({'met' if dv <= 0.05 else 'missed'})"
            ratio = inf["feasible_reward"][0] / tru["feasible_reward"][0] if tru["feasible_reward"][0] > 0 else math.nan
            feas = f"{ratio:.2f} ({'met' if ratio >= 0.9 else 'missed'})" if math.isfinite(ratio) else "-"
        else:
            viol = feas = "-"
        if inf.get("seeds_done") and icl.get("seeds_done"):
            ok = (inf["violation_rate"][0] <= icl["violation_rate"][0]
                  and inf["feasible_reward"][0] >= icl["feasible_reward"][0])
            vs = (f"{inf['violation_rate'][0]:.2f} vs {icl['violation_rate'][0]:.2f}, "
                  f"{inf['feasible_reward'][0]:.0f} vs {icl['feasible_reward'][0]:.0f} ({'met' if ok else 'missed'})")
        elif "icl" not in rows:
            vs = "- (ICL not in this report)"
        elif t not in ICL_TASKS:
            vs = "- (no ICL run on this task)"
        else:
            vs = "- (no finished ICL seed)"
        out.append(f"| {t} | {bound} | {viol} | {feas} | {vs} |")
    return out if any_row else []


def _plateau_lines(res: dict[str, Any], names: Sequence[str], methods: Sequence[str]) -> list[str]:
    """The PPO-Lagrangian rows' :func:`plateau` check: had the policies stopped improving at their budget?"""
    shown = [m for m in ("ppo_lag_true", "ppo_lag_inferred") if m in methods]
    rows = [(t, m, res["tasks"][t][m]["plateau"]) for t in names for m in shown
            if (res["tasks"][t][m].get("plateau") is not None)]
    if not rows:
        return []
    w = rows[0][2]["window"]
    tol = rows[0][2]["tol"]
    out = ["", f"Had the policies stopped improving? Mean evaluation feasible reward over the evaluations in the "
               f"last {w:.0%} of each finished seed's steps against the {w:.0%} before, averaged over the seeds; "
               f"stable when the change is within ±{tol:.0%} (`plateau` in `results.json`). The issue asks for "
               "budgets at which the true-cost expert is stable.", "",
           "| task | method | seeds | feasible reward, last window | window before | change | stable |",
           "|---|---|---|---|---|---|---|"]
    for t, m, p in rows:
        if not math.isfinite(p["change"]):
            change, verdict = "-", "- (no reward before)"
        else:
            change = f"{p['change']:+.1%}"
            verdict = "yes" if p["stable"] else "no, still rising" if p["change"] > 0 else "no, falling"
        out.append(f"| {t} | {_LABELS[m]} | {p['seeds']} | {p['last']:.0f} | {p['before']:.0f} | {change} | "
                   f"{verdict} |")
    return out


def _figures(res: dict[str, Any], fig_dir: Path) -> tuple[dict[str, str], dict[str, str]]:
    """The scatter figure and the learning curves of every task with a finished seed: (scatter, curves) paths."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from pbicrl._atomic import atomic_path

    fig_dir.mkdir(parents=True, exist_ok=True)
    drawn, curves = {}, {}
    for t, rows in res["tasks"].items():
        pts = [(m, a) for m, a in rows.items() if a["seeds_done"]]
        if not pts:
            continue
        fig, ax = plt.subplots(figsize=(5, 3.6))
        for m, a in pts:
            (vx, vs), (fx, fs) = a["violation_rate"], a["feasible_reward"]
            ax.errorbar([vx], [fx], xerr=[vs], yerr=[fs], fmt="o", capsize=3, color=_COLOURS[m],
                        label=f"{_LABELS[m]} ({a['seeds_done']} seed{'s' if a['seeds_done'] > 1 else ''})")
        ax.set_xlabel("constraint violation rate")
        ax.set_ylabel("feasible cumulative reward")
        ax.set_xlim(-0.05, 1.05)
        ax.set_title(f"{t}: mean ± sd over seeds")
        ax.legend(fontsize=7)
        fig.tight_layout()
        name = f"icrl_{t}.png"
        with atomic_path(fig_dir / name) as tmp:
            fig.savefig(tmp, format="png", dpi=120)
        plt.close(fig)
        drawn[t] = f"figures/{name}"
        curve = _curve_figure(t, rows, fig_dir)
        if curve:
            curves[t] = curve
    return drawn, curves


def plateau(per_seed: dict[str, dict[str, Any]], *, window: float = PLATEAU_WINDOW,
            tol: float = PLATEAU_TOL) -> dict[str, Any] | None:
    """Whether a row's policies had stopped improving when training ended (issue 28 asks for budgets at which the
    true-cost expert's feasible reward is stable).

    Per finished seed with evaluations, the mean evaluation feasible reward over the evaluations in the last
    ``window`` of its steps, :math:`(T(1-w), T]`, and over the window before, :math:`(T(1-2w), T(1-w)]`; both
    averaged over the seeds. The row is *stable* when the relative change between them is at most ``tol`` in
    absolute value (evaluations are 10 stochastic episodes each, so a window of several evaluations and seeds
    is what is compared, not two single evaluations).

    Parameters
    ----------
    per_seed : dict
        ``{seed: seed_metrics(...)}``, as in ``build_report``'s results (``per_seed`` of a row).
    window : float
        In (0, 0.5].
    tol : float
        >= 0.

    Returns
    -------
    dict or None
        ``last``, ``before`` (mean feasible reward in each window), ``change`` (``(last - before) / |before|``,
        NaN when ``before`` is 0), ``stable`` (bool), ``seeds`` (how many were used), ``window``, ``tol``; None
        when no finished seed has an evaluation in both windows.
    """
    if not 0 < window <= 0.5:
        raise ValueError(f"window: must be in (0, 0.5], got {window!r}")
    if not tol >= 0:
        raise ValueError(f"tol: must be >= 0, got {tol!r}")
    last, before = [], []
    for v in per_seed.values():
        c = v.get("eval_curve") or {}
        if not v.get("done") or not c.get("steps"):
            continue
        st = np.asarray(c["steps"], dtype=np.float64)
        fr = np.asarray(c["feasible_reward"], dtype=np.float64)
        end = float(st[-1])
        a = fr[(st > end * (1 - window)) & (st <= end)]
        b = fr[(st > end * (1 - 2 * window)) & (st <= end * (1 - window))]
        if a.size and b.size:
            last.append(float(np.mean(a)))
            before.append(float(np.mean(b)))
    if not last:
        return None
    la, be = float(np.mean(last)), float(np.mean(before))
    change = (la - be) / abs(be) if be != 0 else math.nan
    return {"last": la, "before": be, "change": change, "stable": bool(abs(change) <= tol), "seeds": len(last),
            "window": float(window), "tol": float(tol)}


def curve_series(rows: dict[str, Any]) -> list[dict[str, Any]]:
    """What the learning-curve figure of one task draws, per method with an evaluation.

    The thick mean is over the *finished* seeds only, on the steps they share: a run still training would cut
    the mean short at its own step count and disagree with the table, which counts finished seeds. Runs in
    progress are drawn on their own (dashed) and named in the label.

    Parameters
    ----------
    rows : dict
        ``{method: {"per_seed": {seed: seed_metrics(...)}}}``, as in ``build_report``'s results.

    Returns
    -------
    list of dict
        ``method``, ``finished`` and ``in_progress`` (lists of ``eval_curve`` dicts), ``mean`` (``{"steps",
        "feasible_reward", "violation_rate"}`` over the finished seeds, None without one) and ``label``.
    """
    out = []
    for m, a in rows.items():
        seeds = [v for v in a["per_seed"].values() if v.get("eval_curve", {}).get("steps")]
        fin = [v["eval_curve"] for v in seeds if v.get("done")]
        prog = [v["eval_curve"] for v in seeds if not v.get("done")]
        if not fin and not prog:
            continue
        mean = None
        if fin:
            common = sorted(set.intersection(*(set(c["steps"]) for c in fin)))
            if common:
                at = [{st: i for i, st in enumerate(c["steps"])} for c in fin]
                mean = {"steps": common, **{k: [float(np.mean([c[k][a[st]] for c, a in zip(fin, at)])) for st in common]
                                            for k in ("feasible_reward", "violation_rate")}}
        parts = [f"{len(fin)} seed{'s' if len(fin) != 1 else ''}"] if fin else ["no finished seed"]
        if prog:
            parts.append(f"{len(prog)} in progress")
        out.append({"method": m, "finished": fin, "in_progress": prog, "mean": mean,
                    "label": f"{_LABELS[m]} ({', '.join(parts)})"})
    return out


def _curve_figure(t: str, rows: dict[str, Any], fig_dir: Path) -> str | None:
    """Feasible reward and violation rate of every evaluation against the steps: one thin line per seed (dashed
    while it trains), the mean over the finished seeds as a thick line, one colour per method."""
    import matplotlib.pyplot as plt  # the backend was set by _figures

    from pbicrl._atomic import atomic_path

    series = curve_series(rows)
    if not series:
        return None
    fig, axes = plt.subplots(2, 1, figsize=(6, 5.2), sharex=True)
    for s in series:
        colour = _COLOURS[s["method"]]
        for k, key in enumerate(("feasible_reward", "violation_rate")):
            for c in s["finished"]:
                axes[k].plot(np.asarray(c["steps"]) / 1e6, c[key], color=colour, lw=0.6, alpha=0.45)
            for c in s["in_progress"]:
                axes[k].plot(np.asarray(c["steps"]) / 1e6, c[key], color=colour, lw=0.8, alpha=0.6, ls="--")
            label = s["label"] if k == 0 else None
            if s["mean"] is not None:
                axes[k].plot(np.asarray(s["mean"]["steps"]) / 1e6, s["mean"][key], color=colour, lw=2.0,
                             label=label)
            elif label:  # nothing finished: the legend still names the method
                axes[k].plot([], [], color=colour, lw=0.8, ls="--", label=label)
    axes[0].set_ylabel("feasible cumulative reward")
    axes[1].set_ylabel("constraint violation rate")
    axes[1].set_ylim(-0.05, 1.05)
    axes[1].set_xlabel("training steps (millions)")
    axes[0].set_title(f"{t}: evaluations (thin: seeds, dashed: training, thick: mean of finished)",
                      fontsize=9)
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    name = f"icrl_{t}_curves.png"
    with atomic_path(fig_dir / name) as tmp:
        fig.savefig(tmp, format="png", dpi=110)
    plt.close(fig)
    return f"figures/{name}"
