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
def _window(win_length: int, device: str, dtype: torch.dtype) -> torch.Tensor:
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
        window=_window(cfg.win_length, str(x.device), x.dtype),
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
        window=_window(cfg.win_length, str(spec.device), real_dtype),
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


GRIFFIN_LIM_BLOCK_FRAMES = 4096
"Frames per block of :func:`griffin_lim` on long inputs (about 24 s at AV-NeRF's hop): memory stays bounded."


def griffin_lim(
    spec: torch.Tensor, target: torch.Tensor, length: int, iterations: int, momentum: float = 0.99,
    cfg: STFTConfig = STFT, block_frames: int = GRIFFIN_LIM_BLOCK_FRAMES,
) -> torch.Tensor:
    """A waveform ``[..., length]`` whose STFT magnitudes approach ``target``, starting from ``spec``.

    spec: ``[..., F, N]`` complex, the first guess (magnitudes ``target`` with some phase);
    target: ``[..., F, N]`` >= 0. Fast Griffin-Lim (Perraudin, Balazs and Sondergaard 2013):
    each iteration takes the STFT of the current waveform, keeps its phase and restores
    the target magnitudes, extrapolated by ``momentum`` (0 gives Griffin and Lim 1984);
    the waveform returned is that of the last projection. ``iterations = 0`` is the
    iSTFT of ``spec``.

    One iteration mixes a frame only with the frames its window overlaps, so after K
    iterations a frame depends on its neighbours within ``K (n_fft / hop)`` frames. Long
    inputs are therefore done in blocks of ``block_frames``, each with that many frames of
    margin on both sides, which gives the same waveform as one pass to float rounding
    with memory bounded by the block.
    """
    if iterations < 0 or not 0.0 <= momentum < 1.0:
        raise ValueError(f"griffin_lim needs iterations >= 0 and momentum in [0, 1), got {iterations}, {momentum}")
    n = spec.shape[-1]
    reach = -(-cfg.n_fft // cfg.hop_length)  # frames a window overlaps on each side, plus one
    margin = reach * (iterations + 2)
    if iterations == 0 or n <= block_frames + 2 * margin:
        return _griffin_lim(spec, target, length, iterations, momentum, cfg)
    hop = cfg.hop_length
    out = torch.empty(*spec.shape[:-2], length, dtype=target.dtype, device=spec.device)
    for s in range(0, n, block_frames):
        e = min(n, s + block_frames)
        a, b = max(0, s - margin), min(n, e + margin)
        piece_len = length - a * hop if b == n else (b - a - 1) * hop  # centred frames a..b-1 exactly
        y = _griffin_lim(spec[..., a:b], target[..., a:b], piece_len, iterations, momentum, cfg)
        lo, hi = s * hop, (length if e == n else e * hop)
        out[..., lo:hi] = y[..., lo - a * hop : hi - a * hop]
    return out


def _griffin_lim(spec, target, length: int, iterations: int, momentum: float, cfg: STFTConfig) -> torch.Tensor:
    tiny = torch.finfo(target.dtype).tiny
    previous = None
    for _ in range(iterations):
        rebuilt = stft(istft(spec, length, cfg), cfg)  # [..., F, N], a consistent spectrogram
        projected = target * rebuilt / rebuilt.abs().clamp_min(tiny)
        spec = projected if previous is None else projected + momentum * (projected - previous)
        previous = projected
    return istft(spec if previous is None else previous, length, cfg)
