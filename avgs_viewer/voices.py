"""The engine's other sources: one voice per source beyond the first, each its own looped clip
through its own filter, times its own gain, added to the first source's block.

A voice is a small :class:`~avgs_viewer.audio.StreamEngine` path without the extras (a loop
rendered in full, a signal played once, bypass): a :class:`~avgs.acoustics.convolution.BlockConvolver`
fed one block at a time, so a new filter is taken at the next block and crossfaded over it,
as the first source's; a new clip plays from its start, a gain change and a removal ramp over
one block. The make-up gain, volume and pause are the engine's, applied to the sum.
"""

from __future__ import annotations

import numpy as np


class Voice:
    """One source's looped clip [T] through its filter [2, L], at ``gain``."""

    def __init__(self, clip: np.ndarray, gain: float, block: int):
        self.clip = np.ascontiguousarray(clip, dtype=np.float32)
        self.pos = 0  # the clip sample the next block starts at
        self.gain = float(gain)  # target
        self._gain = float(gain)  # at the end of the last block
        self.block = block
        self.conv = None
        self.impulse: np.ndarray | None = None
        self.removing = False

    def set_filter(self, impulse: np.ndarray) -> None:
        from avgs.acoustics.convolution import BlockConvolver

        if self.conv is None:
            self.conv = BlockConvolver(impulse, self.block, batch=1)
        else:
            self.conv.set_impulse(impulse)
        self.impulse = impulse

    def set_clip(self, clip: np.ndarray) -> None:
        self.clip, self.pos = np.ascontiguousarray(clip, dtype=np.float32), 0

    def add_block(self, y: np.ndarray) -> bool:
        """Add this voice's next block to ``y [2, block]``; False once it has faded out (removed)."""
        if self.conv is None:  # no filter yet: silent, the clip waits
            return not self.removing
        n, clip = self.block, self.clip
        x = clip[self.pos:self.pos + n] if self.pos + n <= len(clip) else clip[(self.pos + np.arange(n)) % len(clip)]
        self.pos = (self.pos + n) % len(clip)
        out = self.conv.process(x)  # [2, n]
        target = 0.0 if self.removing else self.gain
        if target == self._gain:
            y += out * np.float32(target)
        else:
            y += out * np.linspace(self._gain, target, n + 1, dtype=np.float32)[1:]
        self._gain = target
        return not self.removing


class Voices:
    """The voices by key (a source's id). Not thread-safe: the engine calls it under its lock."""

    def __init__(self, block: int):
        self.block = block
        self._voices: dict[int, Voice] = {}

    def __len__(self) -> int:
        return len(self._voices)

    def __contains__(self, key: int) -> bool:
        return key in self._voices and not self._voices[key].removing

    def __getitem__(self, key: int) -> Voice:
        return self._voices[key]

    def keys(self) -> list[int]:
        return [k for k, v in self._voices.items() if not v.removing]

    def set(self, key: int, clip: np.ndarray | None = None, gain: float | None = None) -> Voice:
        """Voice ``key`` (made on first use, with ``clip``): its clip from its start if given, its gain."""
        voice = self._voices.get(key)
        if voice is None or voice.removing:
            if clip is None:
                raise ValueError(f"voice {key} is new: it needs a clip")
            voice = self._voices[key] = Voice(clip, 1.0 if gain is None else gain, self.block)
        elif clip is not None and clip is not voice.clip:
            voice.set_clip(clip)
        if gain is not None:
            voice.gain = float(gain)
        return voice

    def remove(self, key: int) -> None:
        """Voice ``key`` fades out over the next block, then is gone."""
        if key in self._voices:
            self._voices[key].removing = True

    def mix(self, y: np.ndarray) -> None:
        """Add every voice's next block to ``y [2, block]`` in place."""
        for key, voice in list(self._voices.items()):
            if not voice.add_block(y):
                del self._voices[key]
