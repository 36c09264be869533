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


def mono_block(block, flushed: bool, dtype=np.float32) -> np.ndarray:
    """A stream's next input ``block`` as a flat array of ``dtype``; ValueError once the stream
    was flushed, or for NaN or Inf samples (every stream's ``process`` takes its input so)."""
    if flushed:
        raise ValueError("this stream was flushed; start a new one")
    x = np.asarray(block, dtype=dtype).reshape(-1)
    if not np.all(np.isfinite(x)):
        raise ValueError("mono block holds NaN or Inf samples")
    return x


class BlockConvolver:
    """Convolve blocks of ``block`` samples with an impulse response ``[C, L]``; switch responses with a crossfade.

    ``process(x [block]) -> [C, block]`` float32. ``set_impulse`` may be called from any
    thread; the response is used from the next output block on (newest wins).

    Input may also be given ahead of time (:meth:`feed` several blocks, then :meth:`pull`
    their outputs one by one): the input's frequency-domain delay line does not depend on
    the response, so the outputs of blocks fed ahead are computed together, in batches of
    up to ``batch`` blocks (one matrix product per bin instead of one per block), while the
    response stays the same. A new response still takes effect at the next :meth:`pull`:
    that block is crossfaded from its old output (computed or cached) to the new one, and
    the outputs cached ahead with the old response are dropped and computed again from the
    delay line. After a switch the batches start again at one block and double while the
    response holds, so a drag (a new response every few blocks) computes no block twice.
    :meth:`drop_ahead` forgets the input fed but not yet pulled (a new clip replaces it).
    """

    def __init__(self, impulse: np.ndarray, block: int, batch: int = 8):
        block = int(block)
        if block < 1 or block & (block - 1):
            raise ValueError(f"block must be a power of two >= 1, got {block}")
        if int(batch) < 1:
            raise ValueError(f"batch must be at least 1 block, got {batch}")
        self.block = block
        self.batch = int(batch)
        self._lock = threading.Lock()
        self._pending: np.ndarray | None = None  # partition spectra waiting for the next block
        self._filter = self._partitions(impulse)  # [F, P, C] complex64, partition P-1 first (see _partitions)
        self.channels = self._filter.shape[2]
        self._history = np.zeros((0, block + 1), np.complex64)  # [T, F] input spectra, oldest first
        self._end = 0        # history rows in use: [0, _end); the newest fed block is _end - 1
        self._ahead = 0      # blocks fed but not pulled yet: the last _ahead rows of the history
        self._fed_x = np.zeros((1, block), np.float32)  # [1 + ahead, block]: the last pulled input, then those fed
        self._cache = np.zeros((0, self.channels, block), np.float32)  # outputs computed ahead, next first
        self._run = 1        # size of the next batch (doubles while the response holds)
        self._make_room(self._filter.shape[1], 0)
        self.switches = 0
        "Responses taken into use so far (after the first)."

    def _partitions(self, impulse: np.ndarray) -> np.ndarray:
        """[F, P, C] spectra of the response's partitions, the last partition first: output block n
        is ``sum_q X[n - P + 1 + q] @ spectra[:, q]`` over the P newest input spectra, oldest first."""
        h = np.asarray(impulse, dtype=np.float32)
        if h.ndim != 2 or h.shape[1] < 1 or not np.all(np.isfinite(h)):
            raise ValueError(f"impulse must be a finite [channels, length] array, got shape {h.shape}")
        import torch  # its float32 FFT: a third of NumPy's (float64) time, on the path from a pose to its sound

        c, b = h.shape[0], self.block
        p = -(-h.shape[1] // b)
        parts = np.zeros((p, c, 2 * b), np.float32)  # [P, C, 2b] the last partition first, each zero-padded to 2 blocks
        parts[:, :, :b] = np.pad(h, ((0, 0), (0, p * b - h.shape[1]))).reshape(c, p, b)[:, ::-1].transpose(1, 0, 2)
        spectra = torch.fft.rfft(torch.from_numpy(parts), dim=-1)  # [P, C, b + 1] complex64
        return spectra.permute(2, 0, 1).contiguous().numpy()  # [b + 1, P, C]

    @property
    def partitions(self) -> int:
        return self._filter.shape[1]

    @property
    def ahead(self) -> int:
        """Blocks fed (:meth:`feed`) whose output has not been pulled yet."""
        return self._ahead

    def set_impulse(self, impulse: np.ndarray) -> None:
        """Use ``impulse [C, L]`` from the next block on (C as before), crossfading over that block."""
        spectra = self._partitions(impulse)
        if spectra.shape[2] != self.channels:
            raise ValueError(f"impulse has {spectra.shape[2]} channels, the convolver {self.channels}")
        with self._lock:
            self._pending = spectra

    def reset(self) -> None:
        """Forget the input so far (silence before the next block), including what was fed ahead."""
        self._history[:] = 0
        self._end = self.partitions - 1  # rows before it: silence
        self._ahead = 0
        self._fed_x = np.zeros((1, self.block), np.float32)
        self._cache = self._cache[:0]

    def _make_room(self, partitions: int, blocks: int) -> None:
        """History for ``partitions`` partitions behind the oldest unpulled block, and room for
        ``blocks`` more: the rows still needed move to the front (older ones, if the history
        grows, are silence)."""
        keep = partitions - 1 + self._ahead  # rows the next outputs read
        if self._end + blocks <= self._history.shape[0] and self._end - self._ahead >= partitions - 1:
            return
        rows = max(self._history.shape[0], keep + blocks + 4 * self.batch)
        history = np.zeros((rows, self.block + 1), np.complex64)
        have = min(keep, self._end)
        history[keep - have:keep] = self._history[self._end - have:self._end]
        self._history, self._end = history, keep

    def _outputs(self, start: int, count: int, spectra: np.ndarray) -> np.ndarray:
        """[count, C, block] outputs of history rows start .. start + count - 1 through ``spectra`` [F, P, C]."""
        p = spectra.shape[1]
        window = self._history[start - p + 1:start + count]  # [P + count - 1, F]
        frames = np.lib.stride_tricks.sliding_window_view(window, p, axis=0)  # [count, F, P]
        acc = np.matmul(np.ascontiguousarray(frames.transpose(1, 0, 2)), spectra)  # [F, count, C]
        y = np.fft.irfft(acc.transpose(1, 2, 0), 2 * self.block, axis=-1)[..., self.block:]  # [count, C, b]
        return y.astype(np.float32, copy=False)

    def feed(self, x: np.ndarray) -> None:
        """Give the next input samples ``x [k * block]`` (k >= 1) ahead of their outputs."""
        x = np.asarray(x, dtype=np.float32).reshape(-1)
        if x.size == 0 or x.size % self.block:
            raise ValueError(f"feed takes a whole number of blocks of {self.block} samples, got {x.size}")
        blocks = x.reshape(-1, self.block)  # [k, b]
        k = len(blocks)
        frames = np.concatenate([np.concatenate([self._fed_x[-1:], blocks[:-1]]), blocks], axis=1)  # [k, 2b]
        self._make_room(self.partitions, k)
        self._history[self._end:self._end + k] = np.fft.rfft(frames, axis=-1)
        self._end += k
        self._ahead += k
        self._fed_x = np.concatenate([self._fed_x, blocks])

    def drop_ahead(self) -> int:
        """Forget the input fed but not pulled yet (it is fed again, or other input instead); how many blocks."""
        dropped, self._ahead = self._ahead, 0
        self._end -= dropped
        self._fed_x = self._fed_x[:1]
        self._cache = self._cache[:0]
        return dropped

    def pull(self) -> np.ndarray:
        """The ``[C, block]`` float32 output of the oldest block fed and not yet pulled."""
        if self._ahead == 0:
            raise ValueError("pull: no input fed ahead (feed first)")
        with self._lock:
            pending, self._pending = self._pending, None
        row = self._end - self._ahead
        if pending is not None:
            if pending.shape[1] > self.partitions:
                self._make_room(pending.shape[1], 0)
                row = self._end - self._ahead
            old = self._cache[0] if len(self._cache) else self._outputs(row, 1, self._filter)[0]
            ramp = np.arange(1, self.block + 1, dtype=np.float32) / self.block  # [b] 1/b .. 1
            y = old * (1.0 - ramp) + self._outputs(row, 1, pending)[0] * ramp
            self._filter, self._cache, self._run = pending, self._cache[:0], 1
            self.switches += 1
        else:
            if not len(self._cache):
                count = min(self._run, self._ahead)
                self._cache = self._outputs(row, count, self._filter)
                self._run = min(2 * self._run, self.batch)
            y, self._cache = self._cache[0], self._cache[1:]
        self._ahead -= 1
        self._fed_x = self._fed_x[1:]
        return y.astype(np.float32, copy=False)

    def process(self, x: np.ndarray) -> np.ndarray:
        """The next ``[C, block]`` float32 output for input block ``x [block]``."""
        x = np.asarray(x, dtype=np.float32).reshape(-1)
        if x.size != self.block:
            raise ValueError(f"process takes blocks of {self.block} samples, got {x.size}")
        self.feed(x)
        return self.pull()


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
        x = mono_block(x, self._done)
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
