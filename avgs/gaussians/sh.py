"""Real spherical harmonics up to degree 3 (the basis and sign convention of 3D-GS and gsplat).

Coefficients are ``[..., K, 3]`` with ``K = (degree + 1)^2`` (16 for degree 3, 48 numbers);
``sh[..., 0, :]`` is the DC term, and ``rgb = 0.5 + SH_C0 * dc`` for a constant colour.
"""

from __future__ import annotations

import torch

SH_C0 = 0.28209479177387814
SH_C1 = 0.4886025119029199
SH_C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792, 0.5462742152960396)
SH_C3 = (
    -0.5900435899266435,
    2.890611442640554,
    -0.4570457994644658,
    0.3731763325901154,
    -0.4570457994644658,
    1.445305721320277,
    -0.5900435899266435,
)
MAX_DEGREE = 3


def num_coeffs(degree: int) -> int:
    """``(degree + 1)^2``."""
    return (degree + 1) ** 2


def rgb_to_sh(rgb: torch.Tensor) -> torch.Tensor:
    """Constant colour in [0, 1] -> DC coefficient (inverse of ``0.5 + SH_C0 * dc``)."""
    return (rgb - 0.5) / SH_C0


def sh_to_rgb(dc: torch.Tensor) -> torch.Tensor:
    """DC coefficient -> colour (unclamped)."""
    return dc * SH_C0 + 0.5


def eval_sh(degree: int, sh: torch.Tensor, dirs: torch.Tensor) -> torch.Tensor:
    """Colour offsets ``[..., 3]`` from coefficients ``sh [..., K, 3]`` for directions ``dirs [..., 3]``.

    ``dirs`` need not be unit length (normalised here; a zero direction gives the DC term only).
    Uses the first ``(degree + 1)^2`` coefficients; add 0.5 and clamp for a colour.
    """
    if not 0 <= degree <= MAX_DEGREE:
        raise ValueError(f"SH degree must be in 0..{MAX_DEGREE}, got {degree}")
    if sh.shape[-2] < num_coeffs(degree):
        raise ValueError(f"SH degree {degree} needs {num_coeffs(degree)} coefficients, got {sh.shape[-2]}")
    out = SH_C0 * sh[..., 0, :]
    if degree == 0:
        return out
    d = dirs / torch.sqrt((dirs * dirs).sum(-1, keepdim=True).clamp_min(1e-24))  # [..., 3]
    x, y, z = d[..., 0:1], d[..., 1:2], d[..., 2:3]
    out = out - SH_C1 * y * sh[..., 1, :] + SH_C1 * z * sh[..., 2, :] - SH_C1 * x * sh[..., 3, :]
    if degree == 1:
        return out
    xx, yy, zz, xy, yz, xz = x * x, y * y, z * z, x * y, y * z, x * z
    out = (
        out
        + SH_C2[0] * xy * sh[..., 4, :]
        + SH_C2[1] * yz * sh[..., 5, :]
        + SH_C2[2] * (2 * zz - xx - yy) * sh[..., 6, :]
        + SH_C2[3] * xz * sh[..., 7, :]
        + SH_C2[4] * (xx - yy) * sh[..., 8, :]
    )
    if degree == 2:
        return out
    return (
        out
        + SH_C3[0] * y * (3 * xx - yy) * sh[..., 9, :]
        + SH_C3[1] * xy * z * sh[..., 10, :]
        + SH_C3[2] * y * (4 * zz - xx - yy) * sh[..., 11, :]
        + SH_C3[3] * z * (2 * zz - 3 * xx - 3 * yy) * sh[..., 12, :]
        + SH_C3[4] * x * (4 * zz - xx - yy) * sh[..., 13, :]
        + SH_C3[5] * z * (xx - yy) * sh[..., 14, :]
        + SH_C3[6] * x * (xx - 3 * yy) * sh[..., 15, :]
    )


def sh_colors(degree: int, sh: torch.Tensor, means: torch.Tensor, campos: torch.Tensor) -> torch.Tensor:
    """RGB ``[N, 3]`` seen from ``campos [3]``: ``max(eval_sh + 0.5, 0)`` (gsplat's rule)."""
    return torch.clamp_min(eval_sh(degree, sh, means - campos) + 0.5, 0.0)
