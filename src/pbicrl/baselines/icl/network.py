"""The learned constraint: a small MLP with a sigmoid output over the constrained coordinate."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

try:
    import torch
    from torch import nn
except ImportError as exc:  # pragma: no cover - exercised only without the extra
    raise ImportError('pbicrl.baselines.icl needs PyTorch: pip install "pbicrl[rl]"') from exc

__all__ = ["ConstraintNet"]


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
