"""NeRF-style positional encoding with log-spaced frequencies (AV-NeRF's ``embedding_module_log``).

``x [..., d] -> [..., d * (1 + 2 n)]``: the input itself, then ``sin(2^k x)`` and
``cos(2^k x)`` for ``k = 0 .. n-1``, i.e. frequencies log-spaced from 1 up to
**2^(n-1)** (2^9 for the default n = 10, as AV-NeRF's code). For n = 10 a listener
(x, y) encodes to 42 dims and a frequency to 21.
"""

from __future__ import annotations

import torch


def encoded_dim(in_dim: int, n_frequencies: int, include_input: bool = True) -> int:
    """Width of :func:`positional_encoding` of an ``in_dim``-vector."""
    return in_dim * (2 * n_frequencies + int(include_input))


def positional_encoding(x: torch.Tensor, n_frequencies: int, include_input: bool = True) -> torch.Tensor:
    """``x [..., d]`` -> ``[..., d * (2 n + 1)]`` (see module docstring)."""
    if n_frequencies < 0:
        raise ValueError(f"n_frequencies must be >= 0, got {n_frequencies}")
    bands = 2.0 ** torch.arange(n_frequencies, device=x.device, dtype=x.dtype)  # [n]
    scaled = (x[..., None, :] * bands[:, None]).flatten(-2)  # [..., n * d], frequency-major
    parts = [x] if include_input else []
    parts += [torch.sin(scaled), torch.cos(scaled)]
    return torch.cat(parts, dim=-1)
