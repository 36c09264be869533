"""Navigation a splat-viewer user expects, driven by real X key events (XTEST) on the demo scene:
letter keys after typing in the pose panel, the orthographic top view, viewpoints (Ctrl+1 / 1),
undo of a pose change (Ctrl+Z / Ctrl+Shift+Z), recent files in a temporary QSettings, drops,
the point size and FPS."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("pytestqt")
from PySide6 import QtCore, QtGui, QtWidgets  # noqa: E402

from real_events import open_window  # noqa: E402

pytestmark = pytest.mark.gui
DEMO = Path(__file__).resolve().parents[1] / "assets" / "demo" / "scene.ckpt"
MODIFIERS = {"Ctrl": 0xFFE3, "Shift": 0xFFE1}


def chord(x, *names: str) -> None:
    """Press ``names`` in order (modifiers first) and release them in reverse: one real key chord (XTEST)."""
    from avgs_viewer.xinput import KEYSYMS

    codes = []
    with x._lock:
        for name in names:
            keysym = MODIFIERS.get(name) or KEYSYMS.get(name) or ord(name.lower())
            codes.append(x._x11.XKeysymToKeycode(x._dpy, keysym))
        for code in codes:
            x._xtst.XTestFakeKeyEvent(x._dpy, code, 1, 0)
        for code in reversed(codes):
            x._xtst.XTestFakeKeyEvent(x._dpy, code, 0, 0)
        x._flush()


@pytest.fixture
def settings_dir(tmp_path):
    """The explorer's QSettings in a temporary folder (never the user's)."""
    fmt, scope = QtCore.QSettings.Format.IniFormat, QtCore.QSettings.Scope.UserScope
    QtCore.QSettings.setPath(fmt, scope, str(tmp_path / "settings"))
    yield tmp_path / "settings"
    QtCore.QSettings.setPath(fmt, scope, str(tmp_path / "settings-after"))


@pytest.fixture
def window(qtbot, x, settings_dir):
    if not DEMO.is_file():
        pytest.skip("the bundled demo scene is missing (scripts/make_demo.sh)")
    w = open_window(qtbot, DEMO)
    yield w
    w.close()


def parallel(w) -> bool:
    return bool(w.plotter.renderer.GetActiveCamera().GetParallelProjection())


def test_letter_keys_act_after_typing_in_the_pose_panel(qtbot, window, x):
    w = window
    box = w.panel.pose.listener[0]
    target = float(np.round(np.mean(w.state.bounds[:, 0]) + 0.2, 2))
    box.setFocus()
    box.selectAll()
    qtbot.waitUntil(box.hasFocus, timeout=5000)
    x.type(f"{target:.2f}\n")  # typed, Enter: taken, and the field is left
    qtbot.waitUntil(lambda: w.state.listener[0] == pytest.approx(target, abs=0.01), timeout=5000)
    qtbot.waitUntil(lambda: not box.hasFocus(), timeout=5000)
    x.key("t")
    qtbot.waitUntil(lambda: parallel(w), timeout=5000)  # the top view, orthographic
    yaw = w.state.yaw
    x.key("q")
    qtbot.waitUntil(lambda: w.state.yaw == pytest.approx((yaw + 15) % 360), timeout=5000)
    x.key("r")
    qtbot.waitUntil(lambda: not parallel(w), timeout=5000)  # back to perspective

    # A field with focus but nothing typed: the letters act.
    box.setFocus()
    qtbot.waitUntil(box.hasFocus, timeout=5000)
    yaw = w.state.yaw
    x.key("q")
    qtbot.waitUntil(lambda: w.state.yaw == pytest.approx((yaw + 15) % 360), timeout=5000)
    # While a value is being typed, a letter does not act; Escape leaves the field unchanged and the keys act again.
    x.type("3")
    qtbot.wait(200)
    before = w.state.listener.copy()
    yaw = w.state.yaw
    x.key("q")
    qtbot.wait(300)
    assert w.state.yaw == yaw
    chord_escape(x)
    qtbot.waitUntil(lambda: not box.hasFocus(), timeout=5000)
    assert np.array_equal(w.state.listener, before)
    x.key("q")
    qtbot.waitUntil(lambda: w.state.yaw == pytest.approx((yaw + 15) % 360), timeout=5000)


def chord_escape(x) -> None:
    with x._lock:
        code = x._x11.XKeysymToKeycode(x._dpy, 0xFF1B)
        x._xtst.XTestFakeKeyEvent(x._dpy, code, 1, 0)
        x._xtst.XTestFakeKeyEvent(x._dpy, code, 0, 0)
        x._flush()


def test_the_top_view_is_orthographic(qtbot, window, x):
    w = window
    w.plotter.setFocus()
    x.key("t")
    qtbot.waitUntil(lambda: parallel(w), timeout=5000)
    lo, hi = w.state.bounds
    p = w.view.projector()
    a = p.to_display(np.array([lo[0] + 0.3, lo[1] + 0.3, lo[2]]))
    b = p.to_display(np.array([lo[0] + 0.3, lo[1] + 0.3, hi[2]]))
    assert np.allclose(a[:2], b[:2], atol=1.0)  # a vertical line is one point: parallel projection from above
    x.key("f")
    qtbot.waitUntil(lambda: not parallel(w), timeout=5000)


def test_viewpoints_saved_and_recalled_and_kept_in_the_settings(qtbot, window, x, settings_dir):
    w = window
    w.plotter.setFocus()
    x.key("t")
    qtbot.waitUntil(lambda: parallel(w), timeout=5000)
    chord(x, "Ctrl", "1")
    qtbot.waitUntil(lambda: 1 in w.navigation.views, timeout=5000)
    top = w.plotter.renderer.GetActiveCamera().GetPosition()
    x.key("r")
    qtbot.waitUntil(lambda: not parallel(w), timeout=5000)
    x.key("1")
    qtbot.waitUntil(lambda: parallel(w), timeout=5000)
    assert w.plotter.renderer.GetActiveCamera().GetPosition() == pytest.approx(top)
    assert list(settings_dir.rglob("*.ini"))  # written in the temporary settings, not the user's


def test_undo_and_redo_of_a_pose_change(qtbot, window, x):
    w = window
    w.plotter.setFocus()
    yaw = w.state.yaw
    x.key("q")
    qtbot.waitUntil(lambda: w.state.yaw == pytest.approx((yaw + 15) % 360), timeout=5000)
    chord(x, "Ctrl", "z")
    qtbot.waitUntil(lambda: w.state.yaw == pytest.approx(yaw), timeout=5000)
    chord(x, "Ctrl", "Shift", "z")
    qtbot.waitUntil(lambda: w.state.yaw == pytest.approx((yaw + 15) % 360), timeout=5000)


def test_recent_files_drops_point_size_and_fps(qtbot, window, tmp_path):
    w = window
    from avgs_viewer.navigation import recent_files

    assert recent_files() == [str(DEMO.resolve())]
    assert [a.text() for a in w.navigation.recent_menu.actions()] == [DEMO.name]
    clip = tmp_path / "tone.wav"
    import soundfile as sf

    sf.write(clip, 0.1 * np.sin(np.arange(22050) * 0.05).astype(np.float32), 22050)
    mime = QtCore.QMimeData()
    mime.setUrls([QtCore.QUrl.fromLocalFile(str(clip))])
    pos = QtCore.QPointF(w.width() / 2, w.height() / 2)
    enter = QtGui.QDragEnterEvent(pos.toPoint(), QtCore.Qt.DropAction.CopyAction, mime,
                                  QtCore.Qt.MouseButton.LeftButton, QtCore.Qt.KeyboardModifier.NoModifier)
    QtWidgets.QApplication.sendEvent(w, enter)
    assert enter.isAccepted()
    drop = QtGui.QDropEvent(pos, QtCore.Qt.DropAction.CopyAction, mime,
                            QtCore.Qt.MouseButton.LeftButton, QtCore.Qt.KeyboardModifier.NoModifier)
    QtWidgets.QApplication.sendEvent(w, drop)
    qtbot.waitUntil(lambda: w._clip_path == clip, timeout=5000)
    assert recent_files()[0] == str(clip.resolve())

    w.navigation.point_size.setValue(12)
    assert w.view._points_actor.prop.point_size == 12
    w.state.turn(15)  # something to draw
    qtbot.waitUntil(lambda: w.navigation.fps > 0, timeout=5000)
    assert w.navigation.fps_label.text() == f"FPS {w.navigation.fps}"
