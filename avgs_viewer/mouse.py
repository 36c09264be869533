"""The 3D view's mouse: left-button drags that start on a handle, to the drag logic and the audio path.

The window's event filter hands :class:`ViewMouse` the 3D view's mouse events, with the
scene's drag logic and audio path: a left press on a handle (the listener's or the source's
sphere) and what follows go to the Qt-free :class:`~avgs_viewer.drag.DragController`,
everything else to VTK (the camera). During a drag, on X11, the pointer is read from the X
server ahead of the GUI thread (:class:`~avgs_viewer.pointer.PointerFollower`) and its poses
handed straight to :meth:`LiveAudio.request <avgs_viewer.worker.LiveAudio.request>`.

Everywhere (Wayland, macOS, Windows, or ``AVGS_VIEWER_NO_POINTER=1``) each Qt move is handled
before anything is drawn: the drag maps it onto the handle's plane without VTK (the plane map
fitted at the press), the state's pose event hands the pose to the audio path, and the view only
asks for a repaint, which the canvas spaces by a frame interval while the drag lasts
(:meth:`SceneCanvas.set_dragging <avgs_viewer.canvas.SceneCanvas.set_dragging>`), so the GUI
thread is free for the next move and the release more of the time.
"""

from __future__ import annotations

import os
from typing import TYPE_CHECKING, Literal

from PySide6 import QtCore, QtGui

if TYPE_CHECKING:  # imported at the first drag
    from .canvas import SceneCanvas
    from .drag import DragController
    from .pointer import PointerFollower
    from .worker import LiveAudio

_MOUSE = (QtCore.QEvent.Type.MouseButtonPress, QtCore.QEvent.Type.MouseMove, QtCore.QEvent.Type.MouseButtonRelease)


class ViewMouse:
    """Mouse events on the 3D view ``plotter``."""

    def __init__(self, plotter: SceneCanvas):
        self.plotter = plotter
        self.follower: PointerFollower | Literal[False] | None = None  # made at the first drag; False: none (not X11)

    def event(self, event: QtCore.QEvent, drag: DragController, live: LiveAudio | None) -> bool | None:
        """Whether the scene's ``drag`` took ``event``; None: not its event (VTK's, as the event
        filter's default). ``live``: the scene's audio path, which a drag's poses go to."""
        kind = event.type()
        if kind not in _MOUSE:
            return None
        plotter = self.plotter
        pos = event.position()
        scale = plotter.devicePixelRatioF()
        x, y = pos.x() * scale, (plotter.height() - pos.y() - 1) * scale  # VTK display pixels
        if kind == QtCore.QEvent.Type.MouseButtonPress:
            if event.button() == QtCore.Qt.MouseButton.LeftButton:
                grabbed = drag.press(x, y)
                if grabbed and drag.dragging is not None:
                    plotter.set_dragging(True)
                    self._follow_pointer(x, y, drag, live)
                return grabbed
        elif kind == QtCore.QEvent.Type.MouseMove:
            return drag.move(x, y)
        elif event.button() == QtCore.Qt.MouseButton.LeftButton:
            if self.follower:
                self.follower.stop()
            taken = drag.release(x, y)
            if live is not None:
                live.follow(False)  # the state's pose, unless the follower already asked for it
            plotter.set_dragging(False)  # the release's frame is drawn now, after its pose went
            return taken
        return None

    def _follow_pointer(self, x: float, y: float, drag: DragController, live: LiveAudio | None) -> None:
        """Hand the drag's moves and release to the audio path straight from the X server, ahead of
        the GUI thread (:mod:`avgs_viewer.pointer`); nothing where that is not possible."""
        from .pointer import PointerFollower, XPointer

        if self.follower is None:
            self.follower = False
            if QtGui.QGuiApplication.platformName() == "xcb" and not os.environ.get("AVGS_VIEWER_NO_POINTER"):
                try:
                    self.follower = PointerFollower(XPointer())
                except OSError:
                    pass
        pose_at = drag.follow_map(x, y)
        if not self.follower or live is None or pose_at is None:
            return
        plotter = self.plotter
        scale, height = plotter.devicePixelRatioF(), plotter.height()
        origin = plotter.mapToGlobal(QtCore.QPoint(0, 0))

        def to_display(root_x: int, root_y: int) -> tuple[float, float]:  # as the event filter maps Qt's positions
            lx, ly = root_x / scale - origin.x(), root_y / scale - origin.y()
            return lx * scale, (height - ly - 1) * scale

        def moved(px: float, py: float, final: bool) -> None:
            pose = pose_at(px, py)
            if pose is not None:
                live.request(pose)

        live.follow(True)
        if not self.follower.start(to_display, (x, y), moved, lambda exc: live.follow(False)):
            live.follow(False)

    def stop(self) -> None:
        """Stop following the pointer (the scene goes)."""
        self.plotter.set_dragging(False)
        if self.follower:
            self.follower.stop()

    def close(self) -> None:
        """Close the pointer follower (the window closes)."""
        if self.follower:
            self.follower.close()
            self.follower = None
