"""STFT / iSTFT with AV-NeRF's settings, batched, in torch.

Shapes: waveforms ``[..., T]``; spectrograms ``[..., F, N]`` with F = n_fft // 2 + 1 = 257
frequency bins and N = 1 + T // hop frames (centred). A 1 s clip at 22050 Hz gives 257 x 173.
"""

from __future__ import annotations

import functools

import numpy as np
import torch

from avgs.config import STFT, STFTConfig


@functools.lru_cache(maxsize=8)
def window(win_length: int, device: str, dtype: torch.dtype) -> torch.Tensor:
    # Made outside inference mode: a cached inference tensor could not be used under autograd later.
    with torch.inference_mode(False):
        return torch.hann_window(win_length, device=device, dtype=dtype)


def _as_tensor(x) -> torch.Tensor:
    if isinstance(x, np.ndarray):
        x = torch.from_numpy(np.ascontiguousarray(x))
    if not torch.is_floating_point(x):
        x = x.float()
    return x


def stft(x: torch.Tensor | np.ndarray, cfg: STFTConfig = STFT) -> torch.Tensor:
    """Complex STFT of ``x [..., T]`` -> ``[..., F, N]``. Works for any length >= 1."""
    x = _as_tensor(x)
    lead = x.shape[:-1]
    T = x.shape[-1]
    flat = x.reshape(-1, T)
    pad_mode = "reflect" if T > cfg.n_fft // 2 else "constant"
    spec = torch.stft(
        flat,
        n_fft=cfg.n_fft,
        hop_length=cfg.hop_length,
        win_length=cfg.win_length,
        window=window(cfg.win_length, str(x.device), x.dtype),
        center=True,
        pad_mode=pad_mode,
        return_complex=True,
    )
    return spec.reshape(*lead, *spec.shape[-2:])


def istft(spec: torch.Tensor, length: int, cfg: STFTConfig = STFT) -> torch.Tensor:
    """Inverse of :func:`stft`: ``[..., F, N]`` complex -> ``[..., length]`` real."""
    lead = spec.shape[:-2]
    flat = spec.reshape(-1, *spec.shape[-2:])
    real_dtype = torch.float64 if flat.dtype == torch.complex128 else torch.float32
    y = torch.istft(
        flat,
        n_fft=cfg.n_fft,
        hop_length=cfg.hop_length,
        win_length=cfg.win_length,
        window=window(cfg.win_length, str(spec.device), real_dtype),
        center=True,
        length=length,
    )
    return y.reshape(*lead, length)


def magnitude(x: torch.Tensor | np.ndarray, cfg: STFTConfig = STFT) -> torch.Tensor:
    """``|STFT(x)|``: ``[..., T]`` -> ``[..., F, N]``."""
    return stft(x, cfg).abs()


def n_frames(length: int, cfg: STFTConfig = STFT) -> int:
    """Number of centred STFT frames for a signal of ``length`` samples."""
    return 1 + length // cfg.hop_length
