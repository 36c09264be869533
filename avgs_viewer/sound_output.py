"""The engine's output: the sound card, or a clock that pulls its blocks where there is none.

:class:`AudioOutput` runs a :class:`~avgs_viewer.audio.StreamEngine` from the sound card's
callback (``sounddevice``), or, where there is no sound card (CI, these machines), from
:class:`SimulatedClock`, a thread that pulls blocks at the card's pace: the same path either
way, so the meters, the benchmark and the tests measure what a user hears.
"""

from __future__ import annotations

import threading
import time
from typing import TYPE_CHECKING, Callable

import numpy as np

if TYPE_CHECKING:
    from .audio import StreamEngine


class SimulatedClock:
    """A sound card's clock where there is none: a thread that calls ``callback(outdata, block)``
    every ``block / sample_rate`` seconds (absolute deadlines; after a stall it goes on from
    now rather than catching up in a burst)."""

    def __init__(self, callback: Callable, sample_rate: int, block: int, name: str = "avgs-audio-clock"):
        self._callback = callback
        self.period = block / float(sample_rate)
        self.block = int(block)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)

    def start(self) -> None:
        self._thread.start()

    def _run(self) -> None:
        out = np.zeros((self.block, 2), dtype=np.float32)
        next_t = time.perf_counter()
        while not self._stop.is_set():
            self._callback(out, self.block, None, None)
            next_t += self.period
            wait = next_t - time.perf_counter()
            if wait < -self.period:
                next_t = time.perf_counter()
            elif wait > 0:
                time.sleep(wait)  # lighter than an Event wait; close() waits at most one period

    def close(self) -> None:
        self._stop.set()
        if self._thread.is_alive() and threading.current_thread() is not self._thread:
            self._thread.join(5)

    @property
    def alive(self) -> bool:
        return self._thread.is_alive()


class AudioOutput:
    """Runs a :class:`StreamEngine`: from a ``sounddevice`` output stream when there is a sound
    card, else from a :class:`SimulatedClock` (``device=False`` forces the clock).

    ``start()`` returns None when a sound card plays, or a one-line reason why not; the
    engine runs either way, so meters, benchmark and tests see the same blocks.
    """

    def __init__(self, engine: StreamEngine, device: bool = True):
        self.engine = engine
        self.blocksize = engine.block
        self._use_device = device
        self._stream = None
        self._clock: SimulatedClock | None = None
        self.message: str | None = None

    @property
    def available(self) -> bool:
        """Whether a sound card plays the engine."""
        return self._stream is not None

    @property
    def running(self) -> bool:
        """Whether the engine is being pulled (by a sound card or the simulated clock)."""
        return self._stream is not None or (self._clock is not None and self._clock.alive)

    def start(self) -> str | None:
        self.message = self._open_device() if self._use_device else "Audio output off"
        if self.message is not None:
            self._clock = SimulatedClock(self.engine.callback, self.engine.sample_rate, self.engine.block)
            self._clock.start()
        return self.message

    def _open_device(self) -> str | None:
        try:
            import sounddevice as sd
        except (ImportError, OSError) as exc:  # OSError: the PortAudio library is missing
            return f"No audio output: sounddevice unavailable ({exc})"
        try:
            stream = sd.OutputStream(samplerate=self.engine.sample_rate, channels=2, dtype="float32",
                                     blocksize=self.blocksize, latency="low", callback=self.engine.callback)
            stream.start()
        except (sd.PortAudioError, ValueError, OSError) as exc:
            return f"No audio device: {str(exc).splitlines()[0]}"
        self._stream = stream
        return None

    def close(self) -> None:
        stream, self._stream = self._stream, None
        clock, self._clock = self._clock, None
        if clock is not None:
            clock.close()
        if stream is not None:
            try:
                stream.stop()
                stream.close()
            except Exception:  # a vanished device must not stop the viewer from closing
                pass
