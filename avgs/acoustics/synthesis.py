"""From masks to sound: the one place where B's masks become ear spectrograms and waveforms.

Training (:meth:`AVGSModel.forward <avgs.acoustics.model.AVGSModel.forward>`), rendering
(:class:`avgs.inference.SceneRenderer`), streaming (:mod:`avgs.streaming`), evaluation and
the benchmarks all go through these functions. Shapes: B poses, F = 257 frequency bins,
N_t STFT frames; channel 0 of an ear axis is the left ear.

The paper's mask model, per frequency, broadcast over frames::

    g_l = m_m (1 + m_d),   g_r = m_m (1 - m_d)                        (ear_gains)
    s_m = |S| m_m,   s_l = |S| g_l,   s_r = |S| g_r

With the reverberant tail (:mod:`avgs.acoustics.reverb_tail`) each ear adds decayed power
of earlier frames: ``s_ear = sqrt((|S| g_ear)^2 + r_ear^2 P)``, and ``s_m`` is the mean of
the two ears. The waveform is the iSTFT of the ear magnitudes with a phase: by default
(:func:`mid_phase_waveform`) one phase that fast Griffin-Lim retrieves for ``s_m`` and both
ears share; the source's (:func:`binaural_waveform`, the paper's) or the pose's filter's, each
refined per ear by ``SynthesisConfig.phase_iterations`` (:class:`~avgs.config.SynthesisConfig`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import torch

from avgs.acoustics.reverb_tail import fill_phase, tail_power
from avgs.config import STFT, STFTConfig, SynthesisConfig
from avgs.phase_retrieval import frame_grid, griffin_lim, retrieve_phase


@dataclass(frozen=True)
class Masks:
    """What B predicts for a batch of poses, and the vicinity sets F read for them."""

    mixture: torch.Tensor  # [B, F] mixture mask m_m (>= 0 with relu, (0, 1) with sigmoid)
    difference: torch.Tensor  # [B, F] difference mask m_d in (-1, 1); > 0: left louder
    reverb: torch.Tensor | None = None  # [B, 2, F] reverberant gains r >= 0; None without a tail
    decay: torch.Tensor | None = None  # [F] the tail's power decay per frame (scene-wide); with reverb
    listener_vicinity: torch.Tensor | None = None  # [B, k] int64 indices into the audio points
    source_vicinity: torch.Tensor | None = None  # [k] int64

    def __post_init__(self):
        if (self.reverb is None) != (self.decay is None):
            raise ValueError("Masks: give both the reverberant gains and the decay, or neither")

    def with_vicinity(self, listener: torch.Tensor, source: torch.Tensor) -> "Masks":
        return replace(self, listener_vicinity=listener, source_vicinity=source)

    def to(self, dtype: torch.dtype | None = None, device=None) -> "Masks":
        """The masks detached from autograd, their real tensors in ``dtype`` on ``device`` (vicinities as they are)."""
        def f(t):
            return None if t is None else t.detach().to(device=device, dtype=dtype)

        return replace(self, mixture=f(self.mixture), difference=f(self.difference), reverb=f(self.reverb),
                       decay=f(self.decay))


def ear_gains(mixture: torch.Tensor, difference: torch.Tensor) -> torch.Tensor:
    """The per-ear gains ``m_m (1 + m_d)`` (left) and ``m_m (1 - m_d)`` (right): masks [..., F] -> [..., 2, F]."""
    return torch.stack([mixture * (1.0 + difference), mixture * (1.0 - difference)], dim=-2)


def ear_magnitudes(mono_mag: torch.Tensor, masks: Masks, power: torch.Tensor | None = None,
                   source_power: torch.Tensor | None = None):
    """Predicted magnitudes ``(s_m, s_l, s_r)``, each [B, F, N_t], of the source magnitudes ``mono_mag`` [B, F, N_t].

    ``power`` [B, F, N_t]: the tail's decayed source power (:func:`~avgs.acoustics.reverb_tail.tail_power`);
    computed here when the masks carry a tail and it is not given (streams pass their recursion's).
    ``source_power``: ``mono_mag^2`` when the caller has it (rendering without autograd).
    """
    gains = ear_gains(masks.mixture, masks.difference)  # [B, 2, F]
    if masks.reverb is None:
        s_l = mono_mag * gains[:, 0, :, None]  # [B, F, N_t]
        s_r = mono_mag * gains[:, 1, :, None]
        return mono_mag * masks.mixture[..., None], s_l, s_r
    if power is None:
        power = tail_power(mono_mag, masks.decay, source_power)  # [B, F, N_t]
    if any(t.requires_grad for t in (mono_mag, gains, masks.reverb, power)):  # training
        s_l = _sqrt0((mono_mag * gains[:, 0, :, None]).square() + masks.reverb[:, 0, :, None].square() * power)
        s_r = _sqrt0((mono_mag * gains[:, 1, :, None]).square() + masks.reverb[:, 1, :, None].square() * power)
        return 0.5 * (s_l + s_r), s_l, s_r
    # Rendering: s_ear = sqrt(|S|^2 g^2 + r^2 P) in three passes per ear (all terms >= 0), no gradient to guard at 0.
    sq = mono_mag.square() if source_power is None else source_power  # [B, F, N_t]
    g2, r2 = gains.square()[..., None], masks.reverb.square()[..., None]  # [B, 2, F, 1]
    s_l = (sq * g2[:, 0]).addcmul_(power, r2[:, 0]).sqrt_()
    s_r = (sq * g2[:, 1]).addcmul_(power, r2[:, 1]).sqrt_()
    return torch.add(s_l, s_r).mul_(0.5), s_l, s_r


def _sqrt0(x: torch.Tensor) -> torch.Tensor:
    """sqrt(x) for x >= 0, exactly 0 at 0 (silence stays silent), with a finite gradient there."""
    tiny = torch.finfo(x.dtype).tiny
    return torch.where(x > tiny, torch.sqrt(x.clamp_min(tiny)), torch.zeros_like(x))


def unit_phase(spec):
    """``spec / |spec|``, 1 where ``spec`` is 0 (numpy or torch, complex)."""
    if isinstance(spec, torch.Tensor):
        size = spec.abs()
        return torch.where(size > 0, spec / size.clamp_min(torch.finfo(size.dtype).tiny), 1.0)
    size = np.abs(spec)
    return np.where(size > 0, spec / np.maximum(size, np.finfo(size.dtype).tiny), 1.0)


def source_phase(mono_stft: torch.Tensor, first_frame: int = 0, tail: bool = False,
                 power: torch.Tensor | None = None) -> torch.Tensor:
    """Unit phasors of the source's STFT [..., F, N_t] (complex), for bins where it is silent: 1, or with
    a reverberant ``tail`` ringing on after the source stops, a fixed pseudo-random phase
    (:func:`~avgs.acoustics.reverb_tail.fill_phase`; ``first_frame`` is the absolute index of frame 0).
    ``power``: ``|mono_stft|^2`` when already at hand."""
    if power is None:
        power = (mono_stft * mono_stft.conj()).real  # |S|^2, without abs()'s hypot
    silent = power == 0
    unit = mono_stft * power.clamp_min(torch.finfo(power.dtype).tiny).rsqrt()
    if not bool(silent.any()):
        return unit
    fill = torch.ones_like(mono_stft)
    if tail:
        fill = fill_phase(power.shape[-2], first_frame, power.shape[-1], power.device).to(mono_stft.dtype).expand_as(mono_stft)
    return torch.where(silent, fill, unit)


START_FLOOR = 1e-3
"Source bins this far below their frame's loudest (60 dB) start from the fill phase: their own is rounding noise."


def start_phase(mono_stft: torch.Tensor, power: torch.Tensor, first_frame: int = 0, tail: bool = False,
                magnitude: torch.Tensor | None = None) -> torch.Tensor:
    """The phase retrieval's first phase [..., F, N_t]: the source's, blended into the fill phase
    (:func:`source_phase`'s for silent bins) where the source is near silent in its frame.

    The phase of a bin 60 dB or more below its frame's loudest is rounding noise of the
    STFT, and depends on the input's scale; where the tail rings on, it would decide the
    output. ``unit(S + START_FLOOR max_f |S| fill)`` keeps the source's phase where it is
    defined, takes the fill phase where it is not, and changes continuously in between:
    the output does not depend on the input's scale, nor on how it is cut into blocks.
    ``power``: ``|mono_stft|^2``. ``magnitude`` [..., F, N_t]: return the phase times it (the
    first guess itself, one pass less).
    """
    n_freq, n = power.shape[-2], power.shape[-1]
    fill = fill_phase(n_freq, first_frame, n, power.device).to(mono_stft.dtype) if tail else None  # [F, N]
    floor = power.amax(dim=-2, keepdim=True).sqrt_().mul_(START_FLOOR)  # [..., 1, N]
    z = mono_stft + (floor if fill is None else floor * fill)  # [..., F, N]
    scale = (z * z.conj()).real.clamp_min(torch.finfo(power.dtype).tiny).rsqrt_()  # 1 / |z|
    if magnitude is not None:
        scale.mul_(magnitude)
    out = z * scale
    silent = floor == 0  # [..., 1, N]: frames where the source is exactly silent, and so is z
    if bool(silent.any()):  # their phase: the fill phase (or 1), as source_phase's
        if fill is None:
            fill = torch.ones((), dtype=mono_stft.dtype, device=mono_stft.device)
        out = torch.where(silent, fill if magnitude is None else fill * magnitude, out)
    return out


def ear_spectrogram(mono_stft: torch.Tensor, masks: Masks, post_conv=None, first_frame: int = 0,
                    phase: torch.Tensor | None = None) -> torch.Tensor:
    """The predicted complex spectrogram of both ears: ear magnitudes with the source's phase, or with ``phase``.

    mono_stft: [B, F, N_t] complex -> [B, 2, F, N_t] complex. Its magnitudes are what B is
    trained to match and what AV-NeRF's evaluation scores. ``post_conv``: the binauralizer's
    :class:`~avgs.acoustics.post_conv.PostConv`, or None. ``first_frame``: the absolute index of
    frame 0 when ``mono_stft`` is a stretch of a longer signal (for the tail's fill phase).
    ``phase``: unit phasors [B, 2, F, N_t] to use instead of the source's, such as those of the
    input through the pose's filter (:func:`avgs.acoustics.impulse_response.filter_phase`;
    the mask model only).
    """
    if phase is not None:
        if post_conv is not None:
            raise ValueError("a given phase needs the mask model; the conv head takes the source's phase")
        _, s_l, s_r = ear_magnitudes(mono_stft.abs(), masks)
        return torch.stack([s_l, s_r], dim=1) * phase  # [B, 2, F, N_t]
    if post_conv is None and masks.reverb is None:
        # |S| g e^{i phase(S)} = S g: the gains scale the source spectrum, keeping its phase.
        return mono_stft[:, None] * ear_gains(masks.mixture, masks.difference)[..., None]  # [B, 2, F, N_t]
    mag = mono_stft.abs()  # [B, F, N_t]
    _, s_l, s_r = ear_magnitudes(mag, masks)
    if post_conv is not None:
        s_l, s_r = post_conv(mag, masks.mixture, masks.difference, s_l, s_r)
    phase = source_phase(mono_stft, first_frame, tail=masks.reverb is not None)  # [B, F, N_t]
    return torch.stack([s_l, s_r], dim=1) * phase[:, None]  # [B, 2, F, N_t]


def waveform(spec: torch.Tensor, length: int, stft: STFTConfig = STFT, synthesis: SynthesisConfig | None = None):
    """Waveform ``[..., length]`` of an ear spectrogram ``spec [..., F, N_t]`` (:func:`ear_spectrogram`):
    its magnitudes restored by ``synthesis``'s phase iterations from its phase (None: the defaults;
    0 iterations is the plain iSTFT)."""
    synthesis = synthesis or SynthesisConfig()
    return griffin_lim(spec, spec.abs(), length, synthesis.iterations, synthesis.phase_momentum, stft)


def binaural_waveform(
    mono_stft: torch.Tensor, masks: Masks, length: int, stft: STFTConfig = STFT, post_conv=None,
    synthesis: SynthesisConfig | None = None, phase: torch.Tensor | None = None,
) -> torch.Tensor:
    """:func:`waveform` of :func:`ear_spectrogram`: [B, 2, length] (channel 0 = left)."""
    return waveform(ear_spectrogram(mono_stft, masks, post_conv, phase=phase), length, stft, synthesis)


def mid_phase_parts(mono_stft: torch.Tensor, masks: Masks, first_frame: int = 0, tail: torch.Tensor | None = None):
    """What the default synthesis retrieves its phase from, frame-major: (first guess [B, N, F]
    complex: the mid magnitudes ``s_m`` with :func:`start_phase`; ``s_m`` [B, N, F]; the ears'
    magnitudes [B, 2, N, F]), of the source's STFT ``mono_stft`` [B, F, N]. ``tail``: the tail's
    power [B, F, N] when the caller carries it (a stream's recursion); ``first_frame``: the
    absolute index of frame 0."""
    power = (mono_stft * mono_stft.conj()).real  # [B, F, N] |S|^2
    s_m, s_l, s_r = ear_magnitudes(power.sqrt(), masks, tail, source_power=power)  # [B, F, N] each
    start = start_phase(mono_stft, power, first_frame, masks.reverb is not None, magnitude=s_m)  # [B, F, N]
    return start.transpose(-1, -2), s_m.transpose(-1, -2), torch.stack([s_l, s_r], dim=1).transpose(-1, -2)


def shared_phase_waveform(ears: torch.Tensor, phase: torch.Tensor, length: int, stft: STFTConfig = STFT) -> torch.Tensor:
    """Waveforms [..., 2, length] of the ears' magnitudes ``ears`` [..., 2, N, F] with one phase
    ``phase`` [..., N, F] (unit phasors, frame-major) for both."""
    grid = frame_grid(phase.shape[-2], stft, ears.dtype, str(ears.device))
    return grid.waveform(grid.synthesise((ears * phase.unsqueeze(-3)).contiguous()), length)


def mid_phase_waveform(
    mono_stft: torch.Tensor, masks: Masks, length: int, stft: STFTConfig = STFT, synthesis: SynthesisConfig | None = None,
    first_frame: int = 0,
) -> tuple[torch.Tensor, torch.Tensor]:
    """The default synthesis: (waveform [B, 2, length], ear magnitudes [B, 2, F, N_t]).

    One phase for both ears: fast Griffin-Lim (``synthesis.iterations``; :mod:`avgs.phase_retrieval`)
    retrieves a phase for the mid magnitudes ``s_m`` from the source's, and each ear's
    magnitudes take it. The ears' magnitudes differ from ``s_m`` by slowly varying gains
    per bin, so the shared phase is nearly as consistent for them as for ``s_m``: one
    retrieval instead of two. Mask model only (no conv head). ``first_frame``: the absolute
    index of frame 0 (:func:`source_phase`). :class:`avgs.mid_phase_stream.MidPhaseStream`
    does the same block by block, from the same two pieces (:func:`mid_phase_parts`,
    :func:`shared_phase_waveform`).
    """
    synthesis = synthesis or SynthesisConfig()
    start, mid, ears = mid_phase_parts(mono_stft, masks, first_frame)  # frame-major
    phase = retrieve_phase(mid.contiguous(), start.contiguous(), length, synthesis.iterations,
                           synthesis.phase_momentum, stft)  # [B, N, F]
    return shared_phase_waveform(ears, phase, length, stft), ears.transpose(-1, -2)
