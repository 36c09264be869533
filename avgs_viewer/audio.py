"""Live binaural playback: the looped mono clip streamed block by block through the pose's filter.

A pose is a filter (B's masks are time-invariant): its binaural impulse response
``[2, L]``. :class:`StreamEngine` reads the looped mono clip one audio block at a time
and convolves it with the current filter (:class:`avgs.acoustics.convolution.BlockConvolver`,
uniformly partitioned, no added latency). A new pose's filter is taken at the next block
and crossfaded over it, so a move is heard one block after its filter is known, with no
re-render of the clip, no gap and no click. Volume and pause ramp over one block.
:meth:`StreamEngine.set_loop` hands it the whole loop rendered at the pose of the
filter playing (:mod:`avgs_viewer.refine`: the renderer's own synthesis, once the pose
has settled); it plays sample for sample in place of the filter's output, crossfaded in
over one block, until the next filter or clip, which crossfade back over their block.
:meth:`StreamEngine.play_once` plays a signal (the pose's impulse response itself) once
instead of the clip: the clip fades out over one block, the signal plays sample for
sample, then the clip fades back in where it stopped. :attr:`StreamEngine.bypass` plays the dry
clip in both ears instead of the filter's output (A/B audition), crossfaded over one block, at
its own make-up gain (the clip at ``target_db`` dB RMS); :meth:`StreamEngine.take_peaks` gives
the meters each ear's sample peak since they last asked (before the output's limit at 1.0).

The engine is pulled by :class:`~avgs_viewer.sound_output.AudioOutput` (the sound card's
callback, or a simulated clock where there is none: :mod:`avgs_viewer.sound_output`), or
by tests directly (:meth:`StreamEngine.render_block`).
"""

from __future__ import annotations

import threading
import time
from collections import OrderedDict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from .voices import Voices

SILENCE_DB = -120.0
ONCE_PEAK = 0.9
"A signal played once (:meth:`StreamEngine.play_once`) peaks at most here (about -1 dB full scale)."


# ---------------------------------------------------------------------- clips
def load_clip(path: str | Path, sample_rate: int, max_seconds: float = 30.0) -> np.ndarray:
    """An audio file as mono float32 [T] at ``sample_rate``: down-mixed, resampled, trimmed
    to ``max_seconds`` (:func:`avgs.io.audio_input.read_mono`)."""
    from avgs.io.audio_input import read_mono

    return read_mono(path, sample_rate, max_seconds=max_seconds)


def make_seamless_loop(mono: np.ndarray, fade: int) -> np.ndarray:
    """Shorten ``mono`` [T] by ``fade`` samples so that looping it has no seam.

    The clip's tail is crossfaded into its head: the loop starts where the original
    tail left off and ends where the original head continues, so the wrap is continuous.
    """
    mono = np.asarray(mono, dtype=np.float32)
    fade = int(min(fade, len(mono) // 4))
    if fade <= 0:
        return mono.copy()
    loop = mono[: len(mono) - fade].copy()
    t = (np.arange(fade) + 0.5) / fade
    loop[:fade] = mono[:fade] * np.sin(0.5 * np.pi * t) + mono[-fade:] * np.cos(0.5 * np.pi * t)
    return loop


# ---------------------------------------------------------------------- levels
def rms_db(x: np.ndarray, axis: int = -1) -> np.ndarray:
    """RMS level in dB full scale along ``axis`` (floored at -120 dB for silence)."""
    rms = np.sqrt(np.mean(np.square(np.asarray(x, dtype=np.float64)), axis=axis))
    return np.maximum(20.0 * np.log10(np.maximum(rms, 1e-12)), SILENCE_DB)


def levels(binaural: np.ndarray) -> tuple[float, float, float]:
    """(left dB, right dB, interaural level difference dB = left - right) of [2, T] audio."""
    binaural = np.asarray(binaural)
    if binaural.ndim != 2 or binaural.shape[0] != 2:
        raise ValueError(f"binaural audio must be [2, T], got shape {binaural.shape}")
    left, right = rms_db(binaural, axis=1)
    return float(left), float(right), float(left - right)


# ---------------------------------------------------------------------- clip spectrum
@dataclass(frozen=True)
class ClipSpectrum:
    """A clip's long-term power spectrum, to tell how loud a filter makes it without convolving it.

    ``density`` [n // 2 + 1] is Welch's estimate (Hann segments of ``n`` samples, half
    overlapping) on the bins of an ``n``-point FFT; ``mean_square`` the clip's mean square.
    For a stationary clip, the mean square of ``h * clip`` is
    ``mean_square * sum(w |H|^2 p) / sum(w p)`` (p: the density on H's bins, w: the one-sided
    weights), which :meth:`output_power` returns per channel.
    """

    density: np.ndarray
    mean_square: float
    n: int
    _weighted: dict = field(default_factory=dict, init=False, repr=False, compare=False)  # m -> (w p on m's bins, sum)

    @classmethod
    def of(cls, mono: np.ndarray, n: int = 2048) -> "ClipSpectrum":
        x = np.asarray(mono, dtype=np.float64)
        n = int(min(n, 1 << max(1, int(np.floor(np.log2(max(len(x), 2)))))))
        hop = n // 2
        starts = range(0, max(1, len(x) - n + 1), hop)
        window = np.hanning(n)
        power = np.zeros(n // 2 + 1)
        for s in starts:
            seg = x[s:s + n]
            if len(seg) < n:
                seg = np.pad(seg, (0, n - len(seg)))
            power += np.abs(np.fft.rfft(seg * window)) ** 2
        return cls(density=power / max(1, len(starts)), mean_square=float(np.mean(np.square(x))) if len(x) else 0.0,
                   n=n)

    def _weights(self, m: int) -> tuple[np.ndarray, float]:
        """``w p`` [m // 2 + 1] on the bins of an ``m``-point FFT and its sum (the same for every filter of a length)."""
        if m not in self._weighted:
            density = np.interp(np.arange(m // 2 + 1) / m, np.arange(self.n // 2 + 1) / self.n, self.density)
            w = np.full(m // 2 + 1, 2.0)
            w[0] = w[-1] = 1.0
            self._weighted[m] = (w * density, float(np.sum(w * density)))
        return self._weighted[m]

    def output_power(self, impulse: np.ndarray) -> np.ndarray:
        """[C] mean square of each channel of ``impulse [C, L]`` applied to the clip."""
        h = np.asarray(impulse, dtype=np.float64)
        m = max(self.n, 1 << int(np.ceil(np.log2(max(h.shape[-1], 2)))))
        weights, total = self._weights(m)
        if total <= 0.0:
            return np.zeros(h.shape[0])
        gain = np.abs(np.fft.rfft(h, m, axis=-1)) ** 2  # [C, m // 2 + 1]
        return self.mean_square * (gain @ weights) / total


def filter_levels(impulse: np.ndarray, spectrum: ClipSpectrum, gain: float = 1.0) -> tuple[float, float, float]:
    """(left dB, right dB, left - right dB) of the clip heard through ``impulse [2, L]`` times ``gain``."""
    power = spectrum.output_power(impulse) * gain ** 2
    left, right = (max(10.0 * np.log10(max(p, 1e-24)), SILENCE_DB) for p in power[:2])
    return float(left), float(right), float(left - right)


# ---------------------------------------------------------------------- engine
_NONE = object()


class _Once:
    """A signal being played once: its samples [L, 2] (gain applied) and how many have played."""

    def __init__(self, samples: np.ndarray):
        self.samples = samples
        self.pos = 0


def _binaural(x, what: str, length: str, items: str) -> np.ndarray:
    """``x`` as a contiguous float32 [2, n] array with n > 0 and finite values, else a ValueError naming ``what``."""
    y = np.ascontiguousarray(x, dtype=np.float32)
    if y.ndim != 2 or y.shape[0] != 2 or y.shape[1] == 0:
        raise ValueError(f"{what} must be [2, {length}] with {length} > 0, got shape {y.shape}")
    if not np.all(np.isfinite(y)):
        raise ValueError(f"{what} has non-finite {items}")
    return y


def _block_convolver():
    from avgs.acoustics.convolution import BlockConvolver

    return BlockConvolver


class StreamEngine:
    """Streams a looped mono clip through a binaural filter, one block at a time; meters its output.

    Thread-safe: :meth:`set_filter`, :meth:`set_clip` and the controls may be called from
    any thread; :meth:`render_block` / :meth:`callback` run on the audio thread.
    A filter handed to :meth:`set_filter` is used from the next block on, crossfaded over
    that block; several set between two blocks: the newest wins. Each filter carries a
    ``tag`` (the viewer's pose number); :attr:`live_tag` is the tag of the filter in the
    last block out, and :meth:`wait_live` tells when a tag's first block left the engine.

    ``block`` is the audio block in samples (128 at 22050 Hz: 5.8 ms; a new filter waits for the
    next block, so the block is part of what a drag's sound lags: 256 gave a p95 5-50 ms worse
    in benchmarks/viewer.md's runs, for about 1 % of a core less). ``ahead`` blocks of
    the clip are read and transformed at once, and their outputs computed in batches while
    the filter holds (:class:`~avgs.acoustics.convolution.BlockConvolver`): the callback of
    most blocks only scales and copies one. A new filter still plays from the next block (the
    blocks computed ahead with the old one are computed again), a new clip from the next
    block too (the input read ahead is read again from the new clip). The make-up gain
    is fitted once per clip, on the first filter, so that the louder ear plays at
    ``target_db`` dB RMS at full volume; it then stays, so level changes between poses
    stay audible. Volume and play/pause changes ramp over one block.
    """

    def __init__(self, sample_rate: int, block: int = 128, target_db: float = -18.0,
                 convolver: Callable | None = None, ahead: int = 16):
        if block < 16:
            raise ValueError(f"audio block must be at least 16 samples, got {block}")
        if ahead < 1:
            raise ValueError(f"blocks read ahead must be at least 1, got {ahead}")
        self.sample_rate = int(sample_rate)
        self.block = int(block)
        self.ahead = int(ahead)
        self._fed_from: list = []  # (clip, position, next clip) before each block fed ahead, oldest first
        self.target_db = float(target_db)
        self._convolver = convolver
        self._lock = threading.Lock()
        self._live_cond = threading.Condition()
        self._clip: np.ndarray | None = None       # [T] float32 loop
        self._next_clip: np.ndarray | None = None  # crossfaded in at the next block
        self._spectrum: ClipSpectrum | None = None
        self._pos = 0
        self._conv = None
        self._impulse: np.ndarray | None = None
        self._pending = False
        self._pending_tag = None
        self._filter_tag = None  # the tag of the newest filter set
        self._loop: tuple | None = None  # (binaural [2, T] float32, its clip [T], tag): set_loop's
        self._loop_mix = 0.0  # how much of the block out was the loop, at the block's end (0 .. 1)
        self.loop_tag = None
        "The tag of the rendered loop fully in the last block out (None: the filter plays)."
        self.loops_set = 0
        self._fresh_loop = _NONE
        self._fifo = np.zeros((0, 2), dtype=np.float32)
        self._live_at: OrderedDict = OrderedDict()  # tag -> perf_counter when its first block left
        self._gain = 0.0             # volume x make-up gain at the end of the last block
        self.volume = 0.8
        self.playing = True
        self.makeup_gain: float | None = None
        self._once: _Once | None = None  # a signal played instead of the clip (play_once)
        self.once_gain: float | None = None
        "The gain of the newest signal played once (:meth:`play_once`)."
        self.live_tag = None
        self._fresh = _NONE
        self.blocks = 0              # blocks rendered with sound (not paused)
        self.filters_set = 0
        self._last_out: np.ndarray | None = None  # [block, 2] the last block out (None: silence)
        self.bypass = False
        "True: the dry clip in both ears (no filter), crossfaded over one block."
        self._bypass_mix = 0.0  # how much of the block out was the dry clip, at its end (0 .. 1)
        self._dry_gain = 1.0  # the dry clip at target_db dB RMS
        self._peaks = np.zeros(2, dtype=np.float32)  # [2] each ear's peak |sample| since take_peaks
        self.voices = Voices(self.block)  # the other sources, added to the first's block (set_voice)
        self.source_gain = 1.0
        "The first source's gain (several sources: :mod:`avgs_viewer.sources`), ramped over one block."
        self._source_gain = 1.0

    # -- other sources (any thread)
    def set_voice(self, key: int, clip: np.ndarray | None = None, gain: float | None = None) -> None:
        """Another source ``key`` (:mod:`avgs_viewer.voices`): its seamless loop [T] (from its start) and gain."""
        with self._lock:
            self.voices.set(key, clip, gain)

    def set_voice_filter(self, key: int, impulse: np.ndarray) -> None:
        """Source ``key``'s filter [2, L], from the next block on (crossfaded over it)."""
        h = _binaural(impulse, "binaural filter", "L", "taps")
        with self._lock:
            self.voices[key].set_filter(h)

    def remove_voice(self, key: int) -> None:
        """Source ``key`` fades out over the next block."""
        with self._lock:
            self.voices.remove(key)

    @property
    def clip_position(self) -> int:
        """The sample of the looped clip the next block out starts at."""
        with self._lock:
            return self._fed_from[0][1] if self._fed_from else self._pos

    def take_peaks(self) -> tuple[float, float]:
        """Each ear's largest |sample| out since the last call (before the limit at 1.0: a value
        >= 1.0 means the output clipped), and start again from zero."""
        peaks, self._peaks = self._peaks, np.zeros(2, dtype=np.float32)
        return float(peaks[0]), float(peaks[1])

    @property
    def block_levels(self) -> tuple[float, float]:
        """(left, right) dB RMS of the last block out (measured when read: the meters read a few a second)."""
        out = self._last_out
        if out is None:
            return (SILENCE_DB, SILENCE_DB)
        left, right = rms_db(out, axis=0)
        return (float(left), float(right))

    # -- control (any thread)
    @property
    def clip(self) -> np.ndarray | None:
        """The looped mono clip [T] (the newest one set)."""
        return self._next_clip if self._next_clip is not None else self._clip

    @property
    def spectrum(self) -> ClipSpectrum | None:
        """The looped clip's long-term spectrum (:func:`filter_levels`)."""
        return self._spectrum

    @property
    def impulse(self) -> np.ndarray | None:
        """The newest filter set, [2, L] float32 (before make-up gain)."""
        return self._impulse

    @property
    def has_pending(self) -> bool:
        """Whether a filter set with :meth:`set_filter` has not been used by a block yet."""
        with self._lock:
            return self._pending

    @property
    def switch_pending(self) -> bool:
        """Whether a filter set with :meth:`set_filter` waits for the next block that plays the clip
        (False while paused or playing a signal once: no block would take it soon)."""
        with self._lock:
            return self._pending and self.playing and self._once is None

    def set_clip(self, mono: np.ndarray) -> None:
        """Loop ``mono [T]`` (at :attr:`sample_rate`, already seamless); the old clip is crossfaded
        into it over the next block, and the make-up gain is fitted again."""
        mono = np.ascontiguousarray(mono, dtype=np.float32)
        if mono.ndim != 1 or len(mono) == 0:
            raise ValueError(f"clip must be mono [T] with T > 0, got shape {mono.shape}")
        if not np.all(np.isfinite(mono)):
            raise ValueError("clip has non-finite samples")
        spectrum = ClipSpectrum.of(mono)
        with self._lock:
            self._unread_ahead()
            if self._clip is None:
                self._clip, self._pos = mono, 0
            else:
                self._next_clip = mono
            self._spectrum = spectrum
            rms = float(np.sqrt(np.mean(np.square(mono, dtype=np.float64))))
            self._dry_gain = 10.0 ** (self.target_db / 20.0) / rms if rms > 0 else 1.0
            self.makeup_gain = None
            if self._impulse is not None:
                self.makeup_gain = self._fit_gain(self._impulse)

    def set_filter(self, impulse: np.ndarray, tag: int | None = None) -> None:
        """Play through ``impulse [2, L]`` float32 (left, right: a pose's ``RenderResult.impulse``)
        from the next block on (a rendered loop playing fades out over that block); ``tag``: the
        viewer's pose number."""
        h = _binaural(impulse, "binaural filter", "L", "taps")
        with self._lock:
            if self._conv is None:
                self._conv = self._convolver(h, self.block) if self._convolver else \
                    _block_convolver()(h, self.block, batch=self.ahead)
            else:
                self._conv.set_impulse(h)
            self._impulse = h
            if self.makeup_gain is None and self._spectrum is not None:
                self.makeup_gain = self._fit_gain(h)
            self._pending, self._pending_tag = True, tag
            self._filter_tag = tag
            self.filters_set += 1

    def set_loop(self, binaural: np.ndarray, tag: int | None, clip: np.ndarray | None = None) -> bool:
        """Play ``binaural [2, T]`` in place of the clip through the filter ``tag``: the looped clip
        rendered at that filter's pose, sample i heard with clip sample i (T = the clip's length).

        It is crossfaded in over the next block and plays, in step with the clip's position,
        until another filter or clip is set (crossfaded back over that one's block); the
        make-up gain, volume and pause apply as to the filter's output. Returns False, and
        plays nothing, when ``tag`` is not the newest filter's or the clip is not the one
        playing (``clip``: the clip it was rendered from; a loop for an older pose or clip).
        """
        y = _binaural(binaural, "a rendered loop", "T", "samples")
        with self._lock:
            playing = self._clip
            if (tag != self._filter_tag or self._next_clip is not None or playing is None
                    or y.shape[1] != len(playing) or (clip is not None and clip is not playing)):
                return False
            self._loop = (y, playing, tag)
            self.loops_set += 1
            return True

    @property
    def playing_once(self) -> bool:
        """Whether a signal handed to :meth:`play_once` has not finished playing."""
        with self._lock:
            return self._once is not None

    def play_once(self, signal: np.ndarray) -> float:
        """Play ``signal [2, L]`` (left, right) once instead of the clip, then the clip again.

        The clip fades out over the next block (at once when nothing plays); the block after
        it starts with the signal's first sample, times one gain (returned): volume x make-up
        gain, lowered if need be so that the signal peaks at :data:`ONCE_PEAK`. It plays even
        while paused (it was asked for); after it the clip fades back in where it stopped, or
        stays paused. A second call replaces a signal still playing.
        """
        x = _binaural(signal, "a signal to play once", "L", "samples")
        peak = float(np.max(np.abs(x)))
        gain = float(self.volume) * (self.makeup_gain or 1.0)
        if peak * gain > ONCE_PEAK:
            gain = ONCE_PEAK / peak
        samples = np.ascontiguousarray((x * np.float32(gain)).T)  # [L, 2]
        with self._lock:
            self._once = _Once(samples)
            self.once_gain = gain
        return gain

    def _play_once_block(self, out: np.ndarray) -> None:
        """The next block of the signal played once into ``out [n, 2]``. Under the lock."""
        once, n = self._once, len(out)
        part = once.samples[once.pos:once.pos + n]
        out[:len(part)] = part
        once.pos += n
        if once.pos >= len(once.samples):
            self._once = None

    def reset_gain(self) -> None:
        """Fit the make-up gain again on the next filter (a new scene)."""
        with self._lock:
            self.makeup_gain = None

    def _fit_gain(self, h: np.ndarray) -> float:
        loudest = float(np.max(self._spectrum.output_power(h)))
        return float(10.0 ** (self.target_db / 20.0) / np.sqrt(loudest)) if loudest > 0 else 1.0

    def wait_live(self, tag: int | tuple[str, int] | None, timeout: float = 10.0) -> float | None:
        """The ``perf_counter`` time at which the first block made with filter ``tag`` left the
        engine (``("loop", tag)``: the first block wholly of its rendered loop), waiting up to
        ``timeout`` s for it; None if it has not (yet)."""
        deadline = time.perf_counter() + timeout
        with self._live_cond:
            while tag not in self._live_at:
                left = deadline - time.perf_counter()
                if left <= 0:
                    return None
                self._live_cond.wait(left)
            return self._live_at[tag]

    # -- audio thread
    def _input(self, blocks: int) -> np.ndarray:
        """The next ``blocks`` blocks of the looped clip, [blocks * block] (a new clip crossfaded in over
        the first); notes where each started (:meth:`_unread_ahead`). Under the lock."""
        n = self.block
        parts = []
        if self._next_clip is not None:
            clip, new = self._clip, self._next_clip
            self._fed_from.append((clip, self._pos, new))
            t = (np.arange(n) + 0.5) / n
            x = clip[(self._pos + np.arange(n)) % len(clip)]
            parts.append(x * np.cos(0.5 * np.pi * t) + new[np.arange(n) % len(new)] * np.sin(0.5 * np.pi * t))
            self._clip, self._next_clip, self._pos = new, None, n % len(new)
            blocks -= 1
        clip, pos = self._clip, self._pos
        self._fed_from.extend((clip, (pos + i * n) % len(clip), None) for i in range(blocks))
        parts.append(clip[(pos + np.arange(blocks * n)) % len(clip)])
        self._pos = (pos + blocks * n) % len(clip)
        return np.concatenate(parts).astype(np.float32, copy=False)

    def _unread_ahead(self) -> None:
        """Give back the clip read ahead and not played yet (a new clip plays from the next block). Under the lock."""
        if self._fed_from and self._conv is not None and hasattr(self._conv, "drop_ahead"):
            self._conv.drop_ahead()
            self._clip, self._pos, self._next_clip = self._fed_from[0]
            self._fed_from.clear()

    def _convolved(self) -> tuple[np.ndarray, tuple]:
        """(the next block of the clip through the filter [2, block], (clip, position, whether a
        new clip is crossfaded in) of its input). Under the lock."""
        conv = self._conv
        if not hasattr(conv, "pull"):  # a convolver that takes one block at a time
            self._fed_from.clear()
            where = (self._clip, self._pos, self._next_clip is not None)
            return conv.process(self._input(1)), where
        if conv.ahead == 0:
            conv.feed(self._input(self.ahead))
        clip, pos, new = self._fed_from.pop(0)
        return conv.pull(), (clip, pos, new is not None)

    def _mix_loop(self, y: np.ndarray, clip, pos: int, new_clip: bool) -> None:
        """Crossfade the rendered loop into (or out of) the block ``y [2, block]`` of ``clip`` from
        ``pos``, in place. Under the lock."""
        loop = self._loop
        mine = loop is not None and loop[1] is clip  # the loop is this block's clip rendered
        on = mine and loop[2] == self._filter_tag and not new_clip
        target = 1.0 if on else 0.0
        if target == 0.0 and self._loop_mix == 0.0:
            self._loop, self.loop_tag = None, None
            return
        n = self.block
        if mine:  # [2, n], in step with the clip
            y_loop, T = loop[0], loop[0].shape[1]
            part = y_loop[:, pos:pos + n] if pos + n <= T else y_loop[:, (pos + np.arange(n)) % T]
        else:  # (not reached: a loop's clip stays until it has faded out) fade to the filter's output
            part = np.zeros_like(y)
        if target == self._loop_mix:  # wholly the loop
            y[:] = part
            if self.loop_tag != loop[2]:
                self._fresh_loop = loop[2]  # its first block wholly out (wait_live)
            self.loop_tag = loop[2]
        else:  # crossfading into it or out of it
            ramp = np.linspace(self._loop_mix, target, n + 1, dtype=np.float32)[1:]  # [n]
            y *= 1.0 - ramp
            y += part * ramp
            self.loop_tag = None
        self._loop_mix = target

    def _mix_sources(self, y: np.ndarray) -> None:
        """The first source's block ``y [2, block]`` at its gain plus the other sources' blocks, in place. Under the lock."""
        gain = float(self.source_gain)
        if gain != self._source_gain:
            y *= np.linspace(self._source_gain, gain, self.block + 1, dtype=np.float32)[1:]
        elif gain != 1.0:
            y *= np.float32(gain)
        self._source_gain = gain
        self.voices.mix(y)

    def _mix_dry(self, y: np.ndarray, clip: np.ndarray, pos: int, makeup: float) -> None:
        """Crossfade the dry clip from ``pos`` (both ears, at its own gain) into or out of the block
        ``y [2, block]``, in place. Under the lock."""
        n = self.block
        dry = clip[(pos + np.arange(n)) % len(clip)] * np.float32(self._dry_gain / makeup)  # [n]
        target = 1.0 if self.bypass else 0.0
        if target == self._bypass_mix:
            y[:] = dry
        else:
            ramp = np.linspace(self._bypass_mix, target, n + 1, dtype=np.float32)[1:]  # [n]
            y *= 1.0 - ramp
            y += dry * ramp
        self._bypass_mix = target

    def render_block(self) -> np.ndarray:
        """The next :attr:`block` output samples, [block, 2] float32 (advances the engine)."""
        n = self.block
        out = np.zeros((n, 2), dtype=np.float32)
        with self._lock:
            once = self._once is not None
            target = float(self.volume) if self.playing and not once else 0.0  # a signal played once: the clip fades out
            if once and (self._gain == 0.0 or self._conv is None or self._clip is None):
                self._play_once_block(out)  # the clip is silent: the signal plays as it is
                np.maximum(self._peaks, np.abs(out).max(axis=0), out=self._peaks)
                self.blocks += 1
                self._last_out = out
                return out
            if self._conv is None or self._clip is None or (self._gain == 0.0 and target == 0.0):
                self._last_out = None
                return out  # nothing to play yet, or paused: the position holds
            y, where = self._convolved()  # [2, n]
            if self._loop is not None or self._loop_mix > 0.0:
                self._mix_loop(y, *where)
            if self.source_gain != 1.0 or self._source_gain != 1.0 or len(self.voices):
                self._mix_sources(y)
            makeup = self.makeup_gain or 1.0
            if self.bypass or self._bypass_mix > 0.0:
                self._mix_dry(y, where[0], where[1], makeup)
            tag, fresh = self._pending_tag, self._pending
            self._pending = False
        # Volume, pause and make-up gain (refitted for a new clip) all ramp over the block, never step.
        gain = target * makeup
        if gain == self._gain:
            np.multiply(y.T, np.float32(gain), out=out)
        else:
            out[:] = (y * np.linspace(self._gain, gain, n + 1, dtype=np.float32)[1:]).T  # ramp [n]
        np.maximum(self._peaks, np.abs(out).max(axis=0), out=self._peaks)
        np.clip(out, -1.0, 1.0, out=out)
        self._gain = gain
        self.blocks += 1
        self._last_out = out
        if fresh:
            self._fresh = tag
        self.live_tag = tag
        return out

    def callback(self, outdata: np.ndarray, frames: int, time_info=None, status=None) -> None:
        """``sounddevice`` output callback: fills ``outdata`` [frames, 2] (any ``frames``)."""
        self._fresh = self._fresh_loop = _NONE
        if frames == self.block and len(self._fifo) == 0:
            outdata[:] = self.render_block()
        else:
            parts = [self._fifo]
            have = len(self._fifo)
            while have < frames:
                parts.append(self.render_block())
                have += self.block
            buf = np.concatenate(parts)
            outdata[:] = buf[:frames]
            self._fifo = buf[frames:]
        if self._fresh is not _NONE or self._fresh_loop is not _NONE:  # a new filter's or loop's first block left
            t = time.perf_counter()
            with self._live_cond:
                if self._fresh is not _NONE:
                    self._live_at[self._fresh] = t
                if self._fresh_loop is not _NONE:
                    self._live_at[("loop", self._fresh_loop)] = t
                while len(self._live_at) > 512:
                    self._live_at.popitem(last=False)
                self._live_cond.notify_all()
