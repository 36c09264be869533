"""Looping binaural playback: clip loading, a click-free buffer swap, meters, the output stream.

One continuous output stream loops the current binaural render of the chosen mono clip.
When the listener or source moves, the whole clip is rendered again for the new pose
(time-invariant masks: the same filter for any length) and :meth:`LoopEngine.set_buffer`
swaps it in with a short crossfade at the current play position, so playback never
restarts, gaps or clicks. The engine is plain numpy: tests drive :meth:`LoopEngine.callback`
directly with known signals; :class:`AudioOutput` connects it to ``sounddevice`` when a
device exists and reports why not otherwise (no sound card on CI).
"""

from __future__ import annotations

import threading
from pathlib import Path

import numpy as np

SILENCE_DB = -120.0


# ---------------------------------------------------------------------- clips
def load_clip(path: str | Path, sample_rate: int, max_seconds: float = 30.0) -> np.ndarray:
    """An audio file as mono float32 [T] at ``sample_rate``: down-mixed, resampled, trimmed
    to ``max_seconds`` (:func:`avgs.audio_input.read_mono`)."""
    from avgs.audio_input import read_mono

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


# ---------------------------------------------------------------------- engine
class LoopEngine:
    """Loops a binaural buffer [2, T]; swaps in new buffers with a crossfade; meters its output.

    Thread-safe: :meth:`set_buffer` may be called from any thread; :meth:`callback` runs
    on the audio thread. A buffer set while a crossfade is running waits for it to end
    and is replaced by any newer one meanwhile (newest wins).

    ``fade_seconds`` is the swap crossfade. ``curve`` "equal_power" (cos/sin gains:
    constant power for uncorrelated material) or "linear" (gains sum to one: constant
    amplitude when old and new are nearly the same signal, as two renders of one clip are).
    Volume and play/pause changes ramp over one block, never step.
    """

    def __init__(self, sample_rate: int, fade_seconds: float = 0.03, curve: str = "equal_power",
                 peak_target: float = 0.5):
        if curve not in ("equal_power", "linear"):
            raise ValueError(f"crossfade curve must be 'equal_power' or 'linear', got {curve!r}")
        self.sample_rate = int(sample_rate)
        self.fade_len = max(1, int(round(fade_seconds * sample_rate)))
        self.curve = curve
        self.peak_target = float(peak_target)
        self._lock = threading.Lock()
        self._current: np.ndarray | None = None   # [T, 2] float32
        self._next: np.ndarray | None = None      # [T', 2] buffer being faded in
        self._pending: np.ndarray | None = None   # [T'', 2] newest buffer waiting
        self._fade_pos = 0
        self._pos = 0
        self._gain = 0.0            # gain applied at the end of the last block
        self.volume = 0.8
        self.playing = True
        self.makeup_gain: float | None = None  # fixed per clip/scene so level changes stay audible
        self.generation = 0          # buffers adopted by the audio thread (a fade started)
        self.submitted = 0           # buffers handed to set_buffer
        self.block_levels = (SILENCE_DB, SILENCE_DB)  # (left, right) dB of the last output block

    # -- control (any thread)
    @property
    def has_pending(self) -> bool:
        """Whether a buffer handed to :meth:`set_buffer` waits to be adopted by the audio thread."""
        with self._lock:
            return self._pending is not None

    def set_buffer(self, binaural: np.ndarray) -> None:
        """Queue binaural [2, T] audio to be crossfaded in at the current play position."""
        binaural = np.asarray(binaural, dtype=np.float32)
        if binaural.ndim != 2 or binaural.shape[0] != 2 or binaural.shape[1] == 0:
            raise ValueError(f"binaural buffer must be [2, T] with T > 0, got shape {binaural.shape}")
        if not np.all(np.isfinite(binaural)):
            raise ValueError("binaural buffer has non-finite samples")
        with self._lock:
            if self.makeup_gain is None:
                peak = float(np.abs(binaural).max())
                self.makeup_gain = self.peak_target / peak if peak > 0 else 1.0
            self._pending = np.ascontiguousarray((binaural * self.makeup_gain).T)  # [T, 2]
            self.submitted += 1

    def reset_gain(self) -> None:
        """Fit the make-up gain again on the next buffer (after a new clip or scene)."""
        with self._lock:
            self.makeup_gain = None

    @property
    def position(self) -> int:
        """Play position in samples within the current loop."""
        return self._pos

    @property
    def current(self) -> np.ndarray | None:
        """The buffer playing now, [2, T] after make-up gain (None before the first)."""
        cur = self._current
        return None if cur is None else cur.T

    # -- audio thread
    def _fade_gains(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if self.curve == "linear":
            return 1.0 - t, t
        return np.cos(0.5 * np.pi * t), np.sin(0.5 * np.pi * t)

    def render_block(self, frames: int) -> np.ndarray:
        """The next ``frames`` output samples, [frames, 2] float32 (advances the engine)."""
        with self._lock:
            if self._next is None and self._pending is not None:
                self._next, self._pending = self._pending, None
                self._fade_pos = 0
                self.generation += 1
            cur, nxt, fade_pos = self._current, self._next, self._fade_pos
        target = self.volume if self.playing else 0.0
        out = np.zeros((frames, 2), dtype=np.float32)
        if self._gain == 0.0 and target == 0.0:
            self.block_levels = (SILENCE_DB, SILENCE_DB)
            return out  # paused: the position holds
        n = np.arange(frames)
        if cur is not None:
            out += cur[(self._pos + n) % len(cur)]
        if nxt is not None:
            t = np.clip((fade_pos + n + 1) / self.fade_len, 0.0, 1.0)[:, None]
            g_old, g_new = self._fade_gains(t)
            out *= g_old
            out += g_new * nxt[(self._pos + n) % len(nxt)]
            if fade_pos + frames >= self.fade_len:  # the fade is over: the new buffer plays
                with self._lock:
                    self._current, self._next = nxt, None
                cur = nxt
            else:
                with self._lock:
                    self._fade_pos = fade_pos + frames
        ramp = np.linspace(self._gain, target, frames + 1, dtype=np.float32)[1:, None]
        out *= ramp
        np.clip(out, -1.0, 1.0, out=out)
        self._gain = target
        playing_buffer = cur if cur is not None else nxt  # the first buffer fades in from silence
        if playing_buffer is not None:
            self._pos = (self._pos + frames) % len(playing_buffer)
        left, right = rms_db(out, axis=0)
        self.block_levels = (float(left), float(right))
        return out

    def callback(self, outdata: np.ndarray, frames: int, time=None, status=None) -> None:
        """``sounddevice`` output callback: fills ``outdata`` [frames, 2]."""
        outdata[:] = self.render_block(frames)


class AudioOutput:
    """One continuous ``sounddevice`` output stream playing a :class:`LoopEngine`.

    ``start()`` returns None when playing, or a one-line reason when there is no usable
    audio device (sounddevice or PortAudio missing, no sound card); the rest of the
    viewer keeps working either way.
    """

    def __init__(self, engine: LoopEngine, blocksize: int = 512):
        self.engine = engine
        self.blocksize = int(blocksize)
        self._stream = None
        self.message: str | None = None

    @property
    def available(self) -> bool:
        return self._stream is not None

    def start(self) -> str | None:
        try:
            import sounddevice as sd
        except (ImportError, OSError) as exc:  # OSError: the PortAudio library is missing
            self.message = f"No audio output: sounddevice unavailable ({exc})"
            return self.message
        try:
            stream = sd.OutputStream(samplerate=self.engine.sample_rate, channels=2, dtype="float32",
                                     blocksize=self.blocksize, callback=self.engine.callback)
            stream.start()
        except (sd.PortAudioError, ValueError, OSError) as exc:
            self.message = f"No audio device: {str(exc).splitlines()[0]}"
            return self.message
        self._stream = stream
        self.message = None
        return None

    def close(self) -> None:
        stream, self._stream = self._stream, None
        if stream is not None:
            try:
                stream.stop()
                stream.close()
            except Exception:  # a vanished device must not stop the viewer from closing
                pass
