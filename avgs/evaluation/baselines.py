"""Reference methods of the RWAVS benchmark (AV-NeRF, AV-GS Table 1).

Each is a *method* in the sense of :mod:`avgs.evaluation.binaural`: a callable
``(clip, scene) -> binaural [2, T]`` float32 (Oracle-Mask: an
:class:`avgs.evaluation.methods.Prediction`, the waveform and the masked magnitudes behind it). Mono-Energy and Stereo-Energy are oracle
baselines: they read the ground-truth energy of the clip they predict.

- Mono-Mono: the source copied to both ears.
- Mono-Energy: the source scaled to the target's mean energy (both channels), both ears.
- Stereo-Energy: the source scaled, per ear, to that ear's target energy.
- Oracle-Mask (not in the paper; a bound, not a method): per ear and frequency, the
  least-squares time-invariant gain fitted to the clip's own ground truth,
  ``g(f) = sum_t |S||B| / sum_t |S|^2``. No model made of time-invariant masks (the
  paper's binauralizer) can have a lower magnitude error on that clip's STFT
  frames, which makes it the ceiling of the mask model and shows what a reverberant
  tail has to add.

Energies are mean squares of the waveforms; a silent source gives silence.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from avgs.evaluation.methods import Prediction

if TYPE_CHECKING:
    from avgs.data.rwavs import AudioClip, RWAVSScene


def _gain(target_energy, source_energy: float) -> np.ndarray:
    if source_energy <= 0.0:
        return np.zeros_like(np.asarray(target_energy, dtype=np.float64))
    return np.sqrt(np.asarray(target_energy, dtype=np.float64) / source_energy)


def mono_mono(clip: "AudioClip", scene: "RWAVSScene | None" = None) -> np.ndarray:
    """The mono source in both ears: ``[2, T]``."""
    return np.stack([clip.mono, clip.mono]).astype(np.float32)


def mono_energy(clip: "AudioClip", scene: "RWAVSScene | None" = None) -> np.ndarray:
    """The source scaled to the binaural target's mean energy, in both ears: ``[2, T]``."""
    mono = clip.mono.astype(np.float64)  # [T]
    g = _gain(np.mean(clip.binaural.astype(np.float64) ** 2), float(np.mean(mono**2)))
    return np.stack([g * mono, g * mono]).astype(np.float32)


def stereo_energy(clip: "AudioClip", scene: "RWAVSScene | None" = None) -> np.ndarray:
    """The source scaled per ear to that ear's target energy: ``[2, T]``."""
    mono = clip.mono.astype(np.float64)  # [T]
    g = _gain(np.mean(clip.binaural.astype(np.float64) ** 2, axis=-1), float(np.mean(mono**2)))  # [2]
    return (g[:, None] * mono[None, :]).astype(np.float32)


def oracle_mask(clip: "AudioClip", scene: "RWAVSScene | None" = None):
    """The best time-invariant mask per ear for this clip's own target, as an
    :class:`avgs.evaluation.methods.Prediction`: the waveform ``[2, T]`` and the masked magnitudes ``[2, F, N]``."""
    import torch

    from avgs import dsp

    mono = torch.from_numpy(np.ascontiguousarray(clip.mono, dtype=np.float32))
    spec = dsp.stft(mono[None].double())[0]  # [F, N] complex
    target = dsp.magnitude(torch.from_numpy(np.ascontiguousarray(clip.binaural)).double())  # [2, F, N]
    mag = spec.abs()
    num = (mag[None] * target).sum(-1)  # [2, F]
    den = mag.square().sum(-1)  # [F]
    gains = torch.where(den > 0, num / den.clamp_min(1e-300), torch.zeros_like(num))  # [2, F]
    y = dsp.istft(spec[None] * gains[..., None], mono.shape[-1])  # [2, T]
    return Prediction(y.float().numpy(), (mag[None] * gains[..., None]).float().numpy())


BASELINES = {
    "mono-mono": mono_mono,
    "mono-energy": mono_energy,
    "stereo-energy": stereo_energy,
    "oracle-mask": oracle_mask,
}
"The baselines by their command-line names, in the paper's order."
