"""Active vs random query order: labels until the posterior names the true constraints.

Not a test: a benchmark. For each problem and seed, a user (the oracle: the true group labels) labels
demonstrations from a pool in batches. The first batch is random (the same for both orders, redrawn until
it holds two groups); after each batch a short inference runs on the labelled ones (``pbicrl.infer``,
grouped likelihood, defaults otherwise) and the next batch is either random or the top of
:func:`pbicrl.analysis.suggest.suggest` (information gain about the indicators, evenly spaced posterior draws).

Criteria, checked after every batch:

* ``strict`` (the issue's): the selected set (P(c=1) > 0.5) equals the true set, P(c=1) > 0.95 for every
  true constraint and < 0.05 for every other feature;
* ``relaxed``: the selected set equals the true set and P(c=1) > 0.95 for every true constraint.

A run stops at the ``strict`` criterion or at the cap; the first batch that meets the ``relaxed`` one is
recorded on the way. (``--stop relaxed`` ends runs earlier; the report then shows the relaxed criterion only.)

Problems: ``synthetic`` (``pbicrl.inference.synthetic.make_problem``, 3 groups, Gumbel ranking noise of scale 1 so
that the grouped model holds exactly, a fresh pool per seed) and ``point_mass`` (the shipped dataset as the
pool, its labels as the oracle).

Usage (results are appended to a JSON file, so a killed run resumes)::

    nice -n 10 python benchmarks/bench_active.py --problems synthetic --seeds 20
    nice -n 10 python benchmarks/bench_active.py --report   # writes benchmarks/reports/active_queries.md
"""

from __future__ import annotations

import argparse
import json
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np

import pbicrl
from pbicrl.inference.data import Dataset
from pbicrl.errors import PbicrlWarning
from pbicrl.analysis.suggest import suggest
from pbicrl.experiments.kinds import shipped_data_tag
from pbicrl.inference.synthetic import make_problem

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "reports" / "active_queries.json"
REPORT = HERE / "reports" / "active_queries.md"
STOP = {"synthetic": "strict", "point_mass": "strict"}


def problem(name: str, seed: int) -> tuple[Dataset, np.ndarray]:
    """The pool (with its true labels) and the true indicator vector."""
    if name == "synthetic":
        prob = make_problem(100, n_groups=3, noise=1.0, violation_rate=0.4, seed=10_000 + seed)
        return prob.dataset, prob.true_indicators.astype(bool)
    if name == "point_mass":
        ds = pbicrl.load_dataset("point_mass")
        return ds, np.array([n in ("in_orange", "in_red") for n in ds.feature_names])
    raise ValueError(f"problem: unknown {name!r}")


def data_tag(name: str) -> str:
    """What a run's pool came from: ``synthetic`` (regenerated from the seed) or the shipped file, named by the
    first 12 hex digits of its SHA-256, so that runs on a regenerated file are not mixed with older ones."""
    return "synthetic" if name == "synthetic" else shipped_data_tag(name)


def current(rows: list[dict[str, Any]]) -> tuple[list[dict[str, Any]], int]:
    """The rows on today's pools, and how many rows on older versions of a shipped file were left out."""
    tags = {name: data_tag(name) for name in {r["problem"] for r in rows}}
    keep = [r for r in rows if r.get("data") == tags[r["problem"]]]
    return keep, len(rows) - len(keep)


def criteria(p: np.ndarray, truth: np.ndarray) -> dict[str, bool]:
    same = bool(np.array_equal(p > 0.5, truth))
    relaxed = same and bool(np.all(p[truth] > 0.95))
    return {"relaxed": relaxed, "strict": relaxed and bool(np.all(p[~truth] < 0.05))}


def first_batch(ds: Dataset, size: int, rng: np.random.Generator) -> np.ndarray:
    for _ in range(1000):
        idx = rng.choice(ds.n_trajectories, size, replace=False)
        if np.unique(ds.group[idx]).size >= 2:
            return np.sort(idx)
    raise RuntimeError("could not draw a first batch with two groups")


def run_one(name: str, strategy: str, seed: int, cfg: dict[str, Any], stop: str) -> dict[str, Any]:
    ds, truth = problem(name, seed)
    labelled = first_batch(ds, cfg["batch"], np.random.default_rng(seed))
    rng = np.random.default_rng([seed, 1])
    history = []
    reached: dict[str, int | None] = {"strict": None, "relaxed": None}
    t0 = time.perf_counter()
    step = 0
    while True:
        sub = ds.subset(labelled)
        post = pbicrl.infer(sub, iterations=cfg["iterations"], chains=cfg["chains"], jobs=1,
                            seed=seed * 1000 + step, progress=False)
        p = post.p_constraint
        ok = criteria(p, truth)
        for k in reached:
            if ok[k] and reached[k] is None:
                reached[k] = int(labelled.size)
        history.append({"labels": int(labelled.size), "p_constraint": [round(float(x), 4) for x in p]})
        if reached[stop] is not None or labelled.size >= cfg["cap"]:
            break
        rest = np.setdiff1d(np.arange(ds.n_trajectories), labelled)
        take = min(cfg["batch"], cfg["cap"] - labelled.size, rest.size)
        if take <= 0:
            break
        if strategy == "random":
            new = rng.choice(rest, take, replace=False)
        else:
            new = np.array(suggest(post, sub, ds, take, candidates=rest, max_draws=cfg["draws"]).indices)
        labelled = np.sort(np.concatenate([labelled, new]))
        step += 1
    return {"problem": name, "data": data_tag(name), "strategy": strategy, "seed": seed, "reached": reached,
            "stop": stop,
            "final_labels": int(labelled.size), "seconds": round(time.perf_counter() - t0, 1),
            "history": history, "settings": cfg}


def full_pool(name: str, cfg: dict[str, Any]) -> dict[str, Any]:
    """The posterior with every demonstration of the pool labelled (seed 0), with the same chains: the end point
    that any order reaches at most."""
    ds, truth = problem(name, 0)
    post = pbicrl.infer(ds, iterations=cfg["iterations"], chains=cfg["chains"], jobs=1, seed=0, progress=False)
    p = post.p_constraint
    return {"problem": name, "data": data_tag(name), "strategy": "all", "seed": 0, "labels": int(ds.n_trajectories),
            "p_constraint": [round(float(x), 4) for x in p], "feature_names": list(ds.feature_names),
            "criteria": criteria(p, truth), "settings": cfg}


def load_results(path: Path) -> list[dict[str, Any]]:
    return json.loads(path.read_text()) if path.exists() else []


def save_results(rows: list[dict[str, Any]], path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(rows, indent=1))
    tmp.replace(path)


def _summary(vals: list[int | None]) -> tuple[str, str, int]:
    got = [v for v in vals if v is not None]
    if not got:
        return "-", "-", len(vals)
    q = np.percentile(got, [25, 50, 75])
    return f"{q[1]:.0f}", f"{q[0]:.0f}-{q[2]:.0f}", len(vals) - len(got)


def report(rows: list[dict[str, Any]]) -> str:
    rows, stale = current(rows)
    lines = ["# Active vs random query order", "",
             "Generated by `benchmarks/bench_active.py --report` from `active_queries.json` (every run, with the "
             "P(c=1) after each batch). Labels until the criterion is met; runs that never meet it by the cap "
             "count as *never* and are left out of the medians. The ratio is the median over seeds where both "
             "orders met the criterion of (active labels / random labels).", "",
             "Caveat: the criteria are checked once per batch on short chains, and the first batch that meets one "
             "counts, so chain noise can end a run early or late; P(c=1) of the features that are not constraints "
             "is the noisiest (it moves slowly towards 0 as labels accumulate, and short chains estimate it "
             "poorly).", ""]
    if stale:
        lines += [f"Left out: {stale} runs in the JSON on an earlier version of a shipped dataset (their `data` "
                  "field names the file's SHA-256 prefix).", ""]
    keys = sorted({(r["problem"], r["stop"]) for r in rows if r["strategy"] != "all"}, key=lambda k: (k[0], k[1] != "strict"))
    notes: dict[str, str] = {}
    for name, stop in list(keys):
        if stop == "relaxed" and (name, "strict") in keys:  # the strict-stopped runs already cover the relaxed one
            keys.remove((name, stop))
            rel = {(r["strategy"], r["seed"]): r["reached"]["relaxed"] for r in rows
                   if r["problem"] == name and r.get("stop") == "relaxed"}
            st = {(r["strategy"], r["seed"]): r["reached"]["relaxed"] for r in rows
                  if r["problem"] == name and r.get("stop") == "strict"}
            common = sorted(set(rel) & set(st))
            same = sum(rel[k] == st[k] for k in common)
            notes[name] = (f"Also in the JSON: {len(rel)} {name} runs stopped at the relaxed criterion (same seeds and "
                           f"random streams); their relaxed label counts equal those above in {same} of "
                           f"{len(common)} paired runs.")
    for name, stop in keys:
        ref = [r for r in rows if r["problem"] == name and r["strategy"] == "all"]
        sub = [r for r in rows if r["problem"] == name and r["strategy"] != "all" and r["stop"] == stop]
        cfg = sub[0]["settings"]
        seeds = sorted({r["seed"] for r in sub})
        lines += [f"## {name}, runs stopped at the {stop} criterion", "",
                  f"Seeds {len(seeds)} ({seeds[0]}..{seeds[-1]}); batches of {cfg['batch']}, cap {cfg['cap']} labels; "
                  f"after each batch `pbicrl.infer` with {cfg['chains']} chain(s) x {cfg['iterations']:,} iterations "
                  f"(a quarter warm-up); suggestions from {cfg['draws']} posterior draws. Runs stop at the "
                  f"`{sub[0]['stop']}` criterion.", "",
                  "| criterion | order | runs | reached | never | median labels | IQR | "
                  "median ratio active/random (paired seeds) |",
                  "|---|---|---|---|---|---|---|---|"]
        for crit in ("strict", "relaxed") if stop == "strict" else ("relaxed",):  # strict needs strict-stopped runs
            by = {s: {r["seed"]: r["reached"][crit] for r in sub if r["strategy"] == s} for s in ("active", "random")}
            paired = [by["active"][s] / by["random"][s] for s in seeds
                      if by["active"].get(s) is not None and by["random"].get(s) is not None]
            ratio = f"{np.median(paired):.2f} ({len(paired)} seeds)" if paired else "-"
            for s in ("active", "random"):
                vals = list(by[s].values())
                med, iqr, never = _summary(vals)
                lines.append(f"| {crit} | {s} | {len(vals)} | {len(vals) - never} | {never} | {med} | {iqr} | "
                             f"{ratio if s == 'active' else ''} |")
        secs = [r["seconds"] for r in sub]
        lines += ["", f"Wall time per run: median {np.median(secs):.0f} s (max {max(secs):.0f} s).", ""]
        for r in ref:
            ps = ", ".join(f"{f} {p:.3f}" for f, p in zip(r["feature_names"], r["p_constraint"]))
            met = [k for k, v in r["criteria"].items() if v]
            lines += [f"With all {r['labels']:,} demonstrations labelled (seed 0, the same chains): P(c=1) = {ps}; "
                      f"criteria met: {', '.join(met) or 'none'}.", ""]
        if name in notes:
            lines += [notes[name], ""]
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--problems", default="synthetic,point_mass")
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--batch", type=int, default=5)
    ap.add_argument("--cap", type=int, default=200)
    ap.add_argument("--iterations", type=int, default=5_000)
    ap.add_argument("--chains", type=int, default=2)
    ap.add_argument("--draws", type=int, default=50)
    ap.add_argument("--stop", choices=["auto", "strict", "relaxed"], default="auto",
                    help="criterion that ends a run (auto: strict)")
    ap.add_argument("--results", type=Path, default=RESULTS, help="JSON of every run (appended, resumed)")
    ap.add_argument("--out", type=Path, default=REPORT, help="the markdown report")
    ap.add_argument("--report", action="store_true", help="only write the report from the saved results")
    ap.add_argument("--full-pool", action="store_true",
                    help="also infer once from the whole labelled pool of each problem (the reference end point)")
    args = ap.parse_args()
    warnings.simplefilter("ignore", PbicrlWarning)
    rows = load_results(args.results)
    cfg = {"batch": args.batch, "cap": args.cap, "iterations": args.iterations, "chains": args.chains,
           "draws": args.draws}
    if args.full_pool:
        for name in args.problems.split(","):
            rows = [r for r in rows if not (r["problem"] == name and r["strategy"] == "all"
                                            and r.get("data") == data_tag(name))]
            rows.append(full_pool(name, cfg))
            save_results(rows, args.results)
            print(f"{name}, whole pool: P(c=1) = {rows[-1]['p_constraint']}", flush=True)
    if not args.report:
        done = {(r["problem"], r["strategy"], r["seed"], r["stop"]) for r in current(rows)[0] if r["strategy"] != "all"}
        for seed in range(args.first_seed, args.first_seed + args.seeds):
            for name in args.problems.split(","):
                for strategy in ("active", "random"):
                    stop = STOP[name] if args.stop == "auto" else args.stop
                    if (name, strategy, seed, stop) in done:
                        continue
                    res = run_one(name, strategy, seed, cfg, stop)
                    rows.append(res)
                    save_results(rows, args.results)
                    print(f"{name} {strategy} seed {seed}: strict {res['reached']['strict']}, relaxed "
                          f"{res['reached']['relaxed']} ({res['seconds']} s)", flush=True)
    args.out.write_text(report(rows))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
