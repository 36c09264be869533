"""Viewer logic with no window and no GL: state, drag, colours, the newest-wins worker."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from avgs_viewer import colors
from avgs_viewer.drag import DragController, pick_handle, ray_plane_z
from avgs_viewer.state import ColourMode, ViewerState
from avgs_viewer.newest import RenderWorker

BOUNDS = np.array([[0.0, 0.0, 0.0], [5.0, 4.0, 3.0]])


class TopDownCamera:
    """An orthographic camera looking down -z: ``ppu`` pixels per metre, origin at pixel (0, 0)."""

    def __init__(self, ppu: float = 100.0):
        self.ppu = ppu

    def to_display(self, world):
        return np.asarray(world, dtype=float)[:2] * self.ppu

    def ray(self, x, y):
        return np.array([x / self.ppu, y / self.ppu, 50.0]), np.array([0.0, 0.0, -1.0])


class TiltedCamera(TopDownCamera):
    """A parallel projection along a tilted direction (rays not vertical), for the plane cast."""

    D = np.array([0.0, 0.6, -0.8])

    def to_display(self, world):
        w = np.asarray(world, dtype=float)
        t = -w[2] / self.D[2]  # slide along D onto z = 0
        return (w + t * self.D)[:2] * self.ppu

    def ray(self, x, y):
        base = np.array([x / self.ppu, y / self.ppu, 0.0])
        return base - 20 * self.D, self.D


def record(event):
    seen = []
    event.connect(seen.append)
    return seen


# ---------------------------------------------------------------------- state
def test_listener_moves_at_its_height_and_stays_in_bounds():
    s = ViewerState(BOUNDS, source=(4, 3, 1.2), listener=(1, 1, 1.5))
    listener_events, pose_events, clamped = record(s.events.listener), record(s.events.pose), record(s.events.clamped)
    s.set_listener((2.0, 2.0, 0.0))  # inside: nothing to say
    assert clamped == []
    s.set_listener((9.0, -2.0, 2.9))
    assert clamped == ["listener kept inside the scene: (9.00, -2.00, 1.50) -> (5.00, 0.00, 1.50)"]
    assert np.allclose(s.listener, [5.0, 0.0, 1.5])  # clamped in xy, height kept
    s.set_listener((9.0, -2.0, 0.0))  # the same clamped place: no event
    assert len(listener_events) == 2 and len(pose_events) == 2
    assert pose_events[-1].listener == (5.0, 0.0, 1.5)
    s.set_source((2.0, 2.0, 7.0))
    assert np.allclose(s.source, [2.0, 2.0, 3.0])  # the source may change height, within bounds
    assert clamped[-1].startswith("source kept inside the scene: (2.00, 2.00, 7.00)")


def test_yaw_wraps_turns_left_and_has_a_facing_vector():
    s = ViewerState(BOUNDS, source=(4, 3, 1.2))
    yaws = record(s.events.yaw)
    s.set_yaw(-90)
    assert s.yaw == 270.0 and np.allclose(s.facing, [0, -1, 0], atol=1e-12)
    s.turn(180)
    assert s.yaw == 90.0 and np.allclose(s.facing, [0, 1, 0], atol=1e-12)
    s.set_yaw(450)  # == 90: no event
    assert yaws == [270.0, 90.0]
    with pytest.raises(ValueError, match="yaw"):
        s.set_yaw(float("nan"))


def test_defaults_put_listener_opposite_the_source_and_the_slice_below_the_ceiling():
    s = ViewerState(BOUNDS, source=(4, 3, 1.2))
    assert np.allclose(s.listener, [1.0, 1.0, 1.2])
    assert 1.2 < s.slice_height < 3.0


def test_invalid_values_name_what_was_expected():
    with pytest.raises(ValueError, match="bounds"):
        ViewerState(np.zeros((3, 3)), source=(0, 0, 0))
    s = ViewerState(BOUNDS, source=(4, 3, 1.2))
    with pytest.raises(ValueError, match="listener must be 3 finite numbers"):
        s.set_listener((1, 2))
    with pytest.raises(ValueError, match="needs the Gaussians"):
        s.set_colour_mode("rgb")
    with pytest.raises(ValueError, match="alpha, rgb, vicinity"):
        s.set_colour_mode("depth")
    s2 = ViewerState(BOUNDS, source=(4, 3, 1.2), has_rgb=True)
    modes = record(s2.events.colour_mode)
    s2.set_colour_mode("rgb")
    assert modes == [ColourMode.RGB]


def test_slice_volume_and_play_are_clamped_and_only_emit_on_change():
    s = ViewerState(BOUNDS, source=(4, 3, 1.2))
    slices, volumes, plays = record(s.events.slice_height), record(s.events.volume), record(s.events.playing)
    s.set_slice_height(10)
    s.set_slice_height(3.0)
    s.set_volume(-1)
    s.toggle_playing()
    s.toggle_playing()
    assert slices == [3.0] and volumes == [0.0] and plays == [False, True]


# ---------------------------------------------------------------------- drag
def test_ray_plane_intersection():
    hit = ray_plane_z(np.array([0.0, 0.0, 5.0]), np.array([0.6, 0.0, -0.8]), 1.0)
    assert np.allclose(hit, [3.0, 0.0, 1.0])
    assert ray_plane_z(np.zeros(3), np.array([1.0, 0.0, 0.0]), 1.0) is None  # parallel
    assert ray_plane_z(np.zeros(3), np.array([0.0, 0.0, 1.0]), -1.0) is None  # behind the origin


def test_pick_prefers_the_handle_under_the_cursor():
    cam = TopDownCamera()
    handles = {"listener": np.array([1.0, 1.0, 1.5]), "source": np.array([1.3, 1.0, 1.2])}
    assert pick_handle(cam, handles, 100, 100, radius=0.2) == "listener"
    assert pick_handle(cam, handles, 125, 100, radius=0.2) == "source"  # both cover it; source is nearer
    assert pick_handle(cam, handles, 300, 300, radius=0.2) is None


def test_drag_listener_follows_the_cursor_on_its_plane_without_jumping():
    s = ViewerState(BOUNDS, source=(4, 3, 1.2), listener=(1, 1, 1.5))
    drag = DragController(s, TiltedCamera, handle_radius=0.2)
    interacting = record(s.events.interacting)
    px = TiltedCamera().to_display(s.listener)
    assert drag.press(px[0] + 5, px[1])  # grabbed 5 px off centre
    assert np.allclose(s.listener, [1, 1, 1.5])  # a press alone moves nothing
    drag.move(px[0] + 5 + 150, px[1] + 80)
    assert np.allclose(s.listener, [2.5, 1.8, 1.5])  # moved by the cursor's motion, at its height
    assert drag.release(px[0] + 5 + 200, px[1] + 80)
    assert np.allclose(s.listener, [3.0, 1.8, 1.5])
    assert interacting == [True, False] and drag.dragging is None
    assert not drag.move(0, 0) and not drag.release(0, 0)  # nothing grabbed any more


def test_drag_is_constrained_to_the_bounds_and_misses_pass_through():
    s = ViewerState(BOUNDS, source=(4, 3, 1.2), listener=(1, 1, 1.5))
    drag = DragController(s, TopDownCamera, handle_radius=0.2)
    assert not drag.press(10, 390)  # empty space: the camera gets the event
    assert drag.press(400, 300)  # the source
    drag.release(2000, -500)
    assert np.allclose(s.source, [5.0, 0.0, 1.2])
    assert np.allclose(s.listener, [1, 1, 1.5])


class PinholeCamera:
    """A perspective camera at ``eye`` looking at ``target`` (z up), focal length ``f`` pixels,
    principal point (400, 300): what VTK's camera is, for the pointer follower's plane map."""

    def __init__(self, eye=(-2.0, -3.0, 6.0), target=(2.5, 2.0, 1.0), f=700.0):
        self.eye = np.asarray(eye, dtype=float)
        fwd = np.asarray(target, dtype=float) - self.eye
        self.fwd = fwd / np.linalg.norm(fwd)
        right = np.cross(self.fwd, [0.0, 0.0, 1.0])
        self.right = right / np.linalg.norm(right)
        self.up = np.cross(self.right, self.fwd)
        self.f = f

    def to_display(self, world):
        d = np.asarray(world, dtype=float) - self.eye
        depth = d @ self.fwd
        return np.array([400 + self.f * (d @ self.right) / depth, 300 + self.f * (d @ self.up) / depth])

    def ray(self, x, y):
        d = self.f * self.fwd + (x - 400) * self.right + (y - 300) * self.up
        return self.eye.copy(), d / np.linalg.norm(d)


def test_follow_map_gives_the_pose_a_move_makes_without_making_it():
    s = ViewerState(BOUNDS, source=(4, 3, 1.2), listener=(1, 1, 1.5))
    drag = DragController(s, PinholeCamera, handle_radius=0.2)
    assert drag.follow_map(0, 0) is None  # nothing dragged
    px = PinholeCamera().to_display(s.listener)
    assert drag.press(px[0] + 3, px[1] - 2)
    pose_at = drag.follow_map(px[0] + 3, px[1] - 2)
    poses = record(s.events.pose)
    rng = np.random.default_rng(0)
    for x, y in np.column_stack([rng.uniform(0, 800, 40), rng.uniform(0, 600, 40)]):
        hit = ray_plane_z(*PinholeCamera().ray(x, y), 1.5)
        predicted = pose_at(x, y)
        if hit is None:  # above the horizon: the drag leaves the handle where it is
            assert predicted is None
            continue
        drag.move(x, y)  # what the state does with the same move
        assert predicted.listener == pytest.approx(tuple(s.listener), abs=1e-9)
        assert predicted.source == tuple(s.source) and predicted.yaw == s.yaw
    assert len(poses) > 10  # the moves moved it, the follow map did not
    drag.release(*PinholeCamera().to_display(s.listener))
    s2 = ViewerState(BOUNDS, source=(4, 3, 1.2), listener=(1, 1, 1.5), source_fixed="one source")
    assert s2.pose_with(source=(1, 1, 1)).source == (4.0, 3.0, 1.2)  # a fixed source stays
    assert s2.pose_with(listener=(9, -9, 0)).listener == (5.0, 0.0, 1.5)  # inside, at its height


def test_live_audio_takes_followed_poses_first_and_asks_once(tmp_path):
    from avgs_viewer.audio import StreamEngine
    from avgs_viewer.state import Pose
    from avgs_viewer.worker import LiveAudio

    class Filters:  # the renderer's interface: a pose's filter
        def binaural_filter(self, listener, yaw, source=None, stop=None):
            return type("R", (), {"impulse": np.tile(np.float32([[1.0], [0.5]]), (1, 4))})()

    s = ViewerState(BOUNDS, source=(4, 3, 1.2), listener=(1, 1, 1.5))
    engine = StreamEngine(22050, block=128)
    live = LiveAudio(Filters(), s, engine, np.zeros(2205, np.float32))
    assert live.worker.wait_idle()
    first = live.request()
    live.follow(True)
    followed = Pose((2.0, 1.0, 1.5), s.yaw, tuple(s.source))
    seq = live.request(followed)  # from the follower's thread, ahead of the GUI
    s.set_listener((1.5, 1.0, 1.5))  # Qt's copy of an older move, handled later: not asked for
    s.set_listener((2.0, 1.0, 1.5))
    assert live.seq == seq == first + 1
    live.follow(False)  # the release: the state agrees with what was followed
    assert live.seq == seq
    s.set_listener((2.5, 1.0, 1.5))  # an ordinary move again
    assert live.seq == seq + 1
    live.follow(True)
    s.set_listener((3.0, 1.0, 1.5))  # the follower missed this one (it failed)
    live.follow(False)
    assert live.seq == seq + 2 and live.worker.wait_idle()
    assert live.heard.request.pose.listener == (3.0, 1.0, 1.5)
    live.close()


# ---------------------------------------------------------------------- colours
def test_alpha_projection_finds_the_planted_components_with_fixed_signs():
    rng = np.random.default_rng(0)
    basis = np.linalg.qr(rng.normal(size=(12, 3)))[0].T  # [3, 12] orthonormal directions
    scores = rng.normal(size=(3000, 3)) * np.array([5.0, 2.0, 1.0])
    alpha = scores @ basis + 0.01 * rng.normal(size=(3000, 12)) + 3.0
    proj = colors.AlphaProjection.fit(alpha)
    for i in range(3):  # each component is the planted direction (up to sign) ...
        assert abs(proj.components[i] @ basis[i]) > 0.999
        big = np.argmax(np.abs(proj.components[i]))  # ... with its largest loading positive
        assert proj.components[i, big] > 0
    assert np.allclose(proj.explained, np.array([25, 4, 1]) / 30, atol=0.02)
    again = colors.AlphaProjection.fit(alpha[::-1] * 1.0)  # same rows, other order: same colours
    assert np.array_equal(proj(alpha), again(alpha))
    rgb = proj(alpha)
    assert rgb.dtype == np.uint8 and rgb.shape == (3000, 3)
    # A point far along +PC1 is pure red-saturated; along -PC1 has no red.
    sign = np.sign(proj.components[0] @ basis[0])
    ends = proj(np.stack([alpha.mean(0) + 40 * sign * basis[0], alpha.mean(0) - 40 * sign * basis[0]]))
    assert ends[0, 0] == 255 and ends[1, 0] == 0
    assert "PC1" in proj.legend()[0][0]


def test_alpha_projection_of_low_dimensional_alpha():
    alpha = np.column_stack([np.linspace(0, 1, 50), np.zeros(50)])
    rgb = colors.AlphaProjection.fit(alpha)(alpha)
    assert rgb[0, 0] == 0 and rgb[-1, 0] == 255  # PC1 spans red
    assert np.all(rgb[:, 2] == 128)  # a missing component shows as mid-level


def test_vicinity_labels_and_colours():
    labels = colors.vicinity_labels(6, [0, 1, 2], [2, 3])
    assert labels.tolist() == [colors.LISTENER, colors.LISTENER, colors.BOTH, colors.SOURCE, 0, 0]
    rgb = colors.vicinity_colours(labels)
    assert np.array_equal(rgb[2], colors.VICINITY_COLOURS[colors.BOTH])
    assert len({tuple(c) for c in colors.VICINITY_COLOURS}) == 4
    with pytest.raises(ValueError, match="listener vicinity indices"):
        colors.vicinity_labels(3, [5], [])


def test_rgb_takes_the_nearest_gaussian_colour():
    means = np.array([[0.0, 0, 0], [10.0, 0, 0]])
    rgb = np.array([[1.0, 0, 0], [0.0, 0, 1.0]])
    out = colors.rgb_from_gaussians(np.array([[1.0, 0, 0], [9.0, 1, 0]]), means, rgb)
    assert out.tolist() == [[255, 0, 0], [0, 0, 255]]


# ---------------------------------------------------------------------- worker
def test_worker_renders_only_the_newest_request():
    gate = threading.Event()
    rendered, results = [], []

    def render(x):
        rendered.append(x)
        gate.wait(5)
        return x * 10

    w = RenderWorker(render, lambda seq, req, res: results.append((seq, res)))
    try:
        w.submit(1)
        deadline = time.monotonic() + 5
        while not rendered and time.monotonic() < deadline:
            time.sleep(0.001)
        for x in (2, 3, 4):  # arrive while 1 is rendering
            w.submit(x)
        gate.set()
        assert w.wait_idle(5)
    finally:
        w.close()
    assert rendered == [1, 4]
    assert results == [(1, 10), (4, 40)]
    assert w.dropped == 2 and not w.alive


def test_worker_reports_errors_and_keeps_going():
    errors, results = [], []

    def render(x):
        if x < 0:
            raise ValueError("negative")
        return x

    w = RenderWorker(render, lambda s, q, r: results.append(r), lambda s, q, e: errors.append(str(e)))
    try:
        w.submit(-1)
        assert w.wait_idle(5)
        w.submit(2)
        assert w.wait_idle(5)
    finally:
        w.close()
    assert errors == ["negative"] and results == [2]
    with pytest.raises(RuntimeError, match="closed"):
        w.submit(3)


def test_pointer_follower_reports_moves_then_the_release_and_survives_a_lost_server():
    from avgs_viewer.pointer import PointerFollower

    class ScriptedPointer:  # what XQueryPointer answers, one reading per call
        def __init__(self, readings, then=None):
            self.readings, self.then = list(readings), then

        def query(self):
            if self.readings:
                return self.readings.pop(0)
            if self.then is not None:
                raise self.then
            return (30, 40, False)

    def follow(pointer, expect=(10.0, 20.0)):
        moved, failed = [], []
        f = PointerFollower(pointer)
        started = f.start(lambda rx, ry: (float(rx), float(ry)), expect, lambda x, y, final: moved.append((x, y, final)),
                          failed.append)
        if started:
            f._thread.join(5)
        return started, moved, failed

    # pressed at (10, 20), held still, moved twice, released at (30, 40)
    ok, moved, failed = follow(ScriptedPointer([(10, 20, True), (10, 20, True), (12, 25, True), (30, 40, True),
                                                (30, 40, False)]))
    assert ok and failed == []
    assert moved == [(12.0, 25.0, False), (30.0, 40.0, False), (30.0, 40.0, True)]
    # a press that did not come through X (pointer elsewhere, or button up): not followed
    assert follow(ScriptedPointer([(200, 20, True)]))[0] is False
    assert follow(ScriptedPointer([(10, 20, False)]))[0] is False
    # the X server goes away mid-drag: reported once, nothing more
    ok, moved, failed = follow(ScriptedPointer([(10, 20, True), (11, 20, True)], then=OSError("gone")))
    assert ok and moved == [(11.0, 20.0, False)] and len(failed) == 1 and isinstance(failed[0], OSError)
    # stopped by the GUI thread (it saw the release first): no callback after stop() returns
    endless = ScriptedPointer([(10, 20, True)] + [(10 + k % 7, 20, True) for k in range(100000)])
    moved = []
    f = PointerFollower(endless)
    assert f.start(lambda rx, ry: (float(rx), float(ry)), (10.0, 20.0), lambda x, y, final: moved.append(x),
                   lambda exc: None)
    time.sleep(0.05)
    f.stop()
    seen = len(moved)
    time.sleep(0.05)
    assert seen > 0 and len(moved) == seen


def test_spare_lane_runs_the_expedited_request_at_once_and_drops_the_stale_result():
    """A drag's release: request 1 (a move) is being computed when 2 (the release) comes; expedite()
    starts 2 on the spare lane at once, 2 is delivered while 1 still runs, and 1's late result is dropped."""
    gate, started = threading.Event(), []
    results = []

    def render(x):
        started.append(x)
        if x == 1:
            gate.wait(5)
        return x * 10

    w = RenderWorker(render, lambda seq, req, res: results.append((seq, res)), spare=True)
    try:
        w.submit(1)
        deadline = time.monotonic() + 5
        while not started and time.monotonic() < deadline:
            time.sleep(0.001)
        w.submit(2)
        assert not w.wait_idle(0.05) and started == [1]  # 2 waits behind 1 ...
        assert w.expedite()  # ... until the spare lane takes it
        deadline = time.monotonic() + 5
        while not results and time.monotonic() < deadline:
            time.sleep(0.001)
        assert results == [(2, 20)] and started == [1, 2]
        gate.set()
        assert w.wait_idle(5)
        assert not w.expedite()  # nothing waiting
    finally:
        w.close()
    assert results == [(2, 20)]
    assert w.superseded == 1 and w.expedited == 1 and w.rendered == 1 and not w.alive


def test_the_newest_request_of_every_burst_is_rendered_with_both_lanes_waiting():
    """Bursts of submissions, each expedited (as LiveAudio does), renders giving up when stale: the
    last of every burst is rendered. Both lanes wait on one condition; a submission that woke only
    the spare lane (which takes expedited work only) left it queued: 8 of 40 bursts lost it."""
    import random

    from avgs.threads import Stopped

    rng = random.Random(0)
    delivered = []
    holder = {}

    def render(seq):
        for _ in range(4):
            time.sleep(0.001)
            if holder["w"].stale(seq):
                raise Stopped("a newer request came")
        return seq

    w = RenderWorker(render, lambda s, q, r: delivered.append(s), spare=True)
    holder["w"] = w
    lost = 0
    try:
        for _ in range(40):
            for _ in range(rng.randint(2, 12)):
                seq = w.submit(w.submitted + 1)
                w.expedite()
                time.sleep(rng.uniform(0.0, 0.006))
            if not w.wait_idle(1.0) or delivered[-1] != seq:
                lost += 1
                w.submit(w.submitted + 1)  # the next submission wakes the lane
                w.wait_idle(1.0)
    finally:
        w.close()
    assert lost == 0 and w.stopped > 0  # (bursts did overlap: stale renders gave up)


def _live_audio(filters):
    """(state, engine, LiveAudio, errors reported) over ``filters`` (the renderer's interface), idle."""
    from avgs_viewer.audio import StreamEngine
    from avgs_viewer.worker import LiveAudio

    s = ViewerState(BOUNDS, source=(4, 3, 1.2), listener=(1, 1, 1.5))
    engine = StreamEngine(22050, block=128)
    errors = []
    live = LiveAudio(filters, s, engine, np.zeros(2205, np.float32), on_error=lambda r, e: errors.append(e))
    assert live.worker.wait_idle()
    return s, engine, live, errors


def _marked_filter(listener):
    """A stand-in pose filter [2, 4] whose right ear holds the listener's x (which pose the engine plays)."""
    return type("R", (), {"impulse": np.tile(np.float32([[1.0], [listener[0]]]), (1, 4))})()


def test_a_moves_filter_made_stale_by_a_newer_pose_stops_and_the_newest_is_heard():
    """While a move's filter is made the user moves on: the old one gives up at its stop check (the
    worker's ``stopped``, no error reported), and the newest pose's filter is what the engine gets."""
    from avgs.threads import Stopped

    inside, moved_on = threading.Event(), threading.Event()
    asked = []

    class Filters:
        def binaural_filter(self, listener, yaw, source=None, stop=None):
            if listener[0] == 2.0:  # the move being made when the user moves on
                inside.set()
                assert moved_on.wait(10)
            asked.append((listener[0], stop()))
            if stop():
                raise Stopped("stale")
            return _marked_filter(listener)

    s, engine, live, errors = _live_audio(Filters())
    s.set_listener((2.0, 1.0, 1.5))
    assert inside.wait(10)
    s.set_listener((3.0, 1.0, 1.5))  # the user moved on
    moved_on.set()
    assert live.worker.wait_idle(10)
    assert (2.0, True) in asked and (3.0, False) in asked
    assert live.worker.stopped == 1 and errors == []
    assert live.heard.request.pose.listener == (3.0, 1.0, 1.5) and engine.impulse[1, 0] == 3.0
    live.close()


def test_a_filter_made_stale_after_its_last_check_is_not_handed_to_the_engine():
    """The user moves on while a move's filter makes its last stage: the filter is made, but the engine
    never gets it (its hand-over would take the CPU from the newest pose's filter); the newest is heard."""
    inside, moved_on, old_made = threading.Event(), threading.Event(), threading.Event()
    made = []

    class Filters:  # never asks ``stop``: as if the newer pose came after the last check
        def binaural_filter(self, listener, yaw, source=None, stop=None):
            if listener[0] == 2.0:
                inside.set()
                assert moved_on.wait(10)
            if listener[0] == 3.0:  # the newest takes longer: the stale one is done first
                assert old_made.wait(10)
                time.sleep(0.05)
            made.append(listener[0])
            if listener[0] == 2.0:
                old_made.set()
            return _marked_filter(listener)

    s, engine, live, errors = _live_audio(Filters())
    filters_before = engine.filters_set
    s.set_listener((2.0, 1.0, 1.5))
    assert inside.wait(10)
    s.set_listener((3.0, 1.0, 1.5))  # the user moved on
    moved_on.set()
    assert live.worker.wait_idle(10)
    assert 2.0 in made and 3.0 in made  # both were made ...
    assert engine.filters_set == filters_before + 1 and engine.impulse[1, 0] == 3.0  # ... the engine got the newest only
    assert live.worker.stopped == 1 and errors == [] and live.heard.request.pose.listener == (3.0, 1.0, 1.5)
    live.close()


def test_a_filter_asked_to_stop_gives_up_and_one_never_asked_is_unchanged():
    from pathlib import Path

    from avgs.render.renderer import SceneRenderer
    from avgs.threads import Stopped

    r = SceneRenderer.load(Path(__file__).resolve().parents[1] / "assets" / "demo" / "scene.ckpt")
    lo, hi = r.bounds
    p, src = lo + (hi - lo) * 0.3, lo + (hi - lo) * 0.7
    asked = []
    kept = r.binaural_filter(p, 30.0, source=src, stop=lambda: asked.append(1) or False)
    assert len(asked) == 5  # at the start, before and after the network, after the direct sound, before its placement
    np.testing.assert_array_equal(kept.impulse, r.binaural_filter(p, 30.0, source=src).impulse)
    with pytest.raises(Stopped):
        r.binaural_filter(p, 30.0, source=src, stop=lambda: True)
    # a newer pose that comes while the vicinities and contexts are made keeps the network from running
    net = r.task_model.model.binauralizer
    ran, seen = [], []
    net.forward = lambda *a, _forward=net.forward, **k: ran.append(1) or _forward(*a, **k)
    try:
        with pytest.raises(Stopped):
            r.binaural_filter(p, 30.0, source=src, stop=lambda: bool(seen) or seen.append(1) or False)
    finally:
        del net.forward
    assert seen and not ran


def test_binaural_filters_on_two_threads_equal_those_made_one_after_another():
    """The explorer's two lanes call SceneRenderer.binaural_filter at once: the same filters, bit for bit."""
    from concurrent.futures import ThreadPoolExecutor
    from pathlib import Path

    from avgs.render.renderer import SceneRenderer

    r = SceneRenderer.load(Path(__file__).resolve().parents[1] / "assets" / "demo" / "scene.ckpt")
    lo, hi = r.bounds
    rng = np.random.default_rng(3)
    poses = [(lo + (hi - lo) * rng.uniform(0.2, 0.8, 3), float(rng.uniform(0, 360)), lo + (hi - lo) * rng.uniform(0.2, 0.8, 3))
             for _ in range(12)]
    serial = [r.binaural_filter(p, y, source=s).impulse for p, y, s in poses]
    with ThreadPoolExecutor(2) as pool:
        parallel = list(pool.map(lambda q: r.binaural_filter(q[0], q[1], source=q[2]).impulse, poses))
    for a, b in zip(serial, parallel):
        np.testing.assert_array_equal(a, b)


def test_a_background_worker_runs_at_a_lower_priority_than_the_process():
    """The inset's and the map's thread (a MapWorker) yields the CPU to the sound: its nice value is the process's + 10."""
    import os

    from avgs_viewer.propagation_view import MapWorker

    seen = []
    base = os.getpriority(os.PRIO_PROCESS, 0)

    def compute(request, cancelled):
        seen.append(os.getpriority(os.PRIO_PROCESS, threading.get_native_id()))
        yield request

    w = MapWorker(compute, lambda *a: None, name="avgs-inset")
    try:
        w.submit(1)
        assert w.wait_idle(5)
    finally:
        w.close()
    assert seen == [min(19, base + 10)]
    assert os.getpriority(os.PRIO_PROCESS, 0) == base  # the process (the GUI, the filter's threads) unchanged
