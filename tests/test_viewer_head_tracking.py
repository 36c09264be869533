"""Head tracking: a real local OSC sender (python-osc's SimpleUDPClient) turns and moves the
listener of the real window, and the filter the engine plays changes with it."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("pytestqt")
pytest.importorskip("pythonosc")

from real_events import demo_window  # noqa: E402

pytestmark = pytest.mark.gui


@pytest.fixture
def window(qtbot, x):
    w = demo_window(qtbot)
    yield w
    w.close()


def test_ypr_and_xyz_from_a_local_sender_move_the_listener_and_change_the_filter(qtbot, window):
    from pythonosc.udp_client import SimpleUDPClient

    w = window
    qtbot.waitUntil(lambda: w.live.heard is not None and w.live.worker.wait_idle(0.01), timeout=30_000)
    yaw0, where0 = w.state.yaw, w.state.listener
    h0 = w.engine.impulse.copy()
    port = w.set_head_tracking(True, 0)  # any free port (the default is 9000)
    assert port and w.tracking_action.isChecked()
    sender = SimpleUDPClient("127.0.0.1", port)
    sender.send_message("/ypr", [60.0, 5.0, -3.0])  # turned 60 degrees to the left
    qtbot.waitUntil(lambda: w.state.yaw == pytest.approx((yaw0 + 60.0) % 360), timeout=5000)
    assert w.panel.pose.yaw.value() == pytest.approx(w.state.yaw % 360, abs=0.05)  # shown in the window
    qtbot.waitUntil(lambda: w.live.heard.request.pose.yaw == pytest.approx(w.state.yaw)
                    and w.live.worker.wait_idle(0.01), timeout=30_000)
    qtbot.waitUntil(lambda: w.engine.live_tag == w.live.seq, timeout=10_000)
    assert not np.allclose(w.engine.impulse, h0, atol=1e-4)  # another filter plays
    sender.send_message("/xyz", [0.3, -0.2, 0.0])
    qtbot.waitUntil(lambda: np.allclose(w.state.listener[:2], where0[:2] + [0.3, -0.2], atol=1e-6), timeout=5000)
    sender.send_message("/ypr", ["not a number", 0, 0])  # ignored, nothing breaks
    qtbot.wait(200)
    assert w.state.yaw == pytest.approx((yaw0 + 60.0) % 360)
    assert w.history.stack.count() == 0  # a tracker's stream is not undo steps
    assert w.set_head_tracking(False) is None and not w.head_tracker.running
    sender.send_message("/ypr", [0.0, 0.0, 0.0])
    qtbot.wait(300)
    assert w.state.yaw == pytest.approx((yaw0 + 60.0) % 360)  # off: not followed
