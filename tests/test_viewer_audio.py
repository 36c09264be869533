"""The audio engine driven through its callback with known signals (no sound card needed),
clip loading, levels, and the live pose -> render -> buffer path on a real checkpoint."""

from __future__ import annotations

import numpy as np
import pytest
import soundfile as sf

from avgs.checkpoint import save_checkpoint, untrained_checkpoint
from avgs.inference import SceneRenderer
from avgs_viewer import audio
from avgs_viewer.audio import LoopEngine
from avgs_viewer.bench import drag_to_audio_latency
from avgs_viewer.state import ViewerState
from avgs_viewer.worker import LiveRender

SR = 22050
BLOCK = 256


def tone(freq: float, amp: float, n: int, phase: float = 0.0) -> np.ndarray:
    return (amp * np.sin(2 * np.pi * freq * np.arange(n) / SR + phase)).astype(np.float32)


def run(engine: LoopEngine, blocks: int) -> np.ndarray:
    """Pump the callback like a sound card would: [blocks * BLOCK, 2]."""
    out = np.empty((BLOCK, 2), dtype=np.float32)
    chunks = []
    for _ in range(blocks):
        engine.callback(out, BLOCK, None, None)
        chunks.append(out.copy())
    return np.concatenate(chunks)


def engine_with(buffer: np.ndarray, **kw) -> LoopEngine:
    e = LoopEngine(SR, peak_target=float(np.abs(buffer).max()), **kw)  # make-up gain exactly 1
    e.volume = 1.0
    e.set_buffer(buffer)
    return e


def test_loop_plays_the_buffer_continuously_and_wraps():
    n = 2000  # 20 periods of a 220.5 Hz tone
    x = tone(220.5, 0.5, n)
    e = engine_with(np.stack([x, 0.5 * x]))
    y = run(e, 40)  # 10240 samples: five wraps
    ramp_end = 3 * BLOCK  # the first buffer fades in from silence over the 30 ms crossfade
    idx = np.arange(len(y)) % n
    assert np.allclose(y[ramp_end:, 0], x[idx[ramp_end:]], atol=1e-6)
    assert np.allclose(y[ramp_end:, 1], 0.5 * x[idx[ramp_end:]], atol=1e-6)
    assert np.all(np.abs(y[:ramp_end, 0]) <= np.abs(x[idx[:ramp_end]]) + 1e-6)
    assert e.generation == 1 and e.position == len(y) % n


@pytest.mark.parametrize("curve", ["equal_power", "linear"])
def test_swap_crossfades_at_the_play_position_without_clicks_or_gaps(curve):
    n = 4000  # 40 periods of 220.5 Hz
    x = tone(220.5, 0.5, n)
    old = np.stack([x, x])
    new = np.stack([0.4 * x, 0.9 * x])  # the next pose: the left ear quieter
    e = engine_with(old, fade_seconds=0.03, curve=curve)
    before = run(e, 10)
    swap_at = len(before)
    e.set_buffer(new)
    after = run(e, 20)
    y = np.concatenate([before, after])
    idx = np.arange(len(y)) % n
    fade, start = e.fade_len, 3 * BLOCK  # the first buffer faded in from silence
    # Before the swap: the old buffer; after the fade: the new one, at the same play position.
    assert np.allclose(y[start:swap_at], old.T[idx[start:swap_at]], atol=1e-6)
    end = swap_at + fade + BLOCK
    assert np.allclose(y[end:], new.T[idx[end:]], atol=1e-6)
    # No click: no sample step larger than a sine of the largest mixed amplitude takes
    # (a real discontinuity is ten times that) ...
    omega = 2 * np.pi * 220.5 / SR
    assert np.max(np.abs(np.diff(y[start:], axis=0))) <= 1.05 * omega * np.hypot(0.5, 0.45)
    # ... and no gap: every period through the fade peaks at least at the quieter buffer's level.
    env = np.abs(y[swap_at:swap_at + fade + BLOCK, 0])
    peak_per_period = env[: len(env) // 100 * 100].reshape(-1, 100).max(axis=1)
    assert peak_per_period.min() > 0.95 * 0.4 * 0.5
    assert e.generation == 2


def test_newest_pending_buffer_wins_during_a_fade():
    n = 2000
    a, b, c = (np.stack([np.full(n, v, np.float32)] * 2) for v in (0.1, 0.2, 0.3))
    e = engine_with(a, fade_seconds=0.05)  # 1102 samples: 4.3 blocks
    run(e, 8)  # a has faded in
    e.set_buffer(b)
    run(e, 1)  # the fade to b has started
    e.set_buffer(c)
    e.set_buffer(a * 4)  # replaces c before it was adopted
    y = run(e, 40)
    assert np.allclose(y[-BLOCK:], 0.4, atol=1e-6)
    assert e.generation == 3 and e.submitted == 4


def test_pause_ramps_down_holds_the_position_and_resumes():
    n = 3000
    x = np.stack([tone(220.5, 0.5, n)] * 2)
    e = engine_with(x)
    run(e, 3)
    e.playing = False
    fade_out = run(e, 1)
    pos = e.position
    silent = run(e, 5)
    assert np.all(silent == 0) and e.position == pos
    assert abs(fade_out[-1, 0]) < 0.01 and np.max(np.abs(np.diff(fade_out[:, 0]))) < 0.1
    e.playing = True
    resumed = run(e, 2)
    assert np.allclose(resumed[BLOCK:, 0], x[0][(pos + BLOCK + np.arange(BLOCK)) % n], atol=1e-6)


def test_volume_scales_and_meters_read_the_output_level():
    n = 2000
    x = np.stack([tone(220.5, 0.5, n), tone(220.5, 0.25, n)])
    e = engine_with(x)
    e.volume = 0.5
    run(e, 20)
    left, right = e.block_levels  # a 0.25-amplitude sine: 20 log10(0.25 / sqrt 2)
    assert left == pytest.approx(20 * np.log10(0.25 / np.sqrt(2)), abs=0.1)
    assert left - right == pytest.approx(20 * np.log10(2), abs=0.1)


def test_levels_and_ild_of_known_signals():
    x = tone(441, 1.0, SR)
    left, right, ild = audio.levels(np.stack([x, 0.5 * x]))
    assert left == pytest.approx(-3.01, abs=0.01)
    assert ild == pytest.approx(6.02, abs=0.01)
    assert audio.levels(np.zeros((2, 10)))[0] == audio.SILENCE_DB
    with pytest.raises(ValueError, match=r"\[2, T\]"):
        audio.levels(np.zeros(10))


def test_engine_rejects_bad_buffers():
    e = LoopEngine(SR)
    with pytest.raises(ValueError, match=r"\[2, T\]"):
        e.set_buffer(np.zeros((1, 100)))
    with pytest.raises(ValueError, match="non-finite"):
        e.set_buffer(np.full((2, 10), np.nan))
    with pytest.raises(ValueError, match="curve"):
        LoopEngine(SR, curve="cubic")


def test_seamless_loop_has_no_seam():
    n, fade = 4943, 300
    x = tone(300.0, 0.5, n)  # 67.25 periods: the clip ends at a crest, the loop jumps to 0
    loop = audio.make_seamless_loop(x, fade)
    assert len(loop) == n - fade
    step = 2 * np.pi * 300 / SR * 0.5  # the largest step of the tone itself
    naive = np.concatenate([x, x[:50]])
    assert np.max(np.abs(np.diff(naive))) > 0.4  # the seam it removes
    wrapped = np.concatenate([loop, loop[:50]])
    # Head and tail are mixed with equal-power gains, so mid-fade the tone may swell to
    # sqrt(2) of its amplitude, never jump.
    assert np.max(np.abs(np.diff(wrapped))) <= 1.05 * np.sqrt(2) * step


def test_load_clip_downmixes_and_resamples(tmp_path):
    sr_in = 44100
    t = np.arange(sr_in) / sr_in
    stereo = np.column_stack([np.sin(2 * np.pi * 1000 * t), np.sin(2 * np.pi * 1000 * t) * 0.0 + 0.2])
    path = tmp_path / "clip.wav"
    sf.write(path, stereo, sr_in)
    mono = audio.load_clip(path, SR)
    assert mono.dtype == np.float32 and len(mono) == SR
    spectrum = np.abs(np.fft.rfft(mono[1000:-1000] - mono[1000:-1000].mean()))
    assert np.argmax(spectrum) * SR / len(mono[1000:-1000]) == pytest.approx(1000, abs=2)
    assert mono.mean() == pytest.approx(0.1, abs=0.01)  # the DC of the down-mix: (0 + 0.2) / 2
    with pytest.raises(FileNotFoundError, match="does not exist"):
        audio.load_clip(tmp_path / "none.wav", SR)
    (tmp_path / "bad.wav").write_bytes(b"not audio")
    with pytest.raises(ValueError, match="cannot read audio file"):
        audio.load_clip(tmp_path / "bad.wav", SR)


def test_no_audio_device_is_reported_not_raised():
    sd = pytest.importorskip("sounddevice")
    out = audio.AudioOutput(LoopEngine(SR))
    message = out.start()
    try:
        has_output = any(d["max_output_channels"] >= 2 for d in sd.query_devices())
        if has_output:
            assert message is None and out.available
        else:
            assert message.startswith("No audio") and not out.available
    finally:
        out.close()
    assert not out.available


# ---------------------------------------------------------------------- live renders
@pytest.fixture(scope="module")
def renderer(tmp_path_factory):
    rng = np.random.default_rng(0)
    pts = rng.uniform([0, 0, 0], [5, 4, 3], size=(400, 3))
    path = tmp_path_factory.mktemp("ckpt") / "scene.ckpt"
    save_checkpoint(untrained_checkpoint(pts, [4.0, 3.0, 1.2], seed=1), path)
    return SceneRenderer.load(path)


def test_pose_changes_put_the_new_render_in_the_engine(renderer):
    clip = tone(330.0, 0.3, SR // 2)
    state = ViewerState(renderer.bounds, renderer.source)
    engine = LoopEngine(renderer.sample_rate)
    live = LiveRender(renderer, state, engine, clip)
    try:
        live.request()
        assert live.worker.wait_idle(30)
        first = engine.submitted
        state.set_listener((1.0, 1.5, 0.0))
        state.set_yaw(45.0)
        assert live.worker.wait_idle(30)
        assert engine.submitted > first
        expected = renderer.render(listener=state.listener, yaw=45.0, mono=live.clip).binaural
        assert len(live.clip) == len(clip) - round(0.05 * SR)  # the seam crossfaded away
        run(engine, 200)  # the audio thread adopts it
        assert np.allclose(engine.current, expected * engine.makeup_gain, atol=1e-5)
        assert live.last_request.pose == state.pose
        assert len(live.last_result.listener_vicinity) == renderer.vicinity_size
    finally:
        live.close()


def test_a_pose_is_heard_first_as_a_draft_then_refined(renderer):
    """The first buffer after a move is the source-phase render, the next the renderer's own."""
    from avgs.config import SynthesisConfig

    clip = tone(330.0, 0.3, SR // 2) + tone(1200.0, 0.1, SR // 2)
    state = ViewerState(renderer.bounds, renderer.source)
    engine = LoopEngine(renderer.sample_rate)
    buffers = []
    live = LiveRender(renderer, state, engine, clip)
    set_buffer = engine.set_buffer
    engine.set_buffer = lambda y: (buffers.append(np.array(y)), set_buffer(y))[1]
    try:
        state.set_listener((1.0, 1.5, 0.0))
        assert live.worker.wait_idle(30)
    finally:
        live.close()
    pose = state.pose
    draft = renderer.render(pose.listener, pose.yaw, live.clip, synthesis=SynthesisConfig(phase_iterations=0)).binaural
    final = renderer.render(pose.listener, pose.yaw, live.clip).binaural
    assert len(buffers) == 2 and not np.allclose(draft, final, atol=1e-4)
    np.testing.assert_allclose(buffers[0], draft, atol=1e-6)
    np.testing.assert_allclose(buffers[1], final, atol=1e-6)
    assert not live.last_request.draft


def test_a_renderer_without_phase_iterations_renders_once(renderer, tmp_path):
    from avgs.config import SynthesisConfig

    plain = SceneRenderer.load(renderer.path, synthesis=SynthesisConfig(phase_iterations=0))
    state = ViewerState(plain.bounds, plain.source)
    engine = LoopEngine(plain.sample_rate)
    live = LiveRender(plain, state, engine, tone(330.0, 0.3, SR // 4))
    try:
        state.set_listener((1.0, 1.5, 0.0))
        assert live.worker.wait_idle(30)
    finally:
        live.close()
    assert engine.submitted == 1 and not live.last_request.draft


def test_latency_benchmark_reports_median_and_p95(renderer):
    out = drag_to_audio_latency(renderer, n=4, clip=tone(330.0, 0.3, SR // 4))
    assert out["n"] == 4 and 0 < out["median_ms"] <= out["p95_ms"] <= out["max_ms"]
    refined = out["refined"]  # the renderer refines with phase iterations: a second buffer, later
    assert refined["n"] == 4 and refined["median_ms"] >= out["median_ms"] and out["draft_render_ms"] > 0


def test_a_long_drag_keeps_memory_flat_and_closing_leaves_no_thread(renderer):
    """An hour of dragging, compressed: hundreds of pose changes through the worker (drafts,
    refinements, newest-wins drops) grow the process by no more than noise, and closing stops
    the worker thread."""
    import threading

    def rss_mb() -> float:
        with open("/proc/self/status") as f:
            return next(int(line.split()[1]) for line in f if line.startswith("VmRSS")) / 1024

    state = ViewerState(renderer.bounds, renderer.source)
    engine = LoopEngine(renderer.sample_rate)
    live = LiveRender(renderer, state, engine, tone(330.0, 0.3, SR // 2))
    rng = np.random.default_rng(0)
    lo, hi = np.asarray(renderer.bounds)

    def drag(moves: int) -> None:
        for i in range(moves):
            state.set_listener(rng.uniform(lo, hi))
            state.set_yaw(float(rng.uniform(0, 360)))
            if i % 10 == 9:
                assert live.worker.wait_idle(30)
                run(engine, 50)

    try:
        drag(100)  # warm-up: allocator pools, caches
        before = rss_mb()
        drag(600)
        grown = rss_mb() - before
    finally:
        live.close()
    assert grown < 25.0, f"RSS grew {grown:.1f} MB over 600 moves"
    assert not live.worker.alive
    assert not [t for t in threading.enumerate() if t.name.startswith("avgs")]
