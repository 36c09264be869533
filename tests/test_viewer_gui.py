"""The real window under Xvfb (pytest-xvfb starts it; pytest-qt drives it) on a trained scene."""

from __future__ import annotations

import numpy as np
import pytest
import soundfile as sf

pytest.importorskip("pytestqt")
from PySide6 import QtCore, QtWidgets  # noqa: E402

from avgs_viewer import colors  # noqa: E402
from avgs_viewer.refine import SEAM_SECONDS, periods_before  # noqa: E402
from avgs_viewer.control_panel import HEARD_TEXT  # noqa: E402
from avgs_viewer.window import MainWindow  # noqa: E402

pytestmark = pytest.mark.gui


@pytest.fixture(scope="module")
def trained_ckpt(free_field_model):
    """200 stage-2 iterations on a free-field scene (the ear facing the source is louder; conftest)."""
    return free_field_model[1]


@pytest.fixture
def window(qtbot, trained_ckpt):
    w = MainWindow()
    qtbot.addWidget(w)
    w.show()
    w.activateWindow()
    qtbot.waitActive(w)  # keyboard shortcuts need the active window
    with qtbot.waitSignal(w.scene_loaded, timeout=60_000):
        w.open_scene(trained_ckpt)
    wait_render(qtbot, w)
    yield w
    w.close()


def wait_render(qtbot, w: MainWindow) -> None:
    """Until the newest pose has been rendered and its result shown on the GUI thread."""
    def done():
        live = w.live
        assert live.worker.wait_idle(0.01)
        assert live.last_request is not None and live.last_request.pose == w.state.pose
        assert w.panel.levels.text().startswith("L ")
        assert w.audio_path._shown_heard is live.heard and not w.audio_path._show_timer.isActive()  # shown on screen
    qtbot.waitUntil(done, timeout=30_000)
    QtWidgets.QApplication.processEvents()


def wait_refined(qtbot, w: MainWindow) -> None:
    """Until the pose heard now plays its loop rendered in full, and the panel says so."""
    def done():
        live = w.live
        assert live.heard is not None and live.refined is not None and live.refined.seq == live.seq == live.heard.request.seq
        assert w.panel.heard.text() == HEARD_TEXT[True]
    qtbot.waitUntil(done, timeout=60_000)


def to_qt(w: MainWindow, display_xy) -> QtCore.QPoint:
    """VTK display pixels (origin bottom left) -> widget coordinates."""
    scale = w.plotter.devicePixelRatioF()
    return QtCore.QPoint(int(round(display_xy[0] / scale)), int(round(w.plotter.height() - 1 - display_xy[1] / scale)))


def ild(w: MainWindow) -> float:
    return w.live.heard.levels[2]  # the clip through the pose's filter


def test_dragging_the_listener_across_the_source_flips_the_ild(qtbot, window):
    w = window
    source = w.state.source
    z = w.state.listener[2]
    w.state.set_listener((source[0] - 1.5, source[1], z))
    w.plotter.setFocus()
    for _ in range(6):  # Q turns left by 15 degrees: face +y
        qtbot.keyClick(w.plotter, QtCore.Qt.Key.Key_Q)
    assert w.state.yaw == 90.0 and w.panel.yaw.value() == 90
    wait_render(qtbot, w)
    before = ild(w)
    assert before < -1.0  # the source is on the right: the right ear is louder

    w.plotter.render()
    QtWidgets.QApplication.processEvents()
    proj = w.view.projector()
    start = to_qt(w, proj.to_display(w.state.listener))
    end = to_qt(w, proj.to_display(np.array([source[0] + 1.5, source[1], z])))
    qtbot.mousePress(w.plotter, QtCore.Qt.MouseButton.LeftButton, pos=start)
    assert w.drag.dragging == "listener" and w.state.interacting
    for t in np.linspace(0, 1, 12)[1:]:
        qtbot.mouseMove(w.plotter, pos=start + (end - start) * float(t))
        QtWidgets.QApplication.processEvents()
    qtbot.mouseRelease(w.plotter, QtCore.Qt.MouseButton.LeftButton, pos=end)
    assert w.drag.dragging is None and not w.state.interacting
    assert w.state.listener[0] == pytest.approx(source[0] + 1.5, abs=0.15)
    assert w.state.listener[2] == z  # dragged at its own height
    wait_render(qtbot, w)
    after = ild(w)
    assert after > 1.0  # now the source is on the left: the left ear is louder
    assert f"ILD {after:+.1f} dB" in w.panel.levels.text()  # gain-free: the same number as played


def test_a_drag_plays_the_filters_and_the_settled_pose_its_full_render(qtbot, window):
    """Mouse events on the real window: while the listener is dragged the engine plays each pose's
    filter; after the release, the loop rendered at the final pose (what avgs render writes)."""
    w = window
    wait_refined(qtbot, w)
    assert w.engine.loop_tag in (None, w.live.seq)  # (the clock may not have pulled its block yet)
    w.plotter.render()
    QtWidgets.QApplication.processEvents()
    start = to_qt(w, w.view.projector().to_display(w.state.listener))
    qtbot.mousePress(w.plotter, QtCore.Qt.MouseButton.LeftButton, pos=start)
    assert w.drag.dragging == "listener"
    for step in range(1, 8):
        qtbot.mouseMove(w.plotter, pos=start + QtCore.QPoint(6 * step, 3 * step))
        QtWidgets.QApplication.processEvents()
    moving = w.live.seq
    qtbot.waitUntil(lambda: w.engine.wait_live(w.live.seq, timeout=0) is not None, timeout=30_000)
    assert w.engine.loop_tag is None  # a pose in a drag: its filter, no full render
    qtbot.mouseRelease(w.plotter, QtCore.Qt.MouseButton.LeftButton, pos=start + QtCore.QPoint(42, 21))
    assert w.drag.dragging is None
    wait_render(qtbot, w)
    wait_refined(qtbot, w)
    live = w.live
    assert live.seq >= moving and live.refined.binaural.shape == (2, len(live.clip))
    qtbot.waitUntil(lambda: w.engine.wait_live(("loop", live.seq), timeout=0) is not None, timeout=10_000)
    assert w.engine.loop_tag == live.seq  # the simulated sound card's blocks are the full render now
    pose = live.heard.request.pose
    assert pose == w.state.pose
    r, loop = w.renderer, live.clip  # the loop is one period of render() of the clip repeated
    copies = periods_before(r, len(loop))
    ref = r.render(pose.listener, pose.yaw, np.tile(loop, copies + 2)).binaural[:, copies * len(loop):(copies + 1) * len(loop)]
    seam = round(SEAM_SECONDS * r.sample_rate)
    np.testing.assert_allclose(live.refined.binaural[:, seam:], ref[:, seam:], atol=1e-3 * np.abs(ref).max())


def test_window_screenshot_shows_the_vicinity_sets(qtbot, window, tmp_path):
    w = window
    w.state.set_colour_mode("vicinity")
    wait_render(qtbot, w)
    out = w.export_screenshot(tmp_path / "window.png", scale=1)
    img = np.asarray(sf_image(out))
    proj = w.view.projector()
    for position, label in ((w.state.listener, colors.LISTENER), (w.state.source, colors.SOURCE)):
        p = proj.to_display(position)
        h = img.shape[0]
        x, y = int(p[0]), int(h - 1 - p[1])
        patch = img[max(0, y - 120): y + 120, max(0, x - 120): x + 120, :3].astype(int)
        hits = np.all(np.abs(patch - colors.VICINITY_COLOURS[label].astype(int)) <= 3, axis=-1).sum()
        both = np.all(np.abs(patch - colors.VICINITY_COLOURS[colors.BOTH].astype(int)) <= 3, axis=-1).sum()
        assert hits + both > 20, f"no {colors.VICINITY_NAMES[label]} colour near its sphere"


def sf_image(path):
    import pyvista as pv

    img = pv.read(path)
    w, h = img.dimensions[:2]
    return img.point_data[img.point_data.keys()[0]].reshape(h, w, -1)[::-1]


def test_exports_have_the_right_size(qtbot, window, tmp_path):
    w = window
    png = w.export_screenshot(tmp_path / "x2.png", scale=2, transparent=True)
    img = sf_image(png)
    size = w.plotter.render_window.GetSize()
    assert img.shape == (2 * size[1], 2 * size[0], 4)
    wait_refined(qtbot, w)  # (else the settled pose's full render could land between the export and the check)
    wav = w.export_audio(tmp_path / "now.wav")
    audio, sr = sf.read(wav, always_2d=True)
    clip = w.audio_path.clip  # the whole clip, not the loop the engine plays (its seam makes it 50 ms shorter)
    assert sr == w.renderer.sample_rate and audio.shape == (len(clip), 2) and len(w.live.clip) < len(clip)
    pose = w.state.pose  # settled: what `avgs render` makes of the whole clip at this pose
    expected = w.renderer.render(listener=pose.listener, yaw=pose.yaw, mono=clip,
                                 source=pose.source if w.renderer.source_aware else None).binaural
    assert np.allclose(audio.T, expected, atol=1e-5)


def test_controls_drive_the_state(qtbot, window):
    w = window
    w.panel.slice.setValue(500)
    lo, hi = w.state.bounds[:, 2]
    assert w.state.slice_height == pytest.approx(lo + 0.5 * (hi - lo))
    assert w.view._cloud.points[:, 2].max() <= w.state.slice_height
    w.panel.yaw.setValue(200)
    assert w.state.yaw == 200.0
    w.panel.volume.setValue(25)
    assert w.engine.volume == pytest.approx(0.25)
    qtbot.mouseClick(w.panel.play, QtCore.Qt.MouseButton.LeftButton)
    assert not w.state.playing and not w.engine.playing and w.panel.play.text() == "Play"
    index = w.panel.colour_mode.findData(w.state.colour_mode.__class__("alpha"))
    w.panel.colour_mode.setCurrentIndex(index)
    assert w.state.colour_mode.value == "alpha" and "PC1" in w.panel.legend.text()
    assert w.panel.colour_mode.findData(w.state.colour_mode.__class__("rgb")) == -1  # no G in this checkpoint


def test_no_sound_card_is_reported_in_the_status_bar(window):
    sd = pytest.importorskip("sounddevice")
    if any(d["max_output_channels"] >= 2 for d in sd.query_devices()):
        pytest.skip("this machine has an audio output")
    assert window.audio_status.text().startswith("No audio")
    assert window.live.last_result is not None and window.output.running  # a simulated clock plays instead
    # The meters show the engine's output, as a sound card would get it.
    window.audio_path._meters_shown = None
    window.audio_path._update_meters()
    left, right = window.engine.block_levels  # (the music moves between blocks: within 12 dB)
    assert abs(window.panel.meter_left.value() - 10 * max(left, -60.0)) <= 120
    assert abs(window.panel.meter_right.value() - 10 * max(right, -60.0)) <= 120
    assert window.panel.meter_left.value() > window.panel.meter_left.minimum()


def test_bad_checkpoint_shows_an_error_dialog(qtbot, window, tmp_path):
    w = window
    bad = tmp_path / "broken.ckpt"
    bad.write_bytes(b"this is not a checkpoint")
    pose = w.state.pose
    w.open_scene(bad)
    qtbot.waitUntil(lambda: w.error_dialog is not None and w.error_dialog.isVisible(), timeout=30_000)
    assert "broken.ckpt" in w.error_dialog.text() and "not an AV-GS checkpoint" in w.error_dialog.text()
    w.error_dialog.accept()
    assert w.state.pose == pose and w.live.worker.alive  # the loaded scene is untouched


def test_closes_cleanly(qtbot, trained_ckpt):
    w = MainWindow()
    qtbot.addWidget(w)
    w.show()
    with qtbot.waitSignal(w.scene_loaded, timeout=60_000):
        w.open_scene(trained_ckpt)
    import threading

    worker = w.live.worker
    w.close()
    QtWidgets.QApplication.processEvents()
    assert not worker.alive and w.live is None
    assert w.output is None or not w.output.available  # the audio stream is closed too
    assert not [t for t in threading.enumerate() if t.name.startswith("avgs")]
    assert [t for t in QtWidgets.QApplication.topLevelWidgets() if t.isVisible()] == []


def test_a_position_kept_inside_the_scene_is_reported_in_the_status_bar(window):
    hi = window.state.bounds[1]
    window.state.set_listener((hi[0] + 40.0, hi[1] - 0.5, 0.0))  # as a drag far past the wall would
    assert window.position_notice.text().startswith("listener kept inside the scene: (")
    assert f"-> ({hi[0]:.2f}," in window.position_notice.text()


def test_a_shown_scene_is_frozen_out_of_the_collector_and_freed_when_the_next_one_comes(qtbot, window, trained_ckpt):
    """After a load the scene's objects are frozen (no collection during a drag walks them); opening
    another scene unfreezes them, and the first scene's renderer is freed (freezing leaks nothing)."""
    import gc
    import weakref

    w = window
    assert gc.get_freeze_count() > 10_000  # the scene, its VTK and Qt objects, the model
    first = weakref.ref(w.renderer)
    with qtbot.waitSignal(w.scene_loaded, timeout=60_000):
        w.open_scene(trained_ckpt)
    wait_render(qtbot, w)
    assert first() is None and gc.get_freeze_count() > 10_000  # freed at the new scene's settle, which froze anew
