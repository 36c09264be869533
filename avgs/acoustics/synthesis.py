"""From masks to sound: the one place where B's masks become ear spectrograms and waveforms.

Training (:meth:`AVGSModel.forward <avgs.acoustics.model.AVGSModel.forward>`), rendering
(:class:`avgs.render.renderer.SceneRenderer`), streaming (:mod:`avgs.render.streaming`), evaluation and
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

from avgs.acoustics.interaural import phase_ramp
from avgs.acoustics.reverb_tail import fill_phase, tail_power
from avgs.config import STFT, STFTConfig, SynthesisConfig
from avgs.dsp.kernels import decayed_power, project_magnitudes
from avgs.dsp.phase_retrieval import frame_grid, griffin_lim, retrieve_phase


@dataclass(frozen=True)
class Masks:
    """What B predicts for a batch of poses, and the vicinity sets F read for them."""

    mixture: torch.Tensor  # [B, F] mixture mask m_m (>= 0 with relu, (0, 1) with sigmoid)
    difference: torch.Tensor  # [B, F] difference mask m_d in (-1, 1); > 0: left louder
    reverb: torch.Tensor | None = None  # [B, 2, F] reverberant gains r >= 0; None without a tail
    decay: torch.Tensor | None = None  # [F] the tail's power decay per frame (scene-wide); with reverb
    listener_vicinity: torch.Tensor | None = None  # [B, k] int64 indices into the audio points
    source_vicinity: torch.Tensor | None = None  # [k] int64
    delay: torch.Tensor | None = None  # [B, 2] seconds each ear hears the pose late (avgs.acoustics.interaural); None: none

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
                       decay=f(self.decay), delay=f(self.delay))


def ear_ramp(masks: Masks, stft: STFTConfig, dtype: torch.dtype = torch.complex64) -> torch.Tensor | None:
    """The ears' delays as phase ramps ``[B, 2, F]`` (:func:`~avgs.acoustics.interaural.phase_ramp`),
    or None for masks without delays."""
    return None if masks.delay is None else phase_ramp(masks.delay, stft, dtype).to(masks.mixture.device)


def ear_gains(mixture: torch.Tensor, difference: torch.Tensor) -> torch.Tensor:
    """The per-ear gains ``m_m (1 + m_d)`` (left) and ``m_m (1 - m_d)`` (right): masks [..., F] -> [..., 2, F]."""
    return torch.stack([mixture * (1.0 + difference), mixture * (1.0 - difference)], dim=-2)


def ear_magnitudes(mono_mag: torch.Tensor, masks: Masks, power: torch.Tensor | None = None):
    """Predicted magnitudes ``(s_m, s_l, s_r)``, each [B, F, N_t], of the source magnitudes ``mono_mag`` [B, F, N_t].

    ``power`` [B, F, N_t]: the tail's decayed source power (:func:`~avgs.acoustics.reverb_tail.tail_power`);
    computed here when the masks carry a tail and it is not given (streams pass their recursion's).
    The default synthesis makes the same magnitudes frame-major (:func:`pose_parts`).
    """
    gains = ear_gains(masks.mixture, masks.difference)  # [B, 2, F]
    if masks.reverb is None:
        s_l = mono_mag * gains[:, 0, :, None]  # [B, F, N_t]
        s_r = mono_mag * gains[:, 1, :, None]
        return mono_mag * masks.mixture[..., None], s_l, s_r
    if power is None:
        power = tail_power(mono_mag, masks.decay)  # [B, F, N_t]
    if any(t.requires_grad for t in (mono_mag, gains, masks.reverb, power)):  # training
        s_l = _sqrt0((mono_mag * gains[:, 0, :, None]).square() + masks.reverb[:, 0, :, None].square() * power)
        s_r = _sqrt0((mono_mag * gains[:, 1, :, None]).square() + masks.reverb[:, 1, :, None].square() * power)
        return 0.5 * (s_l + s_r), s_l, s_r
    # Rendering: s_ear = sqrt(|S|^2 g^2 + r^2 P) in three passes per ear (all terms >= 0), no gradient to guard at 0.
    sq = mono_mag.square()  # [B, F, N_t]
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


def start_phase(spec: torch.Tensor, power: torch.Tensor, first_frame: int = 0, tail: bool = False) -> torch.Tensor:
    """The phase retrieval's first phase, unit phasors [..., N_t, F] (frame-major): the source's,
    blended into the fill phase (:func:`source_phase`'s for silent bins) where the source is near
    silent in its frame.

    The phase of a bin 60 dB or more below its frame's loudest is rounding noise of the
    STFT, and depends on the input's scale; where the tail rings on, it would decide the
    output. ``unit(S + START_FLOOR max_f |S| fill)`` keeps the source's phase where it is
    defined, takes the fill phase where it is not, and changes continuously in between:
    the output does not depend on the input's scale, nor on how it is cut into blocks.
    ``spec``: the source's STFT frame-major [..., N_t, F] complex; ``power``: ``|spec|^2``.
    """
    n, n_freq = power.shape[-2], power.shape[-1]
    fill = fill_phase(n_freq, first_frame, n, power.device).to(spec.dtype).t() if tail else None  # [N, F]
    floor = power.amax(dim=-1, keepdim=True).sqrt_().mul_(START_FLOOR)  # [..., N, 1]
    z = spec + (floor if fill is None else floor * fill)  # [..., N, F]
    out = project_magnitudes(z)  # z / |z|
    silent = floor == 0  # [..., N, 1]: frames where the source is exactly silent, and so is z
    if bool(silent.any()):  # their phase: the fill phase (or 1), as source_phase's
        out = torch.where(silent, torch.ones((), dtype=spec.dtype, device=spec.device) if fill is None else fill, out)
    return out


def ear_spectrogram(mono_stft: torch.Tensor, masks: Masks, post_conv=None, first_frame: int = 0,
                    phase: torch.Tensor | None = None, stft: STFTConfig = STFT) -> torch.Tensor:
    """The predicted complex spectrogram of both ears: ear magnitudes with the source's phase, or with ``phase``.

    mono_stft: [B, F, N_t] complex -> [B, 2, F, N_t] complex. Its magnitudes are what B is
    trained to match and what AV-NeRF's evaluation scores. ``post_conv``: the binauralizer's
    :class:`~avgs.acoustics.post_conv.PostConv`, or None. ``first_frame``: the absolute index of
    frame 0 when ``mono_stft`` is a stretch of a longer signal (for the tail's fill phase).
    ``phase``: unit phasors [B, 2, F, N_t] to use instead of the source's, such as those of the
    input through the pose's filter (:func:`avgs.acoustics.impulse_response.filter_phase`;
    the mask model only), which holds the ears' delays; otherwise each ear is delayed by the
    masks' ``delay`` (phase ramps at ``stft``'s bin frequencies).
    """
    if phase is not None:  # the filter's phase already holds the ears' delays
        if post_conv is not None:
            raise ValueError("a given phase needs the mask model; the conv head takes the source's phase")
        _, s_l, s_r = ear_magnitudes(mono_stft.abs(), masks)
        return torch.stack([s_l, s_r], dim=1) * phase  # [B, 2, F, N_t]
    ramp = ear_ramp(masks, stft, mono_stft.dtype)  # [B, 2, F]: the ears' delays, or None
    if post_conv is None and masks.reverb is None:
        # |S| g e^{i phase(S)} = S g: the gains scale the source spectrum, keeping its phase.
        ears = mono_stft[:, None] * ear_gains(masks.mixture, masks.difference)[..., None]  # [B, 2, F, N_t]
        return ears if ramp is None else ears * ramp[..., None]
    mag = mono_stft.abs()  # [B, F, N_t]
    _, s_l, s_r = ear_magnitudes(mag, masks)
    if post_conv is not None:
        s_l, s_r = post_conv(mag, masks.mixture, masks.difference, s_l, s_r)
    phase = source_phase(mono_stft, first_frame, tail=masks.reverb is not None)  # [B, F, N_t]
    ears = torch.stack([s_l, s_r], dim=1) * phase[:, None]  # [B, 2, F, N_t]
    return ears if ramp is None else ears * ramp[..., None]


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
    return waveform(ear_spectrogram(mono_stft, masks, post_conv, phase=phase, stft=stft), length, stft, synthesis)


@dataclass(frozen=True)
class SourceParts:
    """What the default synthesis takes from the source alone, frame-major ([B, N_t, F]): the same
    for every pose of a clip (:func:`source_parts`; a renderer keeps its last clip's)."""

    power: torch.Tensor  # [B, N, F] |S|^2
    magnitude: torch.Tensor  # [B, N, F] |S|
    tail: torch.Tensor | None  # [B, N, F] the tail's decayed source power P; None: masks without a tail
    start: torch.Tensor  # [B, N, F] complex: the phase retrieval's first phase (start_phase)


def source_parts(mono_stft: torch.Tensor, decay: torch.Tensor | None = None, first_frame: int = 0,
                 tail: torch.Tensor | None = None) -> SourceParts:
    """:class:`SourceParts` of the source's STFT ``mono_stft`` [B, F, N] (complex). ``decay`` [F]:
    the scene's tail decay per frame (``Masks.decay``; None for masks without a tail); ``tail``:
    the tail's power [B, F, N] when the caller carries it (a stream's recursion); ``first_frame``:
    the absolute index of frame 0."""
    spec = mono_stft.transpose(-1, -2)  # [B, N, F]: contiguous for dsp.stft's output
    power = (spec * spec.conj()).real.contiguous()  # [B, N, F] |S|^2
    magnitude = power.sqrt()
    if tail is not None:
        tail = tail.transpose(-1, -2).contiguous()  # [B, N, F]
    elif decay is not None and power.device.type == "cpu":  # the recursion: one loop over the frames
        tail = decayed_power(power, decay)[0]
    elif decay is not None:  # elsewhere (CUDA) the FFT convolution: a loop over frames is a launch per frame
        tail = tail_power(magnitude.transpose(-1, -2), decay, power.transpose(-1, -2)).transpose(-1, -2).contiguous()
    return SourceParts(power, magnitude, tail, start_phase(spec, power, first_frame, decay is not None))


def pose_parts(source: SourceParts, masks: Masks):
    """What the default synthesis retrieves its phase from, frame-major, for one pose's ``masks``:
    (first guess [B, N, F] complex: the mid magnitudes ``s_m`` with :func:`start_phase`; ``s_m``
    [B, N, F]; the ears' magnitudes [B, 2, N, F]), as :func:`ear_magnitudes` makes them."""
    gains = ear_gains(masks.mixture, masks.difference).unsqueeze(-2)  # [B, 2, 1, F]
    if masks.reverb is None:
        ears = source.magnitude.unsqueeze(1) * gains  # [B, 2, N, F]
        mid = source.magnitude * masks.mixture.unsqueeze(-2)  # [B, N, F]
    else:
        if source.tail is None:
            raise ValueError("these masks have a reverberant tail: make the source's parts with their decay")
        # s_ear = sqrt(|S|^2 g^2 + r^2 P): three passes for both ears, all terms >= 0.
        ears = (source.power.unsqueeze(1) * gains.square()).addcmul_(
            source.tail.unsqueeze(1), masks.reverb.square().unsqueeze(-2)).sqrt_()  # [B, 2, N, F]
        mid = torch.add(ears[:, 0], ears[:, 1]).mul_(0.5)  # [B, N, F]
    return source.start * mid, mid, ears


def mid_phase_parts(mono_stft: torch.Tensor, masks: Masks, first_frame: int = 0, tail: torch.Tensor | None = None):
    """:func:`pose_parts` of :func:`source_parts` of the source's STFT ``mono_stft`` [B, F, N]."""
    return pose_parts(source_parts(mono_stft, masks.decay, first_frame, tail), masks)


def shared_phase_waveform(ears: torch.Tensor, phase: torch.Tensor, length: int, stft: STFTConfig = STFT,
                          ramp: torch.Tensor | None = None) -> torch.Tensor:
    """Waveforms [..., 2, length] of the ears' magnitudes ``ears`` [..., 2, N, F] with one phase
    ``phase`` [..., N, F] (unit phasors, frame-major) for both, each ear delayed by ``ramp``
    (phase ramps broadcasting to [..., 2, N, F]: :func:`ear_ramp` [..., 2, 1, F]; None: no delay)."""
    grid = frame_grid(phase.shape[-2], stft, ears.dtype, str(ears.device))
    spec = ears * phase.unsqueeze(-3)  # [..., 2, N, F]
    if ramp is not None:
        spec = spec * ramp
    return grid.waveform(grid.synthesise(spec.contiguous()), length)


def mid_phase_waveform(
    mono_stft: torch.Tensor, masks: Masks, length: int, stft: STFTConfig = STFT, synthesis: SynthesisConfig | None = None,
    first_frame: int = 0, source: SourceParts | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """The default synthesis: (waveform [B, 2, length], ear magnitudes [B, 2, F, N_t]).

    One phase for both ears: fast Griffin-Lim (``synthesis.iterations``; :mod:`avgs.dsp.phase_retrieval`)
    retrieves a phase for the mid magnitudes ``s_m`` from the source's, and each ear's
    magnitudes take it. The ears' magnitudes differ from ``s_m`` by slowly varying gains
    per bin, so the shared phase is nearly as consistent for them as for ``s_m``: one
    retrieval instead of two. Mask model only (no conv head). ``first_frame``: the absolute
    index of frame 0 (:func:`source_phase`). ``source``: :func:`source_parts` of ``mono_stft``
    when already made (``mono_stft`` is then not read). :class:`avgs.render.mid_phase_stream.MidPhaseStream`
    does the same block by block, from the same pieces (:func:`source_parts`, :func:`pose_parts`,
    :func:`shared_phase_waveform`).
    """
    synthesis = synthesis or SynthesisConfig()
    if source is None:
        source = source_parts(mono_stft, masks.decay, first_frame)
    start, mid, ears = pose_parts(source, masks)  # frame-major
    phase = retrieve_phase(mid, start, length, synthesis.iterations, synthesis.phase_momentum, stft)  # [B, N, F]
    ramp = ear_ramp(masks, stft)  # [B, 2, F] or None
    return (shared_phase_waveform(ears, phase, length, stft, None if ramp is None else ramp.unsqueeze(-2)),
            ears.transpose(-1, -2))
