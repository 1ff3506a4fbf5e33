r"""Ranked demonstrations of the ICRL benchmark's tasks, generated the paper's way (issue 28, item 2).

One start distribution (the task's own reset, reset seeds ``seed, seed + 1, ...``), trajectories from a mix of
policies, each trajectory labelled by *what it did* with the task's true wall (the strict per-step indicator on
the post-step :math:`x`, ``info["cost"]``), never by which policy produced it:

=========  ======================================================================================================
group      rule (:math:`n_v` = violating steps of the episode, :math:`T` = the task's episode length)
=========  ======================================================================================================
1 (best)   never crosses the wall: :math:`n_v = 0`
2          crosses briefly: :math:`1 \le n_v \le` ``brief_max_steps`` (default :math:`\lfloor 0.1\,T \rfloor`,
           100 of HalfCheetah's 1000 steps)
3 (worst)  runs through: :math:`n_v \ge` ``through_min_steps`` (default :math:`\lceil 0.5\,T \rceil`: at least
           half of the episode beyond the wall)
unused     :math:`\text{brief\_max} < n_v < \text{through\_min}` (counted in the record, not kept)
=========  ======================================================================================================

The policies (``sources``), taken in turn, one episode each:

``expert``
    the true-cost PPO-Lagrangian expert (``best.pt`` of ``ppo_lag_true``), deterministic (the Gaussian's mean);
``expert_noise``
    the expert's mean plus Gaussian action noise of standard deviation ``noise_sd`` (default 0.5);
``unconstrained``
    the unconstrained PPO policy (``ppo``), stochastic (draws from its Gaussian);
``switch``
    a ``handover`` policy (its mean; default the unconstrained checkpoint) until the state :math:`x` first comes
    within :math:`u` of the wall (:math:`x < \text{wall} + u` for a wall behind, :math:`u \sim U(-s, s)` per
    episode, :math:`s` the task's ``handover_range``: 1 m, 0.01 for the pendulum), then the expert (its mean): it
    reaches the wall and is turned back by the expert, sometimes in time, sometimes after a brief crossing,
    sometimes not at all (the expert then runs on through). On Blocked
    Half-Cheetah the final unconstrained policy runs backwards so fast (and in a gait the expert never saw)
    that the expert almost never turns it back (measured: none of 30 handovers at x = -0.5 to -2.5); an early
    checkpoint of the same run (its ``best.pt``, 102,400 steps) is slower and is turned back after a brief
    crossing in about a third of the handovers (94 of 275): pass it as ``handover``.

A source stops being used once its last ``retire_after`` episodes all landed in full (or unused) groups; the
generation stops when every group has ``n_per_group`` episodes (the first ones in generation order) and fails,
writing nothing, if ``max_episodes`` episodes did not fill them. Every draw comes from the seed: the same
arguments give the same file.

Stored per step (:class:`pbicrl.inference.data.Dataset`): the nominal features (the reward's terms, with
``nominal_weights``) and the post-step :math:`x` (``states``, one column), which a parametric wall constraint
``axis_halfspace`` on column 0 indexes (direction ``<=`` for a wall behind, ``>=`` for one in front). With
``quantize`` (default) :math:`x` is snapped to a :math:`2^{-16}` grid and the actions to a :math:`2^{-10}` grid
and the features that are functions of them recomputed (the speed :math:`|x_{t+1} - x_t|/dt` and :math:`\sum a^2`
are then exact binary fractions, which compress well; the pendulum's ``bias_reward`` follows the quantized
:math:`x`; Ant's distance and the healthy / alive flags are kept); the labels are taken from the quantized
:math:`x`. Actions are not
stored (``keep_actions`` stores them).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "ACTION_QUANTUM",
    "SOURCES",
    "X_QUANTUM",
    "DemoRules",
    "checkpoint_lineage",
    "classify_episode",
    "generate_ranked_demos",
]

X_QUANTUM = 2.0 ** -16
ACTION_QUANTUM = 2.0 ** -10
SOURCES: tuple[str, ...] = ("expert", "expert_noise", "unconstrained", "switch")


@dataclass(frozen=True)
class DemoRules:
    """How episodes become groups (see the module docstring).

    Attributes
    ----------
    brief_max_steps : int
        Largest number of violating steps of a group-2 episode (>= 1).
    through_min_steps : int
        Least number of violating steps of a group-3 episode (> ``brief_max_steps``).
    """

    brief_max_steps: int
    through_min_steps: int

    def __post_init__(self) -> None:
        if int(self.brief_max_steps) != self.brief_max_steps or self.brief_max_steps < 1:
            raise ValueError(f"brief_max_steps: must be an integer >= 1, got {self.brief_max_steps!r}")
        if int(self.through_min_steps) != self.through_min_steps or self.through_min_steps <= self.brief_max_steps:
            raise ValueError(f"through_min_steps: must be an integer > brief_max_steps ({self.brief_max_steps}), "
                             f"got {self.through_min_steps!r}")

    @classmethod
    def for_task(cls, task: str, brief_max_steps: int | None = None,
                 through_min_steps: int | None = None) -> DemoRules:
        """Defaults from the task's episode length :math:`T`: 10% of :math:`T` and half of :math:`T`."""
        from pbicrl.envs.icrl_benchmark import icrl_task

        T = icrl_task(task).max_episode_steps
        return cls(int(brief_max_steps) if brief_max_steps is not None else max(1, T // 10),
                   int(through_min_steps) if through_min_steps is not None else math.ceil(0.5 * T))


def classify_episode(n_violating: int, rules: DemoRules) -> int:
    """Group of an episode with ``n_violating`` violating steps: 1, 2, 3, or 0 (unused)."""
    n = int(n_violating)
    if n < 0:
        raise ValueError(f"n_violating: must be >= 0, got {n_violating!r}")
    if n == 0:
        return 1
    if n <= rules.brief_max_steps:
        return 2
    if n >= rules.through_min_steps:
        return 3
    return 0


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def checkpoint_lineage(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Where a policy checkpoint of :func:`pbicrl.experiments.icrl_benchmark.train_policy` comes from: its path,
    SHA-256, environment steps, the run's method, seed and target, and (``best.pt``) the evaluation it was kept
    at."""
    from pbicrl.experiments.icrl_benchmark import load_run_checkpoint

    p = Path(path)
    if not p.is_file():
        raise ValueError(f"policy: {p} is not a file (a checkpoint.pt or best.pt of a training run)")
    obj = load_run_checkpoint(p)
    out: dict[str, Any] = {"path": str(p.resolve()), "sha256": _sha256(p), "steps": int(obj["agent"]["num_steps"])}
    if "eval" in obj:
        out["kept_at_eval"] = {k: v for k, v in obj["eval"].items()
                               if k in ("steps", "reward", "reward_nc", "violation_rate")}
    cfg = p.parent / "config.json"
    if cfg.is_file():
        c = json.loads(cfg.read_text(encoding="utf-8"))
        out["run"] = {k: c.get(k) for k in ("task", "method", "seed")}
    for name in ("done.json", "progress.json"):
        f = p.parent / name
        if f.is_file():
            out["run_" + name.split(".")[0]] = json.loads(f.read_text(encoding="utf-8"))
            break
    return out


class _Noisy:
    """The expert's mean plus N(0, sd^2) action noise (a numpy Generator re-seeded every episode)."""

    def __init__(self, policy: Callable[[Any], Any], sd: float, seed: int) -> None:
        self.policy, self.sd, self.seed = policy, float(sd), int(seed)
        self.rng = np.random.default_rng(0)

    def reset(self, seed: int) -> None:
        self.rng = np.random.default_rng([self.seed, 1, int(seed)])

    def __call__(self, obs: Any) -> NDArray[np.float64]:
        a = np.asarray(self.policy(obs), dtype=np.float64)
        return a + self.sd * self.rng.standard_normal(a.shape)


class _Switch:
    """``first`` until the state first comes within ``u ~ U(-s, s)`` of the wall (``s`` = ``scale``), then
    ``second``."""

    def __init__(self, first: Callable[[Any], Any], second: Callable[[Any], Any], wall: float, behind: bool,
                 seed: int, scale: float = 1.0) -> None:
        self.first, self.second, self.wall, self.behind, self.seed = first, second, float(wall), behind, int(seed)
        self.scale = float(scale)
        self.u, self.on = 0.0, False

    def reset(self, seed: int) -> None:
        # the draw is U(-1, 1) scaled, so the tasks with scale 1 keep their shipped demonstrations bit for bit
        self.u = self.scale * float(np.random.default_rng([self.seed, 2, int(seed)]).uniform(-1.0, 1.0))
        self.on = False

    def __call__(self, obs: Any) -> NDArray[np.float64]:
        x = float(np.asarray(obs).reshape(-1)[0])  # the current state: the post-step x of the previous step
        if not self.on and (x < self.wall + self.u if self.behind else x > self.wall - self.u):
            self.on = True
        return np.asarray((self.second if self.on else self.first)(obs), dtype=np.float64)


class _Stochastic:
    """A :class:`CheckpointPolicy` with ``deterministic=False`` whose noise is re-seeded from the episode seed."""

    def __init__(self, policy: Any, seed: int) -> None:
        self.policy, self.seed = policy, int(seed)

    def reset(self, seed: int) -> None:
        self.policy.reset(int(np.random.default_rng([self.seed, 3, int(seed)]).integers(2**31)))

    def __call__(self, obs: Any) -> NDArray[np.float64]:
        return np.asarray(self.policy(obs), dtype=np.float64)


def _quantize(ep: dict[str, Any], dt: float, names: Sequence[str]) -> dict[str, Any]:
    """Snap x (and x_0 of the reset) and actions to binary grids and recompute the features that are functions of
    them: ``speed`` :math:`|x_{t+1} - x_t|/dt`, ``action_sq_norm`` :math:`\\sum a^2`, the pendulum's
    ``bias_reward``; the others (Ant's distance, the healthy and alive flags) are kept as they are."""
    from pbicrl.envs.icrl_benchmark import pendulum_reward

    xq = np.round(np.asarray(ep["x"]) / X_QUANTUM) * X_QUANTUM
    x0 = float(np.round(float(ep["obs"][0][0]) / X_QUANTUM) * X_QUANTUM)
    aq = np.round(np.asarray(ep["actions"]) / ACTION_QUANTUM) * ACTION_QUANTUM
    feats = np.array(ep["features"], dtype=np.float64, copy=True)
    for j, name in enumerate(names):
        if name == "speed":
            feats[:, j] = np.abs(np.diff(np.concatenate([[x0], xq]))) / dt
        elif name == "action_sq_norm":
            feats[:, j] = np.sum(aq * aq, axis=1)
        elif name == "bias_reward":
            feats[:, j] = [pendulum_reward(v) for v in xq]
    return {**ep, "x": xq, "actions": aq, "features": feats}


def generate_ranked_demos(task: str, expert: str | os.PathLike[str], unconstrained: str | os.PathLike[str],
                          out: str | os.PathLike[str] | None = None, *, handover: str | os.PathLike[str] | None = None,
                          n_per_group: int = 100, seed: int = 0,
                          rules: DemoRules | None = None, noise_sd: float = 0.5,
                          sources: Sequence[str] = SOURCES, max_episodes: int = 3000, retire_after: int = 20,
                          quantize: bool = True, keep_actions: bool = False, command: str | None = None,
                          log: Callable[[str], None] | None = None) -> tuple[Any, dict[str, Any]]:
    """Generate the ranked demonstrations of ``task`` (see the module docstring) and optionally save them.

    Parameters
    ----------
    task : str
        An ICRL benchmark task (``halfcheetah``, ...).
    expert, unconstrained : path
        Checkpoints (``best.pt`` / ``checkpoint.pt``) of the ``ppo_lag_true`` and ``ppo`` runs.
    out : path, optional
        The ``.npz`` to write; the record goes beside it as ``<stem>.json``. Both are written only when every
        group is full.
    handover : path, optional
        The checkpoint the ``switch`` source starts with (default ``unconstrained``).
    n_per_group : int
        Episodes per group (100).
    seed : int
        Reset seeds are ``seed * 1_000_000 + k`` for the k-th episode; every other draw derives from ``seed``
        and the episode's reset seed.
    rules : DemoRules, optional
        Default :meth:`DemoRules.for_task`.
    noise_sd : float
        ``expert_noise``'s action noise (the actions are clipped to [-1, 1] by the environment).
    sources : sequence of str
        Which of :data:`SOURCES` to take in turn.
    max_episodes, retire_after : int
        Give up after ``max_episodes`` episodes; stop using a source whose last ``retire_after`` episodes
        were all unused.
    quantize, keep_actions : bool
        See the module docstring.
    command : str, optional
        The generating command line, recorded.

    Returns
    -------
    (Dataset, dict)
        The dataset (groups 1, 2, 3) and the record written beside it.

    Raises
    ------
    ValueError
        A bad argument (named), a checkpoint that cannot be read, or groups still short after ``max_episodes``
        episodes (the counts are in the message; nothing is written).
    """
    from pbicrl import __version__
    from pbicrl._atomic import write_json
    from pbicrl.envs.icrl_benchmark import icrl_task
    from pbicrl.experiments.icrl_benchmark import (
        CheckpointPolicy,
        demonstrations_dataset,
        rollout_episodes,
    )

    spec = icrl_task(task)
    for name, v, low in (("n_per_group", n_per_group, 1), ("seed", seed, 0), ("max_episodes", max_episodes, 1),
                         ("retire_after", retire_after, 1)):
        if int(v) != v or v < low:
            raise ValueError(f"{name}: must be an integer >= {low}, got {v!r}")
    if not (math.isfinite(float(noise_sd)) and noise_sd >= 0):
        raise ValueError(f"noise_sd: must be a finite number >= 0, got {noise_sd!r}")
    srcs = list(dict.fromkeys(sources))
    bad = [s for s in srcs if s not in SOURCES]
    if bad or not srcs:
        raise ValueError(f"sources: expected some of {list(SOURCES)}, got {list(sources)!r}")
    rules = rules or DemoRules.for_task(spec.name)
    if rules.through_min_steps > spec.max_episode_steps:
        raise ValueError(f"rules: through_min_steps {rules.through_min_steps} exceeds the episode length "
                         f"{spec.max_episode_steps} of {spec.name}")
    say = log or (lambda _s: None)
    handover = unconstrained if handover is None else handover
    lineage = {"expert": checkpoint_lineage(expert), "unconstrained": checkpoint_lineage(unconstrained),
               "handover": checkpoint_lineage(handover)}
    behind = spec.side == "behind"
    e_mean = CheckpointPolicy(expert, deterministic=True)
    u_mean = CheckpointPolicy(unconstrained, deterministic=True)
    h_mean = CheckpointPolicy(handover, deterministic=True)
    policies: dict[str, Any] = {
        "expert": e_mean,
        "expert_noise": _Noisy(e_mean, noise_sd, seed),
        "unconstrained": _Stochastic(CheckpointPolicy(unconstrained, deterministic=False), seed),
        "switch": _Switch(h_mean, e_mean, spec.wall, behind, seed, spec.handover_range),
    }
    for name, pol in (("expert", e_mean), ("unconstrained", u_mean), ("handover", h_mean)):
        if pol.obs_dim != spec.obs_dim:
            raise ValueError(f"{name}: {pol.obs_dim}-dimensional observations; {spec.name} has {spec.obs_dim}")
    import gymnasium as gym  # noqa: F401  (the environment's dt)

    from pbicrl.experiments.icrl_benchmark import make_task_env

    env = make_task_env(spec.name)
    dt = float(env.unwrapped.dt)
    env.close()

    kept: dict[int, list[dict[str, Any]]] = {1: [], 2: [], 3: []}
    episodes: list[dict[str, Any]] = []
    active = list(srcs)
    recent: dict[str, list[bool]] = {s: [] for s in srcs}
    k = 0
    while any(len(v) < n_per_group for v in kept.values()):
        if k >= max_episodes or not active:
            counts = {g: len(v) for g, v in kept.items()}
            why = f"after {k} episodes" if k >= max_episodes else f"every source retired after {k} episodes"
            raise ValueError(f"groups: not filled {why}: {counts} of {n_per_group} each (per source: "
                             f"{_per_source(episodes)}); raise max_episodes or use other policies or rules")
        src = active[k % len(active)]
        rseed = int(seed) * 1_000_000 + k
        ep = rollout_episodes(spec.name, policies[src], 1, seed=rseed)[0]
        if quantize:
            ep = _quantize(ep, dt, spec.feature_names)
        ep["costs"] = spec.cost(ep["x"])  # the label follows the stored x
        n_v = int(ep["costs"].sum())
        g = classify_episode(n_v, rules)
        useful = g != 0 and len(kept[g]) < n_per_group
        if useful:
            kept[g].append(ep)
        x = np.asarray(ep["x"])
        rewards = np.asarray(ep["rewards"])
        hit = np.flatnonzero(ep["costs"] > 0)
        episodes.append({"k": k, "source": src, "reset_seed": rseed, "violating_steps": n_v, "group": g,
                         "kept": bool(useful), "x_min": float(x.min()), "x_max": float(x.max()),
                         "reward": float(rewards.sum()),
                         "reward_nc": float(rewards[:int(hit[0]) if hit.size else rewards.size].sum())})
        recent[src] = (recent[src] + [useful])[-int(retire_after):]
        if len(recent[src]) >= retire_after and not any(recent[src]):
            active.remove(src)
            say(f"source {src} retired after episode {k} (its last {retire_after} episodes were not needed)")
        k += 1
        if k % 25 == 0:
            say(f"{k} episodes: groups {[len(kept[g]) for g in (1, 2, 3)]} of {n_per_group}")

    groups = {g: eps if keep_actions else [{k: v for k, v in e.items() if k != "actions"} for e in eps]
              for g, eps in kept.items()}
    ds = demonstrations_dataset(spec.name, groups)

    def summary(g: int) -> dict[str, Any]:
        rows = [e for e in episodes if e["kept"] and e["group"] == g]
        nv = [e["violating_steps"] for e in rows]
        xm = [e["x_min"] if behind else e["x_max"] for e in rows]
        return {"n": len(rows), "by_source": {s: sum(e["source"] == s for e in rows) for s in srcs},
                "violating_steps_min": int(min(nv)), "violating_steps_max": int(max(nv)),
                ("x_min" if behind else "x_max") + "_range": [float(min(xm)), float(max(xm))],
                "reward_mean": float(np.mean([e["reward"] for e in rows])),
                "reward_nc_mean": float(np.mean([e["reward_nc"] for e in rows]))}

    record = {
        "what": f"ranked demonstrations of the ICRL benchmark task {spec.name} (issue 28, item 2)",
        "command": command, "pbicrl_version": __version__, "task": spec.name, "env_id": spec.env_id,
        "wall": {"threshold": spec.wall, "side": spec.side,
                 "violation": f"x {'<' if behind else '>'} {spec.wall:g} after the step (strict)"},
        "seed": int(seed), "n_per_group": int(n_per_group),
        "rules": {"group1": "0 violating steps",
                  "group2": f"1 to {rules.brief_max_steps} violating steps (crosses briefly)",
                  "group3": f">= {rules.through_min_steps} violating steps (runs through)",
                  "unused": f"{rules.brief_max_steps + 1} to {rules.through_min_steps - 1} violating steps",
                  "brief_max_steps": rules.brief_max_steps, "through_min_steps": rules.through_min_steps},
        "sources": {
            "expert": "ppo_lag_true checkpoint, deterministic (mean action)",
            "expert_noise": f"ppo_lag_true mean action + N(0, {noise_sd:g}^2) noise",
            "unconstrained": "ppo checkpoint, stochastic (draws from its Gaussian)",
            "switch": "handover checkpoint's mean action until the state first comes within u ~ "
                      f"U(-{spec.handover_range:g}, {spec.handover_range:g}) of the wall, then the ppo_lag_true "
                      "mean action",
            "used": srcs},
        "policies": lineage, "quantize": bool(quantize), "keep_actions": bool(keep_actions),
        "episodes_generated": len(episodes),
        "per_source": _per_source(episodes),
        "groups": {str(g): summary(g) for g in (1, 2, 3)},
        "episodes": episodes,
    }
    if out is not None:
        path = ds.save(out)
        record["file"] = path.name
        record["file_bytes"] = path.stat().st_size
        record["file_sha256"] = _sha256(path)
        write_json(path.with_suffix(".json"), record)
        say(f"wrote {path} ({path.stat().st_size / 2**20:.2f} MiB) and {path.with_suffix('.json')}")
    return ds, record


def _per_source(episodes: list[dict[str, Any]]) -> dict[str, dict[str, int]]:
    out: dict[str, dict[str, int]] = {}
    for e in episodes:
        row = out.setdefault(e["source"], {"episodes": 0, "group1": 0, "group2": 0, "group3": 0, "unused": 0,
                                           "kept": 0})
        row["episodes"] += 1
        row["unused" if e["group"] == 0 else f"group{e['group']}"] += 1
        row["kept"] += int(e["kept"])
    return out

