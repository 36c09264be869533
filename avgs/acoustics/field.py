"""F: the acoustic field network (paper §3.2).

For a position ``X_i`` (listener or source) and its vicinity (the k nearest audio
points): ``G_i = (X - X_i) / ||X - X_i||``, ``C_i = mean_k F(alpha (+) G_i)``.
The overall context is ``C = C_S (+) C_L`` (composed in :mod:`avgs.acoustics.model`).

The forward pass has two parts. F's first layer is linear in ``alpha (+) G_i``, so its
alpha part ``W_alpha alpha + b`` depends only on the points: :meth:`AcousticField.point_features`
computes it, and inference caches it for all points. Per query only ``W_g G_i`` is added
(3 inputs instead of 55). F's last layer is linear too and commutes with the mean over the
vicinity, so it is applied once, to the mean.
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

    def __init__(self, alpha_dim: int, width: int, layers: int, context_dim: int):
        super().__init__()
        if layers < 1:
            raise ValueError(f"the acoustic field network needs >= 1 layer, got {layers}")
        dims = [alpha_dim + 3] + [width] * (layers - 1) + [context_dim]
        mods: list[nn.Module] = []
        for i, (a, b) in enumerate(zip(dims, dims[1:])):
            mods.append(nn.Linear(a, b))
            if i < len(dims) - 2:
                mods.append(nn.ReLU(inplace=True))
        self.mlp = nn.Sequential(*mods)  # kept as one Sequential: the checkpoint's state-dict keys
        self.alpha_dim = alpha_dim
        self.context_dim = context_dim

    @property
    def linears(self) -> list[nn.Linear]:
        return [m for m in self.mlp if isinstance(m, nn.Linear)]

    def point_features(self, alpha: torch.Tensor) -> torch.Tensor:
        """The first layer's alpha part ``W_alpha alpha + b``: alpha [..., D] -> [..., width or context_dim]."""
        first = self.linears[0]
        return nn.functional.linear(alpha, first.weight[:, : self.alpha_dim], first.bias)

    def forward(
        self, X: torch.Tensor, alpha: torch.Tensor, origin: torch.Tensor, indices: torch.Tensor,
        point_features: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """Context of ``origin`` from its vicinity.

        X: [N, 3]; alpha: [N, D]; origin: [B, 3]; indices: [B, k] (into X) -> [B, context_dim].
        ``point_features``: :meth:`point_features` of all N points [N, width], cached at inference.
        """
        first, *rest = self.linears
        B, k = indices.shape
        flat = indices.reshape(-1)  # [B k]
        g = unit_directions(X.index_select(0, flat).view(B, k, 3), origin).view(B * k, 3)  # [B k, 3]
        a = self.point_features(alpha.index_select(0, flat)) if point_features is None else point_features.index_select(0, flat)
        h = torch.addmm(a, g, first.weight[:, self.alpha_dim :].t())  # [B k, w]: the first layer
        if not rest:
            return h.view(B, k, -1).mean(dim=1)  # F is one linear map
        h = h.relu_()
        for layer in rest[:-1]:
            h = torch.addmm(layer.bias, h, layer.weight.t()).relu_()  # [B k, w]
        return rest[-1](h.view(B, k, -1).mean(dim=1))  # [B, C]: the last layer applied to the mean
