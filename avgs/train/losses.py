"""Stage-2 losses of both tasks (paper §3.3): ``L = (1 - lambda_a) L_m + lambda_a L_v``.

L_m is the task's: the binaural task's MSE of the mixture and ear magnitudes
(:func:`magnitude_loss`), the impulse-response task's MSE of log magnitudes plus its energy and
decay terms (:func:`energy_loss`, :func:`decay_loss`); L_v, the vicinity points' prior, is shared."""

from __future__ import annotations

import math

import torch

from avgs.acoustics.rir_model import silenced_magnitudes
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


# -- the impulse-response task: energy per bin and decay curves -----------------------------


def ear_energy(log_mag: torch.Tensor) -> torch.Tensor:
    """Each ear's energy per frequency bin, as the log of the power summed over the frames: [..., 2, F, N] -> [..., 2, F]."""
    return torch.logsumexp(2.0 * log_mag, dim=-1)


def energy_loss(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """MSE of each ear's :func:`ear_energy` plus MSE of the ears' difference in it (the interaural level difference)."""
    e_pred, e_true = ear_energy(pred), ear_energy(target)  # [B, 2, F]
    ild_pred, ild_true = e_pred[:, 0] - e_pred[:, 1], e_true[:, 0] - e_true[:, 1]  # [B, F]
    return torch.nn.functional.mse_loss(e_pred, e_true) + torch.nn.functional.mse_loss(ild_pred, ild_true)


DECAY_BANDS_HZ = (250.0, 500.0, 1000.0, 2000.0, 4000.0)
"Edges between the octave bands whose energy decay :func:`decay_loss` fits (besides the whole band)."

DECAY_RANGE_DB = 50.0
"The decay loss looks at each curve down to this many dB below its start (T60 reads 5 to 35 dB, EDT 0 to 10)."


def band_masks(n_freq: int, sample_rate: float, edges_hz=DECAY_BANDS_HZ) -> torch.Tensor:
    """[K, F] 0/1 float: the whole band, then one row per octave band between ``edges_hz`` (empty bands dropped)."""
    freqs = torch.linspace(0.0, sample_rate / 2.0, n_freq)  # [F]
    bounds = [0.0, *edges_hz, math.inf]
    rows = [torch.ones(n_freq)] + [((freqs >= lo) & (freqs < hi)).float() for lo, hi in zip(bounds[:-1], bounds[1:])]
    return torch.stack([r for r in rows if r.sum() > 0])


def decay_curves(power: torch.Tensor, bands: torch.Tensor) -> torch.Tensor:
    """Schroeder energy decay curves in nats of power re their start, per ear and band: STFT
    power [..., 2, F, N] -> [..., 2, K, N]; the curve bottoms out ``DECAY_RANGE_DB + 30`` dB down."""
    band_power = torch.einsum("kf,...fn->...kn", bands.to(power), power)  # [..., 2, K, N]
    edc = band_power.flip(-1).cumsum(-1).flip(-1)  # energy from frame n on
    start = edc[..., :1]
    return torch.log(edc + start * 10.0 ** (-(DECAY_RANGE_DB + 30.0) / 10.0) + 1e-30) - torch.log(start + 1e-30)


def decay_loss(pred: torch.Tensor, target: torch.Tensor, bands: torch.Tensor, log_floor: float) -> torch.Tensor:
    """MSE of the energy decay curves (:func:`decay_curves`) of predicted and true log magnitudes
    [B, 2, F, N], over the frames where the true curve is within ``DECAY_RANGE_DB`` of its start.

    The prediction's power is that of the magnitudes a waveform is made of
    (:func:`~avgs.acoustics.rir_model.silenced_magnitudes`: silence at the floor), the truth's
    that of the response with the floor's power taken off: the curves T60, EDT and C50 read."""
    floor_power = math.exp(2.0 * log_floor)
    d_pred = decay_curves(silenced_magnitudes(pred, log_floor).square(), bands)
    d_true = decay_curves((torch.exp(2.0 * target) - floor_power).clamp_min(0.0), bands)
    keep = (d_true > -DECAY_RANGE_DB / 10.0 * math.log(10.0)).float()
    return ((d_pred - d_true).square() * keep).sum() / keep.sum().clamp_min(1.0)
