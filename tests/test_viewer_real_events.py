"""The real window driven by real window-system events (XTEST through the X server, as
``xdotool`` sends them) on the bundled demo scene: what the user sees (pixels of the view)
and hears (the audio engine's output, pulled by the simulated sound-card clock).
Timings live in the benchmark (``avgs-viewer --bench``), not here."""

from __future__ import annotations

import time

import numpy as np
import pytest

pytest.importorskip("pytestqt")
from PySide6 import QtCore, QtWidgets  # noqa: E402

from avgs_viewer.window import MainWindow  # noqa: E402
from real_events import demo_window, screen_xy  # noqa: E402

pytestmark = pytest.mark.gui


@pytest.fixture
def window(qtbot, x):
    w = demo_window(qtbot)
    settle(qtbot, w)
    yield w
    w.close()


def settle(qtbot, w: MainWindow) -> None:
    """Until the newest pose's filter is playing and shown."""
    def done():
        assert w.live.worker.wait_idle(0.01)
        assert w.live.heard is not None and w.live.heard.request.seq == w.live.seq
        assert w.engine.live_tag == w.live.seq  # its blocks are leaving the engine
        assert not w.audio_path._show_timer.isActive()
    qtbot.waitUntil(done, timeout=30_000)
    qtbot.wait(100)


def heard_ild(qtbot, w: MainWindow, seconds: float = 1.0) -> float:
    """Left minus right level (dB) of the engine's output over ``seconds``: the ratio of the two
    ears' mean power over the blocks sampled (a block of speech is a few ms: one block's
    difference follows its spectrum, so a median of per-block differences would wander)."""
    powers = []
    t_end = time.perf_counter() + seconds
    while time.perf_counter() < t_end:
        left, right = w.engine.block_levels
        if min(left, right) > -70:
            powers.append((10.0 ** (left / 10.0), 10.0 ** (right / 10.0)))
        qtbot.wait(15)
    assert len(powers) > 10, "the engine is not playing"
    left, right = np.mean(powers, axis=0)
    return float(10.0 * np.log10(left / right))


def blue_pixels_near(w: MainWindow, world, reach: int = 8) -> int:
    """Pixels of the listener's blue within ``reach`` of ``world``'s projection in the view as drawn."""
    w.plotter.render_now()
    img = w.plotter.grab_view()  # what the view shows
    img = img.convertToFormat(img.Format.Format_RGB888)
    arr = np.array(img.constBits(), dtype=np.uint8)
    arr = arr.reshape(img.height(), img.bytesPerLine())[:, : 3 * img.width()].reshape(img.height(), img.width(), 3)
    p = w.view.projector().to_display(np.asarray(world, dtype=np.float64))
    ratio = img.height() / w.plotter.render_window.GetSize()[1]
    cx, cy = int(p[0] * ratio), int(img.height() - 1 - p[1] * ratio)
    patch = arr[max(0, cy - reach): cy + reach, max(0, cx - reach): cx + reach].astype(int)
    return int(np.sum((patch[..., 2] > 150) & (patch[..., 2] - patch[..., 0] > 80)))


def test_a_real_drag_moves_the_listener_on_screen_and_in_the_ears(qtbot, window, x):
    w = window
    # Stationary white noise, not the demo's speech: over one second of speech the ears' level
    # difference follows that second's spectrum (-1.4 to +5.5 dB at one pose of the demo).
    w.live.set_clip(0.1 * np.random.default_rng(0).standard_normal(2 * w.engine.sample_rate).astype(np.float32))
    source = w.state.source
    z = w.state.listener[2]
    w.state.set_yaw(90.0)  # facing +y: a source at larger x is on the listener's right
    w.state.set_listener((source[0] - 1.2, source[1], z))
    settle(qtbot, w)
    before = heard_ild(qtbot, w)
    assert before == pytest.approx(w.live.heard.levels[2], abs=0.5)  # what the viewer says the clip has through the pose's filter
    assert before < -0.5  # the right ear is louder

    target = np.array([source[0] + 1.2, source[1], z])
    start, end = screen_xy(w, w.state.listener), screen_xy(w, target)
    x.press(*start)
    qtbot.waitUntil(lambda: w.drag.dragging == "listener", timeout=5000)
    assert w.state.interacting
    for t in np.linspace(0, 1, 10)[1:-1]:
        x.move(start[0] + t * (end[0] - start[0]), start[1] + t * (end[1] - start[1]))
        qtbot.wait(20)
    x.release(*end)
    qtbot.waitUntil(lambda: w.drag.dragging is None, timeout=5000)
    assert not w.state.interacting
    assert w.state.listener[:2] == pytest.approx(target[:2], abs=0.1) and w.state.listener[2] == z
    settle(qtbot, w)
    after = heard_ild(qtbot, w)
    assert after == pytest.approx(w.live.heard.levels[2], abs=0.5)
    assert after > 0.5 and after - before > 1.5  # the source is now on the left: the left ear is louder
    assert blue_pixels_near(w, w.state.listener) > 20  # the sphere is drawn where it was dropped
    assert blue_pixels_near(w, (source[0] - 1.2, source[1], z)) == 0  # and no longer where it was


def test_keys_turn_the_listener_and_pause_the_sound(qtbot, window, x):
    w = window
    w.plotter.setFocus()
    yaw = w.state.yaw
    x.key("q")
    qtbot.waitUntil(lambda: w.state.yaw == pytest.approx((yaw + 15.0) % 360), timeout=5000)
    x.key("Right")
    qtbot.waitUntil(lambda: w.state.yaw == pytest.approx(yaw % 360), timeout=5000)
    settle(qtbot, w)
    assert w.engine.block_levels[0] > -70  # playing
    x.key("space")
    qtbot.waitUntil(lambda: not w.state.playing, timeout=5000)
    qtbot.waitUntil(lambda: max(w.engine.block_levels) <= -120, timeout=2000)  # ramped down to silence
    assert w.panel.play.text() == "Play"
    qtbot.waitUntil(lambda: not w.meter_timer.isActive(), timeout=2000)  # no meter polling while silent
    x.key("space")
    qtbot.waitUntil(lambda: w.engine.block_levels[0] > -70, timeout=2000)


def test_a_typed_position_is_heard(qtbot, window, x):
    w = window
    panel = getattr(w, "pose", None) or getattr(w.panel, "pose", None)
    if panel is None:
        pytest.skip("no pose panel in this window")
    box = panel.listener[0]
    target = float(np.round(np.mean(w.state.bounds[:, 0]) + 0.3, 2))
    box.setFocus()
    box.selectAll()
    qtbot.waitUntil(box.hasFocus, timeout=5000)
    x.type(f"{target:.2f}\n")
    qtbot.waitUntil(lambda: w.state.listener[0] == pytest.approx(target, abs=0.01), timeout=5000)
    settle(qtbot, w)
    assert w.live.heard.request.pose.listener[0] == pytest.approx(target, abs=0.01)
    QtWidgets.QApplication.processEvents()


def screen_patch(widget: QtWidgets.QWidget) -> np.ndarray:
    """[H, W, 3] of ``widget``'s area as the X server shows it (not as the widget would paint itself)."""
    from PySide6 import QtGui

    g = widget.mapToGlobal(QtCore.QPoint(0, 0))
    img = QtGui.QGuiApplication.primaryScreen().grabWindow(0, g.x(), g.y(), widget.width(), widget.height()).toImage()
    img = img.convertToFormat(img.Format.Format_RGB888)
    arr = np.array(img.constBits(), dtype=np.uint8).reshape(img.height(), img.bytesPerLine())
    return arr[:, : 3 * img.width()].reshape(img.height(), img.width(), 3)


def test_the_meters_repaint_on_screen_without_recomposing_the_3d_view(qtbot, window):
    """A meter update reaches the screen, and the window holding the OpenGL view is not composed
    again for it (no swap of the 3D view's window: with software GL that cost ~20 ms a time)."""
    from PySide6 import QtGui

    w = window
    screen = QtGui.QGuiApplication.primaryScreen().geometry()
    meter = w.panel.meter_left
    w.panel_scroll.ensureWidgetVisible(meter)  # the side panel scrolls on a short window
    qtbot.wait(100)

    def on_screen() -> bool:
        return screen.contains(QtCore.QRect(meter.mapToGlobal(QtCore.QPoint(0, 0)), meter.size()))

    if not on_screen():  # a small virtual screen: slide the window left until the meters show
        g = meter.mapToGlobal(QtCore.QPoint(0, 0))
        w.move(w.x() - max(0, g.x() + meter.width() - screen.width() + 10),
               w.y() - max(0, g.y() + meter.height() - screen.height() + 10))
        qtbot.waitUntil(on_screen, timeout=5000)
    w.raise_()  # above any window an earlier test in this process left on the screen
    w.activateWindow()
    qtbot.waitActive(w)
    centre = meter.mapToGlobal(meter.rect().center())

    def uncovered() -> bool:
        """The meter is what the screen shows at its centre; a window an earlier test in this worker left
        over it is hidden, and ours raised again (the screen is this worker's own Xvfb, without a window
        manager to keep the order)."""
        top = QtWidgets.QApplication.widgetAt(centre)
        if top is meter:
            return True
        if top is not None and top.window() is not w:
            top.window().hide()
        w.raise_()
        return False

    qtbot.waitUntil(uncovered, timeout=10_000)
    w.meter_timer.stop()
    w.panel.show_meters(-60.0, -60.0)
    qtbot.wait(500)
    swaps = []
    w.plotter.frameSwapped.connect(lambda: swaps.append(1))
    frames = w.plotter.frames
    quiet = screen_patch(meter)
    assert quiet.std() > 5  # the meter is on screen (not a blank grab)
    w.panel.show_meters(-3.0, -3.0)
    qtbot.waitUntil(lambda: np.mean(np.any(screen_patch(meter) != quiet, axis=-1)) > 0.5, timeout=5000)
    qtbot.wait(200)
    assert swaps == [] and w.plotter.frames == frames


def test_a_handle_drag_draws_cheap_frames_then_the_full_one(qtbot, window, x):
    """While a handle moves, frames are drawn without multisampling (and with fewer, flat points);
    the handle is still drawn under the pointer; on release the antialiased frame comes back."""
    w = window
    idle_samples = w.plotter.render_window.GetMultiSamples()
    assert idle_samples > 0  # the still frame is antialiased
    centre = np.asarray(w.state.bounds).mean(axis=0)
    target = np.array([centre[0] + 0.8, centre[1] - 0.6, w.state.listener[2]])
    start, end = screen_xy(w, w.state.listener), screen_xy(w, target)
    x.press(*start)
    qtbot.waitUntil(lambda: w.drag.dragging == "listener", timeout=5000)
    for t in np.linspace(0, 1, 8)[1:]:
        x.move(start[0] + t * (end[0] - start[0]), start[1] + t * (end[1] - start[1]))
        qtbot.wait(20)
    qtbot.waitUntil(lambda: w.state.listener[:2] == pytest.approx(target[:2], abs=0.1), timeout=5000)
    assert w.plotter.render_window.GetMultiSamples() == 0
    # drawn where the pointer holds it (within 12 px: the frame may show the move before the last)
    assert blue_pixels_near(w, w.state.listener, reach=12) > 20
    x.release(*end)
    qtbot.waitUntil(lambda: w.drag.dragging is None, timeout=5000)
    assert w.plotter.render_window.GetMultiSamples() == idle_samples
    assert blue_pixels_near(w, w.state.listener) > 20


def test_the_sound_follows_a_drag_while_the_gui_thread_is_busy(qtbot, window, x):
    """The X pointer, not Qt's event queue, carries a handle drag to the audio path: with the GUI
    thread blocked (as by a long software-GL paint), the last move and the release still reach
    the engine; Qt's copies of them, handled afterwards, ask for nothing more."""
    import threading

    w = window
    if not w.mouse.follower and w.mouse.follower is not None:
        pytest.skip("no X pointer to follow on this platform")
    z = w.state.listener[2]
    source = w.state.source
    w.state.set_listener((source[0] - 1.5, source[1] + 0.3, z))
    settle(qtbot, w)
    target = np.array([source[0] - 0.6, source[1] - 0.4, z])
    start, end = screen_xy(w, w.state.listener), screen_xy(w, target)
    x.press(*start)
    qtbot.waitUntil(lambda: w.drag.dragging == "listener", timeout=5000)
    assert w.mouse.follower, "the press came through X: the pointer is followed"
    x.move(0.5 * (start[0] + end[0]), 0.5 * (start[1] + end[1]))
    qtbot.wait(50)
    seq_before = w.live.seq

    def the_hand():  # while the GUI thread sleeps below
        time.sleep(0.1)
        x.move(*end)
        x.release(*end)

    hand = threading.Thread(target=the_hand)
    hand.start()
    time.sleep(1.5)  # the GUI thread is blocked: Qt has neither the last move nor the release
    hand.join()
    assert w.drag.dragging == "listener"  # Qt has not seen the release yet ...
    heard = w.live.heard
    assert heard is not None and heard.request.seq > seq_before
    assert np.asarray(heard.request.pose.listener)[:2] == pytest.approx(target[:2], abs=0.06)  # ... the ears have
    assert w.engine.live_tag == heard.request.seq == w.live.seq  # its blocks are leaving the engine
    qtbot.waitUntil(lambda: w.drag.dragging is None, timeout=5000)
    assert not w.state.interacting
    assert w.state.listener == pytest.approx(np.asarray(heard.request.pose.listener), abs=1e-6)  # the same pose, drawn
    assert w.live.seq == heard.request.seq  # and not computed again
