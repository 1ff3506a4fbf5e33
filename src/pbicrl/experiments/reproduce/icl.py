"""The ICL baseline next to PBICRL on the same wall demonstrations (paper Tables I and II); hours of RL per seed,
so not part of ``pbicrl reproduce all``."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from pbicrl.experiments.reproduce.configs import Context, run_infer_tasks, wall_configs
from pbicrl.experiments.reproduce.markdown import fmt_mean_std, write_report
from pbicrl.experiments.reproduce.paper import PAPER
from pbicrl.experiments.reproduce.stats import mean_std

__all__ = ["exp_icl"]


def exp_icl(ctx: Context) -> Path:
    """ICL (Gaurav et al. 2022) next to PBICRL on the same wall demonstrations (paper Tables I and II).

    Not part of ``all`` (hours of RL per seed). ICL gets the good demonstrations (group 1, up to 200) of the
    dataset PBICRL draws its 100 + 100 from; its budget is the :func:`pbicrl.baselines.icl.icl_preset` named by
    the environment variable ``PBICRL_ICL_BUDGET`` (``smoke``, ``default`` - 23-31 min per HalfCheetah seed
    measured on 2 shared cores - or ``paper``). ``PBICRL_ICL_ENVS`` (comma-separated, default ``halfcheetah,ant``) chooses the
    environments. Each ICL seed is a resumable task (checkpoints under ``<out>/icl/checkpoints``).
    """
    import hashlib
    import os

    from pbicrl.experiments.sweep import run_tasks
    from pbicrl.experiments.tasks import Task, file_sha256
    from pbicrl.analysis.metrics import cmse_grid, cmse_location, halfspace_indicator

    # kind "reproduce-icl" (pbicrl.experiments.tasks) hashes the dataset's content, like the PBICRL runs; the
    # checkpoint directory carries that hash too
    budget = os.environ.get("PBICRL_ICL_BUDGET", "default")
    if budget not in ("smoke", "default", "paper"):
        raise ValueError(f"PBICRL_ICL_BUDGET: expected smoke, default or paper, got {budget!r}")
    envs = [e.strip() for e in os.environ.get("PBICRL_ICL_ENVS", "halfcheetah,ant").split(",") if e.strip()]
    if not envs or any(e not in ("halfcheetah", "ant") for e in envs) or len(set(envs)) != len(envs):
        raise ValueError("PBICRL_ICL_ENVS: expected a comma-separated subset of halfcheetah, ant, got "
                         f"{os.environ.get('PBICRL_ICL_ENVS')!r}")
    # needs torch and MuJoCo: pip install "pbicrl[rl,envs]"
    from pbicrl.baselines.icl import icl_preset

    lines = [(f"ICL (our implementation, `pbicrl.baselines.icl`: PPO-Lagrangian with the multiplier driven by the "
              f"expected discounted cost - the authors' code uses the episode reward there - alternating with the "
              f"constraint adjustment; sigmoid MLP constraint over x) against PBICRL (paper Algorithm 2, 100 good + "
              f"100 violating demonstrations, {ctx.iterations:,} iterations), {ctx.seeds} seed(s) each, ICL budget "
              f"`{budget}`. ICL sees only good demonstrations (up to 200; the paper gave it 200, some violating). "
              "CMSE (location) = (theta_hat - wall)^2 with ICL's theta_hat where c(x) first reaches 0.5 scanning up from "
              "the lowest x of the expert data; CMSE (grid) = mean squared difference between the true indicator "
              "[x >= wall] and the inferred one (PBICRL: its MAP halfspace; ICL: c(x)) on 401 points of [0, 2 wall]. "
              f"Runtimes are wall-clock seconds per seed on this machine (executor "
              f"`{getattr(ctx.executor, 'name', ctx.executor)}`, workers {ctx.workers or 'default'}; concurrent seeds "
              "share cores), the paper's on theirs."), ""]
    results: dict[str, Any] = {"budget": budget, "seeds": ctx.seeds, "iterations": ctx.iterations, "envs": {}}
    for name in envs:
        try:
            dataset = ctx.dataset(name)
        except FileNotFoundError as exc:
            lines.append(f"- {name}: skipped, {exc}")
            results["envs"][name] = {"skipped": str(exc)}
            continue
        paper = PAPER[name]
        wall = float(paper["wall"])
        grid = np.linspace(0.0, 2 * wall, 401)
        truth = halfspace_indicator(wall)(grid)
        configs, names = wall_configs(ctx, name, dataset, 100, ctx.seeds)
        dconfigs, dnames = wall_configs(ctx, name, dataset, 100, ctx.seeds, model="default")
        res = run_infer_tasks(ctx, configs + dconfigs, names + dnames)
        pb, df = res[:len(configs)], res[len(configs):]

        def located(rows: list[dict]) -> dict[str, Any]:
            """MAP wall locations of PBICRL runs and their CMSEs (location over the runs that found a wall)."""
            theta = [r["map_parameters"][0] for r in rows]
            loc = [cmse_location(t, wall) for t in theta if t is not None]
            return {"theta": theta, "cmse_location": mean_std(loc) if loc else None,
                    "cmse_grid": mean_std([cmse_grid(truth, halfspace_indicator(t)(grid) if t is not None
                                                     else np.zeros_like(grid)) for t in theta]),
                    "runtime_s": mean_std([r["runtime_s"] for r in rows])}

        cfg = icl_preset(budget, name)
        sha = file_sha256(Path(dataset))[:12]
        # the preset's values are hashed too: retuning a preset must not reuse results (or checkpoints) of the old one
        cfg_sha = hashlib.sha256(json.dumps(cfg.to_dict(), sort_keys=True).encode()).hexdigest()[:12]
        tasks = [Task("reproduce-icl",
                      {"env": name, "data": dataset, "budget": budget, "budget_sha256": cfg_sha, "seed": s,
                       "n_expert": 200, "demos_seed": s,
                       "checkpoint_dir": str(ctx.out / "icl" / "checkpoints" / f"{name}-{budget}-s{s}-{sha}-{cfg_sha}")},
                      name=f"icl-{name}-{budget}") for s in range(ctx.seeds)]
        res = run_tasks(tasks, ctx.out / "runs", ctx.executor, workers=ctx.workers, progress=ctx.progress, manifest=False)
        icl = []
        for r in res.records:
            if r.status == "failed":
                raise RuntimeError(f"reproduce: ICL run {r.task.dir_name} failed: {r.error}")
            icl.append(r.result)
        icl_loc = [r["cmse_location"] for r in icl if r["cmse_location"] is not None]
        no_loc = sum(r["location"] is None for r in icl)
        row = {"pbicrl": located(pb), "default": located(df),
               "icl": {"location": [r["location"] for r in icl], "cmse_location": mean_std(icl_loc) if icl_loc else None,
                       "seeds_without_location": no_loc, "cmse_grid": mean_std([r["cmse_grid"] for r in icl]),
                       "runtime_s": mean_std([r["runtime_s"] for r in icl]), "n_expert": [r["n_expert"] for r in icl],
                       "ppo_steps": [r["ppo_steps"] for r in icl], "final_policy": [r["final_policy"] for r in icl],
                       "rounds": cfg.rounds},
               "paper": paper}
        results["envs"][name] = row

        def f(ms: Any) -> str:
            return "undefined" if ms is None else fmt_mean_std(*ms)

        fp = row["icl"]["final_policy"]
        from pbicrl.inference.data import load_dataset

        full = load_dataset(dataset)
        reach = [float(full.trajectory_states(i)[:, 0].max()) for i in np.flatnonzero(full.group == 1)]
        row["good_demos_max_x"] = {"mean": float(np.mean(reach)), "max": float(np.max(reach))}
        pd_, dd = row["pbicrl"], row["default"]
        pb_theta = pd_["theta"]
        lines += [f"### {name} (wall x >= {wall:g})", "",
                  "| | PBICRL, paper Alg. 2 (ours) | pbicrl default, MAP | ICL (ours) | paper PBICRL | paper ICL |",
                  "|---|---|---|---|---|---|",
                  (f"| CMSE (location) | {f(pd_['cmse_location'])} | {f(dd['cmse_location'])} | "
                   f"{f(row['icl']['cmse_location'])} | {fmt_mean_std(*paper['cmse'])} | "
                   f"{fmt_mean_std(*paper['icl_cmse'])} |"),
                  f"| CMSE (grid) | {f(pd_['cmse_grid'])} | {f(dd['cmse_grid'])} | {f(row['icl']['cmse_grid'])} | - | - |",
                  (f"| runtime per seed (s) | {f(pd_['runtime_s'])} | {f(dd['runtime_s'])} | "
                   f"{f(row['icl']['runtime_s'])} | {fmt_mean_std(*paper['runtime_s'])} | "
                   f"{fmt_mean_std(*paper['icl_runtime_s'])} |"), "",
                  (f"PBICRL MAP thetas: {np.round([t for t in pb_theta if t is not None], 3).tolist()}; pbicrl default "
                   f"(grouped likelihood, half-t prior, reversible jump; `docs/reproduction` 'default') MAP thetas: "
                   f"{np.round([t for t in dd['theta'] if t is not None], 3).tolist()}. ICL locations: "
                   f"{[None if v is None else round(v, 3) for v in row['icl']['location']]}"
                   + (f" ({no_loc} seed(s) with c < 0.5 everywhere up to x = {5 * wall:g}: no location, left out of "
                      "its CMSE)" if no_loc else "") + ". "
                   f"The good demonstrations reach x = {np.mean(reach):.2f} on average (at most "
                   f"{np.floor(np.max(reach) * 1000) / 1000:.3f}, rounded down). "
                   f"ICL budget `{budget}`: {cfg.rounds} rounds, {cfg.total_steps:,} PPO-Lagrangian steps per seed "
                   f"(done: {row['icl']['ppo_steps']}), beta {cfg.beta}, {row['icl']['n_expert'][0]} expert "
                   f"demonstrations. Final ICL policies (deterministic): mean max x "
                   f"{np.round([p['mean_max_coord0'] for p in fp], 2).tolist()}, fraction of episodes reaching the "
                   f"true wall {np.round([p['fraction_violating'] for p in fp], 2).tolist()}."), ""]
    return write_report(ctx, "icl", "ICL baseline vs PBICRL (paper Tables I and II)", lines, results, None)
