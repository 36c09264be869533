"""Stage-2 losses (paper §3.3): ``L = (1 - lambda_a) L_m + lambda_a L_v``."""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

LOG_PRODUCT_LIMIT = 60.0
"Cap on log|prod alpha| per point (e^60 ~ 1e26): a sum over 10^12 points stays finite in float32."


def magnitude_loss(s_m: torch.Tensor, s_l: torch.Tensor, s_r: torch.Tensor, binaural_mag: torch.Tensor) -> torch.Tensor:
    """``L_m = MSE(s_m) + MSE(s_l) + MSE(s_r)``.

    Predictions [B, F, N_t]; binaural_mag [B, 2, F, N_t] (channel 0 = left). The mixture
    target is the mean of the left and right magnitudes.
    """
    gt_l, gt_r = binaural_mag[:, 0], binaural_mag[:, 1]
    gt_m = 0.5 * (gt_l + gt_r)
    return F.mse_loss(s_m, gt_m) + F.mse_loss(s_l, gt_l) + F.mse_loss(s_r, gt_r)


def log_abs_product(alpha: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(sign, log|prod_d alpha_d|) per row of alpha [M, D], computed in float32 or wider.

    A zero entry gives log|.| = log(tiny) rather than -inf, so gradients stay finite.
    """
    a = alpha.float() if alpha.dtype in (torch.float16, torch.bfloat16) else alpha
    tiny = torch.finfo(a.dtype).tiny
    log_abs = torch.log(a.abs().clamp_min(tiny)).sum(-1)  # [M]
    negatives = (a < 0).sum(-1)  # [M]
    sign = 1.0 - 2.0 * (negatives % 2).to(a.dtype)  # [M] in {-1, 1}
    return sign, log_abs


def volume_loss(alpha: torch.Tensor) -> torch.Tensor:
    """``L_v = sum over points of prod_d alpha_{i,d}`` for the vicinity points alpha [M, D].

    Computed as ``sign * exp(sum log|alpha|)``: a product of 52 numbers under- and
    overflows float32 (and float16 at once), a sum of logs does not. The log-product is
    capped at :data:`LOG_PRODUCT_LIMIT`, so the result is finite for any finite input,
    float16 included (it is returned in float32).
    """
    sign, log_abs = log_abs_product(alpha)
    return (sign * torch.exp(log_abs.clamp(max=LOG_PRODUCT_LIMIT))).sum()


def total_loss(magnitude: torch.Tensor, volume: torch.Tensor, lambda_a: float) -> torch.Tensor:
    """``(1 - lambda_a) L_m + lambda_a L_v``."""
    if not (0.0 <= lambda_a <= 1.0 and math.isfinite(lambda_a)):
        raise ValueError(f"lambda_a must be in [0, 1], got {lambda_a}")
    return (1.0 - lambda_a) * magnitude + lambda_a * volume.to(magnitude.dtype)
