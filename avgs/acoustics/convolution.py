"""Block-by-block convolution of a mono stream with a pose's binaural impulse response.

:class:`BlockConvolver` is uniformly partitioned overlap-save convolution (UPOLS; Wefers,
*Partitioned convolution algorithms for real-time auralization*, 2015, ch. 5): the
response is cut into partitions of one block, each transformed once
(:meth:`~BlockConvolver.set_impulse`); every block of input is transformed once, kept in
a frequency-domain delay line, and multiplied with all partitions. A block costs one FFT
of twice its size, one inverse per ear and ``partitions`` complex multiply-adds per bin,
whatever the response's length, and adds no latency: output block n depends on input
blocks up to n.

A new response (the listener moved) takes effect at the next block: that block is
computed with both the old and the new response and crossfaded linearly (the two outputs
are of the same input through similar filters, so they add coherently; a linear fade
keeps the level), so a pose change never clicks.

:class:`ConvolutionStream` wraps it for blocks of any size: its output equals one
convolution of the whole input, delayed by less than one block.
"""

from __future__ import annotations

import threading

import numpy as np


class BlockConvolver:
    """Convolve blocks of ``block`` samples with an impulse response ``[C, L]``; switch responses with a crossfade.

    ``process(x [block]) -> [C, block]`` float32. ``set_impulse`` may be called from any
    thread; the response is used from the next :meth:`process` on (newest wins).
    """

    def __init__(self, impulse: np.ndarray, block: int):
        block = int(block)
        if block < 1 or block & (block - 1):
            raise ValueError(f"block must be a power of two >= 1, got {block}")
        self.block = block
        self._lock = threading.Lock()
        self._pending: np.ndarray | None = None  # partition spectra waiting for the next block
        self._filter = self._partitions(impulse)  # [C, P, block + 1] complex64
        self.channels = self._filter.shape[0]
        self._delay_line = np.zeros((self._filter.shape[1], block + 1), np.complex64)  # [P, block + 1], newest first
        self._previous = np.zeros(block, np.float32)  # the last input block (overlap-save keeps two)
        self.switches = 0
        "Responses taken into use so far (after the first)."

    def _partitions(self, impulse: np.ndarray) -> np.ndarray:
        h = np.asarray(impulse, dtype=np.float32)
        if h.ndim != 2 or h.shape[1] < 1 or not np.all(np.isfinite(h)):
            raise ValueError(f"impulse must be a finite [channels, length] array, got shape {h.shape}")
        b = self.block
        p = -(-h.shape[1] // b)
        parts = np.zeros((h.shape[0], p, 2 * b), np.float32)  # each partition zero-padded to 2 blocks
        parts[:, :, :b] = np.pad(h, ((0, 0), (0, p * b - h.shape[1]))).reshape(h.shape[0], p, b)
        return np.fft.rfft(parts, axis=-1).astype(np.complex64)  # [C, P, b + 1]

    def set_impulse(self, impulse: np.ndarray) -> None:
        """Use ``impulse [C, L]`` from the next block on (C as before), crossfading over that block."""
        spectra = self._partitions(impulse)
        if spectra.shape[0] != self.channels:
            raise ValueError(f"impulse has {spectra.shape[0]} channels, the convolver {self.channels}")
        with self._lock:
            self._pending = spectra

    def reset(self) -> None:
        """Forget the input so far (silence before the next block)."""
        self._delay_line[:] = 0
        self._previous[:] = 0

    def _apply(self, spectra: np.ndarray) -> np.ndarray:
        p = min(spectra.shape[1], self._delay_line.shape[0])
        acc = np.einsum("pf,cpf->cf", self._delay_line[:p], spectra[:, :p])  # [C, b + 1]
        return np.fft.irfft(acc, 2 * self.block, axis=-1)[:, self.block :]  # [C, b]: the valid half

    def process(self, x: np.ndarray) -> np.ndarray:
        """The next ``[C, block]`` float32 output for input block ``x [block]``."""
        x = np.asarray(x, dtype=np.float32).reshape(-1)
        if x.size != self.block:
            raise ValueError(f"process takes blocks of {self.block} samples, got {x.size}")
        with self._lock:
            pending, self._pending = self._pending, None
        if pending is not None and pending.shape[1] > self._delay_line.shape[0]:
            grown = np.zeros((pending.shape[1], self.block + 1), np.complex64)
            grown[: self._delay_line.shape[0]] = self._delay_line
            self._delay_line = grown
        self._delay_line = np.roll(self._delay_line, 1, axis=0)
        self._delay_line[0] = np.fft.rfft(np.concatenate([self._previous, x]))
        self._previous = x.copy()
        y = self._apply(self._filter)
        if pending is not None:
            ramp = (np.arange(1, self.block + 1, dtype=np.float32) / self.block)  # [b] 1/b .. 1
            y = y * (1.0 - ramp) + self._apply(pending) * ramp
            self._filter = pending
            self.switches += 1
        return y.astype(np.float32, copy=False)


class ConvolutionStream:
    """Convolve a mono stream given in blocks of any size with a response ``[C, L]``.

    Input is gathered into blocks of ``block`` samples for a :class:`BlockConvolver`; the
    output lags the input by less than :attr:`latency` samples, and :meth:`flush` returns
    the rest, so the concatenated output equals the whole input convolved with the
    response and cut to the input's length (float32 rounding).
    """

    def __init__(self, impulse: np.ndarray, block: int = 256):
        self.convolver = BlockConvolver(impulse, block)
        self._pending_in = np.zeros(0, np.float32)
        self._received = 0
        self._emitted = 0
        self._done = False

    @property
    def latency(self) -> int:
        """Upper bound on how many samples the output lags the input."""
        return self.convolver.block

    def set_pose(self, masks, impulse: np.ndarray) -> None:
        """Go on with another pose's response (``masks`` unused: the response is all a filter needs)."""
        self.convolver.set_impulse(impulse)

    def process(self, x) -> np.ndarray:
        """Output ``[C, n]`` (n may be 0) for the next input samples ``x [m]``."""
        if self._done:
            raise ValueError("the stream was flushed; start a new one")
        x = np.asarray(x, dtype=np.float32).reshape(-1)
        if not np.all(np.isfinite(x)):
            raise ValueError("the input block holds NaN or Inf samples")
        self._received += x.size
        buf = np.concatenate([self._pending_in, x])
        b = self.convolver.block
        n = buf.size // b
        out = [self.convolver.process(buf[i * b : (i + 1) * b]) for i in range(n)]
        self._pending_in = buf[n * b :]
        y = np.concatenate(out, axis=1) if out else np.zeros((self.convolver.channels, 0), np.float32)
        self._emitted += y.shape[1]
        return y

    def flush(self) -> np.ndarray:
        """The output still owed for the input given so far ``[C, n]``; the stream ends."""
        if self._done:
            raise ValueError("the stream was flushed already")
        rest = self._received - self._emitted
        y = np.zeros((self.convolver.channels, 0), np.float32)
        if rest > 0:
            b = self.convolver.block
            y = self.convolver.process(np.pad(self._pending_in, (0, b - self._pending_in.size)))[:, :rest]
        self._done = True
        return y
