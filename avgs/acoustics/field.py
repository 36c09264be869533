"""F: the acoustic field network (paper §3.2).

For a position ``X_i`` (listener or source) and its vicinity (the k nearest audio
points): ``G_i = (X - X_i) / ||X - X_i||``, ``C_i = mean_k F(alpha (+) G_i)``.
The overall context is ``C = C_S (+) C_L`` (composed in :mod:`avgs.acoustics.model`).
"""

from __future__ import annotations

import torch
from torch import nn

DIRECTION_EPS = 1e-6
"A point closer than this (normalised units) to the query gets a zero direction instead of NaN."


def unit_directions(points: torch.Tensor, origin: torch.Tensor) -> torch.Tensor:
    """``(points - origin) / ||points - origin||`` with a zero-distance guard.

    points: [..., k, 3]; origin: [..., 3] -> [..., k, 3]. A point on the origin gives a
    zero vector, and the gradient stays finite (the norm is clamped, not divided by 0).
    """
    diff = points - origin[..., None, :]  # [..., k, 3]
    norm = torch.sqrt((diff * diff).sum(-1, keepdim=True).clamp_min(DIRECTION_EPS**2))  # [..., k, 1]
    return diff / norm


class AcousticField(nn.Module):
    """MLP ``(alpha [D] (+) direction [3]) -> feature [context_dim]``, averaged over a vicinity."""

    def __init__(self, alpha_dim: int, width: int = 64, layers: int = 3, context_dim: int = 64):
        super().__init__()
        if layers < 1:
            raise ValueError(f"the acoustic field network needs >= 1 layer, got {layers}")
        dims = [alpha_dim + 3] + [width] * (layers - 1) + [context_dim]
        mods: list[nn.Module] = []
        for i, (a, b) in enumerate(zip(dims, dims[1:])):
            mods.append(nn.Linear(a, b))
            if i < len(dims) - 2:
                mods.append(nn.ReLU(inplace=True))
        self.mlp = nn.Sequential(*mods)
        self.alpha_dim = alpha_dim
        self.context_dim = context_dim

    def forward(self, X: torch.Tensor, alpha: torch.Tensor, origin: torch.Tensor, indices: torch.Tensor) -> torch.Tensor:
        """Context of ``origin`` from its vicinity.

        X: [N, 3]; alpha: [N, D]; origin: [B, 3]; indices: [B, k] (into X) -> [B, context_dim].
        """
        g = unit_directions(X[indices], origin)  # [B, k, 3]
        feats = self.mlp(torch.cat([alpha[indices], g], dim=-1))  # [B, k, C]
        return feats.mean(dim=1)  # [B, C]
