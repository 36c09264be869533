"""A/B audition and the meters on the real window (real X keys): bypass plays the dry clip in
both ears, Shift+A / Shift+B store poses that A, B and X go to, the ground-truth entry is
disabled with its reason where the checkpoint's recordings are not found, and a clipping output
lights the clip light (a real click puts it out) and holds its peak."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("pytestqt")
from PySide6 import QtCore, QtGui  # noqa: E402

from real_events import demo_window  # noqa: E402
from test_viewer_navigation import chord  # noqa: E402

pytestmark = pytest.mark.gui


@pytest.fixture
def window(qtbot, x):
    w = demo_window(qtbot)
    qtbot.waitUntil(lambda: w.live.heard is not None and w.engine.live_tag == w.live.seq, timeout=30_000)
    yield w
    w.close()


def ears_differ(w, qtbot, n: int = 20) -> float:
    diffs = []
    for _ in range(n):
        out = w.engine._last_out
        if out is not None:
            diffs.append(float(np.max(np.abs(out[:, 0] - out[:, 1]))))
        qtbot.wait(10)
    return max(diffs)


def test_bypass_and_poses_a_and_b_from_the_keys(qtbot, window, x):
    w = window
    w.plotter.setFocus()
    assert ears_differ(w, qtbot) > 1e-3  # the pose's filter: two different ears
    x.key("d")
    qtbot.waitUntil(lambda: w.engine.bypass and w.audition.bypass_action.isChecked(), timeout=5000)
    qtbot.wait(100)
    assert ears_differ(w, qtbot) == 0.0  # the dry clip in both ears
    x.key("d")
    qtbot.waitUntil(lambda: not w.engine.bypass, timeout=5000)

    chord(x, "Shift", "a")
    qtbot.waitUntil(lambda: "a" in w.audition.stored, timeout=5000)
    a = w.state.pose
    x.key("q")
    x.key("q")
    qtbot.waitUntil(lambda: w.state.yaw == pytest.approx((a.yaw + 30) % 360), timeout=5000)
    chord(x, "Shift", "b")
    qtbot.waitUntil(lambda: "b" in w.audition.stored, timeout=5000)
    x.key("a")
    qtbot.waitUntil(lambda: w.state.pose == a, timeout=5000)
    x.key("x")
    qtbot.waitUntil(lambda: w.state.pose == w.audition.stored["b"], timeout=5000)
    x.key("x")
    qtbot.waitUntil(lambda: w.state.pose == a, timeout=5000)


def test_ground_truth_is_disabled_with_its_reason_without_recordings(window):
    act = window.audition.truth_action
    assert not act.isEnabled()
    assert act.toolTip().startswith("No recordings: the checkpoint's scene") and "transforms_scale" in act.toolTip()


def test_ground_truth_plays_the_nearest_recording(tmp_path):
    from avgs_viewer.audition import nearest, read_recordings, recordings_folder
    from rwavs_writer import write_scene

    scene = write_scene(tmp_path, n_train=6, n_val=2, seed=0)
    folder, why = recordings_folder(tmp_path / "scene.ckpt", scene.scene_dir.name)
    assert folder == scene.scene_dir and why == ""
    recs = read_recordings(folder, 22050)
    assert len(recs) == 8
    target = recs[3]
    got = nearest(recs, target.listener + 0.01, target.yaw)
    assert got is target and got.binaural.shape[0] == 2


def test_meters_clip_light_and_peak_hold(qtbot, window, x):
    w = window
    panel = w.panel
    w.panel_scroll.ensureWidgetVisible(panel.clip_light)
    w.engine.set_clip((0.9 * np.sign(np.sin(np.arange(22050) * 0.05))).astype(np.float32))
    w.engine._dry_gain = 10.0  # a dry clip far over full scale
    w.engine.bypass = True
    w.engine.volume = 1.0
    qtbot.waitUntil(lambda: panel.clip_light.lit, timeout=5000)
    assert panel.meter_left.peak_held >= 0.0 and panel.meter_left.value() > -100  # the peak line at full scale
    w.engine.bypass = False
    w.state.set_playing(False)
    qtbot.wait(1000)
    w.panel_scroll.ensureWidgetVisible(panel.clip_light)
    screen = QtGui.QGuiApplication.primaryScreen().geometry()
    g = panel.clip_light.mapToGlobal(QtCore.QPoint(0, 0))  # a small virtual screen: slide the window until it shows
    w.move(w.x() - max(0, g.x() + 60 - screen.width()), w.y() - max(0, g.y() + 40 - screen.height()))
    qtbot.waitUntil(lambda: screen.contains(panel.clip_light.mapToGlobal(QtCore.QPoint(22, 11))), timeout=5000)
    g = panel.clip_light.mapToGlobal(QtCore.QPoint(panel.clip_light.width() // 2, panel.clip_light.height() // 2))
    x.press(g.x(), g.y())
    x.release(g.x(), g.y())
    qtbot.waitUntil(lambda: not panel.clip_light.lit, timeout=5000)
