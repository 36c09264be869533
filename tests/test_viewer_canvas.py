"""The 3D view's paints under Xvfb: coalesced, and held back while the audio path makes a filter."""

from __future__ import annotations

import time

import pytest

pytest.importorskip("pytestqt")
import pyvista as pv  # noqa: E402
from PySide6 import QtGui  # noqa: E402

from avgs_viewer.canvas import HOLD_MAX_S, GLWidgetCanvas, NativeCanvas  # noqa: E402
from avgs_viewer.native_view import native_view_supported  # noqa: E402

pytestmark = pytest.mark.gui


@pytest.fixture(params=[NativeCanvas, GLWidgetCanvas], ids=["native", "opengl-widget"])
def canvas(qtbot, request):
    c = request.param()
    qtbot.addWidget(c)
    c.add_mesh(pv.Sphere())
    c.resize(320, 240)
    c.show()
    qtbot.waitUntil(lambda: c.frames > 0, timeout=10_000)
    yield c
    c.close()


def test_many_render_requests_cost_one_paint(qtbot, canvas):
    qtbot.wait(100)
    before = canvas.frames
    for _ in range(20):
        canvas.render()
    qtbot.waitUntil(lambda: canvas.frames > before, timeout=5_000)
    qtbot.wait(100)
    assert canvas.frames == before + 1


def settle(qtbot, canvas) -> dict:
    """Let the fixture's own paints land, then make the audio path busy: a paint still pending when the hold
    began would be held and drawn HOLD_MAX_S later, in the middle of the test. Returns the hold's switch."""
    qtbot.wait(100)
    busy = {"on": True}
    canvas.hold = lambda: busy["on"]
    return busy


def test_a_paint_waits_while_the_audio_path_is_busy_then_draws(qtbot, canvas):
    busy = settle(qtbot, canvas)
    before = canvas.frames
    canvas.render()
    qtbot.wait(int(HOLD_MAX_S * 1000 * 0.4))
    assert canvas.frames == before  # held: the filter comes first
    busy["on"] = False
    qtbot.waitUntil(lambda: canvas.frames == before + 1, timeout=2_000)  # drawn as soon as it is made

    busy["on"] = True  # a filter that never ends cannot freeze the view: drawn after HOLD_MAX_S
    start = time.perf_counter()
    canvas.render()
    qtbot.waitUntil(lambda: canvas.frames == before + 2, timeout=2_000)
    assert time.perf_counter() - start >= HOLD_MAX_S * 0.9


def test_the_release_of_a_drag_gives_its_pose_a_whole_hold(qtbot, canvas):
    """A drag's moves kept the audio path busy for most of a hold when the handle is let go: the released
    pose's filter still gets a whole HOLD_MAX_S before a paint takes the cores (the hold's clock starts
    again at the release), and the frame is drawn once the filter is made."""
    busy = settle(qtbot, canvas)
    before = canvas.frames
    canvas.set_dragging(True)
    canvas.render()  # a move's frame, held behind the moves' filters
    qtbot.wait(int(HOLD_MAX_S * 1000 * 0.5))  # half a hold
    assert canvas.frames == before
    canvas.set_dragging(False)  # the release: its pose's filter is being made
    canvas.render()
    qtbot.wait(int(HOLD_MAX_S * 1000 * 0.6))  # past the drag's hold (1.1 HOLD_MAX_S since it began, at least)
    assert canvas.frames == before
    busy["on"] = False
    qtbot.waitUntil(lambda: canvas.frames == before + 1, timeout=2_000)


def test_the_release_does_not_compose_the_window_while_the_sound_is_made(qtbot, canvas, monkeypatch):
    """A drag's frame waiting on the frame gate at the release is asked for through the hold, like any
    other: a repaint, even one whose paint is held, composes the whole window (software GL: ~10 ms of
    both cores, beside the released pose's filter), so none comes until the filter is made."""
    import avgs_viewer.canvas as canvas_module

    monkeypatch.setattr(canvas_module, "DRAG_FRAME_S", 5.0)  # the frame waits on the gate, however slow the host
    monkeypatch.setattr(canvas_module, "HOLD_MAX_S", 5.0)  # and the hold outlasts the test
    busy = {"on": False}
    canvas.hold = lambda: busy["on"]
    swaps = []
    canvas.frameSwapped.connect(lambda: swaps.append(time.perf_counter()))
    canvas.render()
    qtbot.waitUntil(lambda: len(swaps) > 0, timeout=2_000)
    qtbot.wait(50)
    before = canvas.frames
    canvas.set_dragging(True)
    canvas.render()  # a move's frame, soon after the last: it waits on the frame gate
    assert canvas._frame_gate.isActive()
    busy["on"] = True  # the released pose's filter is being made
    swapped = len(swaps)
    canvas.set_dragging(False)
    qtbot.wait(100)
    assert len(swaps) == swapped and canvas.frames == before  # not even a composition
    busy["on"] = False
    qtbot.waitUntil(lambda: canvas.frames == before + 1, timeout=2_000)  # drawn once the filter is made


def test_the_view_is_a_native_window_where_vtk_can_draw_into_one(monkeypatch):
    monkeypatch.delenv("AVGS_VIEWER_VIEW", raising=False)
    assert [native_view_supported(p) for p in ("xcb", "windows", "cocoa")] == [True, True, True]
    assert not native_view_supported("wayland") and not native_view_supported("offscreen")
    monkeypatch.setenv("AVGS_VIEWER_VIEW", "opengl-widget")
    assert not native_view_supported("xcb")


def test_a_closed_native_view_lets_go_of_its_render_window(qtbot):
    """Its render window (and with it VTK's connection to the X display) goes with the close, not at the
    interpreter's exit, when the display may be gone and Xlib ends the process with status 1."""
    c = NativeCanvas()
    qtbot.addWidget(c)
    c.add_mesh(pv.Sphere())
    c.show()
    qtbot.waitUntil(lambda: c.frames > 0, timeout=10_000)
    rw = c.GetRenderWindow()
    assert rw.GetClassName() == "vtkXOpenGLRenderWindow"  # drawn into the window, whatever VTK_DEFAULT_OPENGL_WINDOW
    c.close()
    assert rw.GetReferenceCount() == 1  # only this test's own reference is left


def test_a_native_drag_frame_is_shown_after_the_sound_is_made(qtbot):
    """During a handle drag the native view renders a frame, then shows it (blit and swap: where software GL
    rasterizes, on every core) a turn of the event loop later, and not while the audio path makes a filter."""
    import avgs_viewer.canvas as canvas_module

    c = NativeCanvas()
    qtbot.addWidget(c)
    c.add_mesh(pv.Sphere())
    c.resize(320, 240)
    c.show()
    qtbot.waitUntil(lambda: c.frames > 0, timeout=10_000)
    qtbot.wait(100)
    swaps = []
    c.frameSwapped.connect(lambda: swaps.append(time.perf_counter()))
    c.set_dragging(True)
    qtbot.wait(int(canvas_module.DRAG_FRAME_S * 1000) + 20)  # past the frame gate
    before = c.frames
    released = {"filter_made": False}
    c.hold = lambda: c.frames > before and not released["filter_made"]  # busy from the frame's render on
    c.render()
    qtbot.waitUntil(lambda: c.frames == before + 1, timeout=2_000)  # rendered ...
    qtbot.wait(int(HOLD_MAX_S * 1000 * 0.5))  # ... and the release's filter is being made
    assert swaps == []  # held: not shown, not rasterized
    released["filter_made"] = True
    qtbot.waitUntil(lambda: len(swaps) == 1, timeout=2_000)
    assert c.frames == before + 1  # shown without another render
    c.set_dragging(False)
    c.close()


def test_a_wayland_session_with_xwayland_gets_the_native_view():
    from avgs_viewer.native_view import prefer_xwayland

    env = {"WAYLAND_DISPLAY": "wayland-0", "DISPLAY": ":0"}
    assert prefer_xwayland(env) and env["QT_QPA_PLATFORM"] == "xcb"
    for kept in ({"WAYLAND_DISPLAY": "wayland-0"},  # no XWayland: Qt's Wayland, the QOpenGLWidget view
                 {"WAYLAND_DISPLAY": "wayland-0", "DISPLAY": ":0", "QT_QPA_PLATFORM": "wayland"},  # the user's choice
                 {"WAYLAND_DISPLAY": "wayland-0", "DISPLAY": ":0", "AVGS_VIEWER_VIEW": "opengl-widget"},
                 {"DISPLAY": ":0"}):  # X11: xcb already
        before = dict(kept)
        assert not prefer_xwayland(kept) and kept == before


def test_a_grab_of_the_window_holds_the_native_views_pixels(qtbot):
    """``QWidget.grab`` (and pytest-qt's ``qtbot.screenshot``) of the window shows the 3D view where it is: Qt alone
    would leave a native view's area with whatever was in memory."""
    import numpy as np
    from real_events import demo_window

    w = demo_window(qtbot)
    try:
        qtbot.wait(300)
        view = w.plotter
        if not isinstance(view, NativeCanvas):
            pytest.skip("the window holds the QOpenGLWidget view (AVGS_VIEWER_VIEW or the platform)")
        img = w.grab().toImage().convertToFormat(QtGui.QImage.Format.Format_RGB888)
        a = np.array(img.constBits(), dtype=np.uint8).reshape(img.height(), img.bytesPerLine())
        window = a[:, : 3 * img.width()].reshape(img.height(), img.width(), 3).astype(int)
        scene = np.asarray(view.screenshot(return_img=True), dtype=int)  # the scene read back from VTK
        o = view.mapTo(w, view.rect().topLeft())
        grabbed = window[o.y(): o.y() + scene.shape[0], o.x(): o.x() + scene.shape[1]]
        assert grabbed.shape == scene.shape
        assert np.mean(np.abs(grabbed - scene)) < 8  # the same scene in the view's place (up to a 16-bit screen's rounding)
        assert len(np.unique(scene.reshape(-1, 3), axis=0)) > 20  # a scene, not a blank area
        below = window[o.y() + scene.shape[0] + 5:, o.x(): o.x() + scene.shape[1]]
        assert np.mean(np.abs(below[:20] - scene[-20:])) > 5  # the panel under the view is not the view
    finally:
        w.close()
