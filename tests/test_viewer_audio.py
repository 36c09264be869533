"""The audio engine driven through its callback with known signals and filters (no sound card
needed), clip loading, levels, the simulated clock, and the live pose -> filter -> engine path
on a real checkpoint."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
import soundfile as sf

from avgs.io.checkpoint import save_checkpoint, untrained_checkpoint
from avgs.render.renderer import SceneRenderer
from avgs_viewer import audio
from avgs_viewer.audio import StreamEngine, filter_levels
from avgs_viewer.sound_output import AudioOutput
from avgs_viewer.state import ViewerState
from avgs_viewer.worker import LiveAudio
from engine_blocks import pull as pull_blocks

SR = 22050
BLOCK = 256


def tone(freq: float, amp: float, n: int, phase: float = 0.0) -> np.ndarray:
    return (amp * np.sin(2 * np.pi * freq * np.arange(n) / SR + phase)).astype(np.float32)


def noise(n: int, seed: int = 0, amp: float = 0.2) -> np.ndarray:
    return (amp * np.random.default_rng(seed).standard_normal(n)).astype(np.float32)


def decaying(seed: int, taps: int = 700, left: float = 1.0, right: float = 0.5) -> np.ndarray:
    """A [2, taps] filter: decaying noise, the right ear scaled by ``right / left``."""
    h = np.random.default_rng(seed).standard_normal(taps) * np.exp(-np.arange(taps) / 120.0) * 0.05
    return np.stack([left * h, right * h]).astype(np.float32)


def run(engine: StreamEngine, blocks: int) -> np.ndarray:
    """Pump the callback like a sound card would: [blocks * BLOCK, 2]."""
    return pull_blocks(engine, blocks, BLOCK)


def reference(clip: np.ndarray, h: np.ndarray, n: int) -> np.ndarray:
    """[n, 2]: the looped clip from its start, convolved with ``h``, from silence."""
    x = np.tile(clip, n // len(clip) + 2)[:n].astype(np.float64)
    return np.stack([np.convolve(x, h[c].astype(np.float64))[:n] for c in range(2)], axis=1)


def engine_with(clip: np.ndarray, h: np.ndarray, **kw) -> StreamEngine:
    e = StreamEngine(SR, block=BLOCK, **kw)
    e.volume = 1.0
    e.set_clip(clip)
    e.set_filter(h, tag=1)
    e.makeup_gain = 1.0  # compare with plain convolution
    return e


def test_the_stream_is_the_looped_clip_convolved_with_the_filter():
    clip, h = noise(3000), decaying(0)
    e = engine_with(clip, h)
    y = run(e, 40)  # 10240 samples: three loops
    ref = reference(clip, h, len(y))
    ramp = np.arange(1, BLOCK + 1) / BLOCK  # the first block fades in from silence
    np.testing.assert_allclose(y[:BLOCK], ref[:BLOCK] * ramp[:, None], atol=2e-5)
    np.testing.assert_allclose(y[BLOCK:], ref[BLOCK:], atol=2e-5)
    assert e.live_tag == 1 and e.blocks == 40


def test_a_new_filter_plays_from_the_next_block_crossfaded_over_it():
    clip, old, new = noise(4000, 1), decaying(1), decaying(2, right=1.5)
    e = engine_with(clip, old)
    before = run(e, 10)
    e.set_filter(new, tag=2)
    assert e.has_pending and e.live_tag == 1
    t_sent = time.perf_counter()
    after = run(e, 10)
    t_live = e.wait_live(2, timeout=0)
    assert t_live is not None and t_live >= t_sent and e.live_tag == 2 and not e.has_pending
    y = np.concatenate([before, after])
    ref_old, ref_new = reference(clip, old, len(y)), reference(clip, new, len(y))
    k = len(before)
    ramp = (np.arange(1, BLOCK + 1) / BLOCK)[:, None]  # linear crossfade over the one block
    np.testing.assert_allclose(y[k:k + BLOCK], ref_old[k:k + BLOCK] * (1 - ramp) + ref_new[k:k + BLOCK] * ramp,
                               atol=2e-5)
    np.testing.assert_allclose(y[k + BLOCK:], ref_new[k + BLOCK:], atol=2e-5)  # with the old input's tail


def test_the_newest_filter_wins_and_each_tag_goes_live_once():
    e = engine_with(noise(2000, 2), decaying(3))
    run(e, 2)
    e.set_filter(decaying(4), tag=2)
    e.set_filter(decaying(5), tag=3)  # before any block: replaces 2
    run(e, 3)
    assert e.live_tag == 3 and e.wait_live(3, 0) is not None and e.wait_live(2, 0) is None
    assert e.filters_set == 3


def test_switching_filters_never_clicks():
    """A tone through filters of very different gains, switched every block: no step larger
    than the tone's own at the loudest gain."""
    e = engine_with(tone(220.5, 0.5, 2000), np.array([[1.0], [0.2]], np.float32))
    run(e, 4)
    chunks = []
    for i in range(40):
        g = 1.0 if i % 2 else 0.1
        e.set_filter(np.array([[g], [1.1 - g]], np.float32), tag=10 + i)
        chunks.append(run(e, 1))
    y = np.concatenate(chunks)
    omega = 2 * np.pi * 220.5 / SR
    assert np.max(np.abs(np.diff(y, axis=0))) <= 1.1 * omega * 0.5 + 0.9 * 0.5 / BLOCK


def test_a_new_clip_is_crossfaded_in_without_a_click():
    e = engine_with(tone(220.5, 0.5, 2000), np.array([[1.0], [1.0]], np.float32))
    a = run(e, 5)
    e.set_clip(tone(330.75, 0.5, 3000, phase=1.0))
    b = run(e, 5)
    y = np.concatenate([a, b])
    gain = e.makeup_gain  # fitted again for the new clip, and ramped to over the same block
    assert gain is not None and gain != 1.0
    step = 2 * np.pi * 330.75 / SR * 0.5 * max(1.0, gain)
    assert np.max(np.abs(np.diff(y[BLOCK:, 0]))) <= 1.5 * step
    np.testing.assert_allclose(b[BLOCK:, 0], gain * tone(330.75, 0.5, 3000, phase=1.0)[BLOCK:5 * BLOCK], atol=1e-5)


def test_a_rendered_loop_plays_in_step_with_the_clip_and_yields_to_the_next_filter():
    """set_loop: from the next block the output is the given loop at the clip's own positions
    (crossfaded in over that block), until a new filter crossfades back to the convolution,
    which ran on underneath: after its block the output is the clip through the new filter."""
    clip, h, new = noise(3000, 4), decaying(6), decaying(7, right=1.4)
    e = engine_with(clip, h)
    before = run(e, 5)
    loop = noise(2 * 3000, 9, amp=0.1).reshape(2, 3000)  # any [2, T]: not the convolution
    assert not e.set_loop(loop, tag=2)  # not the filter playing: refused
    assert not e.set_loop(loop[:, :2999], tag=1)  # not the clip's length
    assert not e.set_loop(loop, tag=1, clip=clip.copy())  # rendered from another clip
    assert e.set_loop(loop, tag=1) and e.loops_set == 1
    t_set = time.perf_counter()
    mixed = run(e, 14)
    t_loop = e.wait_live(("loop", 1), timeout=0)
    assert t_loop is not None and t_loop >= t_set and e.loop_tag == 1
    k = len(before)
    at = (k + np.arange(len(mixed))) % 3000  # the clip's position of each sample out
    conv = reference(clip, h, k + len(mixed))[k:]
    ramp = (np.arange(1, BLOCK + 1) / BLOCK)[:, None]
    np.testing.assert_allclose(mixed[:BLOCK], conv[:BLOCK] * (1 - ramp) + loop.T[at[:BLOCK]] * ramp, atol=2e-5)
    np.testing.assert_array_equal(mixed[BLOCK:], loop.T[at[BLOCK:]])  # sample for sample, wrapping with the clip

    e.set_filter(new, tag=3)
    after = run(e, 6)
    assert e.loop_tag is None and e.live_tag == 3
    n = k + len(mixed)
    ref_new = reference(clip, new, n + len(after))[n:]
    at = (n + np.arange(BLOCK)) % 3000
    old = reference(clip, h, n + BLOCK)[n:]  # the block the filter switches in: old filter -> new, loop -> that
    through = old * (1 - ramp) + ref_new[:BLOCK] * ramp
    np.testing.assert_allclose(after[:BLOCK], loop.T[at] * (1 - ramp) + through * ramp, atol=2e-5)
    np.testing.assert_allclose(after[BLOCK:], ref_new[BLOCK:], atol=2e-5)
    assert not e.set_loop(loop, tag=1)  # a loop for a pose no longer heard


def test_a_new_clip_fades_a_rendered_loop_out():
    clip, h = noise(2000, 5), decaying(8)
    e = engine_with(clip, h)
    run(e, 3)
    loop = noise(4000, 10, amp=0.1).reshape(2, 2000)
    assert e.set_loop(loop, tag=1)
    run(e, 3)
    assert e.loop_tag == 1
    e.set_clip(np.zeros(2500, np.float32))
    run(e, 2)  # the block of the new clip fades the loop out with the old clip
    assert e.loop_tag is None and not e.set_loop(loop, tag=1)  # the loop's clip is gone
    assert np.max(np.abs(run(e, 8)[len(h[0]):])) < 1e-6  # silence through the filter, nothing of the loop


def test_blocks_read_ahead_switch_filters_and_clips_at_the_next_block_exactly():
    """The engine reads the clip ahead and computes its blocks in batches; filters set at
    irregular blocks (inside and at the edges of those batches, two between one pair of blocks)
    and a new clip mid-batch still play from the very next block: the output equals the
    direct convolution of what was asked for, block by block."""
    clip, h = noise(2500, 11), [decaying(20 + i, taps=300 + 211 * i) for i in range(6)]
    e = engine_with(clip, h[0], ahead=8)
    assert e.ahead == 8
    switches = {3: [1], 4: [2], 11: [3, 4], 12: [0], 23: [5]}  # block -> filters set before it (newest wins)
    out = np.empty((BLOCK, 2), dtype=np.float32)
    y = []
    for n in range(40):
        for i in switches.get(n, []):
            e.set_filter(h[i], tag=100 + i)
        e.callback(out, BLOCK, None, None)
        y.append(out.copy())
        if n == 0:
            assert e._conv.ahead == 7  # read ahead: seven blocks transformed, waiting for their turn
    y = np.concatenate(y)
    x = np.tile(clip, 8)[:len(y)].astype(np.float64)
    full = [np.stack([np.convolve(x, f[c].astype(np.float64))[:len(y)] for c in range(2)], axis=1) for f in h]
    ramp = (np.arange(1, BLOCK + 1) / BLOCK)[:, None]
    current = 0
    for n in range(40):
        s = slice(n * BLOCK, (n + 1) * BLOCK)
        want = full[current][s]
        if n in switches:
            new = switches[n][-1]
            want = full[current][s] * (1 - ramp) + full[new][s] * ramp
            current = new
        if n == 0:
            want = want * ramp  # fades in from silence
        np.testing.assert_allclose(y[s], want, atol=3e-5, err_msg=f"block {n}")
    assert e.live_tag == 105 and e._conv.switches == 5

    # A new clip set while blocks of the old one were read ahead plays from the next block.
    e2 = engine_with(tone(220.5, 0.5, 2000), np.array([[1.0], [1.0]], np.float32), ahead=8)
    run(e2, 3)
    assert e2._conv.ahead > 0  # old clip read ahead
    new_clip = tone(330.75, 0.5, 3000, phase=1.0)
    e2.set_clip(new_clip)
    e2.makeup_gain = 1.0
    b = run(e2, 12)
    old_next = np.roll(tone(220.5, 0.5, 2000), -3 * BLOCK)[:BLOCK]
    t = ((np.arange(BLOCK) + 0.5) / BLOCK)
    np.testing.assert_allclose(b[:BLOCK, 0], old_next * np.cos(0.5 * np.pi * t) + new_clip[:BLOCK] * np.sin(0.5 * np.pi * t),
                               atol=1e-5)
    np.testing.assert_allclose(b[BLOCK:, 0], np.tile(new_clip, 2)[BLOCK:12 * BLOCK], atol=1e-5)


def test_the_convolver_fed_ahead_equals_block_by_block_convolution():
    """BlockConvolver: blocks fed ahead in runs of any length and pulled one by one, responses
    switched and of growing length, input dropped and fed again: the same output as one block at a time."""
    from avgs.acoustics.convolution import BlockConvolver

    rng = np.random.default_rng(3)
    b = 64
    x = rng.standard_normal(b * 70).astype(np.float32)
    hs = [(0.03 * rng.standard_normal((2, n))).astype(np.float32) for n in (300, 900, 130, 1500)]
    switches = {5: 1, 17: 2, 18: 3, 40: 0, 41: 3}
    one, ahead = BlockConvolver(hs[0], b), BlockConvolver(hs[0], b, batch=8)
    y_one, y_ahead, fed = [], [], 0
    for n in range(70):
        if n in switches:
            one.set_impulse(hs[switches[n]])
            ahead.set_impulse(hs[switches[n]])
        y_one.append(one.process(x[n * b:(n + 1) * b]))
        if n == 30:  # forget what was fed ahead; feed it again
            fed -= ahead.drop_ahead()
        if ahead.ahead == 0:
            k = min(int(rng.integers(1, 13)), 70 - fed)
            ahead.feed(x[fed * b:(fed + k) * b])
            fed += k
        y_ahead.append(ahead.pull())
    np.testing.assert_allclose(np.concatenate(y_ahead, axis=1), np.concatenate(y_one, axis=1), atol=2e-5)
    assert ahead.switches == one.switches == 5
    with pytest.raises(ValueError, match="feed first"):
        BlockConvolver(hs[0], b).pull()
    with pytest.raises(ValueError, match="whole number of blocks"):
        ahead.feed(np.zeros(b + 1, np.float32))


def test_pause_ramps_down_holds_the_position_and_resumes():
    e = engine_with(tone(220.5, 0.5, 3000), np.array([[1.0], [1.0]], np.float32))
    run(e, 3)
    e.playing = False
    fade_out = run(e, 1)
    blocks = e.blocks
    silent = run(e, 5)
    assert np.all(silent == 0) and e.blocks == blocks  # nothing computed while paused
    assert abs(fade_out[-1, 0]) < 0.01 and np.max(np.abs(np.diff(fade_out[:, 0]))) < 0.1
    e.playing = True
    resumed = run(e, 2)
    x = tone(220.5, 0.5, 3000)
    np.testing.assert_allclose(resumed[BLOCK:, 0], x[5 * BLOCK:6 * BLOCK], atol=1e-5)  # where it stopped


def test_volume_scales_and_meters_read_the_output_level():
    x = tone(220.5, 0.5, 2000)
    e = engine_with(x, np.array([[1.0], [0.5]], np.float32))
    e.volume = 0.5
    run(e, 20)
    left, right = e.block_levels  # a 0.25-amplitude sine: 20 log10(0.25 / sqrt 2)
    assert left == pytest.approx(20 * np.log10(0.25 / np.sqrt(2)), abs=0.1)
    assert left - right == pytest.approx(20 * np.log10(2), abs=0.1)


def test_filter_levels_predict_the_streamed_levels_and_the_make_up_gain_fits_them():
    clip = noise(SR * 2, 5)
    h = decaying(6, taps=2000, left=1.0, right=0.3)
    e = StreamEngine(SR, block=BLOCK, target_db=-20.0)
    e.volume = 1.0
    e.set_clip(clip)
    e.set_filter(h)
    y = run(e, 160)[20 * BLOCK:]
    measured = 20 * np.log10(np.sqrt(np.mean(np.square(y.astype(np.float64)), axis=0)))
    left, right, ild = filter_levels(h, e.spectrum, e.makeup_gain)
    assert left == pytest.approx(measured[0], abs=0.5) and right == pytest.approx(measured[1], abs=0.5)
    assert ild == pytest.approx(20 * np.log10(1 / 0.3), abs=0.1)
    assert max(left, right) == pytest.approx(-20.0, abs=0.01)


def test_any_callback_size_is_served():
    clip, h = noise(3000, 7), decaying(7)
    e = engine_with(clip, h)
    out, chunks = np.empty((1000, 2), np.float32), []
    for frames in (100, 1000, 37, 500):
        e.callback(out[:frames], frames)
        chunks.append(out[:frames].copy())
    y = np.concatenate(chunks)
    ref = reference(clip, h, len(y))
    np.testing.assert_allclose(y[BLOCK:], ref[BLOCK:], atol=2e-5)


def test_levels_and_ild_of_known_signals():
    x = tone(441, 1.0, SR)
    left, right, ild = audio.levels(np.stack([x, 0.5 * x]))
    assert left == pytest.approx(-3.01, abs=0.01)
    assert ild == pytest.approx(6.02, abs=0.01)
    assert audio.levels(np.zeros((2, 10)))[0] == audio.SILENCE_DB
    with pytest.raises(ValueError, match=r"\[2, T\]"):
        audio.levels(np.zeros(10))


def test_engine_rejects_bad_inputs():
    e = StreamEngine(SR)
    with pytest.raises(ValueError, match=r"\[2, L\]"):
        e.set_filter(np.zeros((1, 100)))
    with pytest.raises(ValueError, match="non-finite"):
        e.set_filter(np.full((2, 10), np.nan))
    with pytest.raises(ValueError, match="mono"):
        e.set_clip(np.zeros((2, 10)))
    with pytest.raises(ValueError, match=r"\[2, T\]"):
        e.set_loop(np.zeros(100), tag=None)
    with pytest.raises(ValueError, match="non-finite"):
        e.set_loop(np.full((2, 10), np.inf), tag=None)
    assert np.all(e.render_block() == 0)  # nothing to play yet: silence


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


def test_no_audio_device_is_reported_and_a_simulated_clock_pulls_the_engine():
    e = engine_with(noise(3000, 8), decaying(8))
    out = AudioOutput(e)
    message = out.start()
    try:
        if out.available:
            assert message is None
        else:
            assert message.startswith("No audio") and out.running
            time.sleep(0.5)
            assert 0.5 * 0.5 * SR / BLOCK <= e.blocks <= 1.5 * 0.5 * SR / BLOCK + 2  # the card's pace
    finally:
        out.close()
    assert not out.running and not [t for t in threading.enumerate() if t.name == "avgs-audio-clock"]
    forced = AudioOutput(StreamEngine(SR), device=False)
    assert forced.start() == "Audio output off" and forced.running and not forced.available
    forced.close()


# ---------------------------------------------------------------------- live filters
@pytest.fixture(scope="module")
def renderer(tmp_path_factory):
    rng = np.random.default_rng(0)
    pts = rng.uniform([0, 0, 0], [5, 4, 3], size=(400, 3))
    path = tmp_path_factory.mktemp("ckpt") / "scene.ckpt"
    save_checkpoint(untrained_checkpoint(pts, [4.0, 3.0, 1.2], seed=1), path)
    return SceneRenderer.load(path)


def test_pose_changes_put_the_pose_filter_in_the_engine(renderer):
    clip = tone(330.0, 0.3, SR // 2)
    state = ViewerState(renderer.bounds, renderer.source)
    engine = StreamEngine(renderer.sample_rate, block=BLOCK)
    live = LiveAudio(renderer, state, engine, clip, settle=None)  # the filter path alone (tests/test_viewer_refine.py: the rest)
    try:
        first = live.request()
        assert live.worker.wait_idle(30)
        run(engine, 2)
        assert engine.live_tag == first
        state.set_listener((1.0, 1.5, 0.0))
        state.set_yaw(45.0)
        assert live.worker.wait_idle(30)
        expected = renderer.binaural_filter(state.listener, 45.0).impulse
        np.testing.assert_array_equal(engine.impulse, expected)
        assert live.heard.request.pose == state.pose and live.heard.request.seq == live.seq
        run(engine, 1)
        assert engine.live_tag == live.seq  # heard from the next block on
        assert len(live.clip) == len(clip) - round(0.05 * SR)  # the seam crossfaded away
        assert len(live.last_result.listener_vicinity) == renderer.vicinity_size
        assert live.heard.levels == pytest.approx(filter_levels(expected, engine.spectrum, engine.makeup_gain))
        heard = live.heard_clip()  # what the export writes: the loop through the filter
        assert heard.shape == (2, len(live.clip))
        np.testing.assert_allclose(heard[0, :300], np.convolve(live.clip, expected[0])[:300], atol=1e-5)
    finally:
        live.close()


def test_a_long_drag_keeps_memory_flat_and_closing_leaves_no_thread(renderer):
    """An hour of dragging, compressed: hundreds of pose changes through the worker (newest-wins
    drops included) while the engine streams grow the process by no more than noise, and
    closing stops the worker thread."""

    def rss_mb() -> float:
        with open("/proc/self/status") as f:
            return next(int(line.split()[1]) for line in f if line.startswith("VmRSS")) / 1024

    state = ViewerState(renderer.bounds, renderer.source)
    engine = StreamEngine(renderer.sample_rate, block=BLOCK)
    live = LiveAudio(renderer, state, engine, tone(330.0, 0.3, SR // 2))
    rng = np.random.default_rng(0)
    lo, hi = np.asarray(renderer.bounds)

    def drag(moves: int) -> None:
        for i in range(moves):
            state.set_listener(rng.uniform(lo, hi))
            state.set_yaw(float(rng.uniform(0, 360)))
            run(engine, 1)
            if i % 10 == 9:
                assert live.worker.wait_idle(30)

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
