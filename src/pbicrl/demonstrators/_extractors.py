"""SB3 feature extractor that rescales box observations to about [-1, 1].

Positions such as the point mass's ``[-1, 20]^2`` enter the networks unscaled otherwise;
large raw inputs made the true-reward critic over-generalise the red penalty and the
policy stall far from the goal.  The rescaling is part of the saved policy, so
``policy.predict`` still takes raw positions.  Needs torch (extra ``rl``).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor

__all__ = ["AffineObservation", "RBFObservation"]


class AffineObservation(BaseFeaturesExtractor):
    """Features ``(obs - centre) / half_width`` with ``centre``/``half_width`` from ``low``/``high``.

    Parameters
    ----------
    observation_space : gymnasium.spaces.Box
        Flat box observation space.
    low, high : sequence of float
        Expected observation range (one value per dimension).
    """

    def __init__(self, observation_space, low: Sequence[float], high: Sequence[float]) -> None:
        dim = int(np.prod(observation_space.shape))
        super().__init__(observation_space, features_dim=dim)
        lo = np.asarray(low, dtype=np.float32).reshape(-1)
        hi = np.asarray(high, dtype=np.float32).reshape(-1)
        if lo.shape != (dim,) or hi.shape != (dim,) or np.any(hi <= lo):
            raise ValueError(f"low/high: need {dim} values each with high > low, got {low!r}, {high!r}")
        self.register_buffer("centre", torch.as_tensor((hi + lo) / 2))
        self.register_buffer("half_width", torch.as_tensor((hi - lo) / 2))

    def forward(self, observations: torch.Tensor) -> torch.Tensor:
        return (observations.flatten(1) - self.centre) / self.half_width


class RBFObservation(BaseFeaturesExtractor):
    """Gaussian radial-basis features on a regular grid, plus the rescaled observation.

    A grid of ``n_per_dim`` centres per dimension spans ``[low, high]``; each feature is
    ``exp(-||x - c||^2 / (2 width^2))`` on the rescaled coordinates with ``width`` equal to
    the grid spacing.  Local features let the critic represent a penalty confined to a
    small region without smearing it over the whole workspace (with raw coordinates the
    true-reward critic learned a broad slope away from the regions and the policy stalled).

    Parameters
    ----------
    observation_space : gymnasium.spaces.Box
    low, high : sequence of float
        Expected observation range.
    n_per_dim : int
        Grid resolution per dimension.
    """

    def __init__(self, observation_space, low: Sequence[float], high: Sequence[float], n_per_dim: int = 10) -> None:
        dim = int(np.prod(observation_space.shape))
        n = int(n_per_dim)
        if n < 2:
            raise ValueError(f"n_per_dim: must be >= 2, got {n_per_dim}")
        super().__init__(observation_space, features_dim=dim + n ** dim)
        lo = np.asarray(low, dtype=np.float32).reshape(-1)
        hi = np.asarray(high, dtype=np.float32).reshape(-1)
        if lo.shape != (dim,) or hi.shape != (dim,) or np.any(hi <= lo):
            raise ValueError(f"low/high: need {dim} values each with high > low, got {low!r}, {high!r}")
        axis = np.linspace(-1.0, 1.0, n, dtype=np.float32)
        grid = np.stack(np.meshgrid(*([axis] * dim), indexing="ij"), axis=-1).reshape(-1, dim)
        self.register_buffer("centre", torch.as_tensor((hi + lo) / 2))
        self.register_buffer("half_width", torch.as_tensor((hi - lo) / 2))
        self.register_buffer("grid", torch.as_tensor(grid))
        self.inv_two_var = float(1.0 / (2.0 * (2.0 / (n - 1)) ** 2))

    def forward(self, observations: torch.Tensor) -> torch.Tensor:
        x = (observations.flatten(1) - self.centre) / self.half_width
        d2 = ((x[:, None, :] - self.grid[None, :, :]) ** 2).sum(-1)
        return torch.cat([x, torch.exp(-d2 * self.inv_two_var)], dim=1)
