"""Several sources on the bundled demo (a source-aware checkpoint), driven with real X events: a
second source added through the Sources panel and dragged, and what the engine plays measured
against each source's filter convolved with its clip, times its gain; removing one leaves the other's.
A one-source checkpoint cannot add one. The map of all sources is the sum of the single-source maps."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("pytestqt")

from avgs_viewer.window import MainWindow  # noqa: E402
from real_events import drag_handle, open_window, screen_xy  # noqa: E402

pytestmark = pytest.mark.gui

DEMO = Path(__file__).resolve().parents[1] / "assets" / "demo" / "scene.ckpt"


def click(qtbot, w: MainWindow, x, widget) -> None:
    """A real left click in the middle of ``widget`` (scrolled into view first)."""
    from PySide6 import QtCore, QtGui

    w.panel_scroll.ensureWidgetVisible(widget)
    screen = QtGui.QGuiApplication.primaryScreen().geometry()
    mid = QtCore.QPoint(widget.width() // 2, widget.height() // 2)
    g = widget.mapToGlobal(mid)  # a small virtual screen: slide the window until the widget shows
    w.move(w.x() - max(0, g.x() + 60 - screen.width()), w.y() - max(0, g.y() + 40 - screen.height()))
    qtbot.waitUntil(lambda: screen.contains(widget.mapToGlobal(mid)), timeout=5000)
    g = widget.mapToGlobal(mid)
    x.press(g.x(), g.y())
    x.release(g.x(), g.y())


def circular(clip: np.ndarray, h: np.ndarray) -> np.ndarray:
    """[2, T] the looped ``clip`` [T] through ``h`` [2, L] in steady state (L <= T)."""
    n = len(clip)
    return np.fft.irfft(np.fft.rfft(clip.astype(np.float64)) * np.fft.rfft(h.astype(np.float64), n), n)


def settled(qtbot, w: MainWindow) -> None:
    """The newest filters are the engine's, and every stream has played a whole loop and filter through them."""
    qtbot.waitUntil(lambda: w.live.worker.wait_idle(0.01) and w.engine.live_tag == w.live.seq, timeout=30_000)
    start = w.engine.blocks
    need = (len(w.engine.clip) + w.engine.impulse.shape[1]) // w.engine.block + 4
    qtbot.waitUntil(lambda: w.engine.blocks > start + need, timeout=30_000)


def played_against_sum(w: MainWindow, blocks: int = 40) -> tuple[np.ndarray, np.ndarray]:
    """(what the engine plays next [2, n], the sum of each source's clip through its filter times its
    gain, times volume and make-up gain [2, n]), the clock stopped."""
    from avgs_viewer.audio import make_seamless_loop

    e = w.engine
    w.output.close()  # the test pulls the blocks itself from here on
    seam = int(round(0.05 * e.sample_rate))
    listener, yaw = w.state.listener, w.state.yaw
    n = blocks * e.block
    want = np.zeros((2, n))
    for i, s in enumerate(w.sources.items):
        h = w.renderer.binaural_filter(listener, yaw, source=s.position).impulse  # [2, L]
        loop = make_seamless_loop(s.clip, seam)
        pos = e.clip_position if i == 0 else e.voices[s.id].pos
        y = circular(loop, h)
        want += s.gain * y[:, (pos + np.arange(n)) % len(loop)]
    want *= e.volume * e.makeup_gain
    got = np.concatenate([e.render_block() for _ in range(blocks)]).T  # [2, n]
    return got, want


def test_two_sources_play_the_sum_of_their_filtered_clips(qtbot, x):
    w = open_window(qtbot, DEMO)
    try:
        rng = np.random.default_rng(0)
        sr = w.engine.sample_rate
        w.live.set_clip(0.05 * rng.standard_normal(sr).astype(np.float32))
        w.state.set_volume(0.3)  # the sum stays under full scale (the output is limited at 1.0)
        w.state.set_yaw(90.0)
        w.state.set_listener((6.8, 1.6, 1.5))
        w.state.set_source((5.8, 2.9, 1.5))
        assert w.sources_panel.add_button.isEnabled()
        first = w.sources.items[0].position.copy()

        click(qtbot, w, x, w.sources_panel.add_button)  # a second source, selected: the handle a drag moves
        qtbot.waitUntil(lambda: len(w.sources) == 2, timeout=5000)
        assert w.sources.selected == 1 and w.sources_panel.list.count() == 2
        assert len(w.engine.voices) == 1
        w.sources.set_clip(1, 0.05 * rng.standard_normal(sr).astype(np.float32))  # its own clip
        w.sources_panel.gain.setValue(50)  # its own gain: 0.5
        assert w.sources.items[1].gain == pytest.approx(0.5)

        target = np.array([7.8, 2.9, 1.5])
        w.plotter.render()
        qtbot.wait(100)
        drag_handle(qtbot, w, x, "source", screen_xy(w, w.state.source), screen_xy(w, target))
        assert w.sources.items[1].position[:2] == pytest.approx(target[:2], abs=0.2)  # the dragged one moved
        assert np.array_equal(w.sources.items[0].position, first)  # the other stayed
        np.testing.assert_array_equal(w.sources.items[1].position, w.state.source)
        settled(qtbot, w)
        got, want = played_against_sum(w)
        peak = np.abs(want).max()
        assert peak > 1e-3
        assert np.abs(got - want).max() < 1e-3 * peak  # the sum of both sources' renderings

        # the second source removed: the first's alone (the clock restarted for the fade-out and the filter)
        w.output.start()
        click(qtbot, w, x, w.sources_panel.remove_button)
        qtbot.waitUntil(lambda: len(w.sources) == 1 and len(w.engine.voices) == 0, timeout=5000)
        np.testing.assert_array_equal(w.state.source, first)  # the remaining source is the state's again
        settled(qtbot, w)
        got, want = played_against_sum(w)
        assert np.abs(got - want).max() < 1e-3 * np.abs(want).max()
    finally:
        w.close()


def test_a_one_source_checkpoint_cannot_add_a_source(qtbot, x, one_source_ckpt):
    w = open_window(qtbot, one_source_ckpt)
    try:
        assert not w.sources_panel.add_button.isEnabled()
        assert "one source" in w.sources_panel.add_button.toolTip()
        assert w.sources_panel.add() is None and len(w.sources) == 1
        with pytest.raises(ValueError, match="cannot add a source"):
            w.sources.add()
    finally:
        w.close()


def test_the_map_of_all_sources_is_the_sum_of_their_powers():
    """On the demo, 16 x 16 cells: the map of two sources (the second at half gain) against the
    single-source maps' ear powers, summed."""
    from avgs.render.propagation_map import compute_map
    from avgs.render.renderer import SceneRenderer
    from avgs_viewer.propagation_view import PropagationView
    from avgs_viewer.sources_map import ear_powers
    from avgs_viewer.state import ViewerState

    r = SceneRenderer.load(DEMO)
    state = ViewerState(r.bounds, (5.8, 2.9, 1.5), listener=(6.8, 1.6, 1.5), yaw=30.0)
    other = (3.0, 4.0, 1.5)

    class _Plotter:  # draw_now's drawing is not under test here
        def render(self):
            pass

    view = PropagationView(_Plotter(), r, state, size=16)
    view.set_all_sources(lambda: ((state.source, 1.0), (np.array(other), 0.5)))
    every = view.draw_now()
    view.close()
    singles = [compute_map(r, source=np.array(p), yaw=30.0, z=1.5, size=16) for p in (state.source, other)]
    assert every.complete
    power = sum(g ** 2 * 10 ** (m.level.astype(np.float64) / 10) for m, g in zip(singles, (1.0, 0.5)))
    np.testing.assert_allclose(10 ** (every.level / 10), power, rtol=1e-4)  # powers add
    left = right = 0.0
    for pmap, gain in zip(singles, (1.0, 0.5)):
        lp, rp = ear_powers(pmap.level, pmap.ild)
        left, right = left + gain ** 2 * lp, right + gain ** 2 * rp
    np.testing.assert_allclose(every.ild, 10 * np.log10(left / right), atol=1e-4)
    one = singles[0]
    assert np.all(10 ** (every.level / 10) > 10 ** (one.level / 10))  # louder everywhere than one source


def test_removing_the_first_source_leaves_the_seconds_sound():
    """No window: the engine pulled by hand. Two sources, the first removed: the second's clip now
    plays through the engine's own path, at its gain, through its filter, alone."""
    from avgs.render.renderer import SceneRenderer
    from avgs_viewer.audio import StreamEngine, make_seamless_loop
    from avgs_viewer.sources import Sources
    from avgs_viewer.state import ViewerState
    from avgs_viewer.worker import LiveAudio

    r = SceneRenderer.load(DEMO)
    state = ViewerState(r.bounds, (5.8, 2.9, 1.5), listener=(6.8, 1.6, 1.5), yaw=90.0)
    engine = StreamEngine(r.sample_rate)
    engine.volume = 0.3
    rng = np.random.default_rng(2)
    a, b = (0.05 * rng.standard_normal(r.sample_rate).astype(np.float32) for _ in range(2))
    live = LiveAudio(r, state, engine, a, settle=None)
    try:
        sources = Sources(state.source, a)
        sources.follow(state)
        live.attach_sources(sources)
        sources.add((3.0, 4.0, 1.5), clip=b, gain=0.7)
        assert live.worker.wait_idle(30) and len(engine.voices) == 1
        for _ in range(20):
            engine.render_block()
        sources.remove(0)
        assert len(sources) == 1 and sources.items[0].gain == 0.7
        np.testing.assert_allclose(state.source, (3.0, 4.0, 1.5))  # the one left is the state's source
        assert live.worker.wait_idle(30)
        h = r.binaural_filter(state.listener, state.yaw, source=state.source).impulse
        loop = make_seamless_loop(b, int(round(0.05 * r.sample_rate)))
        for _ in range((len(loop) + h.shape[1]) // engine.block + 4):  # a whole loop and filter through
            engine.render_block()
        assert len(engine.voices) == 0 and engine.live_tag == live.seq
        pos, n = engine.clip_position, 40 * engine.block
        got = np.concatenate([engine.render_block() for _ in range(40)]).T  # [2, n]
        want = 0.7 * engine.volume * engine.makeup_gain * circular(loop, h)[:, (pos + np.arange(n)) % len(loop)]
        assert np.abs(got - want).max() < 1e-3 * np.abs(want).max()
    finally:
        live.close()
