"""A pyvista plotter in a native window of its own: VTK draws straight into the view's window.

pyvistaqt's ``QtInteractor`` is a ``QOpenGLWidget``: VTK renders into an offscreen framebuffer
that Qt then composes, with OpenGL, into the whole top-level window, and every repaint of any
other widget of that window (a meter, a pose field) composes the window again. With software GL
that composition costs about as much as the render itself (``benchmarks/viewer.md``). Here the
view is a plain ``QWidget`` with a native window handle (``vtkmodules.qt``'s
``QVTKRenderWindowInteractor``): VTK's own render window (GLX, WGL or Cocoa) draws into it and
swaps, and the rest of the window repaints by raster copies of its own areas.

A native render window needs a window system VTK can draw into: X11 (XWayland included),
Windows or macOS; on a Wayland display the window keeps pyvistaqt's ``QOpenGLWidget``
(:func:`native_view_supported`), and a Wayland session that also runs XWayland is given Qt's
``xcb`` platform unless it names one (:func:`prefer_xwayland`).
"""

from __future__ import annotations

import contextlib
import os
import sys
from typing import Any

from pyvista import global_theme
from pyvista.plotting import BasePlotter
from pyvista.plotting.render_window_interactor import RenderWindowInteractor
from PySide6 import QtCore, QtGui

import vtkmodules.qt

vtkmodules.qt.QVTKRWIBase = "QWidget"  # the module reads it when the class is made  # noqa: E402
from vtkmodules.qt.QVTKRenderWindowInteractor import QVTKRenderWindowInteractor  # noqa: E402

NATIVE_VIEW_ENV = "AVGS_VIEWER_VIEW"
"``native`` or ``opengl-widget``: which 3D view the window holds (default: native where the platform allows)."


def _widget_asked(environ) -> bool:
    """``AVGS_VIEWER_VIEW`` asks for pyvistaqt's ``QOpenGLWidget`` view."""
    return environ.get(NATIVE_VIEW_ENV, "").strip().lower() in ("opengl-widget", "qopenglwidget")


def native_view_supported(platform_name: str | None = None) -> bool:
    """Whether the 3D view can be a native window VTK draws into: Qt's platform is X11 (``xcb``), Windows or macOS.

    ``AVGS_VIEWER_VIEW=opengl-widget`` asks for pyvistaqt's ``QOpenGLWidget`` view whatever the platform."""
    if _widget_asked(os.environ):
        return False
    if platform_name is None:
        app = QtGui.QGuiApplication.instance()
        platform_name = app.platformName() if app is not None else ""
    return platform_name in ("xcb", "windows", "cocoa")


def _window_system_render_window():
    """A render window that draws into the window system's windows: on X11 ``vtkXOpenGLRenderWindow`` by name, since
    VTK's factory follows ``VTK_DEFAULT_OPENGL_WINDOW``, which the headless exports set to EGL (no window to draw into)."""
    if sys.platform.startswith("linux"):
        from vtkmodules.vtkRenderingOpenGL2 import vtkXOpenGLRenderWindow

        return vtkXOpenGLRenderWindow()
    from vtkmodules.vtkRenderingCore import vtkRenderWindow

    return vtkRenderWindow()


def prefer_xwayland(environ=os.environ) -> bool:
    """On a Wayland session that also runs XWayland (``WAYLAND_DISPLAY`` and ``DISPLAY`` both set) and names no Qt
    platform itself, ask Qt for ``xcb``: the window then gets the native view, whose frames cost less with software
    GL than the ``QOpenGLWidget`` a Wayland window must use. ``QT_QPA_PLATFORM=wayland`` keeps Wayland. Sets the
    variable (before the ``QApplication`` is made) and says whether it did."""
    if environ.get("QT_QPA_PLATFORM") or not environ.get("WAYLAND_DISPLAY") or not environ.get("DISPLAY"):
        return False
    if _widget_asked(environ):
        return False
    environ["QT_QPA_PLATFORM"] = "xcb"
    return True


@contextlib.contextmanager
def _no_base_plotter_init():
    """``QWidget.__init__`` continues the cooperative ``super()`` chain into ``BasePlotter.__init__``
    (with no arguments): a no-op while the Qt half is built, as pyvistaqt does."""
    init = BasePlotter.__init__
    BasePlotter.__init__ = lambda *args, **kwargs: None
    try:
        yield
    finally:
        BasePlotter.__init__ = init


class NativeInteractor(QVTKRenderWindowInteractor, BasePlotter):
    """pyvista's plotter API on a native-window VTK view (what pyvistaqt's ``QtInteractor`` is on a
    ``QOpenGLWidget``). ``frameSwapped`` is emitted after each render reaches the window."""

    frameSwapped = QtCore.Signal()  # noqa: N815 (QOpenGLWidget's name)

    def __init__(self, parent=None, multi_samples: int | None = None, **kwargs: Any) -> None:
        with _no_base_plotter_init():
            QVTKRenderWindowInteractor.__init__(self, parent=parent, rw=_window_system_render_window())
        BasePlotter.__init__(self, **kwargs)
        self.interactor = self
        self._in_paint = False
        self.ren_win = self.GetRenderWindow()
        self.ren_win.SetMultiSamples(global_theme.multi_samples if multi_samples is None else multi_samples)
        for renderer in self.renderers:
            self.ren_win.AddRenderer(renderer)
        self.background_color = global_theme.background
        self._off_screen = False
        self.iren = RenderWindowInteractor(self, interactor=self.ren_win.GetInteractor())
        self.iren.interactor.RemoveObservers("MouseMoveEvent")
        self.iren.initialize()
        self.enable_trackball_style()
        self._observers: dict = {}
        self.iren.add_observer("KeyPressEvent", self.key_press_event)
        self.reset_key_events()
        self._first_time = False  # BasePlotter: this plotter is shown by Qt, not by show()

    def paintEvent(self, ev) -> None:  # noqa: N802
        if self._RenderWindow is None:
            return
        self.render_into_window()
        self.frameSwapped.emit()

    def render_into_window(self) -> None:
        """The interactor's render into the view's window (the paint's; swapped unless ``SwapBuffers`` is off)."""
        self._in_paint = True
        try:
            self._Iren.Render()
        finally:
            self._in_paint = False

    def render(self) -> None:
        if getattr(self, "_closed", False):
            return
        self._rendered = True
        BasePlotter.render(self)

    def Finalize(self) -> None:  # noqa: N802
        """Release the render window: its GL context, and with the last reference to it, which is dropped here, its
        connection to the X display. A render window left to the interpreter's exit closes that connection then,
        when the display may be gone (an Xvfb stopped first): Xlib's fatal I/O error ends the process with status 1."""
        rw, self._RenderWindow = self._RenderWindow, None
        if rw is None:
            return
        rw.Finalize()
        self._Iren.SetRenderWindow(None)
        self.ren_win = None

    def close(self) -> None:
        if getattr(self, "_closed", True):
            return
        self.Finalize()
        BasePlotter.close(self)
        QVTKRenderWindowInteractor.close(self)
