"""ICL's constraint adjustment: discounted costs of trajectories, the objective, the mixture weights of the
policies (visitation histograms, "accruals") and the location read off the learned constraint."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

try:
    import torch
except ImportError as exc:  # pragma: no cover - exercised only without the extra
    raise ImportError('pbicrl.baselines.icl needs PyTorch: pip install "pbicrl[rl]"') from exc

__all__ = ["discount_matrix", "constraint_loss", "accrual", "mixture_weights", "constraint_location"]


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
