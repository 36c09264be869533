"""The impulse-response panel's numbers, playing a response once, and a fixed source: no window.

Known signals: an exponentially decaying noise has a known reverberation time and a straight
energy decay; a Dirac's decimation keeps its peak; the engine plays a response sample for sample.
"""

from __future__ import annotations

import numpy as np
import pytest

from avgs.evaluation.metrics import rt60, schroeder_db
from avgs_viewer.audio import ONCE_PEAK, StreamEngine
from avgs_viewer.drag import DragController
from avgs_viewer.response import DECAY_FLOOR_DB, ResponseSummary, column_edges, min_max_columns
from avgs_viewer.state import ViewerState
from engine_blocks import pull as pull_blocks

SR = 22050
BLOCK = 256
BOUNDS = np.array([[0.0, 0.0, 0.0], [5.0, 4.0, 3.0]])


def decaying_noise(t60: float, seconds: float, seed: int = 0, right: float = 0.5) -> np.ndarray:
    """[2, L]: white noise whose energy falls 60 dB in ``t60`` s; the right ear ``right`` times the left."""
    n = int(seconds * SR)
    t = np.arange(n) / SR
    h = np.random.default_rng(seed).standard_normal(n) * 10.0 ** (-3.0 * t / t60)  # amplitude -60 dB at t60
    return np.stack([h, right * h]).astype(np.float32) * 0.1


def test_decay_curves_and_t60_of_an_exponential_decay():
    h = decaying_noise(t60=0.4, seconds=0.8)
    s = ResponseSummary.of(h, SR)
    assert s.length == h.shape[1] and s.duration_ms == pytest.approx(1000 * h.shape[1] / SR)
    for ear in range(2):
        assert s.t60_s[ear] == pytest.approx(0.4, rel=0.1)  # the T60 the decay was made with
        assert s.t60_s[ear] == rt60(h[ear], fs=SR)  # the number `avgs eval` scores
        # Schroeder curve: -30 dB at half the T60 (the backward integral of an exponential is one).
        assert s.decay_db[ear, int(0.2 * SR)] == pytest.approx(-30.0, abs=2.0)
        curve = schroeder_db(h[ear])
        np.testing.assert_allclose(s.decay_db[ear, :len(curve)], np.maximum(curve, DECAY_FLOOR_DB))
    assert s.decay_db.min() >= DECAY_FLOOR_DB
    assert s.t60_text() == f"T60 L {s.t60_s[0]:.2f} s, R {s.t60_s[1]:.2f} s"
    assert not s.impulse.flags.writeable  # what is drawn cannot change under the plot
    moving = ResponseSummary.of(h, SR, t60=False)  # while a handle moves: the same curves, T60 left out
    np.testing.assert_array_equal(moving.decay_db, s.decay_db)
    assert moving.t60_s is None and moving.t60_text() == "T60 when the move ends"


def test_trace_keeps_every_peak_and_covers_the_whole_response():
    h = np.zeros((2, 10_001), np.float32)
    h[0, 1234], h[1, 9876], h[1, 17] = 1.0, -0.5, 0.25
    s = ResponseSummary.of(h, SR)
    tr = s.trace(300)
    assert tr.low.shape == tr.high.shape == tr.decay_db.shape == (2, 300)
    assert tr.high[0].max() == 1.0 and tr.low[1].min() == -0.5 and tr.high[1].max() == 0.25
    edges = column_edges(h.shape[1], 300)
    assert edges[0] == 0 and edges[-1] == h.shape[1] and np.all(np.diff(edges) >= 1)
    for c in (0, 37, 299):  # each column is the min / max of exactly its samples
        assert tr.high[0, c] == h[0, edges[c]:edges[c + 1]].max() and tr.low[1, c] == h[1, edges[c]:edges[c + 1]].min()
    assert tr.times_ms[0] > 0 and tr.times_ms[-1] < s.duration_ms and np.all(np.diff(tr.times_ms) > 0)
    # More columns than samples: one column per sample.
    short = ResponseSummary.of(h[:, :50], SR).trace(400)
    np.testing.assert_array_equal(short.high, h[:, :50])
    lo, hi = min_max_columns(np.arange(10.0), np.array([0, 3, 10]))
    assert list(lo) == [0.0, 3.0] and list(hi) == [2.0, 9.0]


def test_the_summary_finds_each_ears_direct_sound_and_the_itd():
    fs = 22050
    h = np.zeros((2, 4000), np.float32)
    h[0, 300], h[1, 309] = 1.0, 0.6  # the left ear first, the right 9 samples (408 us) later
    h[:, 400:] = 0.01 * np.random.default_rng(0).standard_normal((2, 3600))  # a quiet tail
    s = ResponseSummary.of(h, fs, t60=False)
    assert s.direct_s == (pytest.approx(300 / fs), pytest.approx(309 / fs))
    assert s.itd_s == pytest.approx(-9 / fs, abs=5e-6)  # negative: the left ear leads
    assert s.direct_text() == "direct L 13.6 ms, R 14.0 ms, ITD -408 us"
    silent = ResponseSummary.of(np.zeros((2, 100), np.float32), fs, t60=False)
    assert silent.direct_s == (None, None) and silent.direct_text() == "direct L -, R -, ITD +0 us"


def test_summary_rejects_bad_responses():
    with pytest.raises(ValueError, match=r"\[2, L\]"):
        ResponseSummary.of(np.zeros((3, 10)), SR)
    with pytest.raises(ValueError, match="non-finite"):
        ResponseSummary.of(np.full((2, 10), np.nan), SR)
    silent = ResponseSummary.of(np.zeros((2, 10)), SR)  # nothing to measure: no T60, the floor
    assert silent.t60_s == (None, None) and np.all(silent.decay_db == DECAY_FLOOR_DB)
    assert silent.t60_text() == "T60 L -, R -"


# ---------------------------------------------------------------------- playing once
def pull(engine: StreamEngine, blocks: int) -> np.ndarray:
    """Pump the callback like a sound card would: [blocks * BLOCK, 2]."""
    return pull_blocks(engine, blocks, BLOCK)


def engine_playing(clip: np.ndarray, h: np.ndarray) -> StreamEngine:
    e = StreamEngine(SR, block=BLOCK)
    e.set_clip(clip)
    e.set_filter(h, tag=1)
    return e


def test_a_response_plays_once_sample_for_sample_then_the_clip_resumes():
    clip = (0.3 * np.sin(2 * np.pi * 220.5 * np.arange(4000) / SR)).astype(np.float32)
    h = decaying_noise(t60=0.05, seconds=0.03, seed=1)  # 661 taps: 2.6 blocks
    e = engine_playing(clip, h)
    before = pull(e, 4)
    assert np.abs(before[-BLOCK:]).max() > 0.05  # the clip plays
    gain = e.play_once(h)
    assert gain == e.once_gain == pytest.approx(e.volume * e.makeup_gain) and e.playing_once
    fade = pull(e, 1)  # the clip fades out over one block
    assert abs(fade[-1, 0]) < 0.02 and np.abs(np.diff(fade[:, 0])).max() < 0.1
    n = h.shape[1]
    blocks = -(-n // BLOCK)
    played = pull(e, blocks)
    np.testing.assert_allclose(played[:n], gain * h.T, atol=1e-7)  # the response itself, from a block's start
    assert np.all(played[n:] == 0) and not e.playing_once
    after = pull(e, 3)  # the clip fades back in where it stopped: as after a pause as long
    ref = engine_playing(clip, h)
    pull(ref, 4)
    ref.playing = False
    pull(ref, 1 + blocks)
    ref.playing = True
    np.testing.assert_allclose(after, pull(ref, 3), atol=1e-6)
    assert np.abs(after[BLOCK:]).max() > 0.05


def test_play_once_works_while_paused_is_limited_in_peak_and_checks_its_input():
    clip = (0.01 * np.random.default_rng(0).standard_normal(3000)).astype(np.float32)
    h = np.zeros((2, 300), np.float32)
    h[:, 0] = (1.0, 0.5)  # a quiet clip: the make-up gain is large, the response's peak is capped
    e = engine_playing(clip, h)
    e.playing = False
    assert np.all(pull(e, 2) == 0)
    gain = e.play_once(h)
    assert gain == pytest.approx(ONCE_PEAK) and gain < e.volume * e.makeup_gain
    out = pull(e, 2)  # paused: it starts at once, no clip to fade out
    np.testing.assert_allclose(out[:300], gain * h.T, atol=1e-7)
    assert np.abs(out).max() == pytest.approx(ONCE_PEAK) and not e.playing_once
    assert np.all(pull(e, 3) == 0)  # and stays paused after it
    for bad, match in ((np.zeros((1, 5)), r"\[2, L\]"), (np.zeros((2, 0)), r"\[2, L\]"),
                       (np.full((2, 5), np.inf), "non-finite")):
        with pytest.raises(ValueError, match=match):
            e.play_once(bad)


# ---------------------------------------------------------------------- a fixed source
class TopDownCamera:
    """An orthographic camera looking down -z: 100 pixels per metre, origin at pixel (0, 0)."""

    def to_display(self, world):
        return np.asarray(world, dtype=float)[:2] * 100.0

    def ray(self, x, y):
        return np.array([x / 100.0, y / 100.0, 50.0]), np.array([0.0, 0.0, -1.0])


def test_a_fixed_source_refuses_moves_and_drags_and_says_why():
    reason = "trained with one source position"
    s = ViewerState(BOUNDS, source=(4, 3, 1.2), listener=(1, 1, 1.5), source_fixed=reason)
    refused, poses = [], []
    s.events.refused.connect(refused.append)
    s.events.pose.connect(poses.append)
    s.set_source((2.0, 2.0, 1.0))
    assert np.array_equal(s.source, (4, 3, 1.2)) and refused == [reason] and poses == []
    with pytest.raises(ValueError, match="source must be 3 finite numbers"):
        s.set_source((1.0, np.nan, 0.0))
    drag = DragController(s, TopDownCamera, handle_radius=0.2)
    assert drag.press(400, 300)  # on the source: the press is taken (the camera does not orbit) ...
    assert drag.dragging is None and drag.held == "source" and len(refused) == 2  # ... and says why once
    assert drag.move(250, 250) and drag.release(200, 200)
    assert np.array_equal(s.source, (4, 3, 1.2)) and poses == [] and len(refused) == 2 and drag.held is None
    assert drag.press(100, 100) and drag.dragging == "listener"  # the listener still moves
    drag.release(150, 120)
    assert s.listener[:2] == pytest.approx((1.5, 1.2)) and len(poses) == 1
    movable = ViewerState(BOUNDS, source=(4, 3, 1.2), listener=(1, 1, 1.5))
    assert movable.source_movable and not s.source_movable
    DragController(movable, TopDownCamera, handle_radius=0.2).press(400, 300)
