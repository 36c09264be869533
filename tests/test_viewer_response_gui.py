"""The real window under Xvfb with real Qt events: the impulse-response panel and its "play
response" key, and a source that stays fixed in a scene trained with one source position.

One checkpoint is trained here on one source (the binaural task: ``source_aware`` False),
one on the impulse responses of several sources (``avgs train --task rir``: source-aware);
the window keys on ``SceneRenderer.source_aware`` alone.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

pytest.importorskip("pytestqt")
from PySide6 import QtCore, QtGui, QtWidgets  # noqa: E402

from avgs_viewer import colors  # noqa: E402
from avgs_viewer.response import column_edges  # noqa: E402
from avgs_viewer.response_view import DIRECT_COLOUR, EAR_COLOURS  # noqa: E402
from avgs_viewer.window import FIXED_SOURCE_REASON, MainWindow  # noqa: E402

pytestmark = pytest.mark.gui
Key = QtCore.Qt.Key
LEFT = QtCore.Qt.MouseButton.LeftButton


@pytest.fixture(scope="module")
def rir_ckpt(quick_rir_scene, tmp_path_factory):
    """A source-aware checkpoint: the quick impulse-response scene (3 sources), 20 iterations of its training."""
    from avgs.train.impulse_responses import rir_quick_config
    from avgs.train.pipeline import train_scene

    torch.set_num_threads(1)
    cfg = rir_quick_config()
    cfg.acoustic.iterations = 20
    cfg.eval_every = cfg.checkpoint_every = cfg.log_every = 20
    out = tmp_path_factory.mktemp("rir_ckpt") / "rir.ckpt"
    train_scene(quick_rir_scene, out, cfg, task="rir", progress=False)
    return out


def open_window(qtbot, path) -> MainWindow:
    w = MainWindow(start_audio=False)
    qtbot.addWidget(w)
    w.resize(1280, 820)
    w.show()
    w.activateWindow()
    qtbot.waitActive(w)  # keyboard shortcuts need the active window
    with qtbot.waitSignal(w.scene_loaded, timeout=60_000):
        w.open_scene(path)
    wait_shown(qtbot, w)
    return w


@pytest.fixture
def window(qtbot, one_source_ckpt):
    w = open_window(qtbot, one_source_ckpt)
    yield w
    w.close()


def wait_shown(qtbot, w: MainWindow) -> None:
    """Until the state's pose plays and its response is on screen."""
    def done():
        live = w.live
        assert live.worker.wait_idle(0.01)
        assert live.last_request is not None and live.last_request.pose == w.state.pose
        assert w.audio_path._shown_heard is live.heard and not w.audio_path._show_timer.isActive()
        summary = w.response.summary
        assert summary is not None and np.array_equal(summary.impulse, live.heard.result.impulse)
    qtbot.waitUntil(done, timeout=30_000)
    w.response.plot.repaint()
    QtWidgets.QApplication.processEvents()


def expected_filter(w: MainWindow):
    p = w.state.pose
    return w.renderer.binaural_filter(p.listener, p.yaw, source=p.source)


def to_qt(w: MainWindow, world) -> QtCore.QPoint:
    """A world point -> the 3D view's widget coordinates."""
    w.plotter.render_now()
    d = w.view.projector().to_display(np.asarray(world, dtype=float))
    scale = w.plotter.devicePixelRatioF()
    return QtCore.QPoint(int(round(d[0] / scale)), int(round(w.plotter.height() - 1 - d[1] / scale)))


def mouse_drag(qtbot, w: MainWindow, start: QtCore.QPoint, end: QtCore.QPoint, steps: int = 10) -> None:
    qtbot.mousePress(w.plotter, LEFT, pos=start)
    for t in np.linspace(0, 1, steps)[1:]:
        qtbot.mouseMove(w.plotter, pos=start + (end - start) * float(t))
        QtWidgets.QApplication.processEvents()
    qtbot.mouseRelease(w.plotter, LEFT, pos=end)


def colour_pixels(w: MainWindow, colour: QtGui.QColor) -> int:
    """Pixels of ``colour`` (within 30 per channel) in the drawn plot."""
    img = w.response.plot.grab().toImage().convertToFormat(QtGui.QImage.Format.Format_RGB888)
    arr = np.frombuffer(img.constBits(), np.uint8, img.bytesPerLine() * img.height())
    arr = arr.reshape(img.height(), img.bytesPerLine())[:, :3 * img.width()].reshape(img.height(), img.width(), 3)
    return int((np.abs(arr.astype(int) - np.array(colour.getRgb()[:3])).max(-1) < 30).sum())


def ear_pixels(w: MainWindow) -> tuple[int, int]:
    """Pixels of the left and the right ear's colour in the drawn plot."""
    return colour_pixels(w, EAR_COLOURS[0]), colour_pixels(w, EAR_COLOURS[1])


def camera(w: MainWindow):
    c = w.plotter.camera
    return np.array(c.position), np.array(c.focal_point)


def test_the_panel_shows_the_current_pose_response_and_follows_a_drag(qtbot, window):
    w, plot = window, window.response.plot
    assert w.response.isVisible() and plot.height() >= 150 and plot.width() >= 500  # readable, not squashed
    first = expected_filter(w).impulse
    summary = w.response.summary
    np.testing.assert_array_equal(summary.impulse, first)  # the filter the engine plays, no other
    np.testing.assert_array_equal(w.engine.impulse, first)
    # What is drawn: each column the min / max of its samples, over the whole response.
    tr = plot.trace
    edges = column_edges(first.shape[1], tr.low.shape[1])
    assert tr.low.shape[1] >= 150  # a column per 2 pixels
    for c in (0, tr.low.shape[1] // 3, tr.low.shape[1] - 1):
        np.testing.assert_array_equal(tr.high[:, c], first[:, edges[c]:edges[c + 1]].max(axis=1))
        np.testing.assert_array_equal(tr.low[:, c], first[:, edges[c]:edges[c + 1]].min(axis=1))
    left_px, right_px = ear_pixels(w)
    assert left_px > 200 and right_px > 200  # both ears' responses and decays are on screen
    assert colour_pixels(w, DIRECT_COLOUR) > 20  # the direct sound marked (dashed lines, its times and ITD)
    assert summary.direct_s[0] is not None and "ITD" in summary.direct_text()
    # Idle: nothing is redrawn (once the window has settled after loading), nor for the same response again.
    qtbot.wait(1500)
    paints = plot.paints
    w.response.show_response(w.live.heard.result.impulse, w.renderer.sample_rate)
    qtbot.wait(1500)
    assert plot.paints == paints

    # A real mouse drag of the listener: the panel shows the new pose's response.
    src, z = w.state.source, w.state.listener[2]
    w.state.set_listener((src[0] - 1.0, src[1] + 0.3, z))
    wait_shown(qtbot, w)
    before = w.response.summary.impulse
    mouse_drag(qtbot, w, to_qt(w, w.state.listener), to_qt(w, (src[0] + 1.0, src[1] + 0.3, z)))
    assert w.state.listener[0] == pytest.approx(src[0] + 1.0, abs=0.15)
    wait_shown(qtbot, w)
    after = w.response.summary.impulse
    np.testing.assert_array_equal(after, expected_filter(w).impulse)
    assert not np.array_equal(after, before)
    assert w.response.summary.t60_s is not None  # measured once the move ended

    # The View menu hides the panel (the 3D view takes the room) and shows it again, up to date.
    w.response_action.trigger()
    assert not w.response.isVisible()
    w.response_action.trigger()
    assert w.response.isVisible() and np.array_equal(w.response.summary.impulse, w.live.heard.result.impulse)


def test_a_pose_passed_through_is_shown_light_and_the_newest_in_full(qtbot, window):
    """After a release the moves' filters still arrive while the released pose's is made: they are
    shown without the T60 and at most every SHOW_MS, so the GUI thread leaves the CPU to the filter
    the user waits for; the released pose's is shown at once, in full."""
    import dataclasses

    from avgs_viewer.audio_path import SHOW_MS

    w = window
    wait_shown(qtbot, w)
    heard = w.live.heard
    src, z = w.state.source, w.state.listener[2]
    stale_pose = dataclasses.replace(heard.request.pose, listener=(float(src[0]) - 1.2, float(src[1]) + 0.4, float(z)))
    stale_result = w.renderer.binaural_filter(stale_pose.listener, stale_pose.yaw, source=stale_pose.source)
    passed = dataclasses.replace(heard, request=dataclasses.replace(heard.request, seq=w.live.seq - 1),
                                 result=stale_result)
    w.audio_path._on_rendered(passed)
    timer = w.audio_path._show_timer
    assert timer.isActive() and timer.interval() == SHOW_MS
    w.live.heard = passed  # as if it were playing now
    qtbot.waitUntil(lambda: not timer.isActive(), timeout=5000)
    summary = w.response.summary
    assert np.array_equal(summary.impulse, stale_result.impulse) and summary.t60_s is None  # light
    w.live.heard = heard
    w.audio_path._on_rendered(heard)  # the newest pose: at once, in full
    assert timer.isActive() and timer.interval() == 0
    qtbot.waitUntil(lambda: not timer.isActive(), timeout=5000)
    assert np.array_equal(w.response.summary.impulse, heard.result.impulse) and w.response.summary.t60_s is not None


def test_the_panels_wait_for_the_sound(qtbot, window, monkeypatch):
    """A due update of the panels (each composes the whole window) waits while a filter waits for its
    first block to leave the engine, and goes once it has; and at most SHOW_WAIT_MAX_S, so a long drag
    whose filters keep coming still shows its poses."""
    import dataclasses
    import time

    import avgs_viewer.audio_path as audio_path
    from avgs_viewer.audio_path import SHOW_WAIT_MAX_S

    monkeypatch.setattr(audio_path, "SHOW_WAIT_MAX_S", 10.0)  # the update waits, however slow the host
    w, e = window, window.engine
    wait_shown(qtbot, w)
    w.output.close()  # no clock pulls the engine now: the test takes its blocks, as a sound card would
    heard = w.live.heard
    src, z = w.state.source, w.state.listener[2]
    moved = dataclasses.replace(heard.request.pose, listener=(float(src[0]) - 1.2, float(src[1]) + 0.4, float(z)))
    result = w.renderer.binaural_filter(moved.listener, moved.yaw, source=moved.source)
    newest = dataclasses.replace(heard, request=dataclasses.replace(heard.request, pose=moved), result=result)
    e.set_filter(result.impulse, tag=newest.request.seq)  # its first block not out yet
    assert w.audio_path.sound_pending()
    w.live.heard = newest
    w.audio_path._on_rendered(newest)
    timer = w.audio_path._show_timer
    qtbot.wait(30)  # the update came due and waits
    assert timer.isActive() and not np.array_equal(w.response.summary.impulse, result.impulse)
    e.render_block()  # the filter's first block leaves the engine
    assert not w.audio_path.sound_pending()
    qtbot.waitUntil(lambda: not timer.isActive(), timeout=5000)
    assert np.array_equal(w.response.summary.impulse, result.impulse)

    # A filter that keeps waiting holds the update SHOW_WAIT_MAX_S at most.
    monkeypatch.setattr(audio_path, "SHOW_WAIT_MAX_S", SHOW_WAIT_MAX_S)
    e.set_filter(heard.result.impulse, tag=heard.request.seq)
    w.live.heard = heard
    t0 = time.perf_counter()
    w.audio_path._on_rendered(heard)
    qtbot.waitUntil(lambda: np.array_equal(w.response.summary.impulse, heard.result.impulse), timeout=5000)
    assert time.perf_counter() - t0 >= SHOW_WAIT_MAX_S and w.audio_path.sound_pending()


def test_play_response_key_plays_the_response_once_then_the_clip(qtbot, window):
    w, e = window, window.engine
    w.output.close()  # no clock pulls the engine now: the test takes its blocks, as a sound card would
    h = w.live.heard.result.impulse
    np.testing.assert_array_equal(h, expected_filter(w).impulse)
    n, block = h.shape[1], e.block
    assert e.render_block().any()  # the clip plays
    w.plotter.setFocus()
    qtbot.keyClick(w.plotter, Key.Key_I)
    assert e.playing_once and "impulse response" in w.statusBar().currentMessage()
    blocks = 1 + -(-n // block) + 2  # the clip's fade-out, the response, the clip again
    out = np.concatenate([e.render_block() for _ in range(blocks)])  # [blocks * block, 2]
    played = out[block:block + n]
    np.testing.assert_allclose(played, e.once_gain * h.T, atol=1e-7)  # the response itself
    assert e.once_gain == pytest.approx(min(e.volume * e.makeup_gain, 0.9 / np.abs(h).max()))
    assert not e.playing_once and np.abs(out[-block:]).max() > 1e-4  # then the clip again
    # The panel's button does the same.
    qtbot.mouseClick(w.response.play_button, LEFT)
    assert e.playing_once


def test_a_one_source_scene_keeps_its_source_fixed_and_says_why(qtbot, window):
    w, pose = window, window.panel.pose
    assert not w.renderer.source_aware and not w.state.source_movable
    note = pose.source_note
    assert note.isVisible() and "Source fixed" in note.text() and note.toolTip() == FIXED_SOURCE_REASON
    source = w.state.source
    # A real mouse drag on the source's sphere: it stays, the camera does not orbit, the window says why.
    cam = camera(w)
    target = source + np.array([-1.2, 0.5, 0.0])
    mouse_drag(qtbot, w, to_qt(w, source), to_qt(w, target))
    assert np.array_equal(w.state.source, source) and w.drag.dragging is None and w.drag.held is None
    assert all(np.allclose(a, b) for a, b in zip(cam, camera(w)))
    assert w.position_notice.text() == FIXED_SOURCE_REASON and w.position_notice.isVisible()
    wait_shown(qtbot, w)
    assert w.live.last_request.pose.source == tuple(source)  # the sound is still that of the trained source
    # The sphere is still drawn where the source is.
    img = w.plotter.screenshot(return_img=True)[..., :3].astype(int)
    d = w.view.projector().to_display(source)
    px = img[int(round(img.shape[0] - 1 - d[1])), int(round(d[0]))] / 255
    assert np.abs(px - np.asarray(colors.SOURCE_COLOUR)).max() < 0.45
    # Typed coordinates are refused: the fields are read-only.
    box = pose.source[0]
    assert all(b.isReadOnly() for b in pose.source) and box.toolTip() == FIXED_SOURCE_REASON
    qtbot.mouseClick(box.lineEdit(), LEFT)
    box.lineEdit().selectAll()
    qtbot.keyClicks(box.lineEdit(), "1.5")
    qtbot.keyClick(box.lineEdit(), Key.Key_Return)
    assert box.value() == pytest.approx(source[0], abs=0.005) and np.array_equal(w.state.source, source)
    # The listener still moves as before.
    assert not all(b.isReadOnly() for b in pose.listener)


@pytest.mark.slow
def test_a_source_aware_scene_moves_the_source_and_its_vicinity_follows(qtbot, rir_ckpt):
    w = open_window(qtbot, rir_ckpt)
    try:
        pose = w.panel.pose
        assert w.renderer.source_aware and w.state.source_movable and not pose.source_note.isVisible()
        assert not any(b.isReadOnly() for b in pose.source)
        source = w.state.source
        labels_before = w.view.labels.copy()
        target = source + np.array([1.5, 0.6, 0.0])
        target = w.state.footprint.clamp(target)
        mouse_drag(qtbot, w, to_qt(w, source), to_qt(w, target))
        moved = w.state.source
        assert np.linalg.norm(moved[:2] - source[:2]) > 1.0 and moved[2] == source[2]  # dragged at its height
        wait_shown(qtbot, w)
        expected = expected_filter(w)
        # The vicinity colours are those of the moved source's vicinity, from the worker's result.
        full = colors.vicinity_labels(w.view.n_points, expected.listener_vicinity, expected.source_vicinity)
        np.testing.assert_array_equal(w.view.labels, full[w.view.drawn])
        assert not np.array_equal(w.view.labels, labels_before)
        np.testing.assert_array_equal(w.response.summary.impulse, expected.impulse)
    finally:
        w.close()
