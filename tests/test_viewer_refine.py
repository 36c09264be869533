"""A settled pose heard as ``avgs render`` makes it: the loop rendered in full on the refiner's
thread and played by the engine in place of the pose's filter, on a trained one-source checkpoint."""

from __future__ import annotations

import time

import numpy as np
import pytest

from avgs.config import SynthesisConfig
from avgs.render.renderer import SceneRenderer
from avgs_viewer.audio import StreamEngine
from avgs_viewer.refine import SEAM_SECONDS, periods_before, refines, render_loop
from avgs_viewer.state import ViewerState
from avgs_viewer.worker import LiveAudio
from engine_blocks import pull as pull_blocks

BLOCK = 256
DEMO = "assets/demo/scene.ckpt"


@pytest.fixture(scope="module")
def renderer(one_source_ckpt):
    return SceneRenderer.load(one_source_ckpt)


def bursts(sr: int, seconds: float = 0.4, seed: int = 0) -> np.ndarray:
    """Noise bursts with silence between them: the tail and the silent bins matter."""
    rng = np.random.default_rng(seed)
    n = int(seconds * sr)
    env = (np.arange(n) % (sr // 8) < sr // 20).astype(np.float32)
    return (0.3 * env * rng.standard_normal(n)).astype(np.float32)


def pump_until(engine: StreamEngine, done, timeout: float = 60.0) -> None:
    out = np.empty((BLOCK, 2), np.float32)
    deadline = time.perf_counter() + timeout
    while not done():
        assert time.perf_counter() < deadline, "timed out"
        engine.callback(out, BLOCK, None, None)
        time.sleep(0.001)


def run(engine: StreamEngine, blocks: int) -> np.ndarray:
    """Pump the callback like a sound card would: [blocks * BLOCK, 2]."""
    return pull_blocks(engine, blocks, BLOCK)


def periodic_render(r: SceneRenderer, listener, yaw: float, loop: np.ndarray) -> np.ndarray:
    """One period of ``render`` of the loop repeated, with as many periods before it as the synthesis reaches."""
    T = len(loop)
    copies = periods_before(r, T)
    return r.render(listener, yaw, np.tile(loop, copies + 2)).binaural[:, copies * T:(copies + 1) * T]


def test_the_loop_is_one_period_of_the_repeated_clips_render(renderer):
    loop = bursts(renderer.sample_rate)
    listener, yaw = renderer.source + np.array([0.8, -0.6, 0.0]), 40.0
    y = render_loop(renderer, listener, yaw, None, loop)
    ref = periodic_render(renderer, listener, yaw, loop)
    seam = round(SEAM_SECONDS * renderer.sample_rate)
    peak = np.abs(ref).max()
    assert y.shape == ref.shape and peak > 0.01
    np.testing.assert_allclose(y[:, seam:], ref[:, seam:], atol=2e-4 * peak)  # float rounding through the iterations
    # The seam: playback wraps from the end to the start without a step larger than the signal's own.
    steps = np.abs(np.diff(np.concatenate([y, y[:, :1]], axis=1), axis=1))
    assert np.all(steps[:, -1] <= np.percentile(steps, 99.9, axis=1))
    # ... and it is not the filter: the convolution differs by far more than rounding.
    h = renderer.binaural_filter(listener, yaw).impulse
    T = len(loop)
    conv = np.stack([np.convolve(np.tile(loop, 4), h[c])[2 * T:3 * T] for c in range(2)])
    assert np.abs(conv - ref).max() > 0.05 * peak
    assert render_loop(renderer, listener, yaw, None, loop, cancelled=lambda: True) is None


def test_a_settled_pose_plays_its_loop_and_a_move_goes_back_to_the_filter(renderer):
    state = ViewerState(renderer.bounds, renderer.source)
    engine = StreamEngine(renderer.sample_rate, block=BLOCK)
    live = LiveAudio(renderer, state, engine, bursts(renderer.sample_rate), settle=0.05)
    try:
        first = live.request()
        pump_until(engine, lambda: live.refined is not None)
        refined = live.refined
        assert refined.seq == first and refined.after_filter >= 0.05  # not before the pose settled
        ref = periodic_render(renderer, state.listener, state.yaw, live.clip)
        seam = round(SEAM_SECONDS * renderer.sample_rate)
        np.testing.assert_allclose(refined.binaural[:, seam:], ref[:, seam:], atol=2e-4 * np.abs(ref).max())
        np.testing.assert_array_equal(live.heard_clip(), refined.binaural)  # what the export writes

        run(engine, 2)  # the block crossfading into the loop, then one wholly of it
        assert engine.loop_tag == first
        played = engine.blocks
        y = run(engine, 12)
        at = (played * BLOCK + np.arange(len(y))) % len(live.clip)  # the clip's position of each sample out
        np.testing.assert_allclose(y, refined.binaural.T[at] * (engine.volume * engine.makeup_gain), atol=1e-6)

        state.set_listener(renderer.source + np.array([-1.0, 0.4, 0.0]))
        assert live.worker.wait_idle(30)
        run(engine, 1)
        assert engine.live_tag == live.seq and engine.loop_tag is None  # moving: the new pose's filter at once
        assert live.refined.seq == first  # the old pose's loop is not heard again
        pump_until(engine, lambda: live.refined.seq == live.seq)
        run(engine, 2)
        assert engine.loop_tag == live.seq
    finally:
        live.close()


def test_a_drag_cancels_refinements_and_the_last_pose_gets_its_own(renderer):
    state = ViewerState(renderer.bounds, renderer.source)
    engine = StreamEngine(renderer.sample_rate, block=BLOCK)
    # settle 0.2 s: a refinement the refiner has started waits that long for its pose to hold
    live = LiveAudio(renderer, state, engine, bursts(renderer.sample_rate, 1.5, seed=1), settle=0.2)
    rng = np.random.default_rng(2)
    lo, hi = np.asarray(renderer.bounds)
    try:
        state.set_listener(rng.uniform(lo, hi))  # the drag's first pose: its refinement starts (it runs at a lower
        run(engine, 1)                           # priority than the filters, so it may wait for the burst's end)
        deadline = time.perf_counter() + 10
        while not live.refiner.worker.running and time.perf_counter() < deadline:
            run(engine, 1)
            time.sleep(0.002)
        assert live.refiner.worker.running
        for i in range(40):  # a pose every few ms: the refinement under way, and those after it, are overtaken
            state.set_listener(rng.uniform(lo, hi))
            run(engine, 1)
            time.sleep(0.003)
        last = live.seq
        pump_until(engine, lambda: live.refined is not None and live.refined.seq == last)
        run(engine, 2)
        assert engine.loop_tag == last
        assert live.refiner.cancelled > 0
        assert live.refiner.worker.rendered + live.refiner.worker.dropped <= live.refiner.worker.submitted
    finally:
        live.close()
    assert not live.refiner.worker.alive


def test_only_a_renderer_whose_render_is_not_its_filter_is_refined(renderer):
    assert refines(renderer)
    assert not refines(SceneRenderer.load(DEMO))  # the rir task: render convolves the predicted response
    r = SceneRenderer.load(renderer.path)
    for synthesis, expected in ((SynthesisConfig(method="filter"), False), (SynthesisConfig(phase="source"), False),
                                (SynthesisConfig(phase="filter"), True), (SynthesisConfig(phase_iterations=4), True)):
        r.synthesis = synthesis
        assert refines(r) is expected, synthesis
    state = ViewerState(renderer.bounds, renderer.source)
    live = LiveAudio(renderer, state, StreamEngine(renderer.sample_rate, block=BLOCK), bursts(renderer.sample_rate),
                     settle=None)
    try:
        assert live.refiner is None
    finally:
        live.close()
