"""Stage-2 losses (paper §3.3): ``L = (1 - lambda_a) L_m + lambda_a L_v``."""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F


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
    """``L_v = sum over points of log(1 + |prod_d alpha_{i,d}|)`` for the vicinity points alpha [M, D].

    The paper writes ``sum_i Prod(alpha_i)``, "encouraging the audio-guidance parameters to
    be small". Two changes make that well posed, and both leave it unchanged where the
    product is small (log(1 + p) = p - p^2/2 + ...), which is where alpha lives:

    - alpha is signed (SH coefficients, quaternions) and a signed product is unbounded
      below: minimising it drives rows with an odd number of negative entries to ever
      larger magnitudes, the opposite of the stated intent. We penalise the magnitude.
    - The gradient of a product of 52 numbers is itself a product of 51: it overflows
      float32 for moderately large alpha and float16 almost at once. ``log(1 + p)`` caps
      the gradient at ``1 / |alpha_d|`` per entry.

    Computed as ``softplus(sum_d log|alpha_d|)``, never forming the product itself, so the
    value and gradient are finite for any finite input, float16 included (the result is
    float32).
    """
    _, log_abs = log_abs_product(alpha)  # [M]
    return torch.nn.functional.softplus(log_abs).sum()


def total_loss(magnitude: torch.Tensor, volume: torch.Tensor, lambda_a: float) -> torch.Tensor:
    """``(1 - lambda_a) L_m + lambda_a L_v``."""
    if not (0.0 <= lambda_a <= 1.0 and math.isfinite(lambda_a)):
        raise ValueError(f"lambda_a must be in [0, 1], got {lambda_a}")
    return (1.0 - lambda_a) * magnitude + lambda_a * volume.to(magnitude.dtype)
