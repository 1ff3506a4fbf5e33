"""Training the SAC navigation policies: cost-to-go shaping, warm starts from relabelled data, budgets."""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from pbicrl.demonstrators.nav_envs import NAV_REWARDS, make_nav_env, nav_spec

__all__ = ["cost_to_go_potential", "train_nav_policy", "relabelled_warm_start", "sac_budget"]


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

    spec = nav_spec(env)
    if reward not in NAV_REWARDS:
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
    spec = nav_spec(env)
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
        Run directory with ``final_model.zip`` and ``checkpoint/replay_buffer.npz``.
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

    from pbicrl.demonstrators import sac_files

    spec = nav_spec(env)
    src, out = Path(source_run), Path(out_dir)
    if (out / "checkpoint").exists():
        raise ValueError(f"out_dir: {out} already holds a checkpoint")
    scale = spec.shaping_scale if shaping_scale is None else float(shaping_scale)
    env_fn = _training_env_fn(env, reward, scale)
    value = env_fn.value  # type: ignore[attr-defined]
    source = sac_files.read_model(src / "final_model.zip", env_fn(), what="source_run")
    old = sac_files.read_buffer_arrays(src / "checkpoint" / "replay_buffer.npz", what="source_run")
    n = old["observations"].shape[0]
    if n > spec.buffer_size:
        raise ValueError(f"source_run: {n} stored transitions exceed the new buffer ({spec.buffer_size})")
    model = SAC("MlpPolicy", env_fn(), learning_rate=source.learning_rate, buffer_size=spec.buffer_size,
                learning_starts=0, batch_size=source.batch_size, tau=source.tau if tau is None else float(tau),
                gamma=source.gamma,
                ent_coef=ent_coef, replay_buffer_kwargs={"handle_timeout_termination": False},
                policy_kwargs=source.policy_kwargs, seed=seed, device="cpu", verbose=0)
    model.policy.load_state_dict(source.policy.state_dict())
    task = make_nav_env(env, reward).task
    w = task.weights(reward)
    obs = old["observations"][:n, 0].astype(np.float64)
    nxt = old["next_observations"][:n, 0].astype(np.float64)
    done = old["dones"][:n, 0].astype(bool)
    # goal reached = terminal; decided from the state, since a source run that treated time
    # limits as terminal did not record which "done" flags were truncations
    reached = task.reached(nxt)
    rewards = task.features(nxt) @ w
    if value is not None:
        phi = np.array([-scale * value(x) for x in obs])
        phi_next = np.where(reached, 0.0, [-scale * value(x) for x in nxt])
        rewards = rewards + phi_next - phi
    buf = model.replay_buffer
    buf.observations[:n, 0] = old["observations"][:n, 0]
    buf.next_observations[:n, 0] = old["next_observations"][:n, 0]
    buf.actions[:n, 0] = old["actions"][:n, 0]
    buf.rewards[:n, 0] = rewards
    buf.dones[:n, 0] = done  # time limits count as terminal in the new run
    buf.pos, buf.full = n % buf.buffer_size, n >= buf.buffer_size
    ckpt = out / "checkpoint"
    ckpt.mkdir(parents=True)
    sac_files.save_model(model, ckpt / "model.zip")
    sac_files.save_replay_buffer(model, ckpt / "replay_buffer.npz")
    (ckpt / "state.json").write_text(json.dumps({"num_timesteps": 0, "wall_time_s": 0.0, "sessions": []}))
    info = {"source_run": str(src), "transitions": int(n), "reward": reward, "ent_coef": ent_coef,
            "tau": float(model.tau),
            "learning_starts": 0, "mean_relabelled_reward": float(rewards.mean())}
    (out / "warm_start.json").write_text(json.dumps(info, indent=2) + "\n")
    return ckpt


def sac_budget(path: str | os.PathLike) -> dict[str, Any] | None:
    """``done_steps``, ``wall_time_s``, ``mean_steps_per_s`` of a policy's ``budget.json``, if found."""
    budget = Path(path).with_name("budget.json")
    if not budget.is_file():  # shipped policies keep it as <name>.budget.json
        budget = Path(path).with_suffix(".budget.json")
    if not budget.is_file():
        return None
    b = json.loads(budget.read_text())
    return {k: b.get(k) for k in ("done_steps", "wall_time_s", "mean_steps_per_s")}
