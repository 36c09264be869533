"""Record the listener's path while the user moves it: a keyframe per pose change, timed.

While recording, every pose the :class:`~avgs_viewer.state.ViewerState` announces (a drag, a
typed position, a turn key) becomes a keyframe ``{"t", "listener", "yaw", "source"}`` at its
time since the start; :meth:`PathRecorder.stop` adds the pose held at the end. The keyframes
are what :func:`avgs.export.flypath.write_path` saves and ``avgs-viewer --flythrough`` plays.
No Qt: the clock is a parameter (tests may give their own).
"""

from __future__ import annotations

import time
from collections.abc import Callable

from avgs.export.flypath import Keyframe

from .state import Pose, ViewerState

MIN_STEP = 1e-3
"Seconds between two keyframes at least: a pose that comes sooner replaces the last keyframe."


class PathRecorder:
    def __init__(self, clock: Callable[[], float] = time.monotonic):
        self.clock = clock
        self.keyframes: list[Keyframe] = []
        self._state: ViewerState | None = None
        self._t0 = 0.0

    @property
    def recording(self) -> bool:
        return self._state is not None

    def start(self, state: ViewerState) -> None:
        """Start a new path at ``state``'s pose now."""
        self.stop()
        self.keyframes = []
        self._t0 = self.clock()
        self._state = state
        state.events.pose.connect(self._on_pose)
        self._add(state.pose, 0.0)

    def stop(self) -> list[Keyframe]:
        """Stop (the pose held now ends the path); returns the keyframes."""
        state, self._state = self._state, None
        if state is not None:
            state.events.pose.disconnect(self._on_pose)
            self._add(state.pose, self.clock() - self._t0, end=True)
        return self.keyframes

    def _on_pose(self, pose: Pose) -> None:
        self._add(pose, self.clock() - self._t0)

    def _add(self, pose: Pose, t: float, end: bool = False) -> None:
        k = Keyframe(round(t, 4), tuple(float(v) for v in pose.listener), float(pose.yaw),
                     tuple(float(v) for v in pose.source))
        if self.keyframes and k.t - self.keyframes[-1].t < MIN_STEP:
            if end:  # the pose held at the end is the last one already
                return
            self.keyframes[-1] = Keyframe(self.keyframes[-1].t, k.listener, k.yaw, k.source)
            return
        self.keyframes.append(k)
