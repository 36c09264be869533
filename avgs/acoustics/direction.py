"""The features through which B reads the direction to the source.

theta is :func:`avgs.data.frame.signed_direction`: positive when the source is on the
listener's **left** (ARCHITECTURE.md). B reads theta as circular harmonics ``cos(n theta), sin(n theta)``,
n = 1 .. K (default), or as the paper's positional encoding of ``theta / (1.01 pi)``.
"""

from __future__ import annotations

import math

import torch

from avgs.acoustics.encodings import encoded_dim, positional_encoding

THETA_SCALE = 1.0 / (1.01 * math.pi)
"theta (radians, in (-pi, pi]) times this lies strictly inside (-1, 1) (the paper's scaling)."

DIRECTION_ENCODINGS = ("fourier", "harmonic")
"Direction features B can use: the paper's Fourier features of theta, or circular harmonics."


def direction_dim(encoding: str, harmonics: int, pe_frequencies: int) -> int:
    """Width of :func:`direction_feature`."""
    return 2 * harmonics if encoding == "harmonic" else encoded_dim(1, pe_frequencies)


def direction_feature(theta: torch.Tensor, encoding: str, harmonics: int, pe_frequencies: int) -> torch.Tensor:
    """theta [B] radians -> feature [B, direction_dim].

    ``harmonic``: cos(n theta), sin(n theta) for n = 1 .. ``harmonics``: periodic across the
    listener's back, with sin(theta), the source's lateral offset, as one of its inputs.
    ``fourier``: :func:`~avgs.acoustics.encodings.positional_encoding` of theta / (1.01 pi).
    """
    if encoding == "harmonic":
        n = torch.arange(1, harmonics + 1, device=theta.device, dtype=theta.dtype)  # [K]
        nt = theta[:, None] * n  # [B, K]
        return torch.cat([torch.cos(nt), torch.sin(nt)], dim=-1)
    return positional_encoding((theta * THETA_SCALE)[:, None], pe_frequencies)
