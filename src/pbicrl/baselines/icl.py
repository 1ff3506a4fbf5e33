"""Inverse Constraint Learning (ICL; Gaurav, Rezaee, Liu, Poupart 2022, arXiv 2206.01311), our implementation.

ICL learns a soft constraint :math:`c(s) \\in [0, 1]` from *expert* demonstrations only, given the nominal
reward, by alternating for ``rounds`` outer rounds:

(a) **constrained RL** under the current constraint: PPO-Lagrangian
    (:class:`pbicrl.baselines.ppo_lagrangian.PPOLagrangian`) maximises the nominal return subject to
    :math:`J_c(\\pi) = \\mathbb{E}[\\sum_t \\gamma^t c(s_{t+1})] \\le \\beta`; its multiplier is updated from the
    expected discounted *cost* (the authors' public code uses the episode reward there; we follow the
    Lagrangian method);
(b) **constraint adjustment**: with trajectories sampled from every policy so far
    :math:`\\pi_1..\\pi_i`, minimise

    .. math:: L(c) = -\\sum_j w_j \\hat J_c(\\pi_j) + \\lambda_h \\max(0, \\hat J_c(\\pi_E) - \\beta)

    so that the learned policies' trajectories become costly while the expert stays within budget. The
    mixture weights :math:`w_j` favour the policies least like the expert: :math:`w_j \\propto` the total
    variation distance between the discounted visitation histogram ("accrual") of :math:`\\pi_j` and the
    expert's over the constrained coordinate (:func:`mixture_weights`).

The constraint function is a small MLP with a sigmoid output over the constrained coordinate only (the
x-position for HalfCheetah/Ant, the position for the point mass), its input standardised with the expert
data's mean and spread. For a 1-D coordinate, the learned constraint location :math:`\\hat\\vartheta` is read off
where :math:`c` first reaches 0.5 (:func:`constraint_location`) and scored with
:func:`pbicrl.analysis.metrics.cmse_location`; :func:`pbicrl.analysis.metrics.cmse_grid` compares :math:`c` with the true
indicator over a grid.

Budgets: :func:`icl_preset` (``"smoke"``: well under a minute on the point mass; ``"default"``: one
HalfCheetah seed in roughly 45 minutes on a 2-core CPU; ``"paper"``: larger, for bigger machines). Runs are
resumable: :func:`run_icl` checkpoints into its directory (every ``checkpoint_every`` environment steps and
after every round) and continues from there when called again; SIGTERM/SIGINT checkpoint and stop.
Checkpoints hold tensors and plain Python values only and are read with ``torch.load(weights_only=True)``: a
``checkpoint.pt`` put into a run directory by someone else cannot run code when the run resumes.

Needs torch and gymnasium (``pip install "pbicrl[rl,envs]"``).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import platform
import signal
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

try:
    import torch
    from torch import nn
except ImportError as exc:  # pragma: no cover - exercised only without the extra
    raise ImportError('pbicrl.baselines.icl needs PyTorch: pip install "pbicrl[rl]"') from exc

from pbicrl._atomic import atomic_path, write_json
from pbicrl.baselines.ppo_lagrangian import PPOLagConfig, PPOLagrangian

__all__ = [
    "ENVS",
    "PRESETS",
    "ConstraintNet",
    "ICLConfig",
    "ICLEnv",
    "accrual",
    "constraint_location",
    "constraint_loss",
    "discount_matrix",
    "expert_coordinates",
    "icl_env",
    "icl_preset",
    "mixture_weights",
    "point_mass_expert_demos",
    "run_icl",
    "run_icl_task",
    "save_checkpoint",
    "write_json_file",
]

PRESETS = ("smoke", "default", "paper")
ENVS = ("halfcheetah", "ant", "point_mass")
_CKPT = "checkpoint.pt"


# --------------------------------------------------------------------------------------------- configuration
@dataclass
class ICLConfig:
    """Settings of one ICL run.

    Attributes
    ----------
    rounds : int
        Outer rounds (constrained RL, then constraint adjustment).
    first_round_steps, round_steps : int
        Environment steps of PPO-Lagrangian in round 1 and in each later round (the policy is warm-started
        from the previous round's unless ``reinit_policy``).
    beta : float
        Budget on the expected discounted cost, used by both the RL and the constraint adjustment.
    gamma : float
        Discount of :math:`J_c` (also PPO's cost discount).
    hinge_weight : float
        :math:`\\lambda_h`, weight of the expert-budget hinge in the constraint loss.
    constraint_hidden : tuple of int
        Hidden layers (ReLU) of the constraint MLP.
    constraint_lr, constraint_steps : float, int
        Adam learning rate and full-batch steps of each constraint adjustment.
    init_bias : float
        Initial output bias (pre-sigmoid) of the constraint net; -5 gives c ~ 0.007 everywhere, so round 1
        is nearly unconstrained RL (a random sigmoid net would put c ~ 0.5 everywhere, an infeasible budget).
    policy_episodes : int
        Episodes sampled from each round's policy for the constraint adjustment.
    weighting : {"dissimilarity", "uniform", "last"}
        Mixture weights of the policies (:func:`mixture_weights`).
    accrual_bins : int
        Bins per coordinate dimension of the accrual histograms.
    reinit_policy : bool
        Start every round's RL from a fresh policy instead of the previous one.
    eval_episodes : int
        Episodes of the final policy rolled out for the report.
    checkpoint_every : int
        Environment steps between checkpoints inside a round.
    ppo : PPOLagConfig
        PPO-Lagrangian settings (its ``cost_budget`` and ``cost_gamma`` are set from ``beta`` and ``gamma``).
    """

    rounds: int = 8
    first_round_steps: int = 1_000_000
    round_steps: int = 500_000
    beta: float = 1.0
    gamma: float = 0.99
    hinge_weight: float = 10.0
    constraint_hidden: tuple[int, ...] = (64, 64)
    constraint_lr: float = 3e-3
    constraint_steps: int = 300
    init_bias: float = -5.0
    policy_episodes: int = 10
    weighting: str = "dissimilarity"
    accrual_bins: int = 40
    reinit_policy: bool = False
    eval_episodes: int = 10
    checkpoint_every: int = 100_000
    ppo: PPOLagConfig = field(default_factory=PPOLagConfig)

    def validate(self) -> ICLConfig:
        """Check every option (raises ValueError naming it) and tie PPO's budget/discount to ours."""
        for name in ("rounds", "first_round_steps", "round_steps", "constraint_steps", "policy_episodes",
                     "accrual_bins", "eval_episodes", "checkpoint_every"):
            v = getattr(self, name)
            if int(v) != v or int(v) < 1:
                raise ValueError(f"icl.{name}: must be an integer >= 1, got {v!r}")
        if not (math.isfinite(self.beta) and self.beta >= 0):
            raise ValueError(f"icl.beta: must be a finite number >= 0, got {self.beta!r}")
        if not 0.0 < self.gamma <= 1.0:
            raise ValueError(f"icl.gamma: must be in (0, 1], got {self.gamma!r}")
        for name in ("hinge_weight", "constraint_lr"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"icl.{name}: must be a finite number > 0, got {v!r}")
        if not math.isfinite(self.init_bias):
            raise ValueError(f"icl.init_bias: must be finite, got {self.init_bias!r}")
        if self.weighting not in ("dissimilarity", "uniform", "last"):
            raise ValueError(f"icl.weighting: expected 'dissimilarity', 'uniform' or 'last', got {self.weighting!r}")
        hidden = tuple(int(h) for h in self.constraint_hidden)
        if not hidden or min(hidden) < 1:
            raise ValueError(f"icl.constraint_hidden: must be a non-empty list of positive sizes, got {self.constraint_hidden!r}")
        self.constraint_hidden = hidden
        if isinstance(self.ppo, dict):
            self.ppo = PPOLagConfig(**self.ppo)
        self.ppo = replace(self.ppo, cost_budget=float(self.beta), cost_gamma=float(self.gamma)).validate()
        return self

    @property
    def total_steps(self) -> int:
        """Environment steps of constrained RL over all rounds."""
        return int(self.first_round_steps + (self.rounds - 1) * self.round_steps)

    def round_target(self, r: int) -> int:
        """Cumulative PPO steps at the end of round ``r`` (0-based)."""
        return int(self.first_round_steps + r * self.round_steps)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict (``ICLConfig.from_dict`` inverts it)."""
        d = asdict(self)
        d["constraint_hidden"] = list(self.constraint_hidden)
        d["ppo"] = self.ppo.to_dict() if isinstance(self.ppo, PPOLagConfig) else dict(self.ppo)
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> ICLConfig:
        """Build from :meth:`to_dict` output; unknown keys are an error naming them."""
        known = {f for f in cls.__dataclass_fields__}
        bad = sorted(set(d) - known)
        if bad:
            raise ValueError(f"icl: unknown option(s) {bad}; known: {sorted(known)}")
        d = dict(d)
        ppo = d.pop("ppo", {})
        if isinstance(ppo, dict):
            pk = set(PPOLagConfig.__dataclass_fields__)
            badp = sorted(set(ppo) - pk)
            if badp:
                raise ValueError(f"icl.ppo: unknown option(s) {badp}; known: {sorted(pk)}")
            ppo = PPOLagConfig(**ppo)
        return cls(**d, ppo=ppo).validate()


def icl_preset(name: str, env: str = "halfcheetah") -> ICLConfig:
    """The named budget for an environment.

    ``smoke``
        A few thousand steps: exercises every part in well under a minute (tests), learns little.
    ``default``
        Sized for one seed in about 45 minutes on a shared 2-core CPU: HalfCheetah 8 rounds,
        1 M + 7 x 0.5 M = 4.5 M PPO steps (measured here: ~2,700-3,200 steps/s including the PPO updates; an
        unconstrained policy passes x = 40 after 0.2 M steps); Ant (simulation ~3.5x slower) 6 rounds,
        1 M + 5 x 0.3 M = 2.5 M steps; point mass 5 rounds x 100 k steps.
    ``paper``
        For a workstation: HalfCheetah/Ant 10 rounds, 2 M + 9 x 1 M = 11 M PPO steps, 20 policy episodes per
        round (2.4x the default's RL; not run here). Not the authors' settings, which the PBICRL paper does not
        print (it reports ~20,000 s per ICL seed).
    """
    if name not in PRESETS:
        raise ValueError(f"budget: unknown preset {name!r}; choose one of {PRESETS}")
    if env not in ENVS:
        raise ValueError(f"env: unknown ICL environment {env!r}; choose one of {ENVS}")
    if env == "point_mass":
        ppo = PPOLagConfig(n_envs=4, n_steps=256, minibatch_size=256, n_epochs=10, init_log_std=0.0)
        if name == "smoke":
            return ICLConfig(rounds=2, first_round_steps=4096, round_steps=2048, beta=1.0, constraint_steps=100,
                             policy_episodes=4, eval_episodes=4, checkpoint_every=2048,
                             ppo=replace(ppo, n_steps=256, n_envs=4)).validate()
        steps = 100_000 if name == "default" else 300_000
        return ICLConfig(rounds=5 if name == "default" else 10, first_round_steps=steps, round_steps=steps,
                         beta=1.0, checkpoint_every=20_000, ppo=ppo).validate()
    ppo = PPOLagConfig(n_envs=4, n_steps=512, minibatch_size=256, n_epochs=10)
    if name == "smoke":
        return ICLConfig(rounds=2, first_round_steps=4096, round_steps=2048, constraint_steps=50,
                         policy_episodes=2, eval_episodes=2, checkpoint_every=2048,
                         ppo=replace(ppo, n_steps=256)).validate()
    if name == "default":
        if env == "ant":
            return ICLConfig(rounds=6, first_round_steps=1_000_000, round_steps=300_000, checkpoint_every=50_000,
                             ppo=ppo).validate()
        return ICLConfig(rounds=8, first_round_steps=1_000_000, round_steps=500_000, ppo=ppo).validate()
    return ICLConfig(rounds=10, first_round_steps=2_000_000, round_steps=1_000_000, policy_episodes=20,
                     eval_episodes=20, checkpoint_every=200_000, ppo=ppo).validate()


# --------------------------------------------------------------------------------------------- environments
@dataclass(frozen=True)
class ICLEnv:
    """What ICL needs to know about an environment.

    Attributes
    ----------
    name : str
    make : callable
        Zero-argument factory of the environment with the *nominal* reward (no constraint penalty).
    coord : callable
        ``coord(next_obs, info) -> (k,)`` constrained coordinate of the reached state.
    true_indicator : callable
        Indicator of the true constraint on rows of coordinates (evaluation only, never used for learning).
    grid : ndarray, shape (G, k)
        Positions for :func:`pbicrl.analysis.metrics.cmse_grid`.
    location_grid : ndarray, shape (L,), or None
        1-D positions scanned for the constraint location (None: no scalar location, e.g. the point mass).
    true_location : float or None
        The true wall position.
    """

    name: str
    make: Callable[[], Any]
    coord: Callable[[Any, dict], NDArray]
    true_indicator: Callable[[NDArray], NDArray]
    grid: NDArray[np.float64]
    location_grid: NDArray[np.float64] | None
    true_location: float | None


class _WallFactory:
    def __init__(self, name: str) -> None:
        self.name = name

    def __call__(self) -> Any:
        from pbicrl.envs.mujoco_wall import make_wall_env

        # the nominal reward only: the constraint is what ICL must learn
        return make_wall_env(self.name, constrained=False, max_episode_steps=500)


class _PointMassFactory:
    def __call__(self) -> Any:
        from pbicrl.envs.point_mass import PointMassEnv

        return PointMassEnv(reward_weights="nominal")


def _wall_coord(obs: Any, info: dict) -> NDArray[np.float64]:
    return np.array([float(info["x_position"])])


def _obs_coord(obs: Any, info: dict) -> NDArray[np.float64]:
    return np.asarray(obs, dtype=np.float64).reshape(-1)[:2]


def icl_env(name: str) -> ICLEnv:
    """The :class:`ICLEnv` of ``"halfcheetah"``, ``"ant"`` (walls at x = 8 and 10) or ``"point_mass"``.

    The CMSE grid spans ``[0, 2 * wall]`` on x (so that an all-0 or all-1 constraint scores 0.5), 401 points;
    the location is scanned up to ``5 * wall`` (from the lowest expert x, see :func:`run_icl`). For the point mass the grid is 43 x 43 over
    ``[-1, 20]^2`` and the truth is the union of the two discs.
    """
    if name in ("halfcheetah", "ant"):
        from pbicrl.envs.mujoco_wall import WALL_SPECS

        wall = WALL_SPECS[name].wall_x
        return ICLEnv(name, _WallFactory(name), _wall_coord,
                      lambda x, w=wall: (np.asarray(x, dtype=np.float64).reshape(-1) >= w).astype(float),
                      np.linspace(0.0, 2 * wall, 401)[:, None], np.linspace(-10.0, 5 * wall, 2001), float(wall))
    if name == "point_mass":
        from pbicrl.envs.point_mass import HIGH, LOW, POINT_MASS_TASK

        g = np.linspace(LOW, HIGH, 43)
        grid = np.stack(np.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)

        def truth(s: NDArray) -> NDArray:
            s = np.asarray(s, dtype=np.float64).reshape(-1, 2)
            return (POINT_MASS_TASK.orange.contains(s) | POINT_MASS_TASK.red.contains(s)).astype(float)

        return ICLEnv(name, _PointMassFactory(), _obs_coord, truth, grid, None, None)
    raise ValueError(f"env: unknown ICL environment {name!r}; choose one of {ENVS}")


def point_mass_expert_demos(n: int, seed: int = 0) -> list[NDArray[np.float64]]:
    """Scripted constraint-respecting point-mass trajectories (positions after each step), for smoke runs.

    From the left edge the expert first climbs to y = 19.5 and then goes right; from the bottom edge it first
    goes right to x = 19.5 and then up: both paths stay clear of the two discs.
    """
    from pbicrl.envs.point_mass import POINT_MASS_TASK, PointMassEnv

    env = PointMassEnv(reward_weights="nominal")
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(int(n)):
        pos, edge = env.sample_start(rng)
        states = []
        for _t in range(env.max_steps):
            if edge == "left":
                a = np.array([0.0, 1.0]) if pos[1] < 19.5 else np.array([1.0, 0.0])
            else:
                a = np.array([1.0, 0.0]) if pos[0] < 19.5 else np.array([0.0, 1.0])
            pos = env.dynamics(pos, a)
            states.append(pos.copy())
            if POINT_MASS_TASK.reached(pos)[0]:
                break
        out.append(np.asarray(states))
    return out


def expert_coordinates(dataset: Any, *, group: int = 1, n: int | None = 200, seed: int = 0,
                       dims: Sequence[int] | None = None) -> list[NDArray[np.float64]]:
    """Constrained coordinates of the expert trajectories of a :class:`pbicrl.inference.data.Dataset`.

    Parameters
    ----------
    dataset : Dataset or path
    group : int
        Label of the expert group (1 = good demonstrations).
    n : int or None
        Use at most ``n`` expert trajectories (a seeded random subset if there are more); None: all.
    seed : int
        Seed of that subset.
    dims : sequence of int, optional
        Columns of ``states`` to use (default: all).
    """
    from pbicrl.inference.data import load_dataset

    ds = dataset if not isinstance(dataset, (str, os.PathLike)) else load_dataset(dataset)
    if ds.states is None:
        raise ValueError("dataset: has no states; ICL needs the constrained coordinate of each state")
    idx = np.flatnonzero(ds.group == int(group))
    if idx.size == 0:
        raise ValueError(f"dataset: no trajectories in group {group} (groups: {ds.group_counts()})")
    if n is not None and idx.size > int(n):
        idx = np.sort(np.random.default_rng(seed).choice(idx, int(n), replace=False))
    cols = slice(None) if dims is None else list(dims)
    return [np.asarray(ds.trajectory_states(int(i)), dtype=np.float64)[:, cols] for i in idx]


# --------------------------------------------------------------------------------------------- constraint
class ConstraintNet(nn.Module):
    """:math:`c(s) = \\sigma(\\mathrm{MLP}((s - \\mu) / \\sigma_s))`, a soft constraint in [0, 1].

    Parameters
    ----------
    dim : int
        Coordinate dimension.
    hidden : sequence of int
        Hidden layer sizes (ReLU).
    center, scale : array-like, shape (dim,)
        Input standardisation (ICL uses the expert data's mean and standard deviation).
    init_bias : float
        Initial pre-sigmoid output bias.
    """

    def __init__(self, dim: int, hidden: Sequence[int], center: ArrayLike, scale: ArrayLike,
                 init_bias: float = -5.0) -> None:
        super().__init__()
        layers: list[nn.Module] = []
        last = int(dim)
        for h in hidden:
            layers += [nn.Linear(last, int(h)), nn.ReLU()]
            last = int(h)
        out = nn.Linear(last, 1)
        nn.init.normal_(out.weight, std=0.01)
        nn.init.constant_(out.bias, float(init_bias))
        layers.append(out)
        self.mlp = nn.Sequential(*layers)
        self.register_buffer("center", torch.as_tensor(np.asarray(center, dtype=np.float32).reshape(dim)))
        scale = np.maximum(np.asarray(scale, dtype=np.float32).reshape(dim), 1e-6)
        self.register_buffer("scale", torch.as_tensor(scale))

    def forward(self, s: torch.Tensor) -> torch.Tensor:
        return torch.sigmoid(self.mlp((s - self.center) / self.scale)).squeeze(-1)

    def numpy(self, s: ArrayLike) -> NDArray[np.float64]:
        """Evaluate on rows of coordinates (numpy in, numpy out)."""
        x = np.asarray(s, dtype=np.float32)
        if x.ndim == 1:
            x = x[:, None] if self.center.numel() == 1 else x[None, :]
        with torch.no_grad():
            return self(torch.as_tensor(x)).numpy().astype(np.float64)


def discount_matrix(trajs: Sequence[NDArray], gamma: float) -> tuple[torch.Tensor, torch.Tensor]:
    """Pad trajectories of coordinates into (N, T_max, k) and discount weights (N, T_max) (0 on padding).

    :math:`\\hat J_c(\\tau_i) = \\sum_t W_{it} c(S_{it})`.
    """
    if len(trajs) == 0:
        raise ValueError("trajectories: need at least one")
    k = np.asarray(trajs[0]).reshape(len(trajs[0]), -1).shape[1]
    tmax = max(len(t) for t in trajs)
    S = np.zeros((len(trajs), tmax, k), dtype=np.float32)
    W = np.zeros((len(trajs), tmax), dtype=np.float32)
    for i, t in enumerate(trajs):
        a = np.asarray(t, dtype=np.float32).reshape(len(t), -1)
        if a.shape[1] != k:
            raise ValueError(f"trajectories: trajectory {i} has {a.shape[1]} coordinates, expected {k}")
        S[i, :len(a)] = a
        W[i, :len(a)] = gamma ** np.arange(len(a))
        if len(a) < tmax:
            S[i, len(a):] = a[-1]  # any finite value; its weight is 0
    return torch.as_tensor(S), torch.as_tensor(W)


def constraint_loss(cost: Callable[[torch.Tensor], torch.Tensor], agent: Sequence[tuple[torch.Tensor, torch.Tensor]],
                    weights: ArrayLike, expert: tuple[torch.Tensor, torch.Tensor], beta: float,
                    hinge_weight: float) -> tuple[torch.Tensor, dict[str, Any]]:
    """ICL's constraint-adjustment objective (to minimise).

    :math:`L = -\\sum_j w_j \\bar J_c(\\pi_j) + \\lambda_h \\max(0, \\bar J_c(\\pi_E) - \\beta)`, where
    :math:`\\bar J_c` is the mean discounted cost of a set of trajectories.

    Parameters
    ----------
    cost : callable
        Tensor (..., k) -> costs (...).
    agent : sequence of (S, W)
        :func:`discount_matrix` of each policy's trajectories.
    weights : array-like
        Mixture weight of each policy (non-negative, summing to 1).
    expert : (S, W)
        :func:`discount_matrix` of the expert trajectories.
    beta, hinge_weight : float

    Returns
    -------
    (loss, info) : the scalar loss tensor and the per-part values (floats).
    """
    w = np.asarray(weights, dtype=np.float64).reshape(-1)
    if w.size != len(agent):
        raise ValueError(f"weights: {w.size} values for {len(agent)} policies")
    if np.any(w < 0) or not np.isclose(w.sum(), 1.0):
        raise ValueError(f"weights: must be non-negative and sum to 1, got {w.tolist()}")
    j_agent = torch.stack([(cost(S) * W).sum(-1).mean() for S, W in agent])
    S, W = expert
    j_exp = (cost(S) * W).sum(-1).mean()
    loss = -(torch.as_tensor(w, dtype=j_agent.dtype) * j_agent).sum() + hinge_weight * torch.relu(j_exp - beta)
    return loss, {"J_agent": j_agent.detach().numpy().astype(float).tolist(), "J_expert": float(j_exp.detach())}


def accrual(trajs: Sequence[NDArray], gamma: float, edges: Sequence[NDArray]) -> NDArray[np.float64]:
    """Normalised discounted visitation histogram of trajectories over coordinate bins (outliers clipped in)."""
    hist = np.zeros([len(e) - 1 for e in edges])
    for t in trajs:
        a = np.asarray(t, dtype=np.float64).reshape(len(t), -1)
        w = gamma ** np.arange(len(a))
        cols = [np.clip(a[:, d], e[0], e[-1]) for d, e in enumerate(edges)]
        h, _ = np.histogramdd(np.column_stack(cols), bins=list(edges), weights=w)
        hist += h
    s = hist.sum()
    return hist / s if s > 0 else hist


def mixture_weights(policy_accruals: Sequence[NDArray], expert_accrual: NDArray, how: str = "dissimilarity") -> NDArray[np.float64]:
    """Weights of the policies in the constraint adjustment.

    ``"dissimilarity"``: proportional to the total variation distance between each policy's accrual and the
    expert's (uniform if all are 0); ``"uniform"``; ``"last"``: all weight on the newest policy.
    """
    n = len(policy_accruals)
    if n == 0:
        raise ValueError("policy_accruals: need at least one policy")
    if how == "uniform":
        return np.full(n, 1.0 / n)
    if how == "last":
        w = np.zeros(n)
        w[-1] = 1.0
        return w
    if how != "dissimilarity":
        raise ValueError(f"weighting: expected 'dissimilarity', 'uniform' or 'last', got {how!r}")
    d = np.array([0.5 * np.abs(np.asarray(a) - expert_accrual).sum() for a in policy_accruals])
    return d / d.sum() if d.sum() > 0 else np.full(n, 1.0 / n)


def constraint_location(values: ArrayLike, grid: ArrayLike, level: float = 0.5) -> float | None:
    """First position on an increasing 1-D grid where the constraint reaches ``level`` (linear interpolation).

    Returns ``grid[0]`` if it is already there at the start and None if it never gets there.
    """
    v = np.asarray(values, dtype=np.float64).reshape(-1)
    g = np.asarray(grid, dtype=np.float64).reshape(-1)
    if v.shape != g.shape or v.size < 2:
        raise ValueError(f"constraint_location: values and grid must be equal 1-D arrays of >= 2, got {v.shape}, {g.shape}")
    hit = np.flatnonzero(v >= level)
    if hit.size == 0:
        return None
    i = int(hit[0])
    if i == 0:
        return float(g[0])
    v0, v1 = v[i - 1], v[i]
    return float(g[i - 1] + (level - v0) / (v1 - v0) * (g[i] - g[i - 1]))


# --------------------------------------------------------------------------------------------- the run
def _versions() -> dict[str, str]:
    out = {"python": platform.python_version()}
    for mod in ("numpy", "torch", "gymnasium", "mujoco"):
        try:
            out[mod] = __import__(mod).__version__
        except Exception:  # noqa: BLE001, S110 - version reporting must never fail a run
            pass
    return out


def write_json_file(path: Path, obj: Any) -> None:
    """Write ``obj`` as JSON atomically (NumPy values as lists, anything else JSON lacks as text)."""
    write_json(path, obj, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o))


_write_json = write_json_file  # the old name, still imported by pbicrl.safe_rl


def _plain_state(obj: Any) -> Any:
    """A copy of a checkpoint with NumPy values made plain (Python numbers, tensors), so that it loads with
    ``torch.load(weights_only=True)``, which refuses every global it does not know."""
    if isinstance(obj, dict):
        return {k: _plain_state(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_plain_state(v) for v in obj]
    if isinstance(obj, tuple):
        return tuple(_plain_state(v) for v in obj)
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return torch.as_tensor(obj)
    return obj


def _numpy_safe_globals() -> list[Any]:
    """NumPy scalar reconstruction, for checkpoints written before :func:`_plain_state` held NumPy numbers. These
    globals build dtypes and scalars from bytes; anything else a pickle might ask for stays refused."""
    out: list[Any] = [np.dtype]
    core = getattr(np, "_core", None) or getattr(np, "core", None)
    scalar = getattr(getattr(core, "multiarray", None), "scalar", None)
    if scalar is not None:
        out.append(scalar)
    dtypes = getattr(np, "dtypes", None)
    if dtypes is not None:
        for name in ("Float64DType", "Float32DType", "Int64DType", "Int32DType", "BoolDType"):
            if hasattr(dtypes, name):
                out.append(getattr(dtypes, name))
    return out


def _load_checkpoint(path: Path) -> dict[str, Any]:
    """Read a checkpoint of :func:`run_icl` safely (``weights_only=True``); errors name the file."""
    import pickle

    ctx = getattr(torch.serialization, "safe_globals", None)
    try:
        if ctx is not None:
            with ctx(_numpy_safe_globals()):
                obj = torch.load(path, weights_only=True, map_location="cpu")
        else:  # older torch: tensors and plain values only
            obj = torch.load(path, weights_only=True, map_location="cpu")
    except (pickle.UnpicklingError, RuntimeError, EOFError, ValueError, TypeError, AttributeError, OSError) as exc:
        lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip()] or [type(exc).__name__]
        # torch's own text suggests weights_only=False, exactly what must not be done with a file of unknown origin
        first = next((ln for ln in lines if "global" in ln.lower() and "weights_only" not in ln), lines[0])
        raise ValueError(f"out_dir: {path} cannot be loaded safely ({type(exc).__name__}: {first[:200]}); it is not "
                         "a checkpoint of this pbicrl version, or it is damaged. Delete it to start the run "
                         "afresh") from None
    if not isinstance(obj, dict) or "state" not in obj:
        raise ValueError(f"out_dir: {path} is not an ICL checkpoint (no 'state'); delete it to start afresh")
    return obj


def save_checkpoint(obj: Any, path: Path) -> None:
    """``torch.save`` of ``obj`` (NumPy values made plain, see :func:`_plain_state`) to ``path`` atomically."""
    with atomic_path(path) as tmp:
        torch.save(_plain_state(obj), tmp)


_torch_save = save_checkpoint  # the old name, still imported by pbicrl.safe_rl


def _rollout_coords(ppo: PPOLagrangian, env: Any, coord: Callable, n: int, seed: int,
                    deterministic: bool = False) -> tuple[list[NDArray], list[float]]:
    """Sample ``n`` episodes of the current policy; their coordinates after each step and returns."""
    trajs, rets = [], []
    g = torch.Generator().manual_seed(seed)
    for e in range(n):
        obs, _ = env.reset(seed=seed + e)
        cs, ret = [], 0.0
        while True:
            x = torch.as_tensor(ppo._norm(np.asarray(obs, dtype=np.float64).reshape(1, -1)), dtype=torch.float32)
            with torch.no_grad():
                d = ppo.ac.dist(x)
                a = d.mean if deterministic else d.mean + d.stddev * torch.randn(d.mean.shape, generator=g)
            a = np.clip(a.numpy()[0].astype(np.float64), ppo.act_low, ppo.act_high)
            obs, r, term, trunc, info = env.step(a)
            cs.append(np.asarray(coord(obs, info), dtype=np.float64).reshape(-1))
            ret += float(r)
            if term or trunc:
                break
        trajs.append(np.asarray(cs))
        rets.append(ret)
    return trajs, rets


def _location(net: ConstraintNet, spec: ICLEnv, xmin: float) -> float | None:
    """Constraint location, scanning upward from the lowest expert coordinate (the demonstrations' start):
    the network's extrapolation below any data says nothing about a halfspace ``x >= theta``."""
    if spec.location_grid is None:
        return None
    g = spec.location_grid[spec.location_grid > xmin]
    g = np.concatenate([[xmin], g])
    return constraint_location(net.numpy(g), g)


def run_icl(env: str | ICLEnv, expert: Sequence[NDArray], config: ICLConfig | str = "default", out_dir: str | os.PathLike = "icl-run",
            *, seed: int = 0, progress: bool = True, max_session_steps: int | None = None) -> dict[str, Any]:
    """Run (or resume) ICL and return its summary (also written to ``out_dir/summary.json``).

    Parameters
    ----------
    env : str or ICLEnv
        ``"halfcheetah"``, ``"ant"``, ``"point_mass"`` or a custom :class:`ICLEnv`.
    expert : sequence of ndarray, each (T_i, k)
        Constrained coordinates of the expert trajectories (:func:`expert_coordinates`).
    config : ICLConfig or preset name
    out_dir : path
        Run directory: ``checkpoint.pt`` (resume point), ``progress.log``, ``budget.json``, and at the end
        ``constraint.pt``, ``constraint_grid.npz`` and ``summary.json``.
    seed : int
    progress : bool
        Echo the log lines to stderr.
    max_session_steps : int, optional
        Stop after this many PPO steps in this call (checkpoint, then ``KeyboardInterrupt``), e.g. to run a
        long budget in slices on a shared machine; calling again resumes.

    Returns
    -------
    dict
        ``location`` (1-D coordinates: where c first reaches 0.5 scanning up from the lowest expert coordinate; None
        if it never does), ``cmse_location`` (None
        without a location), ``cmse_grid``, ``runtime_s`` (wall time summed over sessions), per-round history,
        final-policy statistics and the budget.
    """
    from pbicrl.analysis.metrics import cmse_grid, cmse_location

    spec = icl_env(env) if isinstance(env, str) else env
    cfg = icl_preset(config, spec.name) if isinstance(config, str) else config.validate()
    from pbicrl.envs._mujoco_compat import quiet_mujoco_warnings

    quiet_mujoco_warnings()  # no MUJOCO_LOG.TXT in the working directory, no deprecation note per environment
    if len(expert) == 0:
        raise ValueError("expert: need at least one expert trajectory")
    expert = [np.asarray(t, dtype=np.float64).reshape(len(t), -1) for t in expert]
    k = expert[0].shape[1]
    if any(t.shape[1] != k for t in expert) or any(len(t) == 0 for t in expert):
        raise ValueError("expert: trajectories must be non-empty with the same number of coordinates")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    log_path = out / "progress.log"
    torch.set_num_threads(int(cfg.ppo.torch_threads))
    torch.manual_seed(seed)

    def log(msg: str) -> None:
        line = f"{time.strftime('%Y-%m-%dT%H:%M:%SZ', time.gmtime())} {msg}"
        with open(log_path, "a") as fh:
            fh.write(line + "\n")
        if progress:
            print(line, file=sys.stderr, flush=True)

    allc = np.concatenate(expert)
    h = hashlib.sha256(np.asarray([len(t) for t in expert], dtype=np.int64).tobytes())
    h.update(np.ascontiguousarray(allc).tobytes())
    fingerprint = h.hexdigest()
    xmin = float(allc[:, 0].min())
    center, scale = allc.mean(0), allc.std(0) + 1e-3
    net = ConstraintNet(k, cfg.constraint_hidden, center, scale, cfg.init_bias)
    copt = torch.optim.Adam(net.parameters(), lr=cfg.constraint_lr)

    def cost_np(c: NDArray) -> NDArray:
        return net.numpy(c)

    ppo = PPOLagrangian(spec.make, spec.coord, cost_np, cfg.ppo, seed=seed)
    eval_env = spec.make()
    # accrual bins: the expert's range widened on both sides (policies may roam far beyond it)
    lo, hi = allc.min(0), allc.max(0)
    span = np.maximum(hi - lo, 1.0)
    edges = [np.linspace(lo[d] - 2 * span[d], hi[d] + 2 * span[d], cfg.accrual_bins + 1) for d in range(k)]
    exp_acc = accrual(expert, cfg.gamma, edges)
    exp_mat = discount_matrix(expert, cfg.gamma)

    state: dict[str, Any] = {"round": 0, "phase": "rl", "snapshots": [], "history": [], "wall_time_s": 0.0,
                             "sessions": []}
    ckpt = out / _CKPT
    if ckpt.is_file():
        st = _load_checkpoint(ckpt)
        if st.get("config") != cfg.to_dict() or st.get("seed") != seed:
            raise ValueError(f"out_dir: {out} holds a checkpoint of a different ICL configuration or seed; "
                             "use another directory")
        if st.get("expert_sha256") != fingerprint:
            raise ValueError(f"out_dir: {out} holds a checkpoint made with different expert data; "
                             "use another directory")
        ppo.load_state_dict(st["ppo"])
        net.load_state_dict(st["constraint"])
        copt.load_state_dict(st["constraint_opt"])
        state = st["state"]
        if state["round"] >= cfg.rounds and (out / "summary.json").is_file():
            ppo.close()
            eval_env.close()
            return json.loads((out / "summary.json").read_text())  # finished earlier: nothing to do
        log(f"resume: round {state['round'] + 1}/{cfg.rounds}, phase {state['phase']}, {ppo.num_steps} PPO steps")
    else:
        log(f"new ICL run: env {spec.name}, {len(expert)} expert trajectories, seed {seed}, "
            f"{cfg.rounds} rounds, {cfg.total_steps} PPO steps")
    t_session = time.time()
    wall_before = float(state["wall_time_s"])

    def save(status: str) -> None:
        now = time.time()
        st = dict(state)
        st["wall_time_s"] = wall_before + (now - t_session)
        st["sessions"] = state["sessions"] + [{"started_utc": time.strftime('%Y-%m-%dT%H:%M:%SZ', time.gmtime(t_session)),
                                               "wall_time_s": now - t_session, "end_steps": ppo.num_steps}]
        save_checkpoint({"config": cfg.to_dict(), "seed": seed, "expert_sha256": fingerprint, "ppo": ppo.state_dict(), "constraint": net.state_dict(),
                     "constraint_opt": copt.state_dict(), "state": st}, ckpt)
        write_json_file(out / "budget.json", {
            "status": status, "env": spec.name, "seed": seed, "n_expert": len(expert),
            "requested_ppo_steps": cfg.total_steps, "done_ppo_steps": ppo.num_steps, "rounds": cfg.rounds,
            "rounds_done": state["round"], "wall_time_s": round(st["wall_time_s"], 1), "sessions": st["sessions"],
            "config": cfg.to_dict(), "versions": _versions()})

    stop = {"flag": False}

    def _handler(signum, _frame):
        stop["flag"] = True

    old: dict[int, Any] = {}
    try:
        for sig in (signal.SIGTERM, signal.SIGINT):
            old[sig] = signal.signal(sig, _handler)
    except ValueError:  # not the main thread
        old = {}

    last_ckpt = {"steps": ppo.num_steps, "log_t": time.time()}
    session_start_steps = ppo.num_steps

    def on_update(p: PPOLagrangian, info: dict) -> bool:
        if time.time() - last_ckpt["log_t"] > 30 or p.num_steps >= cfg.round_target(state["round"]):
            log(f"round {state['round'] + 1} steps {p.num_steps} return {info['ep_return']:.1f} len {info['ep_len']:.0f} "
                f"max_coord {info['ep_max_coord']:.2f} Jc {info['ep_cost']:.3f} lambda {info['lam_next']:.3f} "
                f"kl {info['approx_kl']:.4f} std {info['std']:.3f} ({cfg.ppo.n_envs * cfg.ppo.n_steps / info['seconds']:.0f} steps/s)")
            last_ckpt["log_t"] = time.time()
        if p.num_steps - last_ckpt["steps"] >= cfg.checkpoint_every:
            save("running")
            last_ckpt["steps"] = p.num_steps
        if max_session_steps is not None and p.num_steps - session_start_steps >= int(max_session_steps):
            stop["flag"] = True
        return not stop["flag"]

    try:
        while state["round"] < cfg.rounds:
            r = state["round"]
            if state["phase"] == "rl":
                if cfg.reinit_policy and r > 0 and ppo.num_steps == cfg.round_target(r - 1):
                    fresh = PPOLagrangian(spec.make, spec.coord, cost_np, cfg.ppo, seed=seed + 1000 * r)
                    steps, nup = ppo.num_steps, ppo.num_updates
                    ppo.close()
                    ppo = fresh
                    ppo.num_steps, ppo.num_updates = steps, nup
                ppo.set_cost_fn(cost_np)
                ppo.learn(cfg.round_target(r), callback=on_update)
                if stop["flag"]:
                    save("interrupted")
                    log(f"interrupted at {ppo.num_steps} PPO steps; checkpoint written")
                    raise KeyboardInterrupt(f"ICL interrupted at {ppo.num_steps} steps; rerun to resume")
                trajs, rets = _rollout_coords(ppo, eval_env, spec.coord, cfg.policy_episodes,
                                              seed=seed * 1_000_003 + 101 * r)
                state["snapshots"].append({"trajs": [torch.as_tensor(t) for t in trajs], "returns": rets})
                state["phase"] = "constraint"
                save("running")
            # constraint adjustment over all policies so far
            snaps = [[t.numpy() for t in s["trajs"]] for s in state["snapshots"]]
            accs = [accrual(s, cfg.gamma, edges) for s in snaps]
            w = mixture_weights(accs, exp_acc, cfg.weighting)
            mats = [discount_matrix(s, cfg.gamma) for s in snaps]
            info0 = None
            for _ in range(cfg.constraint_steps):
                loss, info = constraint_loss(net, mats, w, exp_mat, cfg.beta, cfg.hinge_weight)
                info0 = info0 or info
                copt.zero_grad()
                loss.backward()
                copt.step()
            with torch.no_grad():
                loss, info = constraint_loss(net, mats, w, exp_mat, cfg.beta, cfg.hinge_weight)
            loc = _location(net, spec, xmin)
            grid_err = cmse_grid(spec.true_indicator(spec.grid), net.numpy(spec.grid))
            ret_mean = float(np.mean(state["snapshots"][-1]["returns"]))
            maxc = float(np.mean([t[:, 0].max() for t in snaps[-1]]))
            rec = {"round": r + 1, "ppo_steps": ppo.num_steps, "lambda": ppo.lam, "weights": w.tolist(),
                   "J_expert_before": info0["J_expert"], "J_expert": info["J_expert"], "J_agent": info["J_agent"],
                   "loss": float(loss), "location": loc, "cmse_grid": grid_err, "policy_return": ret_mean,
                   "policy_max_coord0": maxc}
            state["history"].append(rec)
            log(f"round {r + 1}/{cfg.rounds} constraint: J_expert {info['J_expert']:.3f} (beta {cfg.beta}), "
                f"J_agent {np.round(info['J_agent'], 2).tolist()}, weights {np.round(w, 3).tolist()}, "
                f"location {loc}, cmse_grid {grid_err:.4f}; policy return {ret_mean:.1f}, max coord {maxc:.2f}")
            state["round"] = r + 1
            state["phase"] = "rl"
            save("running" if state["round"] < cfg.rounds else "finishing")
    finally:
        for sig, h in old.items():
            signal.signal(sig, h)

    # final evaluation of the constraint and of the last policy
    trajs, rets = _rollout_coords(ppo, eval_env, spec.coord, cfg.eval_episodes, seed=seed * 1_000_003 + 999_999,
                                  deterministic=True)
    loc = _location(net, spec, xmin)
    vals = net.numpy(spec.grid)
    summary: dict[str, Any] = {
        "env": spec.name, "seed": seed, "n_expert": len(expert), "location": loc, "true_location": spec.true_location,
        "cmse_location": (cmse_location(loc, spec.true_location) if loc is not None and spec.true_location is not None
                          else None),
        "cmse_grid": cmse_grid(spec.true_indicator(spec.grid), vals),
        "final_policy": {"mean_return": float(np.mean(rets)),
                         "mean_max_coord0": float(np.mean([t[:, 0].max() for t in trajs])),
                         "fraction_violating": float(np.mean([np.any(spec.true_indicator(t) > 0) for t in trajs]))},
        "lambda": ppo.lam, "ppo_steps": ppo.num_steps, "history": state["history"], "config": cfg.to_dict(),
    }
    save("complete")
    st = _load_checkpoint(ckpt)["state"]
    summary["runtime_s"] = float(st["wall_time_s"])
    summary["sessions"] = len(st["sessions"])
    save_checkpoint({"state_dict": net.state_dict(), "dim": k, "hidden": list(cfg.constraint_hidden)}, out / "constraint.pt")
    with atomic_path(out / "constraint_grid.npz") as tmp:
        np.savez_compressed(tmp, grid=spec.grid, c=vals, truth=spec.true_indicator(spec.grid))
    write_json_file(out / "summary.json", summary)
    log(f"done: location {loc}, cmse_location {summary['cmse_location']}, cmse_grid {summary['cmse_grid']:.4f}, "
        f"runtime {summary['runtime_s']:.0f} s over {summary['sessions']} session(s)")
    ppo.close()
    eval_env.close()
    return summary


def run_icl_task(config: dict, out_dir: Path) -> dict[str, Any]:
    """Task entry point (``"pbicrl.baselines.icl:run_icl_task"``): one ICL seed on a dataset's good demos.

    Config keys: ``env`` (``halfcheetah``/``ant``/``point_mass``), ``data`` (path to a
    :class:`pbicrl.inference.data.Dataset` with states; or ``"scripted"`` for the point mass's scripted expert),
    ``budget`` (preset name) and/or ``icl`` (dict of :class:`ICLConfig` overrides), ``budget_sha256`` (ignored
    here: lets a caller hash the preset's values into the task), ``seed``, ``n_expert``
    (default 200), ``expert_group`` (default 1), ``demos_seed`` (the draw of the expert demonstrations),
    ``checkpoint_dir`` (a directory that outlives the task's temporary output directory so an interrupted task
    resumes; default: inside ``out_dir``, i.e. no resume). The old names ``dataset`` and ``sample_seed`` are
    accepted until pbicrl 0.3 with a :class:`~pbicrl.errors.PbicrlWarning`.
    """
    from pbicrl.config import ConfigError

    config = dict(config)
    for old, new in (("dataset", "data"), ("sample_seed", "demos_seed")):
        if old in config:
            if new in config:
                raise ConfigError(f"{old}: deprecated name of '{new}', which is given too; keep only '{new}'")
            from pbicrl.errors import warn

            warn(f"ICL task key '{old}' is deprecated and will be removed in pbicrl 0.3: use '{new}'")
            config[new] = config.pop(old)
    env = config.get("env")
    if env not in ENVS:
        raise ValueError(f"env: expected one of {ENVS}, got {env!r}")
    budget = config.get("budget", "default")
    cfg = icl_preset(budget, env)
    if config.get("icl"):
        base = cfg.to_dict()
        over = dict(config["icl"])
        if "ppo" in over:
            base["ppo"] = {**base["ppo"], **over.pop("ppo")}
        base.update(over)
        cfg = ICLConfig.from_dict(base)
    seed = int(config.get("seed", 0))
    data = config.get("data")
    if data == "scripted":
        if env != "point_mass":
            raise ValueError("data: 'scripted' exists only for env point_mass")
        expert = point_mass_expert_demos(int(config.get("n_expert", 200) or 200), seed=int(config.get("demos_seed", 0)))
    elif data:
        expert = expert_coordinates(data, group=int(config.get("expert_group", 1)),
                                    n=config.get("n_expert", 200), seed=int(config.get("demos_seed", 0)))
    else:
        raise ValueError("data: required (path of a dataset with states, or 'scripted' for point_mass)")
    run_dir = Path(config["checkpoint_dir"]) if config.get("checkpoint_dir") else Path(out_dir) / "icl"
    summary = run_icl(env, expert, cfg, run_dir, seed=seed, progress=bool(config.get("progress", False)))
    if run_dir != Path(out_dir) / "icl":
        import shutil

        (Path(out_dir) / "icl").mkdir(parents=True, exist_ok=True)
        for name in ("summary.json", "budget.json", "progress.log", "constraint.pt", "constraint_grid.npz"):
            if (run_dir / name).exists():
                shutil.copy2(run_dir / name, Path(out_dir) / "icl" / name)
    return {k: summary[k] for k in ("env", "seed", "n_expert", "location", "cmse_location", "cmse_grid", "runtime_s",
                                    "ppo_steps", "lambda", "final_policy", "sessions")} | {"budget": budget,
                                                                                          "total_ppo_steps": cfg.total_steps,
                                                                                          "rounds": cfg.rounds}
