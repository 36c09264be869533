"""Evaluation metrics with the exact conventions of the anchors (docs/design.md, "Metrics and baselines").

Binaural quality (RWAVS, AV-NeRF):

- :func:`mag` : ``2 * mean over [2, F, N] of (|S_pred| - |S_gt|)^2`` on the STFT
  magnitudes of :mod:`avgs.dsp` (the sum of the two channels' MSE), ``S_pred`` the STFT
  of the predicted waveform: what a listener hears.
- :func:`mag_spectrogram` : the same distance with ``|S_pred|`` the magnitudes a model
  predicted before it made a waveform of them. AV-NeRF's evaluation scores these
  (its ``Evaluator.update(mag_prd, ...)``). Magnitudes with the source's phase are rarely
  a consistent STFT, so the waveform's own magnitudes differ from them; for a method
  that scales the source's STFT (the baselines, the paper's masks) the two agree.
- :func:`env` : ``sum over channels of RMSE(|hilbert(gt_c)|, |hilbert(pred_c)|)``.
- :func:`ild_error` (ours, not an anchor's): ``|ILD_pred - ILD_gt|`` in dB, the
  interaural level difference of the whole clip above 1.5 kHz, where level is the
  lateral cue (duplex theory). MAG scores both ears' spectra together; this isolates
  whether the sound comes from the right side.

Room acoustics (SoundSpaces / NAF conventions, on impulse responses):

- :func:`t60_error` : ``|pred - gt| / |gt| * 100`` per channel with
  ``pyroomacoustics.experimental.measure_rt60(decay_db=30)``; a failed measurement of
  either counts as 100 %.
- :func:`c50_error` : ``|C50_pred - C50_gt|`` dB, C50 split at ``int(0.05 fs + 1)``.
- :func:`edt_error` : ``|EDT_pred - EDT_gt|`` s, EDT = 6 x the time the Schroeder curve
  takes to fall 10 dB.

Inputs are numpy arrays or torch tensors, ``[..., T]``; leading axes are channels (and
clips): errors are averaged over them, except MAG and ENV which follow the conventions
above for ``[2, T]`` and average over any further leading axes (clips).

Degenerate inputs never raise and never warn; the values they give are:

- MAG / ENV with NaN or Inf in either input: ``inf`` (the worst score).
- :func:`rt60`: ``None`` (failed) for an all-zero, non-finite or too short response,
  or one whose Schroeder curve never falls 5 dB; a failure counts as 100 % T60 error.
- :func:`c50`: ``+C50_LIMIT_DB`` when there is no late energy, ``-C50_LIMIT_DB`` when
  there is no early energy, 0 dB for an all-zero response; results are clipped to
  ``[-C50_LIMIT_DB, C50_LIMIT_DB]``. Non-finite input: 0 dB.
- :func:`edt`: 0 s for an all-zero or non-finite response; a response that ends
  before its curve falls 10 dB is taken to fall at its last non-zero sample (the
  energy is gone after it), so EDT = 6 x its duration up to that sample.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import torch

from avgs import dsp
from avgs.config import STFT, STFTConfig

C50_LIMIT_DB = 100.0
"C50 values are clipped to +-this many dB (a response with no late or no early energy)."
ILD_MIN_HZ = 1500.0
"Lower edge of the band in which :func:`ild` compares the ears (duplex theory: level is the lateral cue above ~1.5 kHz)."
ILD_LIMIT_DB = 60.0
"ILDs are clipped to +-this many dB (one ear silent)."
FAILED_T60_ERROR = 100.0
"T60 error in percent counted when either response's RT60 cannot be measured."


def _numpy(x) -> np.ndarray:
    if isinstance(x, torch.Tensor):
        x = x.detach().cpu().numpy()
    return np.ascontiguousarray(x, dtype=np.float64)  # torch.from_numpy needs positive strides


def _check_binaural(x: np.ndarray, name: str) -> None:
    if x.ndim < 2 or x.shape[-2] != 2 or x.shape[-1] == 0:
        raise ValueError(f"{name}: expected binaural waveforms [..., 2, T] with T >= 1, got {x.shape}")


def _check_pair(pred: np.ndarray, gt: np.ndarray, name: str) -> None:
    if pred.shape != gt.shape:
        raise ValueError(f"{name}: prediction {pred.shape} and ground truth {gt.shape} must have the same shape")
    _check_binaural(pred, name)


def mag(pred, gt, stft: STFTConfig = STFT) -> float:
    """Magnitude-spectrogram distance of binaural ``pred``, ``gt`` ``[..., 2, T]``.

    ``2 * mean((|S_pred| - |S_gt|)^2)`` over channels, frequencies and frames (and clips).
    """
    p, g = _numpy(pred), _numpy(gt)
    _check_pair(p, g, "MAG")
    if not (np.all(np.isfinite(p)) and np.all(np.isfinite(g))):
        return math.inf
    p_mag = dsp.magnitude(torch.from_numpy(p), stft)  # [..., 2, F, N]
    g_mag = dsp.magnitude(torch.from_numpy(g), stft)
    return float(2.0 * torch.mean((p_mag - g_mag) ** 2))


def mag_spectrogram(pred_mag, gt, stft: STFTConfig = STFT) -> float:
    """MAG of predicted magnitudes ``pred_mag [..., 2, F, N]`` against binaural ``gt [..., 2, T]``.

    ``2 * mean((pred_mag - |S_gt|)^2)``, ``|S_gt|`` the STFT magnitudes of ``gt``; its
    frames and bins must match ``pred_mag``'s.
    """
    p, g = _numpy(pred_mag), _numpy(gt)
    _check_binaural(g, "MAG")
    g_mag = dsp.magnitude(torch.from_numpy(g), stft).numpy()  # [..., 2, F, N]
    if p.shape != g_mag.shape:
        raise ValueError(f"MAG: predicted magnitudes {p.shape} do not match the ground truth's STFT {g_mag.shape}")
    if not (np.all(np.isfinite(p)) and np.all(np.isfinite(g))):
        return math.inf
    return float(2.0 * np.mean((p - g_mag) ** 2))


def envelope(x) -> np.ndarray:
    """Hilbert amplitude envelope ``|hilbert(x)|`` along the last axis, ``[..., T]``."""
    from scipy.signal import hilbert  # here: scipy.signal takes a second to import (the explorer needs no ENV)

    return np.abs(hilbert(_numpy(x), axis=-1))


def env(pred, gt) -> float:
    """Envelope distance of binaural ``pred``, ``gt`` ``[..., 2, T]``.

    Sum over the two channels of the RMSE between Hilbert envelopes (mean over clips).
    """
    p, g = _numpy(pred), _numpy(gt)
    _check_pair(p, g, "ENV")
    if not (np.all(np.isfinite(p)) and np.all(np.isfinite(g))):
        return math.inf
    rmse = np.sqrt(np.mean((envelope(g) - envelope(p)) ** 2, axis=-1))  # [..., 2]
    return float(np.mean(np.sum(rmse, axis=-1)))


def ild(x, stft: STFTConfig = STFT) -> np.ndarray:
    """Interaural level difference in dB of binaural ``x [..., 2, T]`` -> ``[...]``.

    ``10 log10(E_left / E_right)``, each ear's energy summed over the STFT bins at or
    above :data:`ILD_MIN_HZ` and over all frames; positive = left louder. Clipped to
    +-:data:`ILD_LIMIT_DB`; 0 dB when both ears are silent.
    """
    x = _numpy(x)
    _check_binaural(x, "ILD")
    m = dsp.magnitude(torch.from_numpy(x), stft).numpy()  # [..., 2, F, N]
    first = int(math.ceil(ILD_MIN_HZ * stft.n_fft / stft.sample_rate))
    e = np.sum(m[..., first:, :] ** 2, axis=(-2, -1))  # [..., 2]
    tiny = np.finfo(np.float64).tiny
    db = 10.0 * (np.log10(e[..., 0] + tiny) - np.log10(e[..., 1] + tiny))
    return np.clip(db, -ILD_LIMIT_DB, ILD_LIMIT_DB)


def ild_error(pred, gt, stft: STFTConfig = STFT) -> float:
    """``|ILD_pred - ILD_gt|`` in dB of binaural ``pred``, ``gt`` ``[..., 2, T]`` (mean over clips)."""
    p, g = _numpy(pred), _numpy(gt)
    _check_pair(p, g, "ILD")
    if not (np.all(np.isfinite(p)) and np.all(np.isfinite(g))):
        return math.inf
    return float(np.mean(np.abs(ild(p, stft) - ild(g, stft))))


# -- room-acoustic parameters of one impulse response ---------------------------------


def schroeder_db(h) -> np.ndarray | None:
    """Schroeder backward-integrated energy curve of ``h [T]`` in dB re its start.

    Trailing all-zero samples are dropped; ``None`` for an all-zero or non-finite ``h``.
    """
    h = _numpy(h).reshape(-1)
    if h.size == 0 or not np.all(np.isfinite(h)):
        return None
    energy = np.cumsum((h**2)[::-1])[::-1]  # [T]
    nonzero = np.nonzero(energy > 0)[0]
    if nonzero.size == 0:
        return None
    energy = energy[: nonzero[-1] + 1]
    return 10.0 * np.log10(energy / energy[0])


def rt60(h, fs: float = STFT.sample_rate, decay_db: float = 30.0) -> float | None:
    """RT60 in seconds of ``h [T]`` by ``pyroomacoustics.experimental.measure_rt60``.

    ``None`` when it cannot be measured (see the module docstring).
    """
    from pyroomacoustics.experimental import measure_rt60  # heavy import, only here

    curve = schroeder_db(h)
    if curve is None or curve.size < 3 or curve[-1] > -5.0:
        return None
    with warnings.catch_warnings(), np.errstate(all="ignore"):
        warnings.simplefilter("ignore")
        try:
            value = float(measure_rt60(_numpy(h).reshape(-1), fs=fs, decay_db=decay_db))
        except (ValueError, ZeroDivisionError, FloatingPointError, np.linalg.LinAlgError):
            return None
    return value if math.isfinite(value) and value > 0 else None


def c50(h, fs: float = STFT.sample_rate) -> float:
    """Clarity C50 in dB of ``h [T]``: ``10 log10(early / late)`` split at ``int(0.05 fs + 1)``."""
    h = _numpy(h).reshape(-1)
    if not np.all(np.isfinite(h)):
        return 0.0
    split = int(0.05 * fs + 1)
    early, late = float(np.sum(h[:split] ** 2)), float(np.sum(h[split:] ** 2))
    if early == 0.0 and late == 0.0:
        return 0.0
    if late == 0.0:
        return C50_LIMIT_DB
    if early == 0.0:
        return -C50_LIMIT_DB
    return float(np.clip(10.0 * math.log10(early / late), -C50_LIMIT_DB, C50_LIMIT_DB))


def edt(h, fs: float = STFT.sample_rate) -> float:
    """Early decay time in seconds of ``h [T]``: 6 x the time the Schroeder curve takes to fall 10 dB."""
    curve = schroeder_db(h)
    if curve is None:
        return 0.0
    below = np.nonzero(curve < -10.0)[0]
    # A response cut off while still loud: its energy falls to nothing after its last sample.
    samples = below[0] if below.size else curve.size
    return 6.0 * float(samples) / fs


# -- errors between predicted and ground-truth responses ------------------------------


def _channels(pred, gt, name: str) -> tuple[np.ndarray, np.ndarray]:
    p, g = _numpy(pred), _numpy(gt)
    if p.shape != g.shape or p.ndim == 0:
        raise ValueError(f"{name}: prediction {p.shape} and ground truth {g.shape} must have the same shape [..., T]")
    return p.reshape(-1, p.shape[-1]), g.reshape(-1, g.shape[-1])  # [C, T]


def t60_error(pred, gt, fs: float = STFT.sample_rate) -> float:
    """T60 error in percent, mean over channels of ``|rt60_pred - rt60_gt| / rt60_gt * 100``."""
    p, g = _channels(pred, gt, "T60")
    errors = []
    for pc, gc in zip(p, g):
        t_pred, t_gt = rt60(pc, fs), rt60(gc, fs)
        if t_pred is None or t_gt is None:
            errors.append(FAILED_T60_ERROR)
        else:
            errors.append(abs(t_pred - t_gt) / t_gt * 100.0)
    return float(np.mean(errors))


def c50_error(pred, gt, fs: float = STFT.sample_rate) -> float:
    """C50 error in dB, mean over channels of ``|C50_pred - C50_gt|``."""
    p, g = _channels(pred, gt, "C50")
    return float(np.mean([abs(c50(pc, fs) - c50(gc, fs)) for pc, gc in zip(p, g)]))


def edt_error(pred, gt, fs: float = STFT.sample_rate) -> float:
    """EDT error in seconds, mean over channels of ``|EDT_pred - EDT_gt|``."""
    p, g = _channels(pred, gt, "EDT")
    return float(np.mean([abs(edt(pc, fs) - edt(gc, fs)) for pc, gc in zip(p, g)]))
