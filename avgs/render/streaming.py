"""The default synthesis block by block, equal to one-shot rendering.

:meth:`avgs.render.renderer.SceneRenderer.render` by default (``SynthesisConfig()``: method
``spectrogram``, phase ``filter``, no phase iterations) makes, per STFT frame, the
predicted ear magnitudes with the phase of the input through the pose's filter. Every
step is causal or frame-local, so :class:`BinauralStream` computes the same thing in blocks
of any size:

1. the input goes through the pose's binaural impulse response block by block
   (:class:`~avgs.acoustics.convolution.ConvolutionStream`);
2. the input and its filtered copy are framed together as their samples arrive, with the
   centred STFT's reflect padding reproduced at both ends (at the start once 257 samples
   are in, at the end in :meth:`BinauralStream.flush`);
3. each frame takes the predicted ear magnitudes (:func:`~avgs.acoustics.synthesis.ear_magnitudes`,
   the reverberant tail's power carried by its one-pole recursion) and the filtered
   frame's phase, and is overlap-added with ``torch.istft``'s window-envelope division.

So the concatenated output equals ``render(...).binaural`` to float rounding. Output lags
input by at most :attr:`BinauralStream.latency` samples (n_fft plus one convolution
block: 29 ms at 22050 Hz). A stream that ends before 257 samples is done in one piece,
as :func:`avgs.dsp.stft` does for such short inputs.
"""

from __future__ import annotations

import numpy as np
import torch

from avgs import dsp
from avgs.acoustics.convolution import ConvolutionStream, mono_block
from avgs.acoustics.reverb_tail import tail_power_recursive
from avgs.acoustics.synthesis import Masks, ear_magnitudes, unit_phase
from avgs.config import STFT, STFTConfig


def _hann(n: int) -> np.ndarray:
    """Periodic Hann window, as ``torch.hann_window`` (float64)."""
    return 0.5 - 0.5 * np.cos(2.0 * np.pi * np.arange(n) / n)


def one_pose(masks: Masks, stft: STFTConfig, dtype: torch.dtype, like: Masks | None = None) -> Masks:
    """``masks`` of one pose ([1, F] each) in ``dtype`` on the CPU, as a stream keeps them; ValueError
    for a batch, another STFT's bins, or (given the stream's current masks ``like``) another scene's."""
    shapes = [tuple(masks.mixture.shape), tuple(masks.difference.shape)]
    if masks.reverb is not None:
        shapes += [tuple(masks.reverb.shape[::2]), (1, *masks.decay.shape)]
    if any(shape != (1, stft.n_freq) for shape in shapes):
        raise ValueError(f"a stream takes the masks of one pose, [1, {stft.n_freq}] for n_fft {stft.n_fft}; got {shapes}")
    if like is not None and ((masks.decay is None) != (like.decay is None) or (masks.delay is None) != (like.delay is None)):
        raise ValueError("set_pose: the new masks must come from the same scene (with or without a tail and ear delays)")
    return masks.to(dtype, "cpu")


class BinauralStream:
    """Binauralise a mono stream block by block with one pose: its :class:`Masks` ([1, F]) and its
    binaural impulse response ``[2, L]`` (:meth:`SceneRenderer.binaural_filter
    <avgs.render.renderer.SceneRenderer.binaural_filter>`)."""

    def __init__(self, masks: Masks, impulse: np.ndarray, stft: STFTConfig = STFT, block: int = 128):
        if stft.win_length != stft.n_fft:
            raise ValueError(f"streaming needs win_length == n_fft, got {stft.win_length} and {stft.n_fft}")
        self.stft = stft
        self.masks = one_pose(masks, self.stft, torch.float64)
        "The pose's masks in float64, on the CPU."
        self._filter = ConvolutionStream(np.asarray(impulse, dtype=np.float32), block)
        self._tail_state = None  # [1, F] float64 tensor: decayed power of the frames so far
        n, hop = stft.n_fft, stft.hop_length
        self._w = _hann(n)  # [n_fft]
        self._w2 = self._w**2
        self._pad = n // 2
        self._hop = hop
        self._waiting = np.zeros(0)  # input whose filtered samples are not out yet
        self._head = np.zeros((3, 0))  # the first (input, filtered) samples, until the start padding can be built
        self._x = np.zeros((3, 0))  # padded-coordinate rows (input, filtered left, right) kept from self._x0
        self._x0 = 0
        self._acc = np.zeros((2, 0))  # overlap-add accumulator from padded index self._a0
        self._a0 = 0
        self._next_frame = 0
        self._emitted = 0  # output samples (original indices) already returned
        self._paired = 0  # input samples whose filtered samples are in
        self._started = False
        self._done = False

    def set_pose(self, masks: Masks, impulse: np.ndarray) -> None:
        """Go on with another pose of the same scene (e.g. from another thread, between blocks).

        The filter switches at the next convolution block with a crossfade over it, the
        magnitudes at the next STFT frame (whose overlap-add fades them in over one window).
        The tail's power needs no reset: it depends on the source and the room, not the pose.
        """
        masks = one_pose(masks, self.stft, torch.float64, like=self.masks)
        self._filter.convolver.set_impulse(np.asarray(impulse, dtype=np.float32))
        self.masks = masks

    @property
    def latency(self) -> int:
        """Upper bound on how many samples the output lags the input."""
        return self.stft.n_fft + self._filter.latency

    # -- internals ---------------------------------------------------------------------

    def _frames(self, t0: int, t1: int) -> None:
        """Compute frames [t0, t1) from self._x and overlap-add them into the accumulator."""
        if t1 <= t0:
            return
        n, hop = self.stft.n_fft, self._hop
        starts = np.arange(t0, t1) * hop - self._x0  # [m] into self._x
        idx = starts[:, None] + np.arange(n)[None, :]  # [m, n_fft]
        masks = self.masks  # one pose for these frames, whatever another thread sets meanwhile
        spec = np.fft.rfft(self._x[:, idx] * self._w, axis=-1)  # [3, m, F]
        mag_t = torch.from_numpy(np.ascontiguousarray(np.abs(spec[0]).T))[None]  # [1, F, m]
        power = None
        if masks.reverb is not None:  # P(t) = w (P(t-1) + |S(t-1)|^2), carried from block to block
            power, self._tail_state = tail_power_recursive(mag_t, masks.decay, self._tail_state)
        _, s_l, s_r = ear_magnitudes(mag_t, masks, power)  # [1, F, m] each
        target = torch.cat([s_l, s_r]).numpy().transpose(0, 2, 1)  # [2, m, F]
        out = np.fft.irfft(target * unit_phase(spec[1:]), n=n, axis=-1) * self._w  # [2, m, n_fft]
        end = (t1 - 1) * hop + n - self._a0
        if end > self._acc.shape[1]:
            self._acc = np.concatenate([self._acc, np.zeros((2, end - self._acc.shape[1]))], axis=1)
        for j, t in enumerate(range(t0, t1)):  # overlap-add (m is small per block)
            s = t * hop - self._a0
            self._acc[:, s : s + n] += out[:, j]
        self._next_frame = t1

    def _envelope(self, j: np.ndarray, n_frames: int | None) -> np.ndarray:
        """sum_t w^2(j - t hop) over frames 0 <= t < n_frames (None: unbounded) at padded indices j."""
        n, hop = self.stft.n_fft, self._hop
        env = np.zeros(len(j))
        for o in range(-(-n // hop)):
            t = j // hop - o
            ok = (t >= 0) & (j - t * hop < n)
            if n_frames is not None:
                ok &= t < n_frames
            env[ok] += self._w2[(j - t * hop)[ok]]
        return env

    def _emit(self, upto: int, n_frames: int | None) -> np.ndarray:
        """Return output samples [self._emitted, upto) (original indices) and drop what is done."""
        if upto <= self._emitted:
            return np.zeros((2, 0), dtype=np.float32)
        j = np.arange(self._emitted, upto) + self._pad  # padded indices
        y = self._acc[:, j - self._a0] / self._envelope(j, n_frames)
        self._emitted = upto
        drop = self._emitted + self._pad - self._a0  # accumulator before this is final
        self._acc = self._acc[:, drop:]
        self._a0 += drop
        return y.astype(np.float32)

    def _pair(self, filtered: np.ndarray) -> np.ndarray:
        """Rows (input, filtered left, filtered right) ``[3, n]`` for the newly filtered samples."""
        n = filtered.shape[1]
        rows = np.concatenate([self._waiting[None, :n], filtered.astype(np.float64)])
        self._waiting = self._waiting[n:]
        self._paired += n
        return rows

    def _take(self, rows: np.ndarray) -> np.ndarray:
        hop, pad = self._hop, self._pad
        if not self._started:
            self._head = np.concatenate([self._head, rows], axis=1)
            if self._head.shape[1] <= pad:  # too short to build the reflect padding yet
                return np.zeros((2, 0), dtype=np.float32)
            self._started = True
            head, self._head = self._head, np.zeros((3, 0))
            self._x = np.concatenate([head[:, pad:0:-1], head], axis=1)  # x_pad from index 0
            self._x0 = 0
        else:
            self._x = np.concatenate([self._x, rows], axis=1)
        # frame t needs x_pad[t hop, t hop + n_fft) = original samples up to t hop + pad - 1
        t_end = (self._paired - pad) // hop + 1  # frames whose samples are all in
        self._frames(self._next_frame, t_end)
        keep_from = self._next_frame * hop  # padded index of the next frame's start
        self._x = self._x[:, keep_from - self._x0 :]
        self._x0 = keep_from
        # sample i is final once frame floor((i + pad) / hop) is in
        return self._emit(self._next_frame * hop - pad, None)

    # -- public ------------------------------------------------------------------------

    def process(self, block) -> np.ndarray:
        """Feed ``block [n]`` (mono, finite); returns the output samples now final ``[2, m]``."""
        x = mono_block(block, self._done, np.float64)
        self._waiting = np.concatenate([self._waiting, x])
        return self._take(self._pair(self._filter.process(x.astype(np.float32))))

    def flush(self) -> np.ndarray:
        """End of stream: the remaining output ``[2, m]`` (with the end's reflect padding)."""
        if self._done:
            raise ValueError("this stream was already flushed")
        rest = self._take(self._pair(self._filter.flush()))
        self._done = True
        T = self._paired
        if not self._started:  # shorter than the padding: in one piece, as the one-shot path
            return self._one_shot(self._head)
        pad, hop = self._pad, self._hop
        n_frames = 1 + T // hop
        end = self._x[:, -1 - pad : -1][:, ::-1] if T > 1 else self._x[:, -1:]  # reflect x[T-2 .. T-1-pad]
        self._x = np.concatenate([self._x[:, : T + pad - self._x0], end], axis=1)
        self._frames(self._next_frame, n_frames)
        return np.concatenate([rest, self._emit(T, n_frames)], axis=1)

    def _one_shot(self, rows: np.ndarray) -> np.ndarray:
        if rows.shape[1] == 0:
            return np.zeros((2, 0), dtype=np.float32)
        with torch.inference_mode():
            spec = dsp.stft(torch.from_numpy(rows), self.stft)  # [3, F, N]
            _, s_l, s_r = ear_magnitudes(spec[:1].abs(), self.masks)
            ears = torch.cat([s_l, s_r]) * unit_phase(spec[1:])  # [2, F, N]
            return dsp.istft(ears, rows.shape[1], self.stft).float().numpy()
