"""The default synthesis (one phase retrieved for the mid magnitudes) block by block.

:meth:`avgs.render.renderer.SceneRenderer.render` by default gives both ears' predicted
magnitudes the phase that fast Griffin-Lim retrieves for the mid magnitudes
(:func:`avgs.acoustics.synthesis.mid_phase_waveform`). :class:`MidPhaseStream` computes the
same waveform from blocks of any size:

1. the input is framed as its samples arrive (the centred STFT's reflect padding at both
   ends), and each frame's magnitudes are computed at once: the source's, the tail's power
   by its one-pole recursion, the ears' and the mid (:func:`~avgs.acoustics.synthesis.ear_magnitudes`);
2. after K iterations a frame depends only on frames within ``4 (K + 2)`` of it (the
   window's reach per iteration; :func:`avgs.dsp.phase_retrieval.griffin_lim`), so every
   ``block_frames`` frames the phase is retrieved on them and that margin on both sides,
   and their output is final.

So the concatenated output equals ``render(...).binaural`` (to float32 rounding, which the
iterations carry along: within a few times the render's own distance from float64), and
lags the input by at most :attr:`MidPhaseStream.latency` samples: the margin and one block,
0.39 s with the default 10 iterations. Where that is too long (an interactive player),
the pose's filter streams with no more than a convolution block of delay
(``SynthesisConfig(method="filter")``, what the explorer plays while a pose changes; a
settled pose it renders in full with this stream: :mod:`avgs_viewer.refine`) and the
filter's phase with 29 ms (:class:`avgs.render.streaming.BinauralStream`).
"""

from __future__ import annotations

import numpy as np
import torch

from avgs import dsp
from avgs.acoustics.convolution import mono_block
from avgs.acoustics.reverb_tail import tail_power_recursive
from avgs.acoustics.synthesis import Masks, ear_ramp, mid_phase_parts, mid_phase_waveform, shared_phase_waveform
from avgs.config import STFT, STFTConfig, SynthesisConfig
from avgs.dsp.phase_retrieval import FrameGrid, retrieve_phase
from avgs.render.streaming import one_pose

BLOCK_FRAMES = 16
"Frames made final per phase retrieval (93 ms at AV-NeRF's hop): shorter adds work, longer adds delay."


class MidPhaseStream:
    """Binauralise a mono stream block by block with one pose's :class:`Masks` ([1, F]) and
    ``synthesis`` (its phase ``mid``; :class:`~avgs.config.SynthesisConfig`)."""

    def __init__(self, masks: Masks, stft: STFTConfig = STFT, synthesis: SynthesisConfig | None = None,
                 block_frames: int = BLOCK_FRAMES):
        if not FrameGrid.covers(stft):
            raise ValueError(f"streaming needs win_length == n_fft and a hop dividing it, got {stft}")
        self.synthesis = synthesis or SynthesisConfig()
        if self.synthesis.phase != "mid" or self.synthesis.method != "spectrogram":
            raise ValueError(f"MidPhaseStream streams the mid phase, not {self.synthesis}")
        if block_frames < 1:
            raise ValueError(f"block_frames must be >= 1, got {block_frames}")
        self.stft = stft
        self.masks = one_pose(masks, stft, torch.float32)
        "The pose's masks in float32, on the CPU (what the one-shot render uses)."
        n, hop = stft.n_fft, stft.hop_length
        self._hop, self._pad = hop, n // 2
        self._window = torch.hann_window(n, dtype=torch.float32)
        self._iterations = self.synthesis.iterations
        self._margin = -(-n // hop) * (self._iterations + 2)  # frames either side of a block: its reach
        self._block = int(block_frames)
        self._head = np.zeros(0, dtype=np.float32)  # the first samples, until the start padding can be built
        self._x = np.zeros(0, dtype=np.float32)  # padded samples from padded index self._x0
        self._x0 = 0
        self._received = 0  # input samples so far
        self._next_frame = 0  # frames whose magnitudes are made
        self._f0 = 0  # absolute index of the first frame kept below
        n_freq = stft.n_freq
        self._start = torch.zeros(0, n_freq, dtype=torch.complex64)  # [N, F] s_m with the source's phase
        self._mid = torch.zeros(0, n_freq)  # [N, F] s_m
        self._ears = torch.zeros(2, 0, n_freq)  # [2, N, F] s_l, s_r
        self._ramp = None if self.masks.delay is None else torch.zeros(2, 0, n_freq, dtype=torch.complex64)  # [2, N, F] the ears' delays
        self._tail_state = None  # [1, F]: decayed source power of the frames so far
        self._final = 0  # frames whose output is out: samples before _final * hop are emitted
        self._started = False
        self._done = False

    def set_pose(self, masks: Masks, impulse=None) -> None:
        """Go on with another pose of the same scene (e.g. from another thread, between blocks):
        frames made from now on take its magnitudes (the phase retrieval and the overlap-add
        blend the change over a few frames). ``impulse`` is not used (the filter streams' argument)."""
        self.masks = one_pose(masks, self.stft, torch.float32, like=self.masks)

    @property
    def latency(self) -> int:
        """Upper bound on how many samples the output lags the input."""
        return (self._block + self._margin + 2) * self._hop + self._pad

    # -- internals ---------------------------------------------------------------------

    def _frames(self, t0: int, t1: int) -> None:
        """Make the magnitudes and first phase of frames [t0, t1) from self._x."""
        if t1 <= t0:
            return
        n, hop = self.stft.n_fft, self._hop
        frames = torch.from_numpy(self._x[t0 * hop - self._x0 : (t1 - 1) * hop + n - self._x0])
        spec = torch.fft.rfft(frames.unfold(0, n, hop) * self._window).T[None]  # [1, F, m]
        masks = self.masks  # one pose for these frames, whatever another thread sets meanwhile
        tail = None
        if masks.reverb is not None:  # P(t) = w (P(t-1) + |S(t-1)|^2), carried from block to block
            tail, self._tail_state = tail_power_recursive(spec.abs(), masks.decay, self._tail_state)
        start, mid, ears = mid_phase_parts(spec, masks, t0, tail)  # [1, m, F], [1, m, F], [1, 2, m, F]
        self._start = torch.cat([self._start, start[0]])
        self._mid = torch.cat([self._mid, mid[0]])
        self._ears = torch.cat([self._ears, ears[0]], dim=1)
        if self._ramp is not None:  # each frame delays the ears as its pose says
            ramp = ear_ramp(masks, self.stft)[0]  # [2, F]
            self._ramp = torch.cat([self._ramp, ramp[:, None, :].expand(2, t1 - t0, ramp.shape[-1])], dim=1)
        self._next_frame = t1

    def _retrieve(self, s: int, e: int, b: int, length: int | None) -> np.ndarray:
        """Output samples of frames [s, e) (to the input's end when ``length`` is given), from a
        phase retrieval on frames [a, b) with a = max(0, s - margin)."""
        hop = self._hop
        a = max(0, s - self._margin)
        piece_len = (b - a - 1) * hop if length is None else length - a * hop  # centred frames a .. b-1
        lo, hi = a - self._f0, b - self._f0
        mid, ears = self._mid[lo:hi], self._ears[:, lo:hi]
        phase = retrieve_phase(mid, self._start[lo:hi], piece_len, self._iterations, self.synthesis.phase_momentum,
                               self.stft)  # [b - a, F]
        ramp = None if self._ramp is None else self._ramp[:, lo:hi]
        y = shared_phase_waveform(ears, phase, piece_len, self.stft, ramp)  # [2, piece_len]
        out_hi = e * hop if length is None else length
        return y[:, s * hop - a * hop : out_hi - a * hop].numpy()

    def _emit(self, available: int) -> np.ndarray:
        """Output of every block whose reach lies within the ``available`` frames."""
        pieces = []
        while self._final + self._block + self._margin <= available:
            s, e = self._final, self._final + self._block
            pieces.append(self._retrieve(s, e, e + self._margin, None))
            self._final = e
        self._forget()
        return np.concatenate(pieces, axis=1) if pieces else np.zeros((2, 0), dtype=np.float32)

    def _forget(self) -> None:
        """Drop frames no later block reaches."""
        keep = max(0, self._final - self._margin)
        if keep > self._f0:
            cut = keep - self._f0
            self._start, self._mid, self._ears = self._start[cut:], self._mid[cut:], self._ears[:, cut:]
            if self._ramp is not None:
                self._ramp = self._ramp[:, cut:]
            self._f0 = keep

    def _take(self, x: np.ndarray) -> np.ndarray:
        hop, pad = self._hop, self._pad
        if not self._started:
            self._head = np.concatenate([self._head, x])
            if self._head.size <= pad:  # too short to build the reflect padding yet
                return np.zeros((2, 0), dtype=np.float32)
            self._started = True
            head, self._head = self._head, np.zeros(0, dtype=np.float32)
            self._x = np.concatenate([head[pad:0:-1], head])  # x_pad from index 0
            self._x0 = 0
        else:
            self._x = np.concatenate([self._x, x])
        # frame t needs x_pad[t hop, t hop + n_fft) = input samples up to t hop + pad - 1
        t_end = (self._received - pad) // hop + 1  # frames whose samples are all in
        self._frames(self._next_frame, t_end)
        keep_from = self._next_frame * hop  # padded index of the next frame's start
        self._x = self._x[keep_from - self._x0 :]
        self._x0 = keep_from
        return self._emit(self._next_frame)

    # -- public ------------------------------------------------------------------------

    def process(self, block) -> np.ndarray:
        """Feed ``block [n]`` (mono, finite); returns the output samples now final ``[2, m]``."""
        x = mono_block(block, self._done)
        self._received += x.size
        with torch.inference_mode():
            return self._take(x)

    def flush(self) -> np.ndarray:
        """End of stream: the remaining output ``[2, m]`` (with the end's reflect padding)."""
        if self._done:
            raise ValueError("this stream was already flushed")
        self._done = True
        T, pad, hop = self._received, self._pad, self._hop
        with torch.inference_mode():
            if not self._started:  # shorter than the padding: in one piece, as the one-shot path
                if self._head.size == 0:
                    return np.zeros((2, 0), dtype=np.float32)
                x = torch.from_numpy(self._head)
                y, _ = mid_phase_waveform(dsp.stft(x[None], self.stft), self.masks, T, self.stft, self.synthesis)
                return y[0].numpy()
            n_frames = 1 + T // hop
            end = self._x[-1 - pad : -1][::-1] if T > 1 else self._x[-1:]  # reflect x[T-2 .. T-1-pad]
            self._x = np.concatenate([self._x[: T + pad - self._x0], end])
            self._frames(self._next_frame, n_frames)
            if self._final >= n_frames:
                return np.zeros((2, 0), dtype=np.float32)
            return self._retrieve(self._final, n_frames, n_frames, T)
