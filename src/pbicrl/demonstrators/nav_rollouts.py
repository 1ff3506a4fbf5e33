"""Rollouts of the navigation policies (:class:`Episode`) and the earlier two-policy dataset design
(:func:`generate_navigation_demos`)."""

from __future__ import annotations

import json
import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from pbicrl._atomic import write_text
from pbicrl.errors import DemonstrationError
from pbicrl.demonstrators.nav_envs import make_nav_env, nav_spec
from pbicrl.demonstrators.nav_training import sac_budget
from pbicrl.inference.data import Dataset

__all__ = ["Episode", "rollout_episodes", "policy_actor", "generate_navigation_demos"]


@dataclass
class Episode:
    """One rollout: states ``s_0..s_T`` (T+1, k), actions (T, a), rewards (T,), features (T+1, 4)."""

    states: NDArray[np.float64]
    actions: NDArray[np.float64]
    rewards: NDArray[np.float64]
    features: NDArray[np.float64]
    reached: bool
    truncated: bool
    group: int
    seed: int
    policy: str


def rollout_episodes(env: Any, act: Callable[[NDArray], NDArray], n_episodes: int, *, seed: int,
                     policy_name: str = "") -> list[Episode]:
    """Roll ``act`` out for ``n_episodes`` episodes, seeding episode ``i`` with ``seed + i``."""
    task = env.task
    out = []
    for i in range(int(n_episodes)):
        obs, _ = env.reset(seed=seed + i)
        states, actions, rewards = [env.position], [], []
        done = trunc = False
        while not (done or trunc):
            a = np.asarray(act(obs), dtype=np.float64).reshape(-1)
            obs, r, done, trunc, _ = env.step(a)
            states.append(env.position)
            actions.append(a)
            rewards.append(r)
        s = np.asarray(states)
        out.append(Episode(states=s, actions=np.asarray(actions), rewards=np.asarray(rewards),
                           features=task.features(s), reached=bool(done), truncated=bool(trunc),
                           group=task.group(s), seed=seed + i, policy=policy_name))
    return out


def policy_actor(path: str | os.PathLike, deterministic: bool) -> Callable[[NDArray], NDArray]:
    from pbicrl.demonstrators.sac import load_policy

    policy = load_policy(path)

    def act(obs: NDArray) -> NDArray:
        a, _ = policy.predict(np.asarray(obs, dtype=np.float32), deterministic=deterministic)
        return a

    return act


def generate_navigation_demos(env: str, good_policy: str | os.PathLike | None, violating_policy: str | os.PathLike,
                              out: str | os.PathLike | None = None, *, n_per_group: int = 300, seed: int = 0,
                              max_episodes: int = 20_000, batch: int = 100, deterministic: bool = True,
                              require_goal: bool = True, return_episodes: bool = False,
                              progress: bool = True) -> tuple[Dataset, dict[str, Any]] | tuple[Dataset, dict[str, Any], list[Episode]]:
    """Roll out both demonstrators and build the three-group ranked dataset.

    Parameters
    ----------
    env : {"point_mass", "fetch_reach"}
    good_policy, violating_policy : path
        ``policy.zip`` files (true-reward and nominal-reward SAC).  With ``good_policy=None``
        G1 is taken from the violating policy's rollouts that enter neither region (a
        fallback when no true-reward demonstrator is available; the report says so).
    out : path, optional
        Write the dataset here (``.npz``, atomic) and a JSON report beside it (``.json``).
    n_per_group : int
        Target number of trajectories per group (extra ones are dropped, first come first kept).
    seed : int
        Episode ``i`` of the good policy uses seed ``seed + i``; the violating policy uses
        ``seed + 10_000_000 + i``.
    max_episodes : int
        Cap on rollouts per policy.
    batch : int
        Episodes per rollout round (between checks of the counts).
    deterministic : bool
        Use the SAC mean action (True) or sample from the policy.
    require_goal : bool
        Keep only trajectories that reach the goal set.

    Returns
    -------
    dataset : Dataset
        Groups 1..3, states ``s_0..s_T``, features, nominal weights.
    report : dict
        Rollout counts per policy and group, success rates, sizes and timing.
    """
    if n_per_group < 1:
        raise ValueError(f"n_per_group: must be >= 1, got {n_per_group}")
    spec = nav_spec(env)
    t0 = time.time()
    environment = make_nav_env(env, "true")
    task = environment.task
    kept: dict[int, list[Episode]] = {1: [], 2: [], 3: []}
    stats: dict[str, dict[str, Any]] = {}
    plan = [("good", good_policy, (1,), 0), ("violating", violating_policy, (2, 3), 10_000_000)]
    if good_policy is None:
        plan = [("violating", violating_policy, (1, 2, 3), 10_000_000)]
    for name, path, wanted, offset in plan:
        act = policy_actor(path, deterministic)
        n_run, by_group, n_reached = 0, {1: 0, 2: 0, 3: 0}, 0
        while n_run < max_episodes and any(len(kept[g]) < n_per_group for g in wanted):
            k = min(batch, max_episodes - n_run)
            for ep in rollout_episodes(environment, act, k, seed=seed + offset + n_run, policy_name=name):
                by_group[ep.group] += 1
                n_reached += ep.reached
                if ep.group in wanted and (ep.reached or not require_goal) and len(kept[ep.group]) < n_per_group:
                    kept[ep.group].append(ep)
            n_run += k
            if progress:
                print(f"[{env} demos] {name}: {n_run} episodes, kept "
                      f"{ {g: len(kept[g]) for g in wanted} }", flush=True)
        stats[name] = {"policy": str(path), "episodes": n_run, "reached_goal": n_reached,
                       "success_rate": round(n_reached / max(n_run, 1), 4),
                       "group_of_rollouts": {f"G{g}": c for g, c in by_group.items()}}
    episodes = kept[1] + kept[2] + kept[3]
    missing = [g for g in (1, 2, 3) if not kept[g]]
    if len(missing) > 1:
        raise DemonstrationError(f"demos: groups {missing} are empty after {max_episodes} rollouts per policy; "
                           "the policies do not produce the intended behaviour")
    ds = Dataset.from_trajectories([e.features for e in episodes], [e.group for e in episodes],
                                   states=[e.states for e in episodes], feature_names=task.feature_names,
                                   nominal_weights=task.nominal_weights)
    report: dict[str, Any] = {
        "env": env, "n_per_group_target": n_per_group,
        "g1_source": "good (true-reward) policy" if good_policy is not None else
                     "violating (nominal-reward) policy rollouts that enter no region (fallback)", "group_counts": {f"G{k}": v for k, v in ds.group_counts().items()},
        "rollouts": stats, "seed": seed, "deterministic": deterministic, "require_goal": require_goal,
        "mean_length": float(ds.lengths.mean()), "true_weights": list(task.true_weights),
        "nominal_weights": list(task.nominal_weights), "paper_sac_steps": spec.paper_steps,
        "wall_time_s": round(time.time() - t0, 1),
        "mean_true_return_per_group": {f"G{g}": float(np.mean([e.rewards.sum() for e in kept[g]])) for g in (1, 2, 3) if kept[g]},
    }
    for name, path in (("good", good_policy), ("violating", violating_policy)):
        if path is None:
            continue
        budget = sac_budget(path)
        if budget is not None:
            report["rollouts"][name]["sac_budget"] = budget
    if out is not None:
        path = ds.save(out)
        report["file"] = path.name
        report["file_bytes"] = path.stat().st_size
        write_text(path.with_suffix(".json"), json.dumps(report, indent=2, sort_keys=True) + "\n")
    environment.close()
    if return_episodes:
        return ds, report, episodes
    return ds, report
