"""The grid example (paper Fig. 1b) and the navigation experiments (point mass, Fetch-Reach): BPL vs PBICRL with
and without margins."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np

from pbicrl.experiments.reproduce.configs import (DEFAULT_MODEL, FLAT_PRIOR, NOT_DEFAULT, PAPER_PRIOR, Context,
                                                  pairwise, run_infer_tasks, shipped_path, subsample)
from pbicrl.experiments.reproduce.figures import WEIGHTS_YLABEL, reward_distributions_figure, weights_figure
from pbicrl.experiments.reproduce.markdown import fmt_mean_std, write_report
from pbicrl.experiments.reproduce.paper import PAPER
from pbicrl.experiments.reproduce.stats import mean_std

__all__ = ["exp_grid", "exp_point_mass", "exp_fetch_reach"]


def exp_grid(ctx: Context) -> Path:
    """BPL with and without margins on the three grid trajectories, weights averaged over 100 runs."""
    from pbicrl.inference.data import Dataset

    path = ctx.out / "grid" / "grid.npz"
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        from pbicrl.envs.grid import grid_dataset

        ds: Dataset = grid_dataset()
    except ImportError:
        from pbicrl.inference.data import load_dataset

        ds = load_dataset(shipped_path("grid"))
    ds.save(path)
    runs = 20 if ctx.quick or ctx.iterations_override else 100
    margins = [2.0, 1.0]  # "the margin between tau_1 and tau_2 is about twice that between tau_2 and tau_3"
    configs, names = [], []
    for label, m in (("BPL", None), ("BPL with margins", margins)):
        for s in range(runs):
            configs.append({"data": str(path), "sampler": "bpl", "margins": m, "iterations": ctx.iterations // 4,
                            "seed": s, "sigma": 0.1, **pairwise("all"), **PAPER_PRIOR, "label": label})
            names.append(f"grid-{'m' if m else 'nom'}")
    res = run_infer_tasks(ctx, configs, names)
    feats = list(ds.feature_names)
    table: dict[str, Any] = {}
    lines = [f"Three trajectories on the 3x3 grid (tau_1 grey only > tau_2 through orange > tau_3 through red), "
             f"one-hot features {feats}. BPL (paper Algorithm 3, flat improper prior, sigma 0.1, "
             f"{ctx.iterations // 4:,} iterations) run {runs} times; MAP weights averaged. Margins (gaps) {margins}.",
             "", "| run | " + " | ".join(feats) + " |", "|---|" + "---|" * len(feats)]
    for label in ("BPL", "BPL with margins"):
        W = np.array([r["map_effective_penalty"] for r, c in zip(res, configs) if c["label"] == label])
        mean, std = W.mean(axis=0), W.std(axis=0)
        table[label] = {"mean": mean.tolist(), "std": std.tolist()}
        lines.append(f"| {label} | " + " | ".join(fmt_mean_std(m, s) for m, s in zip(mean, std)) + " |")
    lines += ["", "The paper reports this as a bar plot only (Fig. 1b): without margins orange and red get similar "
              "weights; with margins red is clearly worse than orange. Ours, mean orange minus red weight: "
              f"{table['BPL']['mean'][1] - table['BPL']['mean'][2]:.3g} without, "
              f"{table['BPL with margins']['mean'][1] - table['BPL with margins']['mean'][2]:.3g} with margins "
              "(three pairs cannot fix the scale of the weights, so the run-to-run spread is large)."]

    def figures(d: Path) -> list[str]:
        return [weights_figure(d, "weights.png", feats, None, table, seeds=runs, ylabel="inferred weight (MAP)",
                               title="grid: BPL with and without margins")]

    return write_report(ctx, "grid", "Grid example (paper Fig. 1b)", lines, {"runs": runs, "weights": table}, figures)


def _navigation(ctx: Context, name: str, dataset: str) -> Path:
    from pbicrl.inference.data import load_dataset
    from pbicrl.analysis.margins import relation_error, tune_margins

    dataset = ctx.dataset(dataset)
    paper = PAPER[name]
    full = load_dataset(dataset)
    n = paper["demos_per_group"]
    true_w = np.array(paper["true_weights"], float)
    wn = np.array(paper["nominal_weights"], float)
    true_pen = true_w - wn
    pm = paper["margins"]
    paper_margins = [[0, pm["m12"], pm["m13"]], [0, 0, pm["m23"]], [0, 0, 0]]
    # Margin tuning, automated: on seed 0's subsample, paper Algorithm 1 with its Eq. 7 (the rows it feeds), shorter runs.
    ds0 = full.sample_per_group(n, seed=0)
    t0 = time.perf_counter()
    tuning = tune_margins(ds0, paper["relation"], gap_grid=(0.0, 0.5, 1.0, 1.5, 2.0, 3.0, 4.0, 6.0),
                          sampler="paper", iterations=max(20_000, ctx.iterations // 10), chains=1, jobs=1,
                          seed=0, pairs=ctx.pairs_for(n), likelihood="pairwise", progress=ctx.progress)
    tune_s = time.perf_counter() - t0
    tuned = tuning.margins.matrix.tolist()
    methods = [("BPL", "bpl", None), ("PBICRL, m = 0", "paper", None), ("PBICRL, tuned margins", "paper", tuned),
               ("PBICRL, paper's margins", "paper", paper_margins),
               ("PBICRL, authors' code, m = 0", "authors", None),
               ("PBICRL (valid RJ sampler), tuned margins", "pbicrl", tuned),
               ("pbicrl default (grouped likelihood, half-t prior)", "default", None)]
    configs, names = [], []
    for label, method, m in methods:
        for s in range(ctx.seeds):
            cfg = {"data": dataset, **subsample(n, s), "sampler": method, "margins": m,
                   "iterations": ctx.iterations, "seed": s, "sigma": 0.1, "f_s": 4, **pairwise(ctx.pairs_for(n)),
                   **(PAPER_PRIOR if method in ("bpl", "paper", "authors") else FLAT_PRIOR), "label": label}
            if method == "authors":
                cfg["init_range"] = list(paper["authors_init_range"])
            if method == "default":  # pbicrl's defaults on the same subsample: grouped likelihood, half-t prior
                cfg = {k: v for k, v in cfg.items() if k not in NOT_DEFAULT}
                cfg.update({"sampler": "pbicrl", **DEFAULT_MODEL})
            configs.append(cfg)
            names.append(f"{name}-{method}")
    res = run_infer_tasks(ctx, configs, names)
    feats = res[0]["features"]
    rows: dict[str, Any] = {}
    lines = [f"{n} demonstrations per group drawn from `{Path(dataset).name}` ({full.group_counts()} available), "
             f"{ctx.seeds} seeds (seed = subsample and chain seed), {ctx.iterations:,} iterations, sigma 0.1, f_s 4, "
             f"pairs: {'all cross-group pairs (paper Eq. 7)' if ctx.pairs == 'all' else f'{n} random pairs per group pair (authors code)'}. "
             f"BPL and PBICRL use the paper's algorithms (3 and 1) with the flat improper prior; the 'valid RJ sampler' row uses "
             f"pbicrl's reversible-jump sampler with the flat prior on [-1000, 1000] (both signs), all with the "
             f"paper's Eq. 7. The authors'-code row is Algorithm 1 with a switched-off weight reset to 0 and initial "
             f"penalties uniform on {list(paper['authors_init_range'])}. The last row is pbicrl's default model (grouped "
             f"likelihood, half-Student-t prior on penalties <= 0, reversible-jump sampler) on the same subsamples.", "",
             f"Margin tuning (automated, relation {paper['relation']} between consecutive gaps): chosen "
             f"{tuning.margins.as_dict()}, relation achieved {np.round(tuning.relation_achieved, 3).tolist()} "
             f"({len(tuning.table)} candidates, {tune_s:.0f} s). Paper (by hand): {pm}.", "",
             "Effective penalty c*w_p, mean ± std over seeds (truth in the first row): the MAP draw for the paper's "
             "algorithms (their convention), the conditional median of the selected set (P(c=1) > 0.5) for pbicrl's "
             "default. Constraint set: MAP indicators for BPL/paper/pbicrl rows; |c*w_p| >= 1 of the MAP for the "
             "authors' code (its reset shrinks c*w_p toward 0 while c is often 1, as the paper's bar charts show "
             "c*w_p); the selected set for the default row.", "",
             "| method | " + " | ".join(feats) + " | exact constraint set | penalties within 15% |",
             "|---|" + "---|" * (len(feats) + 2),
             "| truth | " + " | ".join(f"{v:g}" for v in true_pen) + " | | |"]
    truth_set = (true_pen != 0).astype(int)
    for label, _, _ in methods:
        rr = [r for r, c in zip(res, configs) if c["label"] == label]
        if "default" in label:
            W = np.array([r["selected_effective_penalty"] for r in rr])
            C = np.array([r["selected_indicators"] for r in rr])
        elif "authors" in label:
            W = np.array([r["map_effective_penalty"] for r in rr])
            C = (np.abs(W) >= 1.0).astype(int)
        else:
            W = np.array([r["map_effective_penalty"] for r in rr])
            C = np.array([r["map_indicators"] for r in rr])
        exact_n = int(sum(np.array_equal(c, truth_set) for c in C))
        exact = "n/a (no indicators)" if label == "BPL" else f"{exact_n}/{len(rr)}"
        on = truth_set == 1
        within = int(sum(np.all(np.abs(w[on] - true_pen[on]) <= 0.15 * np.abs(true_pen[on])) for w in W))
        gm_key = "group_means_selected" if "default" in label else "group_means_map"
        rel = [relation_error(r[gm_key], paper["relation"])[1].tolist() for r in rr]
        rows[label] = {"mean": W.mean(0).tolist(), "std": W.std(0).tolist(), "exact_set": exact_n, "within_15pct": within,
                       "per_seed": W.tolist(), "relation_achieved": rel,
                       "runtime_s": mean_std([r["runtime_s"] for r in rr]), "n_pairs": rr[0]["n_pairs"]}
        m_s = W.mean(0), W.std(0)
        lines.append(f"| {label} | " + " | ".join(fmt_mean_std(a, b) for a, b in zip(*m_s)) +
                     f" | {exact} | {within}/{len(rr)} |")
    lines += ["", "Targets (issue): exact set in 5/5 seeds; with tuned margins MAP penalties within 15% of the truth. "
              "The paper shows these results as bar plots (Figs. 3b/4b); it prints no numbers to compare beyond the truth.",
              "Runtime per chain: " + ", ".join(f"{k}: {fmt_mean_std(*v['runtime_s'])} s" for k, v in rows.items()) + "."]
    ds_rel = {"true": tuning.group_means.tolist()}

    def figures(d: Path) -> list[str]:
        weights_figure(d, "weights.png", feats, true_pen, rows, seeds=ctx.seeds, ylabel=WEIGHTS_YLABEL,
                       title=f"{name}: effective penalties by method")
        reward_distributions_figure(d, ds0, true_w, wn, rows)
        return ["weights.png", "reward_distributions.png"]

    results = {"methods": rows, "tuning": tuning.to_dict(), "paper": paper, "pairs": ctx.pairs, "protocol": ctx.pairs,
               "iterations": ctx.iterations, "seeds": ctx.seeds, "group_means_true_seed0": ds_rel}
    return write_report(ctx, name, f"{name}: BPL vs PBICRL with and without margins", lines, results, figures)


def exp_point_mass(ctx: Context) -> Path:
    return _navigation(ctx, "point-mass", "point_mass")


def exp_fetch_reach(ctx: Context) -> Path:
    return _navigation(ctx, "fetch-reach", "fetch_reach")
