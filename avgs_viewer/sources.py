"""The scene's sound sources: where each is, what it plays and how loud (plain Python, no Qt).

A checkpoint trained on impulse responses (``renderer.source_aware``) renders any source
position, so the explorer can play several at once: what is heard is the sum of each source's
clip through its own filter, times its gain. One source is selected: it is the state's source,
the handle a drag moves and the pose panel types; the others stay where they were put.
:class:`Sources` keeps the list and the selection; :meth:`Sources.follow` keeps the selected
source where the state's source is, and puts the state's source on a newly selected one.
A one-source checkpoint keeps its one fixed source (:attr:`Sources.can_add` is False).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from itertools import count
from typing import TYPE_CHECKING, Callable

import numpy as np

if TYPE_CHECKING:
    from .state import ViewerState

MAX_SOURCES = 8
"Sources at most: each is a filter computed on every move and a stream convolved in every block."

_ids = count(1)


@dataclass
class Source:
    """One source: its position [3] (world metres), its clip [T] (mono, at the scene's rate), its
    gain (linear, 0 .. 2) and an id that stays while it exists (the engine's voice key)."""

    position: np.ndarray
    clip: np.ndarray
    gain: float = 1.0
    id: int = field(default_factory=lambda: next(_ids))


class Sources:
    """The sources of one scene, the first made from the state's source; one is selected.

    ``changed()`` callbacks run after every change but a move (sources added, removed, selected,
    a gain or a clip); ``moved()`` after a source's position changed."""

    def __init__(self, position, clip: np.ndarray, can_add: bool = True, why_not: str = ""):
        self.items: list[Source] = [Source(np.array(position, dtype=np.float64), np.asarray(clip, np.float32))]
        self.selected = 0
        self.can_add = bool(can_add)
        self.why_not = why_not  # why sources cannot be added (a one-source checkpoint)
        self.changed: list[Callable[[], None]] = []
        self.moved: list[Callable[[], None]] = []
        self._state: ViewerState | None = None

    def __len__(self) -> int:
        return len(self.items)

    @property
    def current(self) -> Source:
        return self.items[self.selected]

    def positions(self) -> np.ndarray:
        """[N, 3] every source's position, in list order."""
        return np.stack([s.position for s in self.items])

    def _notify(self, callbacks) -> None:
        for cb in list(callbacks):
            cb()

    # ------------------------------------------------------------------ changes
    def add(self, position=None, clip: np.ndarray | None = None, gain: float = 1.0) -> int:
        """A new source (default: 1 m along x from the selected one, playing its clip), selected; its index.
        ValueError when this checkpoint has one fixed source or :data:`MAX_SOURCES` are there."""
        if not self.can_add:
            raise ValueError(f"cannot add a source: {self.why_not}")
        if len(self.items) >= MAX_SOURCES:
            raise ValueError(f"cannot add a source: {MAX_SOURCES} sources at most")
        here = self.current
        position = here.position + np.array([1.0, 0.0, 0.0]) if position is None else position
        self.items.append(Source(np.array(position, dtype=np.float64),
                                 here.clip if clip is None else np.asarray(clip, np.float32), float(gain)))
        self.select(len(self.items) - 1)
        return self.selected

    def remove(self, index: int | None = None) -> None:
        """Remove source ``index`` (default: the selected one); the last one stays (ValueError)."""
        index = self.selected if index is None else int(index)
        if len(self.items) == 1:
            raise ValueError("cannot remove the only source")
        del self.items[index]
        selected = min(self.selected if self.selected < index else max(self.selected - 1, 0), len(self.items) - 1)
        self.selected = -1  # select() below puts the state's source on it
        self.select(selected)

    def select(self, index: int) -> None:
        index = int(index)
        if not 0 <= index < len(self.items):
            raise ValueError(f"source index must be 0 .. {len(self.items) - 1}, got {index}")
        if index == self.selected:
            return
        self.selected = index
        if self._state is not None:
            self._state.set_source(self.items[index].position)  # clamped into the room: moved() follows
        self._notify(self.changed)

    def set_gain(self, index: int, gain: float) -> None:
        gain = float(gain)
        if not np.isfinite(gain) or gain < 0:
            raise ValueError(f"source gain must be a finite number >= 0, got {gain}")
        self.items[index].gain = gain
        self._notify(self.changed)

    def set_clip(self, index: int, clip: np.ndarray) -> None:
        clip = np.asarray(clip, np.float32)
        if clip.ndim != 1 or len(clip) == 0:
            raise ValueError(f"clip must be mono [T] with T > 0, got shape {clip.shape}")
        self.items[index].clip = clip
        self._notify(self.changed)

    # ------------------------------------------------------------------ the state's source
    def follow(self, state: ViewerState) -> None:
        """The selected source is ``state``'s source from now on (a drag, a typed position)."""
        self._state = state
        state.events.source.connect(self._source_moved)

    def unfollow(self) -> None:
        if self._state is not None:
            self._state.events.source.disconnect(self._source_moved)
            self._state = None

    def _source_moved(self, position) -> None:
        here = self.current
        if not np.array_equal(here.position, position):
            here.position = np.array(position, dtype=np.float64)
            self._notify(self.moved)
