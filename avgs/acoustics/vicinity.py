"""Vicinity search: the k audio points nearest a listener or source (paper §3.2).

k = ceil(percentile % of N), clamped to [1, N]. A partial selection, O(N) per query
(``numpy.argpartition`` on the CPU, ``torch.topk`` unsorted elsewhere), never a full
sort: the indices come back in no particular order. The context is a mean over them,
so the order does not matter.
"""

from __future__ import annotations

import math

import numpy as np
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


def nearest_indices(coordinates: torch.Tensor, queries: torch.Tensor, k: int) -> torch.Tensor:
    """Indices ``[B, k]`` (int64, unordered) of the ``k`` points nearest each query.

    coordinates: [3, N], the points axis by axis (``X.T.contiguous()``: each axis is
    contiguous, so the squared distances are summed with no [B, N, 3] temporary);
    queries: [B, 3] (or [3], giving [k]).
    """
    single = queries.dim() == 1
    q = queries.reshape(-1, 3).to(coordinates.dtype)  # [B, 3]
    n = coordinates.shape[1]
    d2 = (coordinates[0] - q[:, 0:1]).square_()  # [B, N]
    for axis in (1, 2):
        d2.add_((coordinates[axis] - q[:, axis : axis + 1]).square_())
    if k >= n:
        idx = torch.arange(n, device=coordinates.device).expand(q.shape[0], n)
    elif d2.device.type == "cpu":
        idx = torch.from_numpy(np.argpartition(d2.float().numpy(), k - 1, axis=-1)[:, :k].astype(np.int64))
    else:
        idx = torch.topk(d2, k, dim=-1, largest=False, sorted=False).indices
    return idx[0] if single else idx
