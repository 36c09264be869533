"""AVGSModel: G_a + F + B, from listener poses to masks and binaural magnitudes.

All inputs are in the normalised frame, angles in radians. Shapes: B poses, N audio
points, k vicinity points, F = 257 frequency bins, N_t STFT frames.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

from avgs.acoustics.binauralizer import Binauralizer
from avgs.acoustics.field import AcousticField
from avgs.acoustics.points import AudioPoints
from avgs.acoustics.reverb_tail import ear_magnitudes, fill_phase, tail_power
from avgs.acoustics.vicinity import nearest_indices, vicinity_size
from avgs.config import STFT, AcousticConfig, SynthesisConfig


def signed_direction(listener: torch.Tensor, yaw: torch.Tensor, source: torch.Tensor) -> torch.Tensor:
    """theta [B] = atan2(cross(f, d), dot(f, d)) in xy, f = facing, d = source - listener.

    Positive when the source is on the listener's **left** (ARCHITECTURE.md).
    listener: [B, 3]; yaw: [B] radians; source: [B, 3] or [3].
    """
    d = source[..., :2] - listener[..., :2]  # [B, 2]
    fx, fy = torch.cos(yaw), torch.sin(yaw)
    return torch.atan2(fx * d[..., 1] - fy * d[..., 0], fx * d[..., 0] + fy * d[..., 1])


@dataclass
class Masks:
    """Per-frequency masks and the vicinity sets that produced them."""

    mixture: torch.Tensor  # [B, F]
    difference: torch.Tensor  # [B, F] in (-1, 1)
    listener_vicinity: torch.Tensor  # [B, k_L] int64
    source_vicinity: torch.Tensor  # [B, k_S] or [k_S] int64
    reverb: torch.Tensor | None = None  # [B, 2, F] reverberant gains, None without a tail


def apply_masks(mono_mag: torch.Tensor, mixture: torch.Tensor, difference: torch.Tensor):
    """``s_m = |S| m_m``, ``s_l = s_m + s_m m_d``, ``s_r = s_m - s_m m_d``.

    mono_mag: [B, F, N_t]; masks: [B, F] -> three [B, F, N_t].
    """
    return ear_magnitudes(mono_mag, mixture, difference)


class AVGSModel(nn.Module):
    """Audio points G_a, acoustic field F and binauralizer B."""

    def __init__(
        self,
        points: AudioPoints,
        cfg: AcousticConfig | None = None,
        n_freq: int = STFT.n_freq,
        vicinity_k: int | None = None,
        stft=STFT,
    ):
        super().__init__()
        self.cfg = cfg = cfg or AcousticConfig()
        self.points = points
        if vicinity_k is not None and int(vicinity_k) < 1:
            raise ValueError(f"vicinity_k must be a positive number of points, got {vicinity_k!r}")
        self.fixed_k = None if vicinity_k is None else int(vicinity_k)
        "An explicit k (a pruned checkpoint keeps its original k); None: k from the percentile."
        self.field = (
            AcousticField(points.alpha_dim, cfg.field_width, cfg.field_layers, cfg.context_dim)
            if cfg.use_context
            else None
        )
        self.binauralizer = Binauralizer(
            2 * cfg.context_dim if cfg.use_context else None,
            n_freq=n_freq,
            width=cfg.binauralizer_width,
            pe_frequencies=cfg.pe_frequencies,
            mixture_activation=cfg.mixture_activation,
            direction_encoding=cfg.direction_encoding,
            direction_embedding=cfg.direction_embedding,
            position_frequencies=cfg.position_frequencies,
            direction_harmonics=cfg.direction_harmonics,
            direction_every_layer=cfg.direction_every_layer,
            post_conv=cfg.post_conv,
            reverb_tail=cfg.reverb_tail,
            hop_seconds=stft.hop_length / stft.sample_rate,
        )

    # -- vicinity and context ------------------------------------------------------------

    @property
    def vicinity_k(self) -> int:
        """k = ceil(percentile % of N) (or the explicit ``vicinity_k``, capped at N), listener and source each."""
        if self.fixed_k is not None:
            return min(self.fixed_k, self.points.num_points)
        return vicinity_size(self.points.num_points, self.cfg.vicinity_percentile)

    def vicinity(self, positions: torch.Tensor) -> torch.Tensor:
        """positions [B, 3] (or [3]) -> indices of the k nearest audio points [B, k] (or [k])."""
        with torch.no_grad():
            return nearest_indices(self.points.X.detach(), positions, self.vicinity_k)

    def context_at(self, positions: torch.Tensor, indices: torch.Tensor) -> torch.Tensor:
        """C_i [B, context_dim] of positions [B, 3] from their vicinities [B, k]."""
        if self.field is None:
            raise ValueError("this model was trained without scene context (--no-context)")
        return self.field(self.points.X, self.points.alpha, positions, indices)

    def source_context(self, source: torch.Tensor) -> tuple[torch.Tensor | None, torch.Tensor]:
        """(C_S [context_dim] or None without context, source vicinity [k]) for source [3]: cacheable."""
        idx = self.vicinity(source)  # [k]
        if self.field is None:
            return None, idx
        return self.context_at(source[None], idx[None])[0], idx

    # -- masks -------------------------------------------------------------------------

    def masks(
        self,
        listener: torch.Tensor,
        theta: torch.Tensor,
        source: torch.Tensor,
        cached_source: tuple[torch.Tensor | None, torch.Tensor] | None = None,
    ) -> Masks:
        """listener [B, 3], theta [B] radians, source [3] -> :class:`Masks`.

        ``cached_source`` is :meth:`source_context` of the same source, reused as is.
        """
        B = listener.shape[0]
        listener_idx = self.vicinity(listener)  # [B, k]
        c_s, source_idx = cached_source if cached_source is not None else self.source_context(source)
        context = None
        if self.field is not None:
            c_l = self.context_at(listener, listener_idx)  # [B, c]
            context = torch.cat([c_s[None].expand(B, -1), c_l], dim=-1)  # [B, 2c] = C_S (+) C_L
        out = self.binauralizer(listener[:, :2], theta, context)
        return Masks(out.mixture, out.difference, listener_idx, source_idx, out.reverb)

    def forward(self, listener: torch.Tensor, theta: torch.Tensor, source: torch.Tensor, mono_mag: torch.Tensor):
        """Predicted magnitudes: (s_m, s_l, s_r) each [B, F, N_t], and the :class:`Masks`."""
        m = self.masks(listener, theta, source)
        tail = self.binauralizer.reverb
        power = tail_power(mono_mag, tail.decay()) if tail is not None else None  # [B, F, N_t]
        s_m, s_l, s_r = ear_magnitudes(mono_mag, m.mixture, m.difference, m.reverb, power)
        post = self.binauralizer.post_conv
        if post is not None:
            s_l, s_r = post(mono_mag, m.mixture, m.difference, s_l, s_r)
        return (s_m, s_l, s_r), m


def binaural_spectrogram(
    mono_stft: torch.Tensor, mixture: torch.Tensor, difference: torch.Tensor, post_conv=None,
    reverb: torch.Tensor | None = None, decay: torch.Tensor | None = None,
) -> torch.Tensor:
    """The predicted complex spectrogram of both ears: the ear magnitudes with the source phase.

    mono_stft: [B, F, N_t] complex; masks [B, F] -> [B, 2, F, N_t] complex (channel 0 = left).
    Its magnitudes are what B is trained to match (:meth:`AVGSModel.forward`), and what
    AV-NeRF's evaluation scores (``avgs.metrics.mag_spectrogram``). ``post_conv``: the
    binauralizer's :class:`~avgs.acoustics.post_conv.PostConv`, or None. ``reverb`` [B, 2, F]
    gains and ``decay`` [F] (:meth:`ReverbTail.decay <avgs.acoustics.reverb_tail.ReverbTail.decay>`):
    the reverberant tail, or both None.
    """
    if (reverb is None) != (decay is None):
        raise ValueError("binaural_spectrogram: pass both the reverberant gains and the decay, or neither")
    if post_conv is None and reverb is None:
        # |S| m e^{i phase(S)} = S m: the masks scale the source spectrum, keeping its phase.
        gain_l = mixture * (1.0 + difference)  # [B, F]
        gain_r = mixture * (1.0 - difference)  # [B, F]
        return mono_stft[:, None] * torch.stack([gain_l, gain_r], dim=1)[..., None]  # [B, 2, F, N_t]
    mag = mono_stft.abs()  # [B, F, N_t]
    power = tail_power(mag, decay) if decay is not None else None  # [B, F, N_t]
    _, s_l, s_r = ear_magnitudes(mag, mixture, difference, reverb, power)
    if post_conv is not None:
        s_l, s_r = post_conv(mag, mixture, difference, s_l, s_r)
    # The source phase. A silent bin (|S| = 0) has none: phase 0 for the conv head's output,
    # a fixed pseudo-random phase for a reverberant tail ringing on after the source stops.
    silent = torch.ones_like(mono_stft)
    if decay is not None and bool((mag == 0).any()):
        silent = fill_phase(mag.shape[-2], 0, mag.shape[-1], mag.device).to(mono_stft.dtype).expand_as(mono_stft)
    phase = torch.where(mag > 0, mono_stft / mag.clamp_min(torch.finfo(mag.dtype).tiny), silent)
    return torch.stack([s_l, s_r], dim=1) * phase[:, None]  # [B, 2, F, N_t]


def binaural_waveform(
    mono_stft: torch.Tensor, mixture: torch.Tensor, difference: torch.Tensor, length: int, stft=STFT, post_conv=None,
    reverb: torch.Tensor | None = None, decay: torch.Tensor | None = None, synthesis: SynthesisConfig | None = None,
):
    """The waveform of :func:`binaural_spectrogram`: [B, 2, length] (channel 0 = left).

    The predicted magnitudes with the source phase are rarely a consistent STFT, so their
    plain iSTFT has a spectrogram blurred away from them. ``synthesis``
    (:class:`~avgs.config.SynthesisConfig`; None = its defaults) sets the fast Griffin-Lim
    iterations that restore them, starting from the source phase; 0 iterations is the
    plain iSTFT, the paper's synthesis (and the streaming one, :mod:`avgs.streaming`).
    """
    spec = binaural_spectrogram(mono_stft, mixture, difference, post_conv, reverb, decay)  # [B, 2, F, N_t]
    return synthesise(spec, length, stft, synthesis)


def synthesise(spec: torch.Tensor, length: int, stft=STFT, synthesis: SynthesisConfig | None = None) -> torch.Tensor:
    """Waveform ``[..., length]`` of the ear spectrogram ``spec [..., F, N_t]`` (:func:`binaural_spectrogram`):
    its magnitudes restored by ``synthesis``'s phase iterations from its phase (None: the defaults)."""
    from avgs import dsp

    synthesis = synthesis or SynthesisConfig()
    return dsp.griffin_lim(spec, spec.abs(), length, synthesis.phase_iterations, synthesis.phase_momentum, stft)
