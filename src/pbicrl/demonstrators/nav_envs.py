"""The navigation environments' training and rollout settings (:data:`NAV_ENVS`) and their factory."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

__all__ = ["NavEnvSpec", "NAV_ENVS", "NAV_REWARDS", "nav_spec", "make_nav_env"]


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
NAV_REWARDS = ("true", "nominal")
"""The rewards a navigation policy is trained on: the true one (penalties included) or the nominal one."""


def nav_spec(name: str) -> NavEnvSpec:
    """The :class:`NavEnvSpec` of ``name``; a ValueError naming ``env`` for an unknown one."""
    if name not in NAV_ENVS:
        raise ValueError(f"env: expected one of {sorted(NAV_ENVS)}, got {name!r}")
    return NAV_ENVS[name]


def make_nav_env(name: str, reward_weights: Any = "true", **kwargs: Any) -> Any:
    """Build ``PointMassEnv`` or ``FetchReachConstrainedEnv`` by name."""
    nav_spec(name)
    if name == "point_mass":
        from pbicrl.envs.point_mass import PointMassEnv

        return PointMassEnv(reward_weights=reward_weights, **kwargs)
    from pbicrl.envs.fetch_reach import FetchReachConstrainedEnv

    return FetchReachConstrainedEnv(reward_weights=reward_weights, **kwargs)
