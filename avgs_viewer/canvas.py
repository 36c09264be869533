"""The window's 3D view: a pyvista plotter that draws on demand, coalesced.

Two kinds, one behaviour (:class:`SceneCanvas`):

- :class:`NativeCanvas` (X11, XWayland, Windows, macOS; :mod:`avgs_viewer.native_view`): VTK draws
  into the view's own native window and swaps it, and the window's other widgets repaint by
  raster copies of their own areas;
- :class:`GLWidgetCanvas` (a Wayland display, or ``AVGS_VIEWER_VIEW=opengl-widget``): pyvistaqt's
  ``QOpenGLWidget``, whose frames Qt composes into the whole top-level window with OpenGL, and
  every repaint of any other widget of that window composes it again (with software GL, as much
  time again as the render: ``benchmarks/viewer.md``).

pyvista's Qt plotters draw in three ways that each cost a full VTK render on the GUI thread, and
on software GL a render is tens of milliseconds during which mouse events wait:

- a periodic render timer (5 Hz by default, 69 % of a core with the window idle on
  Mesa under Xvfb);
- ``plotter.render()``, which renders at once and then schedules a repaint, whose
  paint renders again (two renders per call, one per pose change of a drag);
- the VTK interactor's ``Render()`` on every camera move of an orbit, again followed
  by a repaint that renders.

Here all three become one request: ``render()`` and the interactor's render requests
only mark the widget for repaint (``QWidget.update``, which Qt coalesces), and
the paint renders once. So at most one render is in flight, none runs while nothing
changed, and any number of changes between two paints cost one render. What needs
the pixels at once (screenshots) calls :meth:`SceneCanvas.render_now`.

Sound first: while :attr:`SceneCanvas.hold` says the audio path is making a pose's
filter (a few ms) or the filter waits for its first audio block, a paint keeps the last
frame and tries again 2 ms later (without asking Qt for a repaint meanwhile: each repaint,
even one that draws nothing, composes the whole window of a ``GLWidgetCanvas``), for at most :data:`HOLD_MAX_S`: a software-GL render,
whose threads take every core, never runs between a pose change and its sound.

Input first, during a handle drag (:meth:`SceneCanvas.set_dragging`, from the window's mouse): at
most one render per :data:`DRAG_FRAME_S`, counted from the end of the last, and a render request
that comes sooner waits on a timer instead of asking Qt for a repaint. A render cannot be cut
short, and a mouse event that comes while one runs waits behind it (the release, and with it
the released pose's sound); so the GUI thread is left free at least as long as a frame interval
between two renders, and the drag's moves are handled (their poses sent to the audio path)
as they come, each frame drawing the newest of them. A panel that shows the moving pose (the pose
fields) updates through :meth:`SceneCanvas.with_frame` then: just before a frame is asked for, so its
repaint shares that frame's composition of the window instead of costing one of its own (a
``GLWidgetCanvas`` with software GL: ~10 ms of the GUI thread each, while the next move and the release wait).
A ``NativeCanvas`` also splits a drag's frame in two turns of the event loop: the render, then its showing
(the blit and swap, where software GL rasterizes), so a release that comes during the render is handled
before the showing, and the showing waits, as a paint does, while the released pose's filter is made.
"""

from __future__ import annotations

import time
from collections import deque

from typing import Callable

from pyvistaqt import QtInteractor
from PySide6 import QtCore, QtGui

from avgs_viewer.native_view import NativeInteractor, native_view_supported

HOLD_MAX_S = 0.1
"Longest a repaint waits for the audio path (so a drag still draws while filters keep coming)."
DRAG_FRAME_S = 1 / 30
"During a handle drag, the least time from the end of one render to the start of the next."
SPLIT_DRAG_FRAMES = True
"A native view shows a drag's frame one turn of the event loop after rendering it (:class:`NativeCanvas`)."


class SceneCanvas:
    """The 3D view, either kind (:class:`NativeCanvas`, :class:`GLWidgetCanvas`): a pyvista plotter with no render
    timer whose renders are coalesced into repaints.

    ``frames`` counts the renders drawn (paints); ``frame_times`` keeps the
    ``time.perf_counter()`` of the last 1024, for the frame-rate benchmark, and
    ``paint_seconds`` how long each of them took (the VTK render into the widget).
    """

    def _coalesce_renders(self) -> None:
        self.frames = 0
        self.frame_times: deque[float] = deque(maxlen=1024)
        self.paint_seconds: deque[float] = deque(maxlen=1024)
        iren = self.ren_win.GetInteractor()
        # The interactor (camera orbit, zoom) asks for renders through Render(), which renders
        # only while EnableRender is on and always fires RenderEvent: a repaint request instead.
        iren.EnableRenderOff()
        self._render_observer = iren.AddObserver("RenderEvent", self._vtk_render_requested)
        self._vtk_iren = iren
        self.hold: Callable[[], bool] | None = None
        "True while the audio path is busy: repaints wait (the window's audio path sets it)."
        self._held_since: float | None = None
        self._retry = QtCore.QTimer(self)
        self._retry.setSingleShot(True)
        self._retry.setInterval(2)
        self._retry.timeout.connect(self._request)
        self.dragging = False
        "A handle is being dragged: renders are spaced by DRAG_FRAME_S (:meth:`set_dragging`)."
        self._painted_at = -1.0  # perf_counter at the end of the last render
        self._frame_gate = QtCore.QTimer(self)
        self._frame_gate.setSingleShot(True)
        self._frame_gate.setTimerType(QtCore.Qt.TimerType.PreciseTimer)
        self._frame_gate.timeout.connect(self._request)
        self._with_frame: dict = {}  # key -> what to do just before the next frame is asked for (with_frame)

    def with_frame(self, key, update: Callable[[], None]) -> None:
        """Call ``update`` now, or during a handle drag just before the next frame is asked for (the newest
        per ``key``), so that the widgets it changes repaint with that frame: one composition of the window."""
        if not getattr(self, "dragging", False) and not self._with_frame:
            update()
            return
        self._with_frame[key] = update
        self._request()

    def set_dragging(self, dragging: bool) -> None:
        """A handle drag starts (renders spaced by DRAG_FRAME_S) or ends (a render waiting on the frame gate is
        asked for at once, through the hold: a repaint, even one whose paint is held, composes the window)."""
        self.dragging = bool(dragging)
        if not dragging:  # the released pose's sound gets a whole HOLD_MAX_S, not what the drag's moves left
            self._held_since = None
        if not dragging and (self._frame_gate.isActive() or self._with_frame):
            self._frame_gate.stop()
            self._request()

    def _request(self) -> None:
        """Ask Qt for a repaint (coalesced): during a drag not before DRAG_FRAME_S after the last
        render, and not while the audio path is busy (:meth:`_waiting`, checked again at the paint)."""
        if getattr(self, "dragging", False):
            wait = self._painted_at + DRAG_FRAME_S - time.perf_counter()
            if wait > 0:
                if not self._frame_gate.isActive():
                    self._frame_gate.start(max(1, int(round(wait * 1e3))))
                return
        if self._waiting():  # not even a repaint that draws nothing: Qt composes the window for each
            return
        updates, self._with_frame = getattr(self, "_with_frame", {}), {}
        for update in updates.values():  # their widgets repaint with this frame
            update()
        self.update()

    def _waiting(self) -> bool:
        """True when this paint should wait (:meth:`_held`); then the paint is asked for again 2 ms later."""
        if not self._held():
            return False
        self._retry.start()  # ask again in 2 ms
        return True

    def _held(self) -> bool:
        """True while the audio path is busy and has not had HOLD_MAX_S yet (its clock starts at the first call)."""
        hold, retry = getattr(self, "hold", None), getattr(self, "_retry", None)  # None while QtInteractor builds
        if hold is None or retry is None or not hold():
            self._held_since = None
            return False
        now = time.perf_counter()
        if self._held_since is None:
            self._held_since = now
        return now - self._held_since < HOLD_MAX_S  # waited long enough: paint (the paint starts the clock again)

    def render(self) -> None:
        """Ask for a repaint: the scene is drawn once at the next paint, however many calls came before."""
        if getattr(self, "_closed", False):
            return
        self._rendered = True  # what BasePlotter.render sets: the plotter counts as shown
        self._request()

    def render_now(self) -> None:
        """Render at once (for reading pixels back); the widget repaints after."""
        super().render()

    def screenshot(self, *args, **kwargs):
        """``pyvista``'s screenshot of the scene as it is now (rendered first, not the last paint)."""
        self.render_now()
        return super().screenshot(*args, **kwargs)

    def _vtk_render_requested(self, *_args) -> None:
        if not self._in_paint:
            self._request()

    def close(self) -> None:
        self.hold = None
        self._with_frame = {}
        self._retry.stop()
        self._frame_gate.stop()
        iren, self._vtk_iren = self._vtk_iren, None
        if iren is not None:  # VTK holds the bound method: it would pin the widget after close
            iren.RemoveObserver(self._render_observer)
            iren.EnableRenderOn()
        super().close()

    def _paint(self, draw: Callable[[], None]) -> None:
        """The widget's paint: ``draw`` (the VTK render into it) unless the audio path holds the frame."""
        iren = self._vtk_iren
        if iren is None:  # closed
            return draw()
        if self._waiting():  # sound first: the widget keeps its last frame until the filter is made and heard
            return
        iren.EnableRenderOn()
        t0 = time.perf_counter()
        try:
            draw()
        finally:
            iren.EnableRenderOff()
        t1 = time.perf_counter()
        self._painted_at, self._held_since = t1, None
        self.frames += 1
        self.frame_times.append(t1)
        self.paint_seconds.append(t1 - t0)


class GLWidgetCanvas(SceneCanvas, QtInteractor):
    """pyvistaqt's ``QOpenGLWidget`` view (Wayland): VTK renders into a framebuffer that Qt composes into the window."""

    def __init__(self, parent=None, **kwargs):
        super().__init__(parent, auto_update=False, **kwargs)
        self._coalesce_renders()

    def paintGL(self) -> None:  # noqa: N802
        self._paint(super().paintGL)

    def grab_view(self) -> QtGui.QImage:
        """What the view shows: the widget's framebuffer."""
        return self.grabFramebuffer()


class NativeCanvas(SceneCanvas, NativeInteractor):
    """The native-window view (X11, Windows, macOS): VTK draws into the view's own window.

    A handle drag's frame is drawn in two turns of the event loop (:data:`SPLIT_DRAG_FRAMES`): the render, then
    the blit and swap that show it (:meth:`_show_frame`), which is where software GL rasterizes, on every core.
    Input that came during the render (the release) is handled in between, and while the audio path makes the
    released pose's filter the frame waits to be shown, as a paint waits (:meth:`SceneCanvas._held`).
    """

    def __init__(self, parent=None, **kwargs):
        super().__init__(parent, **kwargs)
        self._coalesce_renders()
        self._swap_pending = False  # a drag's frame rendered and not yet shown
        self._swap = QtCore.QTimer(self)
        self._swap.setSingleShot(True)
        self._swap.setInterval(0)
        self._swap.timeout.connect(self._show_frame)

    def paintEvent(self, ev) -> None:  # noqa: N802
        self._paint(lambda: self._draw(ev))

    def _draw(self, ev) -> None:
        self._swap_pending = False  # a frame rendered and not yet shown: this one replaces it
        self._swap.stop()
        rw = self._RenderWindow
        if not (SPLIT_DRAG_FRAMES and self.dragging) or rw is None:
            NativeInteractor.paintEvent(self, ev)
            return
        rw.SwapBuffersOff()
        try:
            self.render_into_window()
        finally:
            rw.SwapBuffersOn()
        self._swap_pending = True
        self._swap.start(0)

    def _show_frame(self) -> None:
        """Blit and swap the drag's frame that :meth:`_draw` rendered, unless the audio path holds it (then 2 ms later)."""
        rw = self._RenderWindow
        if not self._swap_pending or rw is None:
            self._swap_pending = False
            return
        if self._held():  # its own retry: a repaint asked for now would render the frame again
            self._swap.start(2)
            return
        self._swap_pending = False
        t0 = time.perf_counter()
        rw.Frame()  # with SwapBuffers on: the render's blits again, then the swap
        if self.paint_seconds:  # the frame's paint: its render and its showing
            self.paint_seconds[-1] += time.perf_counter() - t0
        self.frameSwapped.emit()

    def close(self) -> None:
        self._swap.stop()
        self._swap_pending = False
        super().close()

    def grab_view(self) -> QtGui.QImage:
        """What the view shows: its window's pixels as the window system has them."""
        return self.screen().grabWindow(int(self.winId())).toImage()

    def grab(self, rect=None) -> QtGui.QPixmap:  # noqa: A003 (QWidget's name)
        """``QWidget.grab``: the scene rendered and read back from VTK (Qt cannot draw a window that GL draws into
        into a pixmap: it would hold whatever was in memory); ``rect`` in the widget's coordinates."""
        img = self.screenshot(return_img=True)  # [h, w, 3] uint8, device pixels
        h, w = img.shape[:2]
        qimg = QtGui.QImage(img.tobytes(), w, h, 3 * w, QtGui.QImage.Format.Format_RGB888).copy()
        qimg.setDevicePixelRatio(w / max(1, self.width()))
        pix = QtGui.QPixmap.fromImage(qimg)
        if rect is not None and rect.isValid():
            r = qimg.devicePixelRatio()
            pix = pix.copy(QtCore.QRect(round(rect.x() * r), round(rect.y() * r), round(rect.width() * r), round(rect.height() * r)))
        return pix


def make_canvas(parent=None) -> SceneCanvas:
    """The window's 3D view: a native window where the platform allows (:func:`native_view_supported`)."""
    return NativeCanvas(parent) if native_view_supported() else GLWidgetCanvas(parent)
