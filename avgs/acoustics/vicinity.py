"""Vicinity search: the k audio points nearest a listener or source (paper §3.2).

k = ceil(percentile % of N), clamped to [1, N]. Uses ``torch.topk`` on squared
distances (a partial selection, O(N) per query), never a full sort.
"""

from __future__ import annotations

import math

import torch


def vicinity_size(n_points: int, percentile: float) -> int:
    """``ceil(percentile / 100 * n_points)`` clamped to ``[1, n_points]``."""
    if n_points < 1:
        raise ValueError(f"need at least one audio point, got {n_points}")
    if not (0.0 < percentile <= 100.0):
        raise ValueError(f"vicinity percentile must be in (0, 100], got {percentile}")
    # Round before ceil so that e.g. 15 % of 100 is 15, not 16 from 15.000000000000002.
    k = math.ceil(round(percentile / 100.0 * n_points, 9))
    return max(1, min(n_points, k))


def nearest_indices(points: torch.Tensor, queries: torch.Tensor, k: int) -> torch.Tensor:
    """Indices ``[B, k]`` (int64) of the ``k`` points nearest each query, nearest first.

    points: [N, 3]; queries: [B, 3] (or [3], giving [k]).
    """
    single = queries.dim() == 1
    q = queries.reshape(-1, 3)  # [B, 3]
    d2 = ((points[None, :, :] - q[:, None, :]) ** 2).sum(-1)  # [B, N]
    idx = torch.topk(d2, k, dim=-1, largest=False, sorted=True).indices  # [B, k]
    return idx[0] if single else idx
