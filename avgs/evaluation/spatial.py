"""Spatial cues: what a listener localises by (docs/design.md, "Spatial cues").

Binaural audio is ``[2, T]``, channel 0 the LEFT ear; times are in seconds unless a name
says otherwise.

- :func:`itd`: interaural time difference by GCC-PHAT. The cross-spectrum
  ``L(f) conj(R(f))`` of the two ears, divided by its magnitude, is zeroed outside
  :data:`ITD_BAND_HZ` (0.2-1.5 kHz); the FFT length is the next power of two at or above
  twice the signal's length (a linear, not circular, correlation). The lag of the inverse
  transform's peak, searched within +-:data:`ITD_MAX_S` (1 ms), is refined by a parabola
  through the peak and its two neighbours; the result is clipped to +-1 ms. Sign: the
  correlation is ``c(tau) = sum_n l[n + tau] r[n]``, so the ITD is ``t_left - t_right``:
  NEGATIVE when the left ear leads (the right ear a copy of the left delayed by k
  samples gives ``-k / fs``).
- :func:`onset`: the first sample where ``max(|l|, |r|)`` reaches :data:`ONSET_FRACTION`
  (0.1, -20 dB) of its peak.
- :func:`early`: both ears from the onset for :data:`EARLY_S` (5 ms, ``round(0.005 fs)``
  samples), zero-padded where the response ends sooner. :func:`response_itd` is the
  :func:`itd` of that segment; :func:`early_ild` is ``10 log10(E_left / E_right)`` of it.
- :func:`lateralisation`: among the items whose true ``|ITD| >= 150 us``
  (:data:`LAT_TRUE_MIN_S`), the percentage whose predicted ITD has the same sign and
  ``|ITD_pred| >= 50 us`` (:data:`LAT_PRED_MIN_S`), both thresholds met to float rounding
  (:data:`THRESHOLD_RTOL`); ``None`` when no item is eligible.

Degenerate inputs never raise and never warn (only a wrong shape raises); the values:

- :func:`itd`: 0 s for an all-zero input, a silent channel, a cross-spectrum that is zero
  throughout the band, a signal shorter than 2 samples, or any NaN / Inf. Bins whose
  cross-spectrum magnitude is zero (at most :data:`PHAT_GUARD` of the band's largest,
  i.e. rounding) are set to zero rather than divided.
- :func:`onset`: the response's length ``L`` (the sound never arrives) for an all-zero or
  non-finite response; its early segment is then all zero (ITD 0 s, ILD 0 dB).
- :func:`early_ild`: 0 dB when both ears are silent, +-:data:`ILD_LIMIT_DB` (60 dB) when
  one is; values clipped to +-60 dB; 0 dB for a non-finite response.
- Errors (:func:`clip_itd_error_us`, :func:`response_errors`): when the prediction or the
  truth holds a NaN or Inf, the worst case: :data:`ITD_ERROR_LIMIT_US` (2000 us, two
  ITDs at opposite ends of +-1 ms), ``2 x ILD_LIMIT_DB`` (120 dB), and the response's
  length in ms for the onset. A non-finite prediction's ITD (0 s) never agrees in
  :func:`lateralisation`; a non-finite value passed to it counts as 0 s.
"""

from __future__ import annotations

import math
from collections.abc import Iterable

import numpy as np
import torch

from avgs.config import STFT
from avgs.evaluation.metrics import ILD_LIMIT_DB

ITD_BAND_HZ = (200.0, 1500.0)
"The band of the GCC-PHAT cross-spectrum kept for the ITD, Hz (the fine-structure ITD band)."
ITD_MAX_S = 1e-3
"ITDs are searched within, and clipped to, +-this many seconds."
PHAT_GUARD = 1e-12
"Cross-spectrum bins at or below this fraction of the band's largest count as zero magnitude."
ONSET_FRACTION = 0.1
"A response's onset: the first sample where max(|l|, |r|) reaches this fraction of its peak (-20 dB)."
EARLY_S = 5e-3
"The early segment after the onset over which a response's ITD and ILD are measured, s."
LAT_TRUE_MIN_S = 150e-6
"Lateralisation agreement: an item is eligible when its true |ITD| is at least this."
LAT_PRED_MIN_S = 50e-6
"Lateralisation agreement: a prediction agrees when its ITD has the true sign and |ITD| at least this."
THRESHOLD_RTOL = 1e-9
"The lateralisation thresholds are met to float rounding (``50 * 1e-6`` is just below ``50e-6``)."
ITD_ERROR_LIMIT_US = 2.0 * ITD_MAX_S * 1e6
"The ITD error (us) counted when the prediction or the truth is not finite: the largest possible."
ILD_ERROR_LIMIT_DB = 2.0 * ILD_LIMIT_DB
"The early-ILD error (dB) counted when the prediction or the truth is not finite."
RESPONSE_METRICS = ("onset_ms", "itd_us", "ild_db")
"The per-response spatial errors of :func:`response_errors`."


def _numpy(x) -> np.ndarray:
    if isinstance(x, torch.Tensor):
        x = x.detach().cpu().numpy()
    return np.asarray(x, dtype=np.float64)


def _binaural(x, what: str) -> np.ndarray:
    x = _numpy(x)
    if x.ndim != 2 or x.shape[0] != 2:
        raise ValueError(f"{what}: expected a binaural signal [2, T], got {x.shape}")
    return x


def _finite(x: np.ndarray) -> bool:
    return bool(np.all(np.isfinite(x)))


def itd(x, fs: float = STFT.sample_rate) -> float:
    """ITD in seconds of binaural ``x [2, T]`` by GCC-PHAT over the whole signal (module docstring)."""
    x = _binaural(x, "ITD")
    n = x.shape[-1]
    if n < 2 or not _finite(x):
        return 0.0
    peak = np.max(np.abs(x), axis=-1, keepdims=True)  # [2, 1]
    if np.any(peak == 0.0):
        return 0.0  # a silent ear: no time difference to measure
    x = x / peak  # scale is irrelevant to PHAT; this keeps the products far from overflow
    nfft = 1 << int(math.ceil(math.log2(2 * n)))
    spec = np.fft.rfft(x, nfft, axis=-1)  # [2, F]
    cross = spec[0] * np.conj(spec[1])
    freqs = np.fft.rfftfreq(nfft, 1.0 / fs)
    band = (freqs >= ITD_BAND_HZ[0]) & (freqs <= ITD_BAND_HZ[1])
    magnitude = np.abs(cross)
    largest = float(np.max(magnitude[band])) if band.any() else 0.0
    if largest == 0.0:
        return 0.0
    keep = band & (magnitude > PHAT_GUARD * largest)
    weighted = np.zeros_like(cross)
    weighted[keep] = cross[keep] / magnitude[keep]
    corr = np.fft.irfft(weighted, nfft)  # corr[tau] = sum_n l[n + tau] r[n]; negative lags wrap
    max_lag = min(int(math.floor(ITD_MAX_S * fs)), n - 1)
    lags = np.arange(-max_lag, max_lag + 1)
    lag = int(lags[int(np.argmax(corr[lags % nfft]))])
    y_minus, y_0, y_plus = corr[(lag - 1) % nfft], corr[lag % nfft], corr[(lag + 1) % nfft]
    curvature = y_minus - 2.0 * y_0 + y_plus
    delta = 0.5 * (y_minus - y_plus) / curvature if curvature < 0.0 else 0.0
    delta = min(max(delta, -0.5), 0.5)
    return float(np.clip((lag + delta) / fs, -ITD_MAX_S, ITD_MAX_S))


IN_SIGHT_S = 1e-3
"A response whose onset is at most this after distance / c has the direct sound first: it is in sight of the source."


def in_sight(onset_s, distance, speed: float) -> np.ndarray:
    """Whether each response's first arrival is the direct sound, ``[N]`` bool: its onset ``onset_s [N]``
    (seconds, :func:`onset` / fs) at most :data:`IN_SIGHT_S` after ``distance [N] / speed`` (one unit).
    Later, the first arrival has passed around a wall (a simulator without diffraction or
    transmission: a reflection through a door)."""
    return np.asarray(onset_s, dtype=np.float64) - np.asarray(distance, dtype=np.float64) / float(speed) <= IN_SIGHT_S


def onset(h) -> int:
    """Onset sample of a binaural response ``h [2, L]`` (module docstring); ``L`` when it has none."""
    h = _binaural(h, "onset")
    length = h.shape[-1]
    if length == 0 or not _finite(h):
        return length
    level = np.max(np.abs(h), axis=0)  # [L]
    peak = float(np.max(level))
    if peak == 0.0:
        return length
    return int(np.argmax(level >= ONSET_FRACTION * peak))


def early_samples(fs: float = STFT.sample_rate) -> int:
    """The early segment's length in samples, ``round(EARLY_S * fs)`` (110 at 22050 Hz)."""
    return max(1, int(round(EARLY_S * fs)))


def early(h, fs: float = STFT.sample_rate) -> np.ndarray:
    """``[2, early_samples(fs)]``: both ears from the onset on, zero-padded past the response's end."""
    h = _binaural(h, "early")
    n = early_samples(fs)
    out = np.zeros((2, n))
    if not _finite(h):
        return out
    start = onset(h)
    segment = h[:, start : start + n]
    out[:, : segment.shape[-1]] = segment
    return out


def response_itd(h, fs: float = STFT.sample_rate) -> float:
    """The direct sound's ITD in seconds: :func:`itd` of the 5 ms after the onset."""
    return itd(early(h, fs), fs)


def early_ild(h, fs: float = STFT.sample_rate) -> float:
    """``10 log10(E_left / E_right)`` dB over the 5 ms after the onset; positive = left louder."""
    segment = early(h, fs)
    scale = float(np.max(np.abs(segment)))
    if scale == 0.0:
        return 0.0
    energy = np.sum((segment / scale) ** 2, axis=-1)  # [2]; scaled: no overflow
    if energy[0] == 0.0 or energy[1] == 0.0:
        return ILD_LIMIT_DB if energy[0] > 0.0 else -ILD_LIMIT_DB
    return float(np.clip(10.0 * math.log10(energy[0] / energy[1]), -ILD_LIMIT_DB, ILD_LIMIT_DB))


def clip_itds(pred, gt, fs: float = STFT.sample_rate) -> tuple[float, float, float]:
    """``(ITD_pred s, ITD_true s, |ITD_pred - ITD_true| us)`` of one clip, each over the whole clip;
    the error is :data:`ITD_ERROR_LIMIT_US` when either clip is not finite."""
    p, g = _binaural(pred, "ITD"), _binaural(gt, "ITD")
    t_pred, t_true = itd(p, fs), itd(g, fs)
    if not (_finite(p) and _finite(g)):
        return t_pred, t_true, ITD_ERROR_LIMIT_US
    return t_pred, t_true, abs(t_pred - t_true) * 1e6


def clip_itd_error_us(pred, gt, fs: float = STFT.sample_rate) -> float:
    """``|ITD_pred - ITD_true|`` in microseconds of one binaural clip (see :func:`clip_itds`)."""
    return clip_itds(pred, gt, fs)[2]


def response_errors(pred, gt, fs: float = STFT.sample_rate) -> dict[str, float]:
    """The spatial errors of one binaural response ``[2, L]``: ``onset_ms`` (``|onset_pred -
    onset_true|`` ms), ``itd_us`` (``|ITD_pred - ITD_true|`` of the direct sound, us) and
    ``ild_db`` (``|ILD_pred - ILD_true|`` of the early 5 ms, dB); the worst case for a
    non-finite prediction or truth (module docstring)."""
    p, g = _binaural(pred, "spatial errors"), _binaural(gt, "spatial errors")
    if p.shape != g.shape:
        raise ValueError(f"spatial errors: prediction {p.shape} and ground truth {g.shape} must have the same shape")
    if not (_finite(p) and _finite(g)):
        return {"onset_ms": 1000.0 * p.shape[-1] / fs, "itd_us": ITD_ERROR_LIMIT_US, "ild_db": ILD_ERROR_LIMIT_DB}
    return {
        "onset_ms": 1000.0 * abs(onset(p) - onset(g)) / fs,
        "itd_us": 1e6 * abs(response_itd(p, fs) - response_itd(g, fs)),
        "ild_db": abs(early_ild(p, fs) - early_ild(g, fs)),
    }


def lateralisation(true_itds: Iterable[float], pred_itds: Iterable[float]) -> float | None:
    """Lateralisation agreement in percent (module docstring): of the items with a true
    ``|ITD| >= 150 us``, the share whose predicted ITD has the same sign and is at least
    50 us; ``None`` when none is eligible (the JSON's ``null``, the table's ``n/a``)."""
    true = np.nan_to_num(np.asarray(list(true_itds), dtype=np.float64), nan=0.0, posinf=0.0, neginf=0.0)
    pred = np.nan_to_num(np.asarray(list(pred_itds), dtype=np.float64), nan=0.0, posinf=0.0, neginf=0.0)
    if true.shape != pred.shape:
        raise ValueError(f"lateralisation: {true.size} true and {pred.size} predicted ITDs")
    eligible = np.abs(true) >= LAT_TRUE_MIN_S * (1.0 - THRESHOLD_RTOL)
    if not eligible.any():
        return None
    agree = (np.sign(pred) == np.sign(true)) & (np.abs(pred) >= LAT_PRED_MIN_S * (1.0 - THRESHOLD_RTOL))
    return float(100.0 * np.count_nonzero(agree & eligible) / np.count_nonzero(eligible))


def median(values: Iterable[float]) -> float | None:
    """The median of per-item errors (the issue's targets are medians); ``None`` when empty."""
    values = [float(v) for v in values]
    return float(np.median(values)) if values else None
