"""SAC demonstrators and ranked demonstrations for the point mass and Fetch-Reach.

Two policies per environment (paper Sec. V-A/V-B): a *good* one trained on the true
reward (penalties included) and a *violating* one trained on the nominal reward (no
penalties, so it cuts through the constraint regions).  Two ways to turn them into a
three-group ranked dataset; both label every trajectory from its states
(:meth:`pbicrl.envs.regions.NavigationTask.group`: G3 if it entered red, else G2 if it
entered orange, else G1):

* :func:`generate_paper_protocol_demos` (the paper's design, used for the shipped data):
  every rollout starts from the environment's one start distribution and is made by the
  good policy with probability ``p_good``, else by the violating one; the group is the
  worst region the trajectory entered, whichever policy made it.  All rollouts are kept
  except those that do not reach the goal (counted in the report); it stops once every
  group holds at least ``n_per_group``.  :func:`group_feature_balance` measures how far
  the groups differ in their nominal features (standardised mean differences).
* :func:`generate_navigation_demos` (earlier design): ``G1`` = good policy, ``G2``/``G3`` =
  violating policy, each filled to exactly ``n_per_group``.  Its groups differ in nominal
  behaviour (the policies move differently), which a ranking model can exploit.

Training settings per environment are in :data:`NAV_ENVS` (see :class:`NavEnvSpec` for why
they depart from the paper's SAC table).

Each stored trajectory holds the visited states ``s_0 .. s_T`` (start included) and their
features; actions are not stored in the ``.npz`` (there are only ``T`` of them), but the
Minari export (:mod:`pbicrl.envs.minari_io`) keeps them.
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from pbicrl._atomic import atomic_path, write_text
from pbicrl.inference.data import Dataset

__all__ = [
    "NAV_ENVS",
    "Episode",
    "NavEnvSpec",
    "PAPER_PROTOCOL",
    "generate_navigation_demos",
    "generate_paper_protocol_demos",
    "group_feature_balance",
    "make_nav_env",
    "plot_navigation_demos",
    "relabelled_warm_start",
    "rollout_episodes",
    "train_nav_policy",
]


@dataclass(frozen=True)
class NavEnvSpec:
    """Training/rollout settings of one navigation environment.

    Attributes
    ----------
    name : str
        Key in :data:`NAV_ENVS`.
    paper_steps : int
        SAC steps the paper used.
    default_steps : int
        SAC steps used for the shipped policies (see the budget notes in the data README).
    learning_starts : int
        Random-action warm-up steps (the paper: 40 episodes).
    shaping_scale : float
        Scale ``c`` of the potential ``Phi(s) = -c * ||s - goal||`` added during training
        (see :class:`PotentialShaping`); 0 disables it.
    obs_low, obs_high : tuple of float
        Range mapped to [-1, 1] by the policy's input layer
        (:class:`pbicrl.demonstrators._extractors.AffineObservation`).
    buffer_size : int
        Replay buffer size.
    rbf_per_dim : int
        Grid resolution of the policy's radial-basis input layer.
    grid_low, grid_high, grid_resolution
        Grid of the shaping cost-to-go (:func:`cost_to_go_potential`).
    ent_coef : float or "auto"
        SAC entropy coefficient.  Fixed for these tasks: with ``"auto"`` the true-reward run
        saturated its actions near the regions, the learned coefficient rose ~10x (0.43 vs
        0.04 for the nominal run) and the policy stalled.
    gamma : float
        Discount factor.
    timeout_is_terminal : bool
        Treat the time limit as terminal in the critic's targets (no bootstrapping past it).
        Biased but bounded: in true-reward point-mass trials the bootstrapped critic drifted
        to values ~+350 (achievable returns are below ~+20) once the policy stopped
        reaching the goal, and nothing anchored it.
    """

    name: str
    paper_steps: int
    default_steps: int
    learning_starts: int
    shaping_scale: float = 0.0
    obs_low: tuple[float, ...] = ()
    obs_high: tuple[float, ...] = ()
    buffer_size: int = 100_000
    rbf_per_dim: int = 10
    grid_low: tuple[float, ...] = ()
    grid_high: tuple[float, ...] = ()
    grid_resolution: float = 0.25
    ent_coef: float | str = "auto"
    gamma: float = 0.99
    timeout_is_terminal: bool = False


NAV_ENVS: dict[str, NavEnvSpec] = {
    "point_mass": NavEnvSpec("point_mass", paper_steps=200_000, default_steps=40_000, learning_starts=40 * 60,
                             shaping_scale=1.0, obs_low=(-1.0, -1.0), obs_high=(20.0, 20.0),
                             grid_low=(-1.0, -1.0), grid_high=(20.0, 20.0), grid_resolution=0.25, ent_coef=0.05,
                             timeout_is_terminal=True),
    "fetch_reach": NavEnvSpec("fetch_reach", paper_steps=250_000, default_steps=30_000, learning_starts=40 * 50,
                              shaping_scale=20.0, obs_low=(0.6, 0.4, 0.4), obs_high=(1.5, 1.4, 1.0), rbf_per_dim=8,
                              grid_low=(0.5, 0.3, 0.35), grid_high=(1.6, 1.5, 1.1), grid_resolution=0.02,
                              ent_coef=0.2, timeout_is_terminal=True),
}
_REWARDS = ("true", "nominal")


def _spec(name: str) -> NavEnvSpec:
    if name not in NAV_ENVS:
        raise ValueError(f"env: expected one of {sorted(NAV_ENVS)}, got {name!r}")
    return NAV_ENVS[name]


def make_nav_env(name: str, reward_weights: Any = "true", **kwargs: Any) -> Any:
    """Build ``PointMassEnv`` or ``FetchReachConstrainedEnv`` by name."""
    _spec(name)
    if name == "point_mass":
        from pbicrl.envs.point_mass import PointMassEnv

        return PointMassEnv(reward_weights=reward_weights, **kwargs)
    from pbicrl.envs.fetch_reach import FetchReachConstrainedEnv

    return FetchReachConstrainedEnv(reward_weights=reward_weights, **kwargs)


def cost_to_go_potential(task: Any, weights: Any, low: Any, high: Any, resolution: float,
                         region_cost: float = 3.0) -> Callable[[Any], float]:
    """Cost-to-go ``V(s)`` from ``s`` to the goal on a grid, penalty regions made expensive.

    Moving a unit length costs ``1`` outside the regions and ``region_cost`` inside a region
    whose weight is non-zero, so ``V`` is the length of the shortest route that skirts the
    penalised regions (with a nominal reward: the distance to the goal).  ``region_cost`` is
    kept small (3): with the penalty ratio ``1 + |w_region| / |w_living|`` (101 for red) the
    shaping paid up to +54 for a step out of red, the critic spread that bonus to the
    region's surroundings and the policy parked next to it.  Computed with
    Dijkstra on an 8- (2-D) or 26-neighbour (3-D) grid over ``[low, high]`` from all goal
    cells; queries are clamped to the grid and add the Euclidean distance to it.  A
    distance field has no local minima besides the goal, unlike ``||s - goal||`` behind a
    region (where a greedy learner stalls).
    """
    from itertools import product

    from scipy.interpolate import RegularGridInterpolator
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import dijkstra

    w = np.asarray(weights, dtype=np.float64)
    lo, hi = np.asarray(low, dtype=np.float64), np.asarray(high, dtype=np.float64)
    axes = [np.arange(a, b + resolution / 2, resolution) for a, b in zip(lo, hi)]
    shape = tuple(len(a) for a in axes)
    pts = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, lo.size)
    in_region = (w[1] != 0) & task.orange.contains(pts) | (w[2] != 0) & task.red.contains(pts)
    cost = np.where(in_region, float(region_cost), 1.0)
    idx = np.arange(pts.shape[0]).reshape(shape)
    rows, cols, vals = [], [], []
    for off in product((-1, 0, 1), repeat=lo.size):
        if not any(off) or next(o for o in off if o) < 0:
            continue  # each undirected edge once
        src = idx[tuple(slice(max(0, -o), n - max(0, o)) for o, n in zip(off, shape))].ravel()
        dst = idx[tuple(slice(max(0, o), n - max(0, -o)) for o, n in zip(off, shape))].ravel()
        rows.append(src)
        cols.append(dst)
        vals.append(resolution * np.linalg.norm(off) * (cost[src] + cost[dst]) / 2)
    graph = coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                       shape=(pts.shape[0],) * 2).tocsr()
    goal_nodes = np.flatnonzero(task.goal.contains(pts))
    dist = dijkstra(graph, directed=False, indices=goal_nodes, min_only=True)
    interp = RegularGridInterpolator(axes, dist.reshape(shape))

    def value(state: Any) -> float:
        x = np.asarray(state, dtype=np.float64).reshape(-1)
        inside = np.clip(x, lo, hi)
        return float(interp(inside[None, :])[0] + np.linalg.norm(x - inside))

    return value


def _shaping_wrapper():
    import gymnasium as gym

    class PotentialShaping(gym.Wrapper):
        """Adds the progress term ``Phi(s') - Phi(s)``, ``Phi(s) = -scale * V(s)`` (``Phi = 0`` on reaching the goal).

        ``V`` is :func:`cost_to_go_potential` for the reward being trained (with the nominal
        reward it is the plain distance to the goal).  Over an episode the term telescopes to
        ``Phi(s_T) - Phi(s_0)``, so every complete start-to-goal path gains the same amount
        and the penalties of the reward decide between routes; it gives SAC a direction long
        before a random walk finds the goal (a 60-step random walk of the point mass moves
        ~4.5 units; the goal is ~20 away).  The discounted form ``gamma Phi(s') - Phi(s)``
        would be exactly policy-invariant (Ng et al., 1999) but pays ``(1 - gamma) |Phi|``
        per step for staying far from the goal, and true-reward SAC learned to stall with
        it.  Only used for training; the demonstrations use the plain reward.
        """

        def __init__(self, env: Any, scale: float, value: Callable[[Any], float]) -> None:
            super().__init__(env)
            self.scale, self.value = float(scale), value
            self._phi = 0.0

        def _potential(self) -> float:
            return -self.scale * self.value(self.env.unwrapped.position)

        def reset(self, **kwargs: Any):
            out = self.env.reset(**kwargs)
            self._phi = self._potential()
            return out

        def step(self, action: Any):
            obs, r, term, trunc, info = self.env.step(action)
            phi = 0.0 if term else self._potential()
            shaped = r + phi - self._phi
            self._phi = phi
            return obs, shaped, term, trunc, info

    return PotentialShaping


def train_nav_policy(env: str, reward: str, out_dir: str | os.PathLike, total_steps: int | None = None,
                     *, seed: int = 0, shaping_scale: float | None = None, **sac_kwargs: Any) -> Path:
    """Train (or resume) a SAC demonstrator with :func:`pbicrl.demonstrators.sac.train_sac`.

    Parameters
    ----------
    env : {"point_mass", "fetch_reach"}
    reward : {"true", "nominal"}
        ``"true"`` gives the good demonstrator, ``"nominal"`` the violating one.
    out_dir : path
        Run directory (checkpoints, ``progress.log``, ``budget.json``, ``policy.zip``).
    total_steps : int, optional
        Defaults to the environment's ``default_steps``.
    seed : int
    shaping_scale : float, optional
        Scale of the progress shaping used in training (:func:`_shaping_wrapper`; default:
        the environment's ``shaping_scale``; 0 trains on the bare reward).
    **sac_kwargs
        Passed on to ``train_sac`` (paper defaults otherwise; ``learning_starts`` defaults to
        40 episodes of random actions as in the paper).

    Returns
    -------
    pathlib.Path
        Path of ``policy.zip``.
    """
    from pbicrl.demonstrators.sac import train_sac

    spec = _spec(env)
    if reward not in _REWARDS:
        raise ValueError(f"reward: expected 'true' or 'nominal', got {reward!r}")
    steps = spec.default_steps if total_steps is None else int(total_steps)
    sac_kwargs.setdefault("learning_starts", spec.learning_starts)
    sac_kwargs.setdefault("buffer_size", spec.buffer_size)
    sac_kwargs.setdefault("ent_coef", spec.ent_coef)
    sac_kwargs.setdefault("gamma", spec.gamma)
    if spec.timeout_is_terminal:
        sac_kwargs.setdefault("replay_buffer_kwargs", {"handle_timeout_termination": False})
    if spec.obs_low and "policy_kwargs" not in sac_kwargs:
        from pbicrl.demonstrators._extractors import RBFObservation

        sac_kwargs["policy_kwargs"] = {"features_extractor_class": RBFObservation,
                                       "features_extractor_kwargs": {"low": spec.obs_low, "high": spec.obs_high,
                                                                     "n_per_dim": spec.rbf_per_dim}}
    scale = spec.shaping_scale if shaping_scale is None else float(shaping_scale)
    if scale < 0:
        raise ValueError(f"shaping_scale: must be >= 0, got {scale}")
    meta = {"env": env, "reward_weights": reward, "paper_steps": spec.paper_steps,
            "role": "good (true reward)" if reward == "true" else "violating (nominal reward)",
            "potential_shaping": {"phi": "-scale * cost-to-go to the goal (penalised regions cost 3 per unit "
                                         "length; grid Dijkstra); reward += Phi(s') - Phi(s)", "scale": scale,
                                  "grid": [list(spec.grid_low), list(spec.grid_high), spec.grid_resolution]}}

    warm = Path(out_dir) / "warm_start.json"
    if warm.is_file():
        meta["warm_start"] = json.loads(warm.read_text())
    return train_sac(_training_env_fn(env, reward, scale), steps, out_dir, seed=seed, metadata=meta, **sac_kwargs)


def _training_env_fn(env: str, reward: str, scale: float) -> Callable[[], Any]:
    """Factory of the (shaped) training environment."""
    spec = _spec(env)
    value = None
    if scale > 0:
        probe = make_nav_env(env, reward)
        value = cost_to_go_potential(probe.task, probe.w, spec.grid_low, spec.grid_high, spec.grid_resolution)
        probe.close()

    def env_fn() -> Any:
        e = make_nav_env(env, reward)
        return _shaping_wrapper()(e, scale, value) if scale > 0 else e

    env_fn.value = value  # type: ignore[attr-defined]
    return env_fn


def relabelled_warm_start(source_run: str | os.PathLike, env: str, reward: str, out_dir: str | os.PathLike, *,
                          ent_coef: float = 0.05, tau: float | None = None, seed: int = 0,
                          shaping_scale: float | None = None) -> Path:
    """Start a run from another run's networks and replay buffer, relabelled with ``reward``.

    Writes ``out_dir/checkpoint`` (model with the source's policy weights, ``learning_starts=0``,
    fixed ``ent_coef``; replay buffer with every stored transition's reward recomputed as
    ``w . phi(s') + Phi(s') - Phi(s)`` for the new reward) and ``out_dir/warm_start.json``;
    :func:`train_nav_policy` on ``out_dir`` then resumes from it.  Used for the true-reward
    point-mass demonstrator, where SAC from scratch stalled: the nominal policy's last 10k
    transitions, rescored with the penalties, show the critic what crossing a region costs
    while the policy still reaches the goal.

    Parameters
    ----------
    source_run : path
        Run directory with ``final_model.zip`` and ``checkpoint/replay_buffer.pkl``.
    env, reward : str
        Environment and reward of the new run.
    out_dir : path
        New run directory (must not hold a checkpoint yet).
    ent_coef : float
        Fixed entropy coefficient of the new run.
    tau : float, optional
        Target-network update rate (default: the source's).
    """
    from pbicrl.demonstrators.sac import require_rl

    require_rl()
    from stable_baselines3 import SAC
    from stable_baselines3.common.save_util import load_from_pkl

    spec = _spec(env)
    src, out = Path(source_run), Path(out_dir)
    if (out / "checkpoint").exists():
        raise ValueError(f"out_dir: {out} already holds a checkpoint")
    scale = spec.shaping_scale if shaping_scale is None else float(shaping_scale)
    env_fn = _training_env_fn(env, reward, scale)
    value = env_fn.value  # type: ignore[attr-defined]
    source = SAC.load(src / "final_model.zip", device="cpu")
    old = load_from_pkl(src / "checkpoint" / "replay_buffer.pkl")
    n = old.buffer_size if old.full else old.pos
    model = SAC("MlpPolicy", env_fn(), learning_rate=source.learning_rate, buffer_size=spec.buffer_size,
                learning_starts=0, batch_size=source.batch_size, tau=source.tau if tau is None else float(tau),
                gamma=source.gamma,
                ent_coef=ent_coef, replay_buffer_kwargs={"handle_timeout_termination": False},
                policy_kwargs=source.policy_kwargs, seed=seed, device="cpu", verbose=0)
    model.policy.load_state_dict(source.policy.state_dict())
    task = make_nav_env(env, reward).task
    w = task.weights(reward)
    obs = old.observations[:n, 0].astype(np.float64)
    nxt = old.next_observations[:n, 0].astype(np.float64)
    done = old.dones[:n, 0].astype(bool)
    # goal reached = terminal; decided from the state, since a source run that treated time
    # limits as terminal did not record which "done" flags were truncations
    reached = task.reached(nxt)
    rewards = task.features(nxt) @ w
    if value is not None:
        phi = np.array([-scale * value(x) for x in obs])
        phi_next = np.where(reached, 0.0, [-scale * value(x) for x in nxt])
        rewards = rewards + phi_next - phi
    buf = model.replay_buffer
    buf.observations[:n, 0] = old.observations[:n, 0]
    buf.next_observations[:n, 0] = old.next_observations[:n, 0]
    buf.actions[:n, 0] = old.actions[:n, 0]
    buf.rewards[:n, 0] = rewards
    buf.dones[:n, 0] = done  # time limits count as terminal in the new run
    buf.pos, buf.full = n % buf.buffer_size, n >= buf.buffer_size
    ckpt = out / "checkpoint"
    ckpt.mkdir(parents=True)
    model.save(ckpt / "model.zip")
    model.save_replay_buffer(ckpt / "replay_buffer.pkl")
    (ckpt / "state.json").write_text(json.dumps({"num_timesteps": 0, "wall_time_s": 0.0, "sessions": []}))
    info = {"source_run": str(src), "transitions": int(n), "reward": reward, "ent_coef": ent_coef,
            "tau": float(model.tau),
            "learning_starts": 0, "mean_relabelled_reward": float(rewards.mean())}
    (out / "warm_start.json").write_text(json.dumps(info, indent=2) + "\n")
    return ckpt


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


def _policy_actor(path: str | os.PathLike, deterministic: bool) -> Callable[[NDArray], NDArray]:
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
    spec = _spec(env)
    t0 = time.time()
    environment = make_nav_env(env, "true")
    task = environment.task
    kept: dict[int, list[Episode]] = {1: [], 2: [], 3: []}
    stats: dict[str, dict[str, Any]] = {}
    plan = [("good", good_policy, (1,), 0), ("violating", violating_policy, (2, 3), 10_000_000)]
    if good_policy is None:
        plan = [("violating", violating_policy, (1, 2, 3), 10_000_000)]
    for name, path, wanted, offset in plan:
        act = _policy_actor(path, deterministic)
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
        raise RuntimeError(f"demos: groups {missing} are empty after {max_episodes} rollouts per policy; "
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
        budget = _sac_budget(path)
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


#: Settings of the shipped paper-protocol datasets (``pbicrl envs demos --paper-protocol`` defaults).
#: ``p_good`` is the probability that a rollout is made by the good (true-reward) policy (see
#: docs/envs.md for why it is small with the shipped policies); ``env_kwargs`` select the start
#: distribution (point mass: its left/bottom edges; Fetch-Reach: the ``"equidistant"`` start box).
PAPER_PROTOCOL: dict[str, dict[str, Any]] = {
    "point_mass": {"p_good": 0.01, "deterministic": False, "n_per_group": 300, "seed": 0,
                   "env_kwargs": {"start": "random"}},
    "fetch_reach": {"p_good": 0.01, "deterministic": False, "n_per_group": 300, "seed": 0,
                    "env_kwargs": {"start": "equidistant"}},
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
    start = getattr(environment, "start", "random")
    edges = {"left": "left edge x in [0, 1], y in [9, 19]", "bottom": "bottom edge x in [9, 19], y in [0, 1]"}
    if start == "random":
        return f"uniform on the {edges['left']} or the {edges['bottom']}, probability 1/2 each"
    return f"uniform on the {edges[start]}"


def _sac_budget(path: str | os.PathLike) -> dict[str, Any] | None:
    """``done_steps``, ``wall_time_s``, ``mean_steps_per_s`` of a policy's ``budget.json``, if found."""
    budget = Path(path).with_name("budget.json")
    if not budget.is_file():  # shipped policies keep it as <name>.budget.json
        budget = Path(path).with_suffix(".budget.json")
    if not budget.is_file():
        return None
    b = json.loads(budget.read_text())
    return {k: b.get(k) for k in ("done_steps", "wall_time_s", "mean_steps_per_s")}


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

    spec = _spec(env)
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
    actors = {name: _policy_actor(path, deterministic) for name, path in paths.items()}
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
        raise RuntimeError(f"demos: groups {short} hold fewer than {n_per_group} trajectories after {n_run} rollouts; "
                           "the policies do not produce the intended behaviour")
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
        budget = _sac_budget(paths[name])
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




_GROUP_COLOURS = {1: "tab:green", 2: "tab:orange", 3: "tab:red"}


def plot_navigation_demos(dataset: Dataset | str | os.PathLike, env: str, out: str | os.PathLike,
                          *, max_per_group: int | None = 60, seed: int = 0, title: str | None = None,
                          policies: str | None = None) -> Path:
    """PNG of the demonstrations coloured by group (paper Fig. 3a / 4a style).

    The point mass is drawn in the plane; Fetch-Reach as a top view (x-y) and a side
    view (x-z) with the boxes and the goal ball.  ``max_per_group`` trajectories are drawn
    per group (random, seeded; ``None`` for all).  ``policies`` (one letter per trajectory,
    ``g`` good / ``v`` violating; default: ``trajectory_policy`` of the JSON report next to a
    dataset file, if any) draws the good policy's trajectories dashed.
    """
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        from matplotlib.patches import Circle, Rectangle
    except ImportError as exc:
        raise ImportError('plotting needs matplotlib: pip install "pbicrl[plot]"') from exc
    ds = dataset if isinstance(dataset, Dataset) else Dataset.load(dataset)
    if ds.states is None:
        raise ValueError("dataset: has no states to plot")
    _spec(env)
    if policies is None and not isinstance(dataset, Dataset):
        report = Path(dataset).with_suffix(".json")
        if report.is_file():
            policies = json.loads(report.read_text()).get("trajectory_policy")
    letters = np.array(list(policies)) if policies else None
    if letters is not None and letters.size != ds.n_trajectories:
        raise ValueError(f"policies: {letters.size} letters for {ds.n_trajectories} trajectories")
    if max_per_group is not None:
        rng = np.random.default_rng(seed)
        picks = []
        for k in ds.group_labels:
            members = np.flatnonzero(ds.group == k)
            picks.append(members if members.size <= max_per_group
                         else np.sort(rng.choice(members, size=max_per_group, replace=False)))
        keep = np.concatenate(picks)
        ds = ds.subset(keep)
        letters = None if letters is None else letters[keep]
    if env == "point_mass":
        from pbicrl.envs.point_mass import HIGH, LOW
        from pbicrl.envs.point_mass import POINT_MASS_TASK as task

        fig, ax = plt.subplots(figsize=(5, 5))
        axes = [(ax, 0, 1)]
        ax.set_xlim(LOW, HIGH)
        ax.set_ylim(LOW, HIGH)
        for reg, col in ((task.goal, "tab:blue"), (task.orange, "orange"), (task.red, "red")):
            ax.add_patch(Circle(reg.centre, reg.radius, color=col, alpha=0.3))
    else:
        from pbicrl.envs.fetch_reach import FETCH_REACH_TASK as task

        fig, (a1, a2) = plt.subplots(1, 2, figsize=(10, 4.5))
        axes = [(a1, 0, 1), (a2, 0, 2)]
        for ax, i, j in axes:
            for box, col in ((task.orange, "orange"), (task.red, "red")):
                ax.add_patch(Rectangle((box.low[i], box.low[j]), box.high[i] - box.low[i],
                                       box.high[j] - box.low[j], color=col, alpha=0.3))
            ax.add_patch(Circle((task.goal.centre[i], task.goal.centre[j]), task.goal.radius, color="tab:blue", alpha=0.4))
        a1.set_title("top view")
        a2.set_title("side view")
        a2.set_ylim(0.4, 1.0)
    names = "xyz"
    for k in ds.group_labels:
        idx = np.flatnonzero(ds.group == k)
        n_good = 0 if letters is None else int((letters[idx] == "g").sum())
        label = f"G{k} ({idx.size} shown" + (f", {n_good} good policy, dashed)" if n_good else ")")
        for n, i in enumerate(idx):
            s = ds.trajectory_states(int(i))
            good = letters is not None and letters[i] == "g"
            for ax, a, b in axes:
                ax.plot(s[:, a], s[:, b], color=_GROUP_COLOURS.get(int(k), "grey"), lw=1.2 if good else 0.8,
                        alpha=0.9 if good else 0.6, ls="--" if good else "-",
                        label=label if n == 0 and ax is axes[0][0] else None)
                ax.plot(s[0, a], s[0, b], ".", color="black", ms=2)
    for ax, a, b in axes:
        ax.set_xlabel(names[a])
        ax.set_ylabel(names[b])
        ax.set_aspect("equal", adjustable="box")
    # the point mass's middle is free of trajectories; Fetch's top view is free at low x
    axes[0][0].legend(loc="center" if env == "point_mass" else "lower left", fontsize=8)
    fig.suptitle(title or f"{env} demonstrations by group")
    fig.tight_layout()
    out = Path(out)
    with atomic_path(out) as tmp:
        fig.savefig(tmp, dpi=120)
    plt.close(fig)
    return out
