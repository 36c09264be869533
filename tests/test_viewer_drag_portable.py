"""A handle drag on the portable path (Qt's mouse events only, as on Wayland, macOS and Windows:
``AVGS_VIEWER_NO_POINTER=1``), driven by real X events (XTEST): each move's pose reaches the audio
worker before the 3D view renders again, and the view still draws during the drag.
Ordering only; the latency is the benchmark's (``avgs-viewer --bench``)."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("pytestqt")
from PySide6 import QtCore  # noqa: E402

from avgs_viewer.canvas import HOLD_MAX_S  # noqa: E402
from real_events import drag_handle, open_window, screen_xy  # noqa: E402

pytestmark = pytest.mark.gui
DEMO = Path(__file__).resolve().parents[1] / "assets" / "demo" / "scene.ckpt"


class _Log(QtCore.QObject):
    """Notes, in order, the view's mouse moves and releases as Qt delivers them (before the window's
    own filter, installed earlier, handles them), the poses handed to the audio worker, and each
    VTK render of the view (its render window's StartEvent: a paint's or any direct render)."""

    def __init__(self, w):
        super().__init__()
        self.events: list[tuple[str, float, object]] = []
        submit = w.live.worker.submit

        def logged_submit(request):
            self.events.append(("pose", time.perf_counter(), np.array(request.pose.listener)))
            return submit(request)

        w.live.worker.submit = logged_submit
        self.window = w
        w.plotter.installEventFilter(self)
        self._observer = w.plotter.ren_win.AddObserver(
            "StartEvent", lambda *_: self.events.append(("render", time.perf_counter(), None)))

    def close(self) -> None:
        self.window.plotter.ren_win.RemoveObserver(self._observer)

    def eventFilter(self, obj, event):  # noqa: N802
        kinds = {QtCore.QEvent.Type.MouseMove: "move", QtCore.QEvent.Type.MouseButtonRelease: "release"}
        if event.type() in kinds and self.window.drag.dragging is not None:  # the drag's own
            self.events.append((kinds[event.type()], time.perf_counter(), None))
        return False


def _portable_window(qtbot, monkeypatch, settle_ms: int):
    """The demo's window on Qt's events alone (``AVGS_VIEWER_NO_POINTER=1``), its first pose heard, then
    ``settle_ms`` for the paints that follow; skips without the demo."""
    if not DEMO.is_file():
        pytest.skip("the bundled demo scene is missing (scripts/make_demo.sh)")
    monkeypatch.setenv("AVGS_VIEWER_NO_POINTER", "1")
    w = open_window(qtbot, DEMO)
    try:
        qtbot.waitUntil(lambda: w.live.heard is not None and w.live.heard.request.seq == w.live.seq, timeout=30_000)
        qtbot.wait(settle_ms)
    except BaseException:
        w.close()
        raise
    return w


@pytest.mark.parametrize("view", ["native", "opengl-widget"])
def test_portable_drag_sends_each_pose_before_the_next_render(qtbot, x, monkeypatch, view):
    monkeypatch.setenv("AVGS_VIEWER_VIEW", view)  # both kinds of 3D view (avgs_viewer.canvas)
    w = _portable_window(qtbot, monkeypatch, 200)
    try:
        assert type(w.plotter).__name__ == {"native": "NativeCanvas", "opengl-widget": "GLWidgetCanvas"}[view]
        log = _Log(w)
        start = screen_xy(w, w.state.listener)
        bounds = np.asarray(w.state.bounds)
        target = np.array([*(0.7 * bounds[0, :2] + 0.3 * bounds[1, :2]), w.state.listener[2]])
        drag_handle(qtbot, w, x, "listener", start, screen_xy(w, target))
        qtbot.waitUntil(lambda: log.events[-1][0] == "render", timeout=5000)  # the released pose's frame
        log.close()
        assert w.mouse.follower is False  # Qt's events alone: no X pointer followed
        events = log.events
        kinds = [k for k, _, _ in events]
        moves = [i for i, k in enumerate(kinds) if k == "move"]
        assert len(moves) >= 5, kinds
        assert "render" in kinds[moves[0]:kinds.index("release")], "the view drew nothing during the drag"
        for i in moves:  # the move's pose went to the worker, before any render
            after = [k for k in kinds[i + 1:] if k in ("pose", "render")]
            assert after and after[0] == "pose", f"event {i} of {kinds}: a render before the move's pose"
        release = kinds.index("release")
        first_paint = release + kinds[release:].index("render")
        sent = [e for e in events[:first_paint] if e[0] == "pose"]
        assert np.allclose(sent[-1][2], w.state.listener, atol=1e-6)  # the released pose, sent before its frame
        assert np.linalg.norm(w.state.listener[:2] - target[:2]) < 0.05  # the handle followed the pointer
        qtbot.waitUntil(lambda: w.live.heard.request.seq == w.live.seq, timeout=10_000)
        assert np.allclose(w.live.heard.request.pose.listener, w.state.listener)  # and is what plays
    finally:
        w.close()


class _Paints(QtCore.QObject):
    """The times of the pose fields' paints and of the 3D view's renders (its render window's StartEvent)."""

    def __init__(self, w):
        super().__init__()
        self.window, self.fields, self.renders = w, [], []
        self._boxes = set(w.panel.pose.listener)
        for box in self._boxes:
            box.installEventFilter(self)
        self._observer = w.plotter.ren_win.AddObserver("StartEvent", lambda *_: self.renders.append(time.perf_counter()))

    def close(self) -> None:
        self.window.plotter.ren_win.RemoveObserver(self._observer)
        for box in self._boxes:
            box.removeEventFilter(self)

    def eventFilter(self, obj, event):  # noqa: N802
        if event.type() == QtCore.QEvent.Type.Paint:
            self.fields.append(time.perf_counter())
        return False


def test_during_a_drag_the_pose_fields_repaint_only_with_the_views_frames(qtbot, x, monkeypatch):
    """The listener's fields follow a drag, but each of their repaints comes with a frame of the 3D view (the same
    composition of the window, SceneCanvas.with_frame), and after the release they show where it ended. On the
    QOpenGLWidget view, whose window Qt composes at every repaint (a native view's panels repaint on their own)."""
    monkeypatch.setenv("AVGS_VIEWER_VIEW", "opengl-widget")
    w = _portable_window(qtbot, monkeypatch, 300)
    try:
        paints = _Paints(w)
        before = [box.value() for box in w.panel.pose.listener]
        bounds = np.asarray(w.state.bounds)
        target = np.array([*(0.3 * bounds[0, :2] + 0.7 * bounds[1, :2]), w.state.listener[2]])
        drag_handle(qtbot, w, x, "listener", screen_xy(w, w.state.listener), screen_xy(w, target), steps=16)
        qtbot.waitUntil(lambda: w.live.heard.request.seq == w.live.seq, timeout=10_000)
        qtbot.wait(400)
        paints.close()
        shown = [box.value() for box in w.panel.pose.listener]
        assert np.allclose(shown, np.round(w.state.listener, 2), atol=0.006) and not np.allclose(shown, before)
        # the three fields repaint together (one burst); each burst in a frame's composition: the window's raster
        # widgets are painted just before the view's render (or its render is held for the sound, HOLD_MAX_S at
        # most, and follows). Each move's own repaint, as before, made more bursts than frames (15 for 10), some
        # 15-40 ms after a render with none soon after them.
        bursts = [t for i, t in enumerate(paints.fields) if i == 0 or t - paints.fields[i - 1] > 0.003]
        renders = np.array(paints.renders)
        assert 2 <= len(bursts) <= len(renders) + 2, (bursts, paints.renders)
        for t in bursts:
            after = renders[renders >= t]
            assert after.size and after[0] - t < HOLD_MAX_S + 0.05, (t, paints.renders)
    finally:
        w.close()
