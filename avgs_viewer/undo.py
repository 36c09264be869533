"""Undo and redo of pose changes (Ctrl+Z / Ctrl+Shift+Z) on a ``QUndoStack``.

:class:`PoseHistory` watches a :class:`~avgs_viewer.state.ViewerState`: each settled pose change
(a typed value, a key's turn, a recalled pose, or a whole drag: its start to its drop, one
step) is one command; changes while the state is ``interacting`` wait for the end of the
interaction. Undo and redo set the state to the pose before or after; the history's own
changes, and those it is told to ignore (head tracking's stream, :meth:`PoseHistory.quiet`),
are not recorded.
"""

from __future__ import annotations

from contextlib import contextmanager

from PySide6 import QtGui

from .state import Pose, ViewerState


def set_pose(state: ViewerState, pose: Pose) -> None:
    """Put ``state`` at ``pose`` (the source only where it may move)."""
    state.set_listener(pose.listener, keep_height=False)
    state.set_yaw(pose.yaw)
    if state.source_movable:
        state.set_source(pose.source)


class _PoseChange(QtGui.QUndoCommand):
    def __init__(self, history: "PoseHistory", before: Pose, after: Pose, text: str):
        super().__init__(text)
        self.history, self.before, self.after = history, before, after
        self._first = True

    def redo(self) -> None:
        if self._first:  # pushed after the change was made
            self._first = False
            return
        self.history._put(self.after)

    def undo(self) -> None:
        self.history._put(self.before)


class PoseHistory:
    """The undo stack of ``state``'s poses (``bind`` again for a new scene: the stack is cleared)."""

    def __init__(self, parent=None):
        self.stack = QtGui.QUndoStack(parent)
        self.state: ViewerState | None = None
        self._settled: Pose | None = None
        self._quiet = 0

    def bind(self, state: ViewerState) -> None:
        if self.state is not None:
            self.state.events.pose.disconnect(self._on_pose)
            self.state.events.interacting.disconnect(self._on_interacting)
        self.stack.clear()
        self.state, self._settled = state, state.pose
        state.events.pose.connect(self._on_pose)
        state.events.interacting.connect(self._on_interacting)

    @contextmanager
    def quiet(self):
        """Changes made inside are not recorded; the pose after them is the one the next change undoes to."""
        self._quiet += 1
        try:
            yield
        finally:
            self._quiet -= 1
            if self.state is not None:
                self._settled = self.state.pose

    def apply(self, pose: Pose, text: str = "pose") -> None:
        """Go to ``pose`` as one undoable step."""
        if self.state is None:
            return
        with self.quiet():
            before = self.state.pose
            set_pose(self.state, pose)
            after = self.state.pose
        if after != before:
            self.stack.push(_PoseChange(self, before, after, text))

    def _put(self, pose: Pose) -> None:
        with self.quiet():
            set_pose(self.state, pose)

    def _on_pose(self, pose: Pose) -> None:
        if self._quiet or self.state is None or self.state.interacting:
            return
        self._record(pose, "pose change")

    def _on_interacting(self, moving: bool) -> None:
        if not moving and not self._quiet and self.state is not None:
            self._record(self.state.pose, "drag")

    def _record(self, pose: Pose, text: str) -> None:
        before = self._settled
        self._settled = pose
        if before is not None and before != pose:
            self.stack.push(_PoseChange(self, before, pose, text))
