"""The binaural task's model as the renderer uses it (:class:`BinauralTaskModel`).

B predicts time-invariant masks for a pose (:meth:`AVGSModel.masks
<avgs.acoustics.model.AVGSModel.masks>`), so a pose is a filter, its binaural impulse response
(:mod:`avgs.acoustics.impulse_response`). By default (:class:`~avgs.config.SynthesisConfig`) a
render is B's predicted ear magnitudes with one phase that fast Griffin-Lim retrieves for their
mid, for any length, and the stream gives the same block by block; ``method="filter"`` is the
convolution alone (what the explorer plays), ``phase="filter"`` the filter output's phase,
``phase="source"`` the paper's synthesis (:mod:`avgs.acoustics.synthesis`).

One source position in training: a moved source changes only the direction the ears hear it
from (theta) and C_S; the model never heard a source elsewhere (``source_aware`` False).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import replace

import numpy as np
import torch

from avgs import dsp
from avgs.acoustics.impulse_response import TailShaper, convolve, impulse_response
from avgs.acoustics.model import AVGSModel
from avgs.acoustics.synthesis import (Masks, SourceParts, ear_gains, ear_spectrogram, mid_phase_waveform, source_parts,
                                      unit_phase, waveform)
from avgs.config import STFTConfig, SynthesisConfig
from avgs.data.frame import SceneFrame
from avgs.render.cells import ear_power, listener_contexts
from avgs.render.tasks import HEADROOM_DB, BlockStream, HeadroomLimited, Pose, Response, check_finite, peak, reach_frames
from avgs.threads import stopped

RENDER_BLOCK_FRAMES = 2048
"Frames per block when a long input is rendered (about 12 s at AV-NeRF's hop): memory stays bounded."


def _numpy(t):
    return None if t is None else t.detach().double().cpu().numpy()


class BinauralTaskModel:
    """:class:`~avgs.render.tasks.TaskModel` of an :class:`~avgs.acoustics.model.AVGSModel`."""

    source_aware = False

    def __init__(self, model: AVGSModel, cache, stft: STFTConfig, where: str, source_context,
                 frame: SceneFrame | None = None, bounds: np.ndarray | None = None):
        self.model, self.cache, self.stft, self.where = model, cache, stft, where
        self.device = next(iter(model.points.parameters())).device
        self._source_context = source_context  # the renderer's cached C_S of a source [3]
        self._clip: tuple[np.ndarray, torch.Tensor | None, SourceParts] | None = None  # (input, decay, its parts)
        tail = model.binauralizer.reverb
        self._tail = None if tail is None else TailShaper(tail.decay().detach(), stft)
        "The reverberant tail's decaying noise (scene-wide), shaped per pose by :meth:`impulse`."

    @property
    def post_conv(self):
        return self.model.binauralizer.post_conv

    # -- one pose --------------------------------------------------------------------------

    def response(self, pose: Pose, impulse: bool = False, stop=None) -> Response:
        stopped(stop, "the pose's response")
        masks = self.model.masks(pose.listener, pose.theta, pose.source, self._source_context(pose.source), self.cache)
        stopped(stop, "the pose's response")
        check_finite((masks.mixture, masks.difference, masks.reverb, masks.decay), self.where,
                     f"masks at listener {tuple(pose.listener_world)}, yaw {pose.yaw!r}")
        m, power = self._within_headroom(masks)
        return Response(power.sqrt(), m.listener_vicinity, m.source_vicinity, masks=m,
                        impulse=self.impulse(m) if impulse else None)

    def _within_headroom(self, m: Masks) -> tuple[Masks, torch.Tensor]:
        """The masks, scaled down when the pose's ear filter would gain more than HEADROOM_DB in a bin,
        and each ear's power gain per bin ``[1, 2, F]`` float64 after it (the response's ``gains`` squared).

        A bin's energy gain is at most ``g_ear^2 + r_ear^2 w / (1 - w)`` (direct gain, plus the
        tail's geometric sum of decayed power, w its decay per frame); scaling the mixture and
        reverberant gains by c scales it by c^2.
        """
        power = ear_gains(m.mixture, m.difference).double().square()  # [1, 2, F]
        if m.reverb is not None:
            w = m.decay.double().clamp(max=1.0 - 1e-9)
            power = power + m.reverb.double().square() * (w / (1.0 - w))
        peak_db = 10.0 * math.log10(max(float(power.max()), 1e-300))
        if peak_db <= HEADROOM_DB:
            return m, power
        c = 10.0 ** ((HEADROOM_DB - peak_db) / 20.0)
        warnings.warn(f"the ear filter at this pose gains {peak_db:.1f} dB in its loudest bin; scaled to "
                      f"the {HEADROOM_DB:g} dB headroom", HeadroomLimited, stacklevel=5)  # the caller of render() etc.
        reverb = None if m.reverb is None else m.reverb * c
        return replace(m, mixture=m.mixture * c, reverb=reverb), power * (c * c)

    def impulse(self, m: Masks) -> np.ndarray:
        """The binaural impulse response ``[2, L]`` float32 of one pose's masks."""
        if self.post_conv is not None:
            raise ValueError(f"{self.where}: trained with the time-frequency conv head "
                             "(--post-conv), whose output depends on the input: it is not a filter")
        return impulse_response(m, self.stft, self._tail)[0].float().numpy()

    # -- sound -----------------------------------------------------------------------------

    def render(self, response: Response, x: np.ndarray, synthesis: SynthesisConfig, magnitudes: bool = False):
        return self.synthesise(response.masks, x, synthesis, magnitudes, response.impulse)

    def synthesise(self, m: Masks, x: np.ndarray, synthesis: SynthesisConfig, magnitudes: bool = False,
                   impulse: np.ndarray | None = None):
        """(binaural [2, T] float32 of ``x`` (at unit peak), predicted magnitudes [2, F, N_t] or
        None, the output's peak): the synthesis of one pose's masks ``m`` (``impulse``: their
        response, when already made)."""
        m32 = m.to(torch.float32)
        y = np.empty((2, x.size), dtype=np.float32)  # [2, T]
        mags, top = None, 0.0
        mid = synthesis.method == "spectrogram" and synthesis.phase == "mid" and self.post_conv is None
        filtered = None  # [2, T] the input through the pose's filter, when the synthesis uses it
        if self.post_conv is None and (synthesis.method == "filter" or synthesis.phase == "filter"):
            h = self.impulse(m) if impulse is None else impulse
            filtered = convolve(torch.from_numpy(x), torch.from_numpy(h))
        if synthesis.method == "filter" and filtered is not None:
            y[:] = filtered.numpy()
            top = peak(y)
            pieces = [(0, x.size, 0, x.size)] if magnitudes else []  # the predicted magnitudes only
        else:
            pieces = self._pieces(x.size, m32, synthesis, whole=magnitudes)
        for lo, hi, start, stop in pieces:
            piece = torch.from_numpy(x[start:stop]).to(self.device)  # [stop - start]
            if mid:  # one retrieved phase for both ears (the default)
                kept = stop - start == x.size and dsp.n_frames(x.size, self.stft) <= RENDER_BLOCK_FRAMES  # a clip, not a file
                parts = self._clip_parts(x, piece, m32.decay) if kept else None
                spec = None if parts is not None else dsp.stft(piece[None], self.stft)
                wave, ears = mid_phase_waveform(spec, m32, stop - start, self.stft, synthesis,
                                                start // self.stft.hop_length, parts)
                if magnitudes:
                    mags = ears[0].double().cpu().numpy()
                y[:, lo:hi] = wave[0, :, lo - start : hi - start].float().cpu().numpy()
                top = max(top, peak(y[:, lo:hi]))
                continue
            if filtered is None:  # the source's phase
                ears = ear_spectrogram(dsp.stft(piece[None], self.stft), m32, self.post_conv,
                                       start // self.stft.hop_length, stft=self.stft)  # [1, 2, F, N]
            else:  # the predicted magnitudes with the filter's phase: the input and its filtered copy in one STFT
                both = torch.cat([piece[None], filtered[:, start:stop].to(self.device)])  # [3, stop - start]
                spec = dsp.stft(both, self.stft)  # [3, F, N]
                ears = ear_spectrogram(spec[:1], m32, phase=unit_phase(spec[1:])[None])  # [1, 2, F, N]
            if magnitudes:
                mags = ears[0].abs().double().cpu().numpy()
            if synthesis.method == "filter" and filtered is not None:
                break
            wave = waveform(ears, stop - start, self.stft, synthesis)[0]  # [2, stop - start]
            y[:, lo:hi] = wave[:, lo - start : hi - start].float().cpu().numpy()
            top = max(top, peak(y[:, lo:hi]))  # NaN once any sample is not finite
            del piece, ears, wave
        return y, mags, top

    def _clip_parts(self, x: np.ndarray, unit: torch.Tensor, decay: torch.Tensor | None) -> SourceParts:
        """:func:`~avgs.acoustics.synthesis.source_parts` of the whole input ``x`` ([T], at unit
        peak), kept for the next render of the same clip: the explorer and the benchmarks hear
        one clip from many poses, and only the pose's part of the synthesis changes. One clip of
        at most RENDER_BLOCK_FRAMES frames is kept (about 12 s, 11 MB)."""
        kept = self._clip
        if (kept is not None and kept[0].shape == x.shape and np.array_equal(kept[0], x)
                and (kept[1] is None) == (decay is None) and (decay is None or torch.equal(kept[1], decay))):
            return kept[2]
        parts = source_parts(dsp.stft(unit[None], self.stft), decay)
        self._clip = (x.copy(), None if decay is None else decay.clone(), parts)
        return parts

    def _pieces(self, length: int, masks: Masks, synthesis: SynthesisConfig, whole: bool = False):
        """Yield (lo, hi, start, stop): output samples [lo, hi) are those of the input's samples
        [start, stop), a stretch with enough margin for the result to equal one pass.

        The filter of a pose is fixed, and output frame t depends only on input frames within
        a reach (:meth:`reach_frames`). So a long input is rendered in blocks of
        RENDER_BLOCK_FRAMES with that reach as margin: memory stays bounded by the block, and
        the result equals one pass to float rounding.
        """
        hop = self.stft.hop_length
        n = dsp.n_frames(length, self.stft)
        margin = self.reach_frames(synthesis, n, masks.decay)
        block = RENDER_BLOCK_FRAMES
        if whole or n <= block + 2 * margin:
            yield 0, length, 0, length
            return
        for s in range(0, n, block):
            e = min(n, s + block)
            a, b = max(0, s - margin), min(n, e + margin)
            start, stop = a * hop, (length if b == n else b * hop)  # centred frames a .. b-1 of the piece
            yield s * hop, (length if e == n else e * hop), start, stop

    def tail_decay(self) -> torch.Tensor | None:
        tail = self.model.binauralizer.reverb
        return None if tail is None else tail.decay().detach()

    def reach_frames(self, synthesis: SynthesisConfig, n_frames: int | None = None,
                     decay: torch.Tensor | None = None) -> int:
        """:func:`~avgs.render.tasks.reach_frames` of the model's tail (or ``decay``) and conv head."""
        from avgs.acoustics.post_conv import CONTEXT_FRAMES

        return reach_frames(self.stft, synthesis, self.tail_decay() if decay is None else decay, n_frames,
                            CONTEXT_FRAMES if self.post_conv is not None else 0)

    def stream(self, response: Response, synthesis: SynthesisConfig, block_frames: int | None = None) -> BlockStream:
        """With the default synthesis (phase ``mid``) a :class:`~avgs.render.mid_phase_stream.MidPhaseStream`,
        with the filter's phase and no iterations a :class:`~avgs.render.streaming.BinauralStream`,
        with ``method="filter"`` a :class:`~avgs.acoustics.convolution.ConvolutionStream`."""
        from avgs.acoustics.convolution import ConvolutionStream
        from avgs.render.mid_phase_stream import MidPhaseStream
        from avgs.render.streaming import BinauralStream

        s = synthesis
        if self.post_conv is not None:
            raise ValueError(
                f"{self.where}: trained with the time-frequency conv head (--post-conv), whose "
                "output depends on neighbouring frames; block streaming supports only the mask model. "
                "Use render() on the whole signal."
            )
        if s.method == "spectrogram" and s.phase != "mid" and s.iterations > 0:
            raise ValueError(f"{self.where}: a stream cannot do {s.iterations} phase iterations from the {s.phase}'s "
                             "phase (they need the whole signal); stream with SynthesisConfig() or method='filter'")
        if s.method == "spectrogram" and s.phase == "source":
            raise ValueError(f"{self.where}: the source's phase does not stream; stream with SynthesisConfig() or method='filter'")
        m = response.masks
        if s.method == "spectrogram" and s.phase == "mid":
            return MidPhaseStream(m, self.stft, s, **({} if block_frames is None else {"block_frames": block_frames}))
        impulse = self.impulse(m) if response.impulse is None else response.impulse
        return ConvolutionStream(impulse) if s.method == "filter" else BinauralStream(m.to(torch.float32), impulse, self.stft)

    def beyond_filter(self, synthesis: SynthesisConfig) -> bool:
        """The mid phase (the default) or the filter's phase without iterations, on the mask model."""
        s = synthesis
        return (self.post_conv is None and s.method == "spectrogram"
                and (s.phase == "mid" or (s.phase == "filter" and s.iterations == 0)))

    def move_stream(self, stream: BlockStream, response: Response) -> None:
        stream.set_pose(response.masks.to(torch.float32), response.impulse)

    # -- the propagation map -----------------------------------------------------------------

    def cell_power(self, listener, theta, yaw, source, cached_source, bins=None, fast=None) -> np.ndarray:
        """Each ear's power ``[n, 2, f]``: with ``fast`` B alone at ``bins`` on F's exact contexts,
        else the very masks of :meth:`response` (without its headroom limit: the map applies it)."""
        decay = self.tail_decay()
        decay = None if decay is None else decay.double().cpu().numpy()  # [F]
        if fast is None:
            m = self.model.masks(listener, theta, source, cached_source, self.cache)
            return ear_power(_numpy(m.mixture), _numpy(m.difference), _numpy(m.reverb), decay)
        model, n = self.model, len(listener)
        context = None
        if model.field is not None:
            c_s = cached_source[0][None].expand(n, -1)  # [n, c]
            context = torch.cat([c_s, listener_contexts(model, self.cache, listener)], dim=-1)  # [n, 2c] = C_S (+) C_L
        m = model.binauralizer(listener[:, :2], theta, context, self.cache.frequency, bins)
        if decay is not None and bins is not None:
            decay = decay[bins.numpy()]  # [f]
        return ear_power(_numpy(m.mixture), _numpy(m.difference), _numpy(m.reverb), decay)

    def predict_responses(self, source, receiver, yaw) -> np.ndarray:
        raise ValueError(f"{self.where}: trained for the binaural task (one source); impulse responses of "
                         "sources anywhere need a checkpoint of 'avgs train --task rir'")
