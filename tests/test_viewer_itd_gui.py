"""Real events on the real window: dragging the listener past the source flips the interaural time
difference of what plays (the engine's filter, and the full render the engine loops once the pose
settles), as the source crosses the listener's median plane. A one-source checkpoint trained on
recordings that carry an ITD (tests/rwavs_writer.py), its head fitted to them."""

from __future__ import annotations

import numpy as np
import pytest
import torch

pytest.importorskip("pytestqt")

from avgs.acoustics.impulse_response import convolve  # noqa: E402
from avgs.evaluation import spatial  # noqa: E402
from avgs_viewer.window import MainWindow  # noqa: E402
from real_events import drag_handle, open_window, screen_xy  # noqa: E402

pytestmark = pytest.mark.gui


@pytest.fixture
def window(qtbot, x, one_source_ckpt):
    w = open_window(qtbot, one_source_ckpt)
    yield w
    w.close()


def settled(qtbot, w: MainWindow) -> None:
    """Until the newest pose's filter is the engine's and its full render is looping."""
    def done():
        assert w.live.worker.wait_idle(0.01)
        assert w.engine.live_tag == w.live.seq and w.engine.impulse is not None
        assert w.engine._loop is not None and w.engine._loop[2] == w.live.seq
    qtbot.waitUntil(done, timeout=60_000)


def played_itd(w: MainWindow) -> tuple[float, float]:
    """(ITD of white noise through the engine's filter, ITD of the loop it plays), seconds."""
    noise = torch.from_numpy(np.random.default_rng(0).standard_normal(2 * w.engine.sample_rate).astype(np.float32))
    through_filter = convolve(noise, torch.from_numpy(np.ascontiguousarray(w.engine.impulse))).numpy()
    return spatial.itd(through_filter), spatial.itd(w.engine._loop[0])


def test_dragging_the_listener_past_the_source_flips_the_itd_of_what_plays(qtbot, window, x):
    w = window
    w.live.set_clip(0.1 * np.random.default_rng(1).standard_normal(2 * w.engine.sample_rate).astype(np.float32))
    source = w.state.source
    z = w.state.listener[2]
    w.state.set_yaw(90.0)  # facing +y: a source at larger x is on the listener's right
    w.state.set_listener((source[0] - 1.0, source[1], z))
    settled(qtbot, w)
    before = played_itd(w)
    assert all(t > 150e-6 for t in before), before  # the right ear leads: positive

    target = np.array([source[0] + 1.0, source[1], z])
    drag_handle(qtbot, w, x, "listener", screen_xy(w, w.state.listener), screen_xy(w, target))
    assert w.state.listener[:2] == pytest.approx(target[:2], abs=0.15)
    settled(qtbot, w)
    after = played_itd(w)
    assert all(t < -150e-6 for t in after), after  # the source is now on the left: the left ear leads


DEMO = __import__("pathlib").Path(__file__).resolve().parents[1] / "assets" / "demo" / "scene.ckpt"


def test_dragging_the_demos_source_around_the_head_flips_the_direct_sounds_itd(qtbot, x):
    """The bundled demo (impulse responses, sources anywhere): the source dragged with real events from
    the listener's left to its right, in the listener's room; the ITD of the filter that plays, its
    direct sound's, changes sign as the source crosses the median plane."""
    w = open_window(qtbot, DEMO)
    try:
        z = 1.5
        w.state.set_yaw(90.0)  # facing +y: smaller x is the listener's left
        w.state.set_listener((6.8, 1.6, z))
        w.state.set_source((5.8, 2.9, z))

        def heard_itd() -> float:
            qtbot.waitUntil(lambda: w.live.worker.wait_idle(0.01) and w.engine.live_tag == w.live.seq, timeout=30_000)
            return spatial.response_itd(w.engine.impulse, w.engine.sample_rate)

        assert heard_itd() < -150e-6  # the source on the left: the left ear leads
        target = np.array([7.8, 2.9, z])
        drag_handle(qtbot, w, x, "source", screen_xy(w, w.state.source), screen_xy(w, target))
        assert w.state.source[0] == pytest.approx(7.8, abs=0.2)
        assert heard_itd() > 150e-6  # now on the right: the right ear leads
    finally:
        w.close()
