"""Differentiable SSIM with an 11 x 11 Gaussian window (sigma 1.5), as 3D-GS computes it
(zero padding, so the output has the input's size; constants for images in [0, 1])."""

from __future__ import annotations

import functools

import torch
import torch.nn.functional as F

C1 = 0.01**2
C2 = 0.03**2


@functools.lru_cache(maxsize=8)
def _window(size: int, sigma: float, channels: int, dtype: torch.dtype, device: str) -> torch.Tensor:
    x = torch.arange(size, dtype=torch.float64) - (size - 1) / 2
    g = torch.exp(-(x**2) / (2 * sigma**2))
    g = g / g.sum()
    w = (g[:, None] * g[None, :]).to(dtype=dtype, device=device)  # [size, size]
    return w.expand(channels, 1, size, size).contiguous()  # [C, 1, size, size]


def ssim(img1: torch.Tensor, img2: torch.Tensor, window_size: int = 11, sigma: float = 1.5, reduce: bool = True) -> torch.Tensor:
    """SSIM of two images ``[H, W, C]`` or ``[B, H, W, C]`` (channels last, values in [0, 1]).

    Returns the mean SSIM (a scalar) or, with ``reduce=False``, the SSIM map ``[B, C, H, W]``.
    """
    if img1.shape != img2.shape:
        raise ValueError(f"ssim: images differ in shape, {list(img1.shape)} vs {list(img2.shape)}")
    if img1.dim() == 3:
        img1, img2 = img1[None], img2[None]
    if img1.dim() != 4:
        raise ValueError(f"ssim: expected [H, W, C] or [B, H, W, C], got {list(img1.shape)}")
    x = img1.permute(0, 3, 1, 2)  # [B, C, H, W]
    y = img2.permute(0, 3, 1, 2)
    c = x.shape[1]
    w = _window(window_size, sigma, c, x.dtype, str(x.device))
    pad = window_size // 2
    mu_x = F.conv2d(x, w, padding=pad, groups=c)
    mu_y = F.conv2d(y, w, padding=pad, groups=c)
    xx = F.conv2d(x * x, w, padding=pad, groups=c) - mu_x * mu_x
    yy = F.conv2d(y * y, w, padding=pad, groups=c) - mu_y * mu_y
    xy = F.conv2d(x * y, w, padding=pad, groups=c) - mu_x * mu_y
    s = ((2 * mu_x * mu_y + C1) * (2 * xy + C2)) / ((mu_x * mu_x + mu_y * mu_y + C1) * (xx + yy + C2))
    return s.mean() if reduce else s
