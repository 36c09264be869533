"""Late reverberation for the binauralizer: an exponentially decaying tail in the power domain.

B's masks are per frequency and time-invariant: ``s = |S| m`` can colour and pan the
source but never puts energy where the source is silent, so the reverberant tail that a
room adds after every onset is lost. Per clip, the best possible time-invariant mask
(fitted to the ground truth of that very clip) reaches only about 0.63x Stereo-Energy's
MAG on our scenes, where a model with this tail reaches 0.66x from the training clips
alone (docs/paper-deviations.md, "Reverberant tail").

The tail follows the statistical model of late reverberation used in dereverberation
(Lebart et al. 2001; Habets 2007): in a diffuse field the reverberant power at frame t
is the source power of earlier frames, decayed exponentially at the room's decay rate::

    P(f, t) = sum_{k >= 1} w_f^k |S(f, t - k)|^2,    w_f = 10^(-6 hop / RT60_f)
    s_ear   = sqrt((m_ear |S|)^2 + r_ear^2 P)        m_l = m_m (1 + m_d), m_r = m_m (1 - m_d)

``RT60_f`` (one per frequency bin) is a property of the room, not of the pose: it is a
learned scene-wide parameter, readable in seconds (:meth:`ReverbTail.rt60`). The
reverberant gains ``r_l, r_r >= 0`` (per frequency and ear) depend on where the listener
stands and which way it faces; the binauralizer predicts them from the same features
as its masks (:class:`avgs.acoustics.binauralizer.Binauralizer`). With ``r = 0`` the
model is exactly the paper's mask model.

Like the masks, the filter is fixed for a pose, so audio of any length is binauralised
by it: ``P`` is a causal convolution along frames, computed by FFT for any length, or
frame by frame by its one-pole recursion ``P(t) = w (P(t-1) + |S(t-1)|^2)``
(:func:`tail_power_recursive`: streams, and renders on the CPU).
"""

from __future__ import annotations

import functools
import math
from collections import OrderedDict

import torch
from torch import nn

from avgs.dsp.kernels import decayed_power

LN_1E6 = math.log(1e6)
"RT60 is the time for the power to fall by 60 dB, a factor of 1e6."

MIN_RT60 = 1e-3
"Smallest representable RT60 in seconds (the tail vanishes well before one frame)."


def rt60_seconds(log_rt60: torch.Tensor) -> torch.Tensor:
    """RT60 in seconds from the stored parameter ``log_rt60`` (log seconds), floored at ``MIN_RT60``."""
    return log_rt60.exp().clamp_min(MIN_RT60)


def decay_per_frame(rt60: torch.Tensor, hop_seconds: float) -> torch.Tensor:
    """Power decay factor per STFT frame ``w = 10^(-6 hop / RT60)`` in (0, 1), for RT60 [F] in seconds."""
    return torch.exp(-LN_1E6 * hop_seconds / rt60)


NEGLIGIBLE_POWER = 1e-14
"Kernel taps whose power weight falls below this (float32 eps squared) are dropped: 140 dB down."

BLOCK_FRAMES = 2048
"Frames per FFT block when a long input is convolved block by block (overlap-add)."


def tail_length(decay: torch.Tensor, n_frames: int) -> int:
    """Kernel taps needed: the first k with ``max_f decay_f^k < NEGLIGIBLE_POWER``, at most ``n_frames``."""
    w = float(decay.detach().max())
    if w <= 0.0:
        return min(2, n_frames)
    if w >= 1.0:
        return n_frames
    return int(min(n_frames, math.ceil(math.log(NEGLIGIBLE_POWER) / math.log(w)) + 1))


def tail_power(mono_mag: torch.Tensor, decay: torch.Tensor, source_power: torch.Tensor | None = None) -> torch.Tensor:
    """``P[..., f, t] = sum_{k=1}^{t} decay_f^k |S[..., f, t-k]|^2`` by FFT convolution along frames.

    mono_mag: [..., F, N_t] >= 0 (``source_power``: its square, when at hand); decay: [F] in
    (0, 1) -> [..., F, N_t] >= 0. The sum starts
    at the first frame (silence before the signal); taps below ``NEGLIGIBLE_POWER`` are
    dropped, and inputs longer than ``BLOCK_FRAMES`` are convolved block by block, so time
    and memory grow linearly with the length (a 10-minute input is fine).
    """
    n = mono_mag.shape[-1]
    power = mono_mag.square() if source_power is None else source_power  # [..., F, N]
    taps = tail_length(decay, n)
    block = max(BLOCK_FRAMES, taps) if n > BLOCK_FRAMES else n
    size = 1 << (block + taps - 1).bit_length()  # >= block + taps: linear, not circular; a power of 2 is fast
    if decay.requires_grad:  # training: through autograd
        kernel_spec = _kernel_spectrum(decay, taps, size)
    else:  # rendering: the decay is the scene's, the same for every pose
        kernel_spec = _cached_kernel_spectrum(decay, taps, size)
    if block >= n:
        out = torch.fft.irfft(torch.fft.rfft(power, size) * kernel_spec, size)[..., :n]
        return out.clamp_min(0.0)  # FFT rounding can dip a hair below zero
    out = torch.zeros(*power.shape[:-1], n + size, device=power.device, dtype=power.dtype)
    for start in range(0, n, block):  # overlap-add
        piece = power[..., start : start + block]
        out[..., start : start + size] += torch.fft.irfft(torch.fft.rfft(piece, size) * kernel_spec, size)
    return out[..., :n].clamp_min(0.0)


def _kernel_spectrum(decay: torch.Tensor, taps: int, size: int) -> torch.Tensor:
    """rfft [F, size // 2 + 1] of the kernel ``decay^k`` for k = 1 .. taps-1 (zero at k = 0: the
    direct part is the mask's), as exp(k log w)."""
    k = torch.arange(taps, device=decay.device, dtype=decay.dtype)  # [L]
    kernel = torch.exp(k * torch.log(decay)[:, None]) * (k > 0)  # [F, L]
    return torch.fft.rfft(kernel, size)


KERNEL_CACHE = 8
"Kernel spectra kept for rendering (one per scene decay, length and FFT size)."

_kernels: "OrderedDict[tuple, torch.Tensor]" = OrderedDict()


def _cached_kernel_spectrum(decay: torch.Tensor, taps: int, size: int) -> torch.Tensor:
    """:func:`_kernel_spectrum` of a decay without autograd, cached by its values: a scene's
    decay is the same for every pose it renders."""
    key = (decay.detach().cpu().numpy().tobytes(), taps, size, decay.dtype, str(decay.device))
    spec = _kernels.get(key)
    if spec is None:
        with torch.inference_mode(False):  # usable in and out of inference mode
            spec = _kernel_spectrum(decay.detach().clone(), taps, size)
        _kernels[key] = spec
        while len(_kernels) > KERNEL_CACHE:
            _kernels.popitem(last=False)
    return spec


def tail_power_recursive(mono_mag: torch.Tensor, decay: torch.Tensor, state: torch.Tensor | None = None):
    """The same sum by the recursion ``P(t) = w (P(t-1) + |S(t-1)|^2)``, frame by frame
    (:func:`avgs.dsp.kernels.decayed_power`: one compiled loop on the CPU).

    mono_mag: [..., F, N_t]; decay [F]; ``state`` = ``P(t0) + |S(t0)|^2`` of the frame before
    this block ([..., F], zeros at the start). Returns (P [..., F, N_t], the next state).
    """
    power, state = decayed_power(mono_mag.square().transpose(-1, -2), decay, state)  # frame-major
    return power.transpose(-1, -2), state


class ReverbTail(nn.Module):
    """The scene's reverberation time per frequency and the head that predicts the per-pose gains.

    ``head`` maps the binauralizer's difference features ``[B, F, width]`` to the two ears'
    reverberant gains ``r [B, 2, F]`` (softplus, >= 0). Its bias starts at ``init_gain``
    (a quiet tail), so an untrained tail barely changes the mask model.
    """

    def __init__(self, n_freq: int, width: int, hop_seconds: float, init_rt60: float = 0.5, init_gain: float = 0.05):
        super().__init__()
        if not (hop_seconds > 0 and init_rt60 > MIN_RT60 and init_gain > 0):
            raise ValueError(
                f"ReverbTail needs hop_seconds > 0, init_rt60 > {MIN_RT60} and init_gain > 0; "
                f"got {hop_seconds}, {init_rt60}, {init_gain}"
            )
        self.hop_seconds = float(hop_seconds)
        self.log_rt60 = nn.Parameter(torch.full((n_freq,), math.log(init_rt60)))  # [F], log seconds
        self.head = nn.Linear(width, 2)
        nn.init.zeros_(self.head.weight)
        nn.init.constant_(self.head.bias, math.log(math.expm1(init_gain)))  # softplus^-1

    def rt60(self) -> torch.Tensor:
        """Reverberation time per frequency bin, seconds [F]."""
        return rt60_seconds(self.log_rt60)

    def decay(self) -> torch.Tensor:
        """Power decay per STFT frame [F] in (0, 1)."""
        return decay_per_frame(self.rt60(), self.hop_seconds)

    def gains(self, features: torch.Tensor) -> torch.Tensor:
        """features [..., F, width] -> reverberant gains [..., 2, F] (channel 0 = left), >= 0."""
        return torch.nn.functional.softplus(self.head(features)).movedim(-1, -2)


@functools.lru_cache(maxsize=8)
def fill_phase(n_freq: int, first_frame: int, n_frames: int, device=None) -> torch.Tensor:
    """Unit phasors [F, N_t] (complex64) for bins where the source is exactly silent (its phase undefined).

    The tail rings on after the source stops; a constant phase there would make every
    frame a pulse at the frame edge, which the synthesis window erases. A diffuse tail has
    random phase: this is a fixed pseudo-random one, an integer hash of (frequency, frame),
    so one-shot and block-streamed output agree. ``first_frame`` is the absolute index of
    the first frame. Cached (a render of the same length reuses it): do not modify in place.
    """
    f = torch.arange(n_freq, device=device, dtype=torch.int64)[:, None]
    t = torch.arange(first_frame, first_frame + n_frames, device=device, dtype=torch.int64)[None, :]
    h = ((f * 73856093) ^ (t * 19349663)) % 65536  # [F, N_t]
    angle = h.to(torch.float32) * (2 * math.pi / 65536)
    return torch.polar(torch.ones_like(angle), angle)
