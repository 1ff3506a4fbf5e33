r"""Close the loop: does a policy trained on an *inferred* constraint violate the true one less?

For each environment (point mass; HalfCheetah with a wall) the experiment

1. infers the constraint from the shipped ranked demonstrations (``pbicrl infer``: point mass with its four
   known features; HalfCheetah with a parametric wall :math:`x \ge \vartheta`);
2. trains, per seed, PPO-Lagrangian policies (:func:`pbicrl.experiments.safe_rl.train_safe`, the same settings for all)
   that maximise the nominal return under a budget :math:`D` on the expected episode cost of

   * ``nominal``: no cost (the multiplier stays 0),
   * ``true``: the true constraint (1 per step inside orange or red / at :math:`x \ge 8`),
   * ``inferred``: the posterior's cost (:class:`~pbicrl.envs.inferred_cost.InferredConstraintCost`,
     ``indicator`` mode by default; other modes as ``inferred-<mode>``);
3. evaluates every final policy (deterministic: the Gaussian's mean) on 100 episodes with the same reset
   seeds: violation rate (fraction of steps in a true constraint region / at or beyond the wall), true
   return and nominal return (:func:`pbicrl.experiments.safe_rl.evaluate_policy`).

Everything is cached under ``--out`` (inference runs, ``train-safe`` directories, evaluations), so a rerun
resumes where it stopped and retraining is never needed for the table. The stages that depend on a shipped
dataset (its inference run, the ``inferred`` policies and their evaluations) are named by the first 12 hex
digits of the file's SHA-256 (``infer/point_mass-51c6750fa6d9``), so a regenerated file is never read through
an older run. Results go to
``--out/results.json`` and ``table.md``; with ``--docs DIR`` also ``DIR/figures/close_loop.png``,
``close_loop_point_mass_paths.png`` and ``close_loop_results.json``.

Usage (the command line is :mod:`pbicrl.cli.close_loop`)::

    nice -n 10 python -m pbicrl.experiments.close_loop --out runs/close_loop --docs docs

Needs torch, gymnasium, mujoco and matplotlib (``pip install "pbicrl[rl,envs,plot]"``).
"""

from __future__ import annotations

import json
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from pbicrl._moved import moved_to_cli
from pbicrl.experiments.kinds import shipped_data_tag

__all__ = ["CloseLoopConfig", "EnvPlan", "default_config", "run"]

EVAL_SEED = 20_240_513  # reset seeds of the evaluation episodes (the same for every policy)


@dataclass(frozen=True)
class EnvPlan:
    """What to run for one environment.

    Attributes
    ----------
    env : str
        ``point_mass`` or ``halfcheetah`` (also the shipped dataset's name).
    steps : int
        PPO-Lagrangian steps per policy.
    seeds : tuple of int
        Training seeds (each policy kind is trained once per seed).
    cost_limit : float
        :math:`D`, budget on the expected cost per episode.
    policies : tuple of str
        ``nominal``, ``true``, ``inferred`` (indicator) or ``inferred-<mode>``.
    ppo : dict
        Overrides of :func:`pbicrl.experiments.safe_rl.ppo_config`.
    warmup_steps : int
        Steps of nominal training before the cost is on (:func:`pbicrl.experiments.safe_rl.train_safe`).
    constraints : list of dict or None
        Parametric constraints for the inference (``pbicrl infer --config`` tables).
    """

    env: str
    steps: int
    seeds: tuple[int, ...]
    cost_limit: float
    policies: tuple[str, ...] = ("nominal", "true", "inferred")
    ppo: dict = field(default_factory=dict)
    warmup_steps: int = 0
    constraints: list | None = None


@dataclass(frozen=True)
class CloseLoopConfig:
    """Settings of the whole experiment (recorded in ``results.json``).

    Attributes
    ----------
    plans : tuple of EnvPlan
    episodes : int
        Evaluation episodes per policy.
    iterations, chains : int
        MCMC iterations per chain and chains of each inference run (``pbicrl`` sampler, seed 0).
    """

    plans: tuple[EnvPlan, ...]
    episodes: int = 100
    iterations: int = 40_000
    chains: int = 2


def default_config(pm_steps: int = 100_000, hc_steps: int = 200_000, seeds: int = 3, hc_seeds: int = 3,
                   pm_cost_limit: float = 0.1, hc_cost_limit: float = 1.0, hc_probability: bool = True,
                   episodes: int = 100, iterations: int = 40_000) -> CloseLoopConfig:
    """The budget of ``docs/closing_the_loop.md`` (measured: 52 minutes on a shared 2-core CPU).

    Point mass: PPO learning rate 1e-3 (with the default 3e-4 a nominal policy reached the goal only after
    about 50 k steps here), multiplier step 0.2, 20 k warm-up steps (a random walk from the edges enters the
    discs, and with :math:`D = 0.1` the multiplier it raises falls by only 0.005 per update: without the
    warm-up a policy learned to stand still). HalfCheetah: the default PPO settings, no warm-up (a random
    policy never reaches the wall), an ``inferred-conservative`` policy (the wall at the edge of the identified
    region nearest the good demonstrations, the default of :class:`~pbicrl.envs.inferred_cost.InferredConstraintCost`
    for parametric constraints) beside ``inferred`` (indicator: the wall at the posterior median); with
    ``hc_probability`` also an ``inferred-probability`` policy (the rankings do not identify the wall's location,
    see the docs).
    """
    hc_pol = ("nominal", "true", "inferred", "inferred-conservative") + (("inferred-probability",) if hc_probability
                                                                          else ())
    wall = [{"family": "axis_halfspace", "dims": [0], "direction": ">=", "name": "wall"}]
    return CloseLoopConfig(
        plans=(EnvPlan("point_mass", pm_steps, tuple(range(seeds)), pm_cost_limit,
                       ppo={"lr": 1e-3, "lagrange_lr": 0.2}, warmup_steps=min(20_000, pm_steps // 5)),
               EnvPlan("halfcheetah", hc_steps, tuple(range(hc_seeds)), hc_cost_limit, hc_pol, constraints=wall)),
        episodes=episodes, iterations=iterations)


def _log(msg: str) -> None:
    print(f"{time.strftime('%H:%M:%S')} close_loop: {msg}", file=sys.stderr, flush=True)


def _policy_cost(kind: str) -> tuple[str, str]:
    if kind in ("nominal", "true"):
        return ("none" if kind == "nominal" else "true"), "indicator"
    if kind == "inferred":
        return "inferred", "indicator"
    if kind.startswith("inferred-"):
        return "inferred", kind.split("-", 1)[1]
    raise ValueError(f"policies: unknown policy kind {kind!r}; use nominal, true, inferred or inferred-<mode>")


def _stage(kind: str, data_tag: str) -> str:
    """Directory name of a policy kind: those trained on an inferred cost carry the data they were inferred from."""
    return f"{kind}-{data_tag}" if _policy_cost(kind)[0] == "inferred" else kind


def _infer(plan: EnvPlan, cfg: CloseLoopConfig, out: Path) -> Path:
    """The inference run of ``plan.env`` (cached per content of the shipped dataset: a regenerated file
    gets a new run, and the ``inferred`` policies trained on it with it)."""
    run_dir = out / "infer" / shipped_data_tag(plan.env)
    if (run_dir / "summary.json").is_file():
        return run_dir
    from pbicrl.api import infer
    from pbicrl.inference.data import load_dataset

    _log(f"inferring the {plan.env} constraint ({cfg.chains} chains x {cfg.iterations} iterations)")
    post = infer(load_dataset(plan.env), iterations=cfg.iterations, chains=cfg.chains, jobs=1, seed=0,
                 constraints=plan.constraints, progress=False)
    post.save(run_dir)
    return run_dir


def _paths(policy: Any, n: int) -> list[np.ndarray]:
    """Point-mass positions of ``n`` evaluation episodes (start included), for the figure."""
    from pbicrl.experiments.safe_rl import make_env

    env = make_env("point_mass")
    out = []
    for k in range(n):
        obs, _ = env.reset(seed=EVAL_SEED + k)
        pos = [env.position]
        while True:
            obs, _, term, trunc, _ = env.step(policy(obs))
            pos.append(env.position)
            if term or trunc:
                break
        out.append(np.asarray(pos))
    return out


def run(cfg: CloseLoopConfig, out: Path, docs: Path | None = None) -> dict[str, Any]:
    """Run (or resume) the experiment; returns the results (also ``out/results.json``)."""
    from pbicrl.experiments.safe_rl import evaluate_policy, load_policy, train_safe

    out.mkdir(parents=True, exist_ok=True)
    timing: dict[str, float] = {}
    results: dict[str, Any] = {"config": asdict(cfg), "eval_seed": EVAL_SEED, "envs": {}}
    for plan in cfg.plans:
        kinds = [(k, *_policy_cost(k)) for k in plan.policies]
        t0 = time.time()
        run_dir = _infer(plan, cfg, out)
        timing[f"{plan.env}/infer"] = time.time() - t0
        from pbicrl.io.runs import read_run

        rec = read_run(run_dir)
        post = {"data": run_dir.name, "selected": rec.selected(), "p_constraint": dict(zip(rec.feature_names, rec.p_constraint.tolist())),
                "parameters": {n: {"median": float(m), "ci90": [float(lo), float(hi)]} for n, m, lo, hi in
                               zip(rec.parameter_names, *(rec.parameter_conditional()[k] for k in ("median", "low", "high")))}}
        env_res: dict[str, Any] = {"plan": asdict(plan), "posterior": post, "policies": {}}
        per_episode: dict[tuple[str, int], dict] = {}
        for kind, cost, mode in kinds:
            per_seed = []
            for seed in plan.seeds:
                stage = _stage(kind, run_dir.name)
                d = out / "train" / plan.env / stage / f"seed{seed}"
                t0 = time.time()
                _log(f"{plan.env} {kind} seed {seed}: training {plan.steps} steps (resumes if interrupted)")
                s = train_safe(d, plan.env, plan.steps, plan.cost_limit, run=run_dir if cost == "inferred" else None,
                               cost=cost, mode=mode, seed=seed, ppo=plan.ppo, warmup_steps=plan.warmup_steps,
                               eval_episodes=0, progress=False)
                timing[f"{plan.env}/{kind}/seed{seed}/train"] = time.time() - t0
                ev_path = out / "eval" / f"{plan.env}-{stage}-seed{seed}.json"
                if ev_path.is_file():
                    ev = json.loads(ev_path.read_text())
                else:
                    t0 = time.time()
                    ev = evaluate_policy(load_policy(d), plan.env, cfg.episodes, seed=EVAL_SEED).to_dict()
                    ev["eval_runtime_s"] = round(time.time() - t0, 1)
                    timing[f"{plan.env}/{kind}/seed{seed}/eval"] = time.time() - t0
                    ev_path.parent.mkdir(parents=True, exist_ok=True)
                    ev_path.write_text(json.dumps(ev))
                per_episode[(kind, seed)] = ev["per_episode"]
                ev = {k: v for k, v in ev.items() if k != "per_episode"}
                ev.update(train_runtime_s=s["runtime_s"], final_lambda=s["lambda"], steps=s["steps"],
                          train_episode_cost_last_10=s["last_10_updates"]["ep_cost"],
                          cost_description=s["cost_description"])
                per_seed.append(ev)
                _log(f"{plan.env} {kind} seed {seed}: violation rate {ev['violation_rate']:.4f}, true return "
                     f"{ev['true_return']:.1f}, nominal return {ev['nominal_return']:.1f}")
            agg = {k: [e[k] for e in per_seed] for k in ("violation_rate", "violating_episodes", "true_return",
                                                          "nominal_return", "mean_steps", "max_x")
                   if all(k in e for e in per_seed)}
            env_res["policies"][kind] = {"per_seed": per_seed,
                                         "mean": {k: float(np.mean(v)) for k, v in agg.items()},
                                         "std": {k: float(np.std(v)) for k, v in agg.items()}}
        # the same cost at every state gives the same training: say so when it happened
        env_res["identical_to_true"] = {
            kind: all(per_episode.get((kind, s)) == per_episode.get(("true", s)) for s in plan.seeds)
            for kind in plan.policies if kind.startswith("inferred") and "true" in plan.policies}
        results["envs"][plan.env] = env_res
    # this call's stage times (cached stages take ~0 s); training times over all sessions are per seed
    # (train_runtime_s) and summed per environment here
    results["session_timing_s"] = {k: round(v, 1) for k, v in timing.items()}
    results["train_runtime_s_total"] = {env: round(sum(e["train_runtime_s"] for p in r["policies"].values()
                                                       for e in p["per_seed"]), 1)
                                        for env, r in results["envs"].items()}
    table = markdown_table(results)
    (out / "results.json").write_text(json.dumps(results, indent=2))
    (out / "table.md").write_text(table + "\n")
    if docs is not None:
        fig_dir = docs / "figures"
        fig_dir.mkdir(parents=True, exist_ok=True)
        (fig_dir / "close_loop_results.json").write_text(json.dumps(results, indent=2))
        plot(results, fig_dir / "close_loop.png")
        pm = next((p for p in cfg.plans if p.env == "point_mass"), None)
        if pm is not None:
            tag = shipped_data_tag("point_mass")
            paths = {k: _paths(load_policy(out / "train" / "point_mass" / _stage(k, tag) / f"seed{pm.seeds[0]}"), 20)
                     for k in pm.policies}
            plot_paths(paths, fig_dir / "close_loop_point_mass_paths.png", seed=pm.seeds[0])
    print(table)
    return results


def _ms(m: float, s: float, digits: int) -> str:
    return f"{m:.{digits}f} ± {s:.{digits}f}"


def markdown_table(results: dict[str, Any]) -> str:
    """The evaluation table: mean ± std over seeds of each policy's per-seed 100-episode means."""
    lines = ["| environment | policy | seeds | violation rate | episodes with a violation | true return | "
             "nominal return | episode length | furthest x |", "|---|---|---|---|---|---|---|---|---|"]
    for env, r in results["envs"].items():
        for kind, p in r["policies"].items():
            m, s = p["mean"], p["std"]
            lines.append(f"| {env} | {kind} | {len(p['per_seed'])} | {_ms(m['violation_rate'], s['violation_rate'], 4)} | "
                         f"{_ms(m['violating_episodes'], s['violating_episodes'], 2)} | "
                         f"{_ms(m['true_return'], s['true_return'], 1)} | {_ms(m['nominal_return'], s['nominal_return'], 1)} | "
                         f"{_ms(m['mean_steps'], s['mean_steps'], 1)} | "
                         + (f"{_ms(m['max_x'], s['max_x'], 1)} |" if "max_x" in m else "- |"))
    return "\n".join(lines)


def _tick_name(kind: str) -> str:
    """A policy kind as a tick label: ``inferred-<mode>`` on two lines (``probability`` as "P-weighted")."""
    if kind.startswith("inferred-"):
        mode = kind.split("-", 1)[1]
        return "inferred\n(" + ("P-weighted" if mode == "probability" else mode) + ")"
    return kind


def plot(results: dict[str, Any], path: Path) -> None:
    """Per policy (bars: mean over seeds; dots: seeds): violation rate, true return, and how far it went -
    the furthest x with the true wall and the posterior's median wall (walls) or the episode length (point
    mass, whose episodes end at the goal). One row per environment."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    from pbicrl.analysis import style

    envs = list(results["envs"])
    colours = {"nominal": "0.55", "true": style.GROUP_GOOD, "inferred": style.ACTIVE, "inferred-probability": "#7e57c2",
               "inferred-conservative": "#f0a030"}
    with style.rc():
        most = max(len(results["envs"][e]["policies"]) for e in envs)  # ~1.1 inch per bar keeps the ticks apart
        fig, axes = plt.subplots(len(envs), 3, figsize=(max(13.0, 3.3 * 1.1 * most + 2.5), 3.3 * len(envs)),
                                 squeeze=False, layout="constrained")
        for row, env in zip(axes, envs):
            r = results["envs"][env]
            pols = r["policies"]
            n_seeds = len(next(iter(pols.values()))["per_seed"])
            wall = all("max_x" in e for p in pols.values() for e in p["per_seed"])
            third = ("max_x", "furthest x in an episode (m)") if wall else ("mean_steps", "episode length (steps)")
            for ax, (key, label) in zip(row, (("violation_rate", "violation rate\n(fraction of steps)"),
                                              ("true_return", "true return (reward units)"), third)):
                for i, (kind, p) in enumerate(pols.items()):
                    vals = [e[key] for e in p["per_seed"]]
                    ax.bar(i, np.mean(vals), color=colours.get(kind, "tab:orange"), alpha=0.75)
                    ax.scatter(np.full(len(vals), i), vals, color="black", s=12, zorder=3)
                # short two-line tick names: "inferred-<mode>" in one line crowded its neighbours
                ax.set_xticks(range(len(pols)), [_tick_name(k) for k in pols])
                ax.set_xlabel("policy")
                ax.set_ylabel(label)
                ax.set_title(f"{env} ({n_seeds} seed{'s' if n_seeds != 1 else ''})")
            if wall:
                from pbicrl.envs.mujoco_wall import WALL_SPECS

                ax = row[2]
                ax.axhline(WALL_SPECS[env].wall_x, color=style.REGION_COLOURS["wall"], lw=1.2)
                med = r["posterior"]["parameters"].get("wall.threshold", {}).get("median")
                if med is not None:
                    ax.axhline(med, color=style.ACTIVE, lw=1.2, ls="--")
        handles = [Patch(color="0.7", label="bar: mean over seeds"),
                   Line2D([], [], color="black", marker="o", ls="none", ms=4, label="dot: one seed"),
                   Line2D([], [], color=style.REGION_COLOURS["wall"], lw=1.2, label="true wall"),
                   Line2D([], [], color=style.ACTIVE, lw=1.2, ls="--", label="posterior median wall")]
        fig.legend(handles=handles, loc="outside right center", frameon=False)
        fig.savefig(path, dpi=120)
        plt.close(fig)


def plot_paths(paths: dict[str, list[np.ndarray]], path: Path, seed: int) -> None:
    """Point-mass evaluation paths of each policy over the constraint discs."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Circle

    from matplotlib.patches import Patch

    from pbicrl.analysis import style
    from pbicrl.envs.point_mass import HIGH, LOW, POINT_MASS_TASK as task

    with style.rc():
        fig, axes = plt.subplots(1, len(paths), figsize=(3.4 * len(paths) + 1.8, 3.6), squeeze=False,
                                 layout="constrained")
        for ax, (kind, ps) in zip(axes[0], paths.items()):
            for name, disc in (("orange", task.orange), ("red", task.red), ("goal", task.goal)):
                ax.add_patch(Circle(disc.centre, disc.radius, color=style.REGION_COLOURS[name], alpha=0.35))
            for p in ps:
                ax.plot(p[:, 0], p[:, 1], "-", color="black", lw=0.7, alpha=0.6)
            ax.set_xlim(LOW, HIGH)
            ax.set_ylim(LOW, HIGH)
            ax.set_aspect("equal")
            ax.set_xlabel("x (arena units)")
            ax.set_ylabel("y (arena units)")
            ax.set_title(f"{kind} policy (seed {seed})")
        handles = [Patch(color=style.REGION_COLOURS[n], alpha=0.5, label=f"{n} region") for n in ("goal", "orange", "red")]
        fig.legend(handles=handles + [plt.Line2D([], [], color="black", lw=0.8, label="evaluation episode")],
                   loc="outside right center", frameon=False)
        fig.savefig(path, dpi=120)
        plt.close(fig)


__getattr__ = moved_to_cli(__name__, {"main": "pbicrl.cli.close_loop"})  # the command line moved
