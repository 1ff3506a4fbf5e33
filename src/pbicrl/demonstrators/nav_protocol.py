"""The paper's dataset design (:func:`generate_paper_protocol_demos`, the shipped data) and how far its groups
differ in their nominal features (:func:`group_feature_balance`)."""

from __future__ import annotations

import json
import os
import time
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from pbicrl._atomic import write_text
from pbicrl.errors import DemonstrationError
from pbicrl.demonstrators.nav_envs import make_nav_env, nav_spec
from pbicrl.demonstrators.nav_rollouts import Episode, policy_actor, rollout_episodes
from pbicrl.demonstrators.nav_training import sac_budget
from pbicrl.inference.data import Dataset

__all__ = ["PAPER_PROTOCOL", "group_feature_balance", "generate_paper_protocol_demos"]


#: Settings of the shipped paper-protocol datasets (``pbicrl envs demos --paper-protocol`` defaults).
#: ``p_good`` is the probability that a rollout is made by the good (true-reward) policy (see
#: docs/envs.md for why it is small with the shipped policies); ``env_kwargs`` select the start
#: distribution (point mass: the ``"balanced"`` strips along its left/bottom edges; Fetch-Reach: the
#: ``"balanced"`` start box).
PAPER_PROTOCOL: dict[str, dict[str, Any]] = {
    "point_mass": {"p_good": 0.01, "deterministic": False, "n_per_group": 300, "seed": 0,
                   "env_kwargs": {"start": "balanced"}},
    "fetch_reach": {"p_good": 0.01, "deterministic": False, "n_per_group": 300, "seed": 0,
                    "env_kwargs": {"start": "balanced"}},
}


def _display_path(path: str | os.PathLike) -> str:
    """``path`` relative to the working directory when it lies below it (no machine paths in reports)."""
    p = Path(path).resolve()
    try:
        return str(p.relative_to(Path.cwd().resolve()))
    except ValueError:
        return str(path)


def _start_description(environment: Any) -> str:
    """Words for the start distribution of a point-mass or Fetch-Reach environment."""
    if hasattr(environment, "start_low"):
        lo, hi = environment.start_low, environment.start_high
        return (f"{environment.start!r} box: uniform on " + ", ".join(f"{a} in [{l:g}, {h:g}]" for a, l, h in zip("xyz", lo, hi))
                + " (gripper driven there at reset)")
    from pbicrl.envs.point_mass import START_STRIPS

    start = getattr(environment, "start", "random")
    (a_lo, a_hi), (c_lo, c_hi) = START_STRIPS[start]
    edges = {"left": f"left strip x in [{c_lo:g}, {c_hi:g}], y in [{a_lo:g}, {a_hi:g}]",
             "bottom": f"bottom strip x in [{a_lo:g}, {a_hi:g}], y in [{c_lo:g}, {c_hi:g}]"}
    if start in ("left", "bottom"):
        return f"uniform on the {edges[start]}"
    return f"{start!r}: uniform on the {edges['left']} or the {edges['bottom']}, probability 1/2 each"


def _pooled_smd(a: NDArray[np.float64], b: NDArray[np.float64]) -> float:
    """``(mean(a) - mean(b)) / pooled sd`` (sample variances, ``n - 1``); 0 for two equal constants."""
    na, nb = a.size, b.size
    if na < 2 or nb < 2:
        return float("nan")
    pooled = np.sqrt(((na - 1) * a.var(ddof=1) + (nb - 1) * b.var(ddof=1)) / (na + nb - 2))
    diff = float(a.mean() - b.mean())
    if pooled == 0:
        return 0.0 if diff == 0 else float(np.copysign(np.inf, diff))
    return diff / float(pooled)


def group_feature_balance(dataset: Dataset, features: Any = None) -> dict[str, Any]:
    """Per-group means/sds of per-trajectory mean features and standardised mean differences.

    The per-trajectory feature is the trajectory's mean over its states
    (:attr:`pbicrl.inference.data.Dataset.mean_features`, what the ranking likelihood scores).  For
    groups ``a, b`` the standardised mean difference (SMD) is ``(mean_a - mean_b) / s_p`` with
    the pooled sd ``s_p = sqrt(((n_a-1) s_a^2 + (n_b-1) s_b^2) / (n_a + n_b - 2))``.

    Parameters
    ----------
    dataset : Dataset
    features : sequence of str, optional
        Feature names to report; default: the *nominal* features, i.e. those with a non-zero
        nominal weight (all features if the dataset has no nominal weights).

    Returns
    -------
    dict
        ``features`` (names), ``groups`` (labels), ``n`` (per group), ``mean`` / ``sd``
        (``{feature: {"G1": ..}}``), ``smd`` (``{feature: {"G1-G2": ..}}``), ``max_abs_smd``,
        ``length`` (mean and sd of the number of states per group).
    """
    names = list(dataset.feature_names)
    if features is None:
        w = dataset.nominal_weights
        features = names if w is None else [n for n, x in zip(names, w) if x != 0]
    cols = []
    for f in features:
        if f not in names:
            raise ValueError(f"features: {f!r} is not one of {names}")
        cols.append(names.index(f))
    mf = dataset.mean_features
    labels = [int(k) for k in dataset.group_labels]
    out: dict[str, Any] = {"features": list(features), "groups": [f"G{k}" for k in labels],
                           "n": {f"G{k}": int((dataset.group == k).sum()) for k in labels},
                           "mean": {}, "sd": {}, "smd": {}}
    worst = 0.0
    for f, j in zip(features, cols):
        per = {k: mf[dataset.group == k, j] for k in labels}
        out["mean"][f] = {f"G{k}": float(v.mean()) for k, v in per.items()}
        out["sd"][f] = {f"G{k}": float(v.std(ddof=1)) if v.size > 1 else float("nan") for k, v in per.items()}
        out["smd"][f] = {}
        for i, a in enumerate(labels):
            for b in labels[i + 1:]:
                d = _pooled_smd(per[a], per[b])
                out["smd"][f][f"G{a}-G{b}"] = d
                if np.isfinite(d) or np.isinf(d):
                    worst = max(worst, abs(d))
    out["max_abs_smd"] = worst
    out["length"] = {}
    for k in labels:
        lk = dataset.lengths[dataset.group == k].astype(np.float64)
        out["length"][f"G{k}"] = {"mean": float(lk.mean()), "sd": float(lk.std(ddof=1)) if lk.size > 1 else float("nan")}
    return out


def generate_paper_protocol_demos(env: str, good_policy: str | os.PathLike, violating_policy: str | os.PathLike,
                                  out: str | os.PathLike | None = None, *, p_good: float = 0.5,
                                  n_per_group: int = 300, seed: int = 0, deterministic: bool = False,
                                  max_episodes: int = 50_000, batch: int = 100, require_goal: bool = True,
                                  env_kwargs: dict[str, Any] | None = None, command: str | None = None,
                                  torch_threads: int | None = 1,
                                  return_episodes: bool = False, progress: bool = True,
                                  ) -> tuple[Dataset, dict[str, Any]] | tuple[Dataset, dict[str, Any], list[Episode]]:
    """Ranked demonstrations the paper's way: one start distribution, a policy mix, labels after the fact.

    Rollout ``i`` draws ``u_i ~ U(0, 1)`` and an environment seed from
    ``numpy.random.default_rng(seed)``; it is made by the good policy if ``u_i < p_good``, else
    by the violating policy, from a start drawn by the environment's own start distribution
    (the same for both policies).  Its group is the worst region it entered (G3 red, G2
    orange but not red, G1 neither; :meth:`~pbicrl.envs.regions.NavigationTask.group`),
    whichever policy made it.  Every rollout is kept, except (with ``require_goal``) those
    that do not reach the goal within the time limit, which are counted per policy and
    group in the report.  Rollouts run in batches of ``batch`` until every group holds at
    least ``n_per_group`` trajectories (or ``max_episodes`` rollouts are spent); group sizes
    therefore differ, and nothing is dropped to equalise them.

    Parameters
    ----------
    env : {"point_mass", "fetch_reach"}
    good_policy, violating_policy : path
        ``policy.zip`` files of the true-reward and the nominal-reward SAC demonstrators.
    out : path, optional
        Write the dataset here (``.npz``, atomic) and the JSON report beside it (``.json``).
    p_good : float in [0, 1]
        Probability that a rollout uses the good policy.
    n_per_group : int
        Minimum number of kept trajectories per group.
    seed : int
        Seeds the policy choice and start states (``default_rng(seed)``) and the sampling of
        stochastic actions (``torch.manual_seed(seed)``).
    deterministic : bool
        SAC mean actions (True) or actions sampled from the policies (False).
    max_episodes : int
        Cap on the total number of rollouts.
    require_goal : bool
        Reject rollouts that do not reach the goal (counted in the report).
    env_kwargs : dict, optional
        Passed to the environment (:func:`make_nav_env`), e.g. ``{"start": "equidistant"}`` for
        Fetch-Reach's start box; the same for every rollout and both policies.
    command : str, optional
        The command line that regenerates the data, stored in the report.
    torch_threads : int, optional
        Torch threads during the rollouts (restored afterwards); ``None`` leaves them.

    Returns
    -------
    dataset : Dataset
    report : dict
        Mix, seeds, rollouts and rejections per policy and group, composition of each group,
        goal-reaching rate per group before the filter, :func:`group_feature_balance` of the
        nominal features, mean lengths and true returns, and ``trajectory_policy`` (one
        letter per stored trajectory, ``g`` good / ``v`` violating, in file order).
    """
    if not 0.0 <= float(p_good) <= 1.0:
        raise ValueError(f"p_good: must be in [0, 1], got {p_good}")
    if n_per_group < 1:
        raise ValueError(f"n_per_group: must be >= 1, got {n_per_group}")
    if batch < 1 or max_episodes < 1:
        raise ValueError(f"batch and max_episodes: must be >= 1, got {batch} and {max_episodes}")
    import torch

    spec = nav_spec(env)
    t0 = time.time()
    old_threads = torch.get_num_threads()
    if torch_threads is not None:
        torch.set_num_threads(int(torch_threads))
    torch.manual_seed(int(seed))
    rng = np.random.default_rng(int(seed))
    env_kwargs = dict(env_kwargs or {})
    environment = make_nav_env(env, "true", **env_kwargs)
    task = environment.task
    paths = {"good": good_policy, "violating": violating_policy}
    actors = {name: policy_actor(path, deterministic) for name, path in paths.items()}
    zero = {1: 0, 2: 0, 3: 0}
    stats = {name: {"episodes": 0, "reached": 0, "rollout_groups": dict(zero), "kept": dict(zero),
                    "rejected": dict(zero)} for name in paths}
    kept: list[Episode] = []
    counts = dict(zero)
    n_run = 0
    try:
        while n_run < max_episodes and min(counts.values()) < n_per_group:
            for _ in range(min(batch, max_episodes - n_run)):
                name = "good" if rng.random() < p_good else "violating"
                ep_seed = int(rng.integers(2**31 - 1))
                ep = rollout_episodes(environment, actors[name], 1, seed=ep_seed, policy_name=name)[0]
                st = stats[name]
                st["episodes"] += 1
                st["reached"] += ep.reached
                st["rollout_groups"][ep.group] += 1
                if ep.reached or not require_goal:
                    st["kept"][ep.group] += 1
                    counts[ep.group] += 1
                    kept.append(ep)
                else:
                    st["rejected"][ep.group] += 1
                n_run += 1
            if progress:
                print(f"[{env} paper-protocol demos] {n_run} rollouts, kept per group {counts}", flush=True)
    finally:
        environment.close()
        torch.set_num_threads(old_threads)
    short = [g for g in (1, 2, 3) if counts[g] < n_per_group]
    if short and len([g for g in (1, 2, 3) if counts[g] == 0]) > 1:
        raise DemonstrationError(f"demos: groups {short} hold fewer than {n_per_group} trajectories after {n_run} "
                                 "rollouts; the policies do not produce the intended behaviour")
    episodes = sorted(kept, key=lambda e: e.group)  # stable: rollout order within a group
    ds = Dataset.from_trajectories([e.features for e in episodes], [e.group for e in episodes],
                                   states=[e.states for e in episodes], feature_names=task.feature_names,
                                   nominal_weights=task.nominal_weights)
    g = lambda d: {f"G{k}": int(v) for k, v in d.items()}  # noqa: E731
    rollouts: dict[str, Any] = {}
    for name, st in stats.items():
        rollouts[name] = {"policy": _display_path(paths[name]), "episodes": st["episodes"],
                          "reached_goal": st["reached"],
                          "success_rate": round(st["reached"] / max(st["episodes"], 1), 4),
                          "group_of_rollouts": g(st["rollout_groups"]), "kept_per_group": g(st["kept"]),
                          "rejected_goal_not_reached_per_group": g(st["rejected"])}
        budget = sac_budget(paths[name])
        if budget is not None:
            rollouts[name]["sac_budget"] = budget
    all_groups = {k: stats["good"]["rollout_groups"][k] + stats["violating"]["rollout_groups"][k] for k in (1, 2, 3)}
    reached_groups = {k: all_groups[k] - stats["good"]["rejected"][k] - stats["violating"]["rejected"][k]
                      if require_goal else None for k in (1, 2, 3)}
    report: dict[str, Any] = {
        "env": env, "protocol": "paper",
        "protocol_description": (
            "each rollout starts from the environment's start distribution and uses the good (true-reward) policy "
            "with probability p_good, else the violating (nominal-reward) policy; its group is the worst region "
            "it entered (G3 red, G2 orange not red, G1 neither); all rollouts are kept except those that do not "
            "reach the goal (require_goal); rollouts stop once every group holds n_per_group_min"),
        "p_good": float(p_good), "deterministic": bool(deterministic), "seed": int(seed),
        "env_kwargs": env_kwargs, "start_distribution": _start_description(environment),
        "seeds": {"policy_choice_and_start": f"numpy.random.default_rng({int(seed)}): per rollout u ~ U(0,1), "
                                             "then the environment's reset seed (start state)",
                  "actions": f"torch.manual_seed({int(seed)})"},
        "batch": int(batch), "max_episodes": int(max_episodes), "n_per_group_min": int(n_per_group),
        "require_goal": bool(require_goal), "total_rollouts": n_run,
        "groups_short_of_target": [f"G{k}" for k in short],
        "filters": {"goal_reached": {"applied": bool(require_goal),
                                     "rejected": sum(st["rejected"][k] for st in stats.values() for k in (1, 2, 3)),
                                     "rejected_per_policy": {n: sum(st["rejected"].values())
                                                             for n, st in stats.items()}}},
        "group_counts": {f"G{k}": v for k, v in ds.group_counts().items()},
        "group_composition": {f"G{k}": {name: stats[name]["kept"][k] for name in stats} for k in (1, 2, 3)},
        "goal_reaching_rate_per_group": {
            f"G{k}": round(reached_groups[k] / all_groups[k], 4) if all_groups[k] and require_goal else None
            for k in (1, 2, 3)},
        "g1_source": "mix: good-policy rollouts and violating-policy rollouts that entered no region (paper protocol)",
        "rollouts": rollouts,
        "feature_balance": group_feature_balance(ds),
        "mean_length": float(ds.lengths.mean()), "true_weights": list(task.true_weights),
        "nominal_weights": list(task.nominal_weights), "paper_sac_steps": spec.paper_steps,
        "mean_true_return_per_group": {f"G{k}": float(np.mean([e.rewards.sum() for e in episodes if e.group == k]))
                                       for k in (1, 2, 3) if counts[k]},
        "trajectory_policy": "".join(e.policy[0] for e in episodes),
        "command": command,
        "wall_time_s": round(time.time() - t0, 1),
    }
    if out is not None:
        path = ds.save(out)
        report["file"] = path.name
        report["file_bytes"] = path.stat().st_size
        write_text(path.with_suffix(".json"), json.dumps(report, indent=2, sort_keys=True) + "\n")
    if return_episodes:
        return ds, report, episodes
    return ds, report
