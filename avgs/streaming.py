"""Block-wise binauralisation equal to one-shot processing.

The masks of a pose are time-invariant, so :meth:`avgs.inference.SceneRenderer.render`
is ``istft(gain * stft(x))`` over the whole input. :class:`BinauralStream` computes the
same thing in blocks of any size: it keeps the last ``n_fft`` input samples, turns each
frame into its spectrum as soon as its samples are in, applies the per-ear gains, and
overlap-adds with the same window-envelope division as ``torch.istft``. The centred
STFT's reflect padding is reproduced at both ends: at the start once 257 samples have
arrived, at the end in :meth:`flush` (the stream's length is known only then). So the
concatenation of all outputs equals ``render(...).binaural`` made with the source's phase
(``SynthesisConfig(phase_iterations=0)``) to float rounding: the phase iterations that
``render`` runs by default need the whole signal.

A model with a reverberant tail (:mod:`avgs.acoustics.reverb_tail`) is streamed the same
way: the tail's power is carried from frame to frame by its one-pole recursion, one
value per frequency, so blocks still concatenate to the one-shot result.

Output lags input by at most ``latency`` = ``n_fft`` samples (23 ms at 22050 Hz). A
stream that ends before 257 samples falls back to the one-shot path (constant padding,
as :func:`avgs.dsp.stft` does for such short inputs).
"""

from __future__ import annotations

import numpy as np
import torch

from avgs import dsp
from avgs.acoustics.reverb_tail import tail_power_recursive
from avgs.acoustics.synthesis import Masks, binaural_waveform, ear_gains, ear_magnitudes, source_phase
from avgs.config import STFT, STFTConfig, SynthesisConfig


def _hann(n: int) -> np.ndarray:
    """Periodic Hann window, as ``torch.hann_window`` (float64)."""
    return 0.5 - 0.5 * np.cos(2.0 * np.pi * np.arange(n) / n)


class BinauralStream:
    """Binauralise a mono stream block by block with the fixed :class:`Masks` of one pose ([1, F])."""

    def __init__(self, masks: Masks, stft: STFTConfig = STFT):
        if stft.win_length != stft.n_fft:
            raise ValueError(f"streaming needs win_length == n_fft, got {stft.win_length} and {stft.n_fft}")
        shapes = [tuple(masks.mixture.shape), tuple(masks.difference.shape)]
        if masks.reverb is not None:
            shapes += [tuple(masks.reverb.shape[::2]), (1, *masks.decay.shape)]
        if any(shape != (1, stft.n_freq) for shape in shapes):
            raise ValueError(f"a stream takes the masks of one pose, [1, {stft.n_freq}] for n_fft {stft.n_fft}; got {shapes}")
        self.stft = stft

        self.masks = masks.to(torch.float64, "cpu")
        "The pose's masks in float64, on the CPU."
        self.gains = ear_gains(self.masks.mixture, self.masks.difference)[0].numpy()  # [2, F]
        self._tail_state = None  # [1, F] float64 tensor: decayed power of the frames so far
        n, hop = stft.n_fft, stft.hop_length
        self._w = _hann(n)  # [n_fft]
        self._w2 = self._w**2
        self._pad = n // 2
        self._head = np.zeros(0)  # the first samples, until the start padding can be built
        self._x = np.zeros(0)  # padded-coordinate input kept: x_pad[self._x0 : self._x0 + len]
        self._x0 = 0
        self._acc = np.zeros((2, 0))  # overlap-add accumulator from padded index self._a0
        self._a0 = 0
        self._next_frame = 0
        self._emitted = 0  # output samples (original indices) already returned
        self._received = 0
        self._started = False
        self._done = False
        self._hop = hop

    @property
    def latency(self) -> int:
        """Upper bound on how many samples the output lags the input."""
        return self.stft.n_fft

    # -- internals ---------------------------------------------------------------------

    def _check(self, block) -> np.ndarray:
        if self._done:
            raise ValueError("this stream was flushed; start a new one")
        x = np.asarray(block, dtype=np.float64).reshape(-1)
        if not np.all(np.isfinite(x)):
            raise ValueError("mono block holds NaN or Inf samples")
        return x

    def _frames(self, t0: int, t1: int) -> None:
        """Compute frames [t0, t1) from self._x and overlap-add them into the accumulator."""
        if t1 <= t0:
            return
        n, hop = self.stft.n_fft, self._hop
        starts = np.arange(t0, t1) * hop - self._x0  # [m] into self._x
        idx = starts[:, None] + np.arange(n)[None, :]  # [m, n_fft]
        frames = self._x[idx] * self._w  # [m, n_fft]
        spec = np.fft.rfft(frames, axis=-1)  # [m, F]
        if self.masks.reverb is None:
            ears = spec[None] * self.gains[:, None, :]  # [2, m, F]
        else:
            ears = self._with_tail(spec, t0)
        out = np.fft.irfft(ears, n=n, axis=-1) * self._w  # [2, m, n_fft]
        end = (t1 - 1) * hop + n - self._a0
        if end > self._acc.shape[1]:
            self._acc = np.concatenate([self._acc, np.zeros((2, end - self._acc.shape[1]))], axis=1)
        for j, t in enumerate(range(t0, t1)):  # overlap-add (m is small per block)
            s = t * hop - self._a0
            self._acc[:, s : s + n] += out[:, j]
        self._next_frame = t1

    def _with_tail(self, spec: np.ndarray, t0: int) -> np.ndarray:
        """Ear spectra [2, m, F] of frames spec [m, F]: sqrt((g |S|)^2 + r^2 P) with the source phase."""
        mag = np.abs(spec)  # [m, F]
        mag_t = torch.from_numpy(np.ascontiguousarray(mag.T))[None]  # [1, F, m] float64
        # P(t) = w (P(t-1) + |S(t-1)|^2), carried from the previous block in self._tail_state
        power, self._tail_state = tail_power_recursive(mag_t, self.masks.decay, self._tail_state)
        _, s_l, s_r = ear_magnitudes(mag_t, self.masks, power)
        ear_mag = torch.cat([s_l, s_r]).numpy().transpose(0, 2, 1)  # [2, m, F]
        phase = source_phase(torch.from_numpy(np.ascontiguousarray(spec.T))[None], t0, tail=True)[0]  # [F, m], frames t0 ..
        return ear_mag * phase.numpy().T[None]

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

    # -- public ------------------------------------------------------------------------

    def process(self, block) -> np.ndarray:
        """Feed ``block [n]`` (mono, finite); returns the output samples now final ``[2, m]``."""
        x = self._check(block)
        self._received += len(x)
        hop, pad = self._hop, self._pad
        if not self._started:
            self._head = np.concatenate([self._head, x])
            if len(self._head) <= pad:  # too short to build the reflect padding yet
                return np.zeros((2, 0), dtype=np.float32)
            self._started = True
            head, self._head = self._head, np.zeros(0)
            self._x = np.concatenate([head[pad:0:-1], head])  # x_pad from index 0
            self._x0 = 0
        else:
            self._x = np.concatenate([self._x, x])
        # frame t needs x_pad[t hop, t hop + n_fft) = original samples up to t hop + pad - 1
        t_end = (self._received - pad) // hop + 1  # frames whose samples are all in
        self._frames(self._next_frame, t_end)
        keep_from = self._next_frame * hop  # padded index of the next frame's start
        self._x = self._x[keep_from - self._x0 :]
        self._x0 = keep_from
        # sample i is final once frame floor((i + pad) / hop) is in
        return self._emit(self._next_frame * hop - pad, None)

    def flush(self) -> np.ndarray:
        """End of stream: the remaining output ``[2, m]`` (with the end's reflect padding)."""
        if self._done:
            raise ValueError("this stream was already flushed")
        self._done = True
        T = self._received
        if not self._started:  # shorter than the padding: the one-shot path does it exactly
            return self._one_shot(self._head)
        pad, hop = self._pad, self._hop
        n_frames = 1 + T // hop
        tail = self._x[-1 - pad : -1][::-1] if T > 1 else self._x[-1:]  # reflect x[T-2 .. T-1-pad]
        self._x = np.concatenate([self._x[: T + pad - self._x0], tail])
        self._frames(self._next_frame, n_frames)
        return self._emit(T, n_frames)

    def _one_shot(self, x: np.ndarray) -> np.ndarray:
        if len(x) == 0:
            return np.zeros((2, 0), dtype=np.float32)
        with torch.inference_mode():
            spec = dsp.stft(torch.from_numpy(x.astype(np.float32))[None], self.stft)  # [1, F, N]
            y = binaural_waveform(spec, self.masks.to(torch.float32), len(x), self.stft, synthesis=SynthesisConfig(phase_iterations=0))[0]
        return y.numpy()
