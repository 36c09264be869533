"""The interaural time difference: when each ear hears the direct sound, from the source's direction.

A listener localises a source first by the interaural time difference (ITD) below about
1.5 kHz (and by the level difference, ILD, above it: :func:`ild_law` at the end). B predicts magnitudes only, so the ears' timing comes from geometry, as binaural
synthesis does in the field (a time warp from the source's direction relative to the head,
then learned amplitudes: Richard et al., ICLR 2021): the spherical head of Woodworth,

    tau = (a / c) (phi + sin phi),      phi = asin(sin theta)  (the lateral angle, in [-pi/2, pi/2])

with theta the signed direction to the source (positive on the listener's left,
:func:`avgs.data.frame.signed_direction`), a the head's radius and c the speed of sound:
``tau > 0`` means the source is on the left and the right ear hears it ``tau`` seconds after
the left. A source behind the head has the ITD of its mirror image in front (the lateral
angle), as a sphere gives. ``a / c`` (the ITD scale, seconds; 255 us for a = 8.75 cm) is the
one number the model learns: :func:`fit_scale` takes it from the ITDs the training
recordings themselves carry (their GCC-PHAT lags against the Woodworth shape), which holds
the recording head's size and the frequency band the cue lives in.

The ears get delays ``(max(0, -tau), max(0, tau))``: the lagging ear is delayed, the leading
one not, so a filter stays causal. In the STFT domain a delay d is the phase ramp
``exp(-i 2 pi f d)`` per bin (:func:`phase_ramp`), exact for a stationary signal and within
a few percent of a window for the sub-millisecond delays here.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from avgs.config import STFTConfig

HEAD_RADIUS = 0.0875
"Metres: the spherical head of Woodworth's formula (an adult's, about KEMAR's)."

SPEED_OF_SOUND = 343.0
"Metres per second."

DEFAULT_SCALE = HEAD_RADIUS / SPEED_OF_SOUND
"Seconds: ``a / c`` of the default head (255 us; the ITD at 90 degrees is 2.57 times it, 656 us)."

FIT_MIN_LATERAL = math.radians(15.0)
"Recordings whose source is within this of the median plane say little about the scale; the fit leaves them out."


def lateral_angle(theta: torch.Tensor) -> torch.Tensor:
    """``asin(sin theta)`` [...]: the angle from the median plane, in [-pi/2, pi/2], positive on the left."""
    return torch.asin(torch.sin(theta).clamp(-1.0, 1.0))


def woodworth_shape(theta: torch.Tensor) -> torch.Tensor:
    """``phi + sin phi`` [...] of the signed direction ``theta`` [...] (radians): the ITD in units of ``a / c``."""
    phi = lateral_angle(theta)
    return phi + torch.sin(phi)


def interaural_delay(theta: torch.Tensor, scale) -> torch.Tensor:
    """``tau`` [...] seconds: the right ear's arrival after the left's (> 0: the source is on the left)."""
    return woodworth_shape(theta) * scale


def ear_delays(theta: torch.Tensor, scale) -> torch.Tensor:
    """Each ear's delay ``[..., 2]`` seconds (left, right) for directions ``theta`` [...]: the lagging ear by |tau|."""
    return lagging_ear(interaural_delay(theta, scale))


def lagging_ear(tau: torch.Tensor) -> torch.Tensor:
    """Each ear's delay ``[..., 2]`` seconds (left, right) for ITDs ``tau`` [...] (> 0: the right ear later)."""
    return torch.stack([(-tau).clamp_min(0.0), tau.clamp_min(0.0)], dim=-1)


def phase_ramp(delays: torch.Tensor, stft: STFTConfig, dtype: torch.dtype = torch.complex64) -> torch.Tensor:
    """``exp(-i 2 pi f d)`` ``[..., 2, F]`` for ear delays ``delays`` [..., 2] (seconds) at the STFT's bin frequencies."""
    real = torch.float64 if dtype == torch.complex128 else torch.float32
    freqs = torch.linspace(0.0, stft.sample_rate / 2.0, stft.n_freq, dtype=torch.float64, device=delays.device)  # [F]
    angle = (-2.0 * math.pi) * delays.double()[..., None] * freqs  # [..., 2, F]
    return torch.polar(torch.ones_like(angle, dtype=real), angle.to(real))


def fit_scale(theta, itd, default: float = DEFAULT_SCALE) -> float:
    """The ITD scale ``a / c`` (seconds) that fits measured ITDs to Woodworth's shape.

    ``theta`` [M]: each recording's signed direction (radians); ``itd`` [M]: its measured ITD
    in seconds in the metric's sign (negative when the left ear leads:
    :func:`avgs.evaluation.spatial.itd`), so ``tau = -itd``. Least squares through the
    origin over the recordings at least :data:`FIT_MIN_LATERAL` off the median plane whose
    measured ITD has the sign of their side (a lag that reverberation won is left out);
    ``default`` when fewer than three remain or the fit is not positive.
    """
    shape = woodworth_shape(torch.as_tensor(np.asarray(theta, dtype=np.float64))).numpy()  # [M]
    tau = -np.asarray(itd, dtype=np.float64)
    keep = (np.abs(np.arcsin(np.clip(np.sin(np.asarray(theta, dtype=np.float64)), -1, 1))) >= FIT_MIN_LATERAL) \
        & (np.sign(tau) == np.sign(shape)) & np.isfinite(tau)
    if keep.sum() < 3:
        return float(default)
    s, t = shape[keep], tau[keep]
    scale = float(np.dot(s, t) / np.dot(s, s))
    return scale if math.isfinite(scale) and scale > 0 else float(default)


def sine_series(theta: torch.Tensor, coefficients: torch.Tensor) -> torch.Tensor:
    """``sum_k c_k sin(k theta)`` [...] of directions ``theta [...]`` (radians), k = 1..K for
    ``coefficients [K]``: the form of the direct sound's laws (:func:`itd_law`, :func:`ild_law`)."""
    k = torch.arange(1, coefficients.shape[-1] + 1, dtype=theta.dtype, device=theta.device)  # [K]
    return (torch.sin(theta[..., None] * k) * coefficients.to(theta)).sum(-1)


def fit_linear(basis: np.ndarray, values: np.ndarray, least: int, robust: bool = False) -> np.ndarray | None:
    """Least-squares coefficients ``[K]`` of ``basis [M, K] @ coef = values [M]`` over the rows where both are
    finite; None with fewer than ``least`` such rows or a fit that is not finite. ``robust``: fitted again
    without the rows more than three median absolute deviations off the first fit (if ``least`` remain).
    The fit of every law of the direct sound (:func:`fit_sine_series`, :func:`fit_direct_level`)."""
    keep = np.all(np.isfinite(basis), axis=-1) & np.isfinite(values)
    if keep.sum() < least:
        return None
    basis, values = basis[keep], values[keep]
    coef, *_ = np.linalg.lstsq(basis, values, rcond=None)
    if robust:
        residual = np.abs(values - basis @ coef)
        inliers = residual <= 3.0 * max(np.median(residual), 1e-6)
        if inliers.sum() >= least:
            coef, *_ = np.linalg.lstsq(basis[inliers], values[inliers], rcond=None)
    return coef if np.all(np.isfinite(coef)) else None


def fit_sine_series(theta, values, harmonics: int, least: int, robust: bool = False) -> np.ndarray | None:
    """Least-squares coefficients ``[harmonics]`` of :func:`sine_series` for ``values [M]`` measured at
    ``theta [M]`` (:func:`fit_linear`: finite pairs only, at least ``least``, ``robust`` as there)."""
    theta = np.asarray(theta, dtype=np.float64).reshape(-1)
    values = np.asarray(values, dtype=np.float64).reshape(-1)
    return fit_linear(np.sin(theta[:, None] * np.arange(1, harmonics + 1)), values, least, robust)  # basis [M, K]


ITD_HARMONICS = 3
"Sine harmonics of the direction in the direct sound's ITD law (:func:`itd_law`)."


def itd_law(theta: torch.Tensor, coefficients: torch.Tensor) -> torch.Tensor:
    """The direct sound's ITD ``tau [...]`` seconds (> 0: the source is on the left, the right ear later)
    of directions ``theta [...]`` (radians): ``sum_k c_k sin(k theta)``, k = 1..K for ``coefficients [K]``
    seconds; the same form as :func:`ild_law`.

    Woodworth's sphere has one free number and a fixed shape; a measured head (KEMAR) has its own
    shape, and its ears sit behind the head's centre (front and back differ: the even harmonics).
    Three harmonics follow it closer: fitted to the early ITDs of the training responses in sight
    of the source (:func:`fit_itd_law`; two rooms: 43 / 26 us from the measured ITDs against 57 /
    49 us for the fitted sphere, val / held out)."""
    return sine_series(theta, coefficients)


def fit_itd_law(theta, tau, harmonics: int = ITD_HARMONICS) -> np.ndarray | None:
    """Coefficients ``[harmonics]`` (seconds) of :func:`itd_law` for measured ITDs ``tau [M]`` (seconds,
    > 0 when the right ear lags) at directions ``theta [M]``; None with fewer than ``8 * harmonics``
    finite measurements or a fit that is not finite (Woodworth's head is then kept).

    Least squares, then again without the measurements more than three median absolute deviations
    off the first fit: an early reflection that won the first milliseconds' cross-correlation is
    not the head's ITD."""
    return fit_sine_series(theta, tau, harmonics, least=8 * harmonics, robust=True)


ILD_HARMONICS = 3
"Sine harmonics of the direction in the direct sound's ILD law (:func:`ild_law`)."


def ild_law(theta: torch.Tensor, coefficients: torch.Tensor) -> torch.Tensor:
    """The direct sound's early ILD ``[...]`` dB (left over right, as
    :func:`avgs.evaluation.spatial.early_ild`) of directions ``theta [...]`` (radians, positive on the
    left): ``sum_k c_k sin(k theta)``, k = 1..K for ``coefficients [K]``.

    Odd in theta (a source mirrored left to right swaps the ears), with even harmonics for the
    front-back asymmetry of a head with ears behind its centre. The head shadow is a matter of
    the head, not of the room: the law is fitted to the training responses (:func:`fit_ild_law`).
    """
    return sine_series(theta, coefficients)


def fit_ild_law(theta, ild_db, harmonics: int = ILD_HARMONICS) -> np.ndarray | None:
    """Least-squares coefficients ``[harmonics]`` (dB) of :func:`ild_law` for measured early ILDs
    ``ild_db [M]`` at directions ``theta [M]`` (radians); None with fewer than ``4 * harmonics``
    finite measurements or a fit that is not finite (the law is then not used)."""
    return fit_sine_series(theta, ild_db, harmonics, least=4 * harmonics)


LOCAL_NEIGHBOURS = 3
"Training responses whose early ILD, off the law, corrects it at a pose (:func:`local_correction`)."


def local_features(listener: torch.Tensor, source: torch.Tensor, theta: torch.Tensor) -> torch.Tensor:
    """Where a pose is, for the early ILD's local correction: ``[B, 6]`` of the listener's and the source's
    floor-plan position (x, y of ``listener, source [B, 3]``, any one unit) and the direction's cos and sin
    (``theta [B]`` radians)."""
    return torch.cat([listener[:, :2], source[:, :2], torch.cos(theta)[:, None], torch.sin(theta)[:, None]], dim=-1)


def fit_local_scale(features: torch.Tensor) -> torch.Tensor:
    """Each column's spread ``[D]`` (standard deviation, at least 1e-3) of training ``features [M, D]``:
    :func:`local_correction` measures nearness in these units."""
    return features.std(dim=0).clamp_min(1e-3) if features.shape[0] > 1 else torch.ones(features.shape[-1], dtype=features.dtype)


def local_correction(features: torch.Tensor, at: torch.Tensor, values: torch.Tensor,
                     k: int = LOCAL_NEIGHBOURS) -> torch.Tensor:
    """``[B]``: the mean of ``values [M]`` at the ``k`` entries of ``at [M, D]`` nearest each of ``features
    [B, D]`` (both already divided by :func:`fit_local_scale`), weighted by inverse distance.

    The early ILD's law of the direction (:func:`ild_law`) leaves what the room adds in the first
    5 ms: the floor's and the near walls' reflections, whose directions and delays change with where
    the listener and the source are. Fitted and scored on the simulator's own responses in sight of
    the source, the law alone is 1.3-2.7 dB off (six presets); the law plus the training responses'
    residuals near a pose, 0.9-2.1 dB (held-out sources). The residual is the room's, so it is read
    where the room was measured: near the training poses."""
    if at.shape[0] == 0:
        return torch.zeros(features.shape[0], dtype=features.dtype, device=features.device)
    k = min(int(k), at.shape[0])
    distance, index = torch.cdist(features, at.to(features)).topk(k, dim=-1, largest=False)  # [B, k]
    weight = 1.0 / (distance + 1e-6)
    return (values.to(features)[index] * weight).sum(-1) / weight.sum(-1)


def direct_level_db(theta: torch.Tensor, distance: torch.Tensor, coefficients: torch.Tensor) -> torch.Tensor:
    """The direct sound's energy ``[...]`` in dB (both ears, over its first milliseconds: what
    :func:`avgs.acoustics.direct_placement.sharpen_direct_sound` makes an impulse of) at directions ``theta``
    (radians) and distances ``distance`` (> 0, the unit the law was fitted in): ``c0 + c1 cos theta +
    c2 cos 2 theta - 20 log10 distance`` for ``coefficients [3]``.

    A point source's direct sound falls as 1 / d^2 wherever it is heard (the simulator's responses in
    sight of the source: ``E d^2`` within 2.1-2.8 dB of each other across six presets); the head adds a
    gain that depends on the direction (front and back, the sides), even in theta. Near the source,
    where the direct sound carries most of the response, this is what the level follows; a network of
    the distance extrapolates there (docs/rir_level_distance.md)."""
    coefficients = coefficients.to(theta)
    shape = coefficients[0] + coefficients[1] * torch.cos(theta) + coefficients[2] * torch.cos(2.0 * theta)
    return shape - 20.0 * torch.log10(distance.to(theta).clamp_min(1e-6))


def fit_direct_level(theta, distance, energy) -> np.ndarray | None:
    """Least-squares coefficients ``[3]`` of :func:`direct_level_db` for measured direct-sound energies
    ``energy [M]`` (linear) at directions ``theta [M]`` and distances ``distance [M]``; None with fewer
    than 12 finite positive measurements or a fit that is not finite."""
    theta = np.asarray(theta, dtype=np.float64).reshape(-1)
    distance = np.asarray(distance, dtype=np.float64).reshape(-1)
    energy = np.asarray(energy, dtype=np.float64).reshape(-1)
    basis = np.stack([np.ones_like(theta), np.cos(theta), np.cos(2.0 * theta)], axis=-1)  # [M, 3]
    with np.errstate(divide="ignore", invalid="ignore"):  # an energy or distance <= 0: not finite, left out
        db = 10.0 * np.log10(energy) + 20.0 * np.log10(distance)  # [M]
    return fit_linear(basis, db, least=12)
