"""Behind a wall, in the impulse-response task: the straight path's test in G_a's points
(avgs.acoustics.line_of_sight), and what the direct sound does where it finds a wall: the first sound by the
walls' reflection that passes the opening, the fitted lag after distance / c, and the early ILD B's own times
the fitted factor (avgs.train.blocked_ild); on a partition of points put into the quick room's model."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch


@pytest.fixture(scope="module")
def renderer(quick_rir_renderer):
    return quick_rir_renderer


def test_a_wall_of_points_blocks_the_straight_path_and_the_threshold_is_fitted():
    """A wall of points at x = 0 (a door at 1 < y < 2): paths across it count its points, a path through
    the door or beside it none; the threshold fitted from labelled pairs separates them."""
    from avgs.acoustics.line_of_sight import fit_blocked_count, points_on_path

    ys, zs = np.meshgrid(np.arange(-3.0, 3.0, 0.05), np.arange(0.0, 2.5, 0.05))
    wall = np.stack([np.zeros(ys.size), ys.ravel(), zs.ravel()], 1)
    wall = wall[(wall[:, 1] < 1.0) | (wall[:, 1] > 2.0) | (wall[:, 2] > 2.1)]  # the door's opening
    pts = torch.from_numpy(wall)
    a = torch.tensor([[-2.0, 0.0, 1.5], [-2.0, 1.5, 1.5], [-2.0, -1.0, 1.5], [1.0, 0.0, 1.5]])
    b = torch.tensor([[2.0, 0.0, 1.5], [2.0, 1.5, 1.5], [-0.5, 2.5, 1.5], [3.0, 1.0, 1.5]])
    counts = points_on_path(pts, a, b, radius=0.2, margin=0.3).numpy()
    assert counts[0] > 20 and counts[1] == 0 and counts[2] == 0 and counts[3] == 0  # across, door, same side x2
    near = points_on_path(pts, torch.tensor([[-0.1, 0.0, 1.5]]), torch.tensor([[2.0, 0.0, 1.5]]), 0.2, 0.3)
    assert int(near[0]) == 0  # the wall within the margin of the listener: its own surroundings
    labels = np.array([False, True, True, True] * 3)
    noisy = np.concatenate([counts, counts + 2, counts + 1])
    t = fit_blocked_count(noisy, labels)
    assert t is not None and np.all((noisy >= t) == ~labels)
    assert fit_blocked_count(noisy, np.ones(12, bool)) is None  # no pair behind a wall: nothing to tell apart


def test_the_walls_count_widens_for_a_sparse_wall_so_no_path_slips_through_a_gap():
    """A wall of points 0.4 m apart: a 0.2 m path test lets a path between its points count none, the
    walls' radius (three spacings) counts the wall on every path across it; a dense wall keeps 0.2 m."""
    from avgs.acoustics.line_of_sight import WALL_SPACINGS, points_on_path, wall_radius

    def wall(step):
        ys, zs = np.meshgrid(np.arange(-3.0, 3.0, step), np.arange(0.0, 2.5, step))
        return torch.from_numpy(np.stack([np.zeros(ys.size), ys.ravel(), zs.ravel()], 1))

    sparse, dense = wall(0.4), wall(0.05)
    assert wall_radius(sparse, 0.2) == pytest.approx(WALL_SPACINGS * 0.4)
    assert wall_radius(dense, 0.2) == pytest.approx(0.2)
    ys = torch.linspace(-1.0, 1.0, 21)
    a = torch.stack([torch.full_like(ys, -2.0), ys, torch.full_like(ys, 1.4)], 1)  # 21 paths across, between the rows
    b = a + torch.tensor([4.0, 0.0, 0.0])
    assert int((points_on_path(sparse, a, b, 0.2, 0.3) == 0).sum()) > 5  # gaps: these cross and count no wall
    assert bool((points_on_path(sparse, a, b, wall_radius(sparse, 0.2), 0.3) > 0).all())


def _partition_model(renderer):
    """A copy of ``renderer``'s model whose G_a is a partition at x = 3 (y < 2, 2.5 m high, two faces 0.12 m
    apart) and whose straight path's test counts it: a path across it below y = 2 is behind a wall."""
    import copy

    model = copy.deepcopy(renderer.model)
    u = np.arange(0.0, 6.05, 0.1)
    yy, zz = np.meshgrid(u[u <= 2.0], u[u <= 2.5])
    partition = [np.stack([np.full(yy.size, x), yy.ravel(), zz.ravel()], -1) for x in (3.0, 3.12)]
    model.points.X.data = torch.as_tensor(np.concatenate(partition), dtype=model.points.X.dtype)
    with torch.no_grad():
        for name, value in (("sight_radius", 0.2), ("sight_margin", 0.3), ("sight_blocked", 20.0)):
            getattr(model.binauralizer, name).fill_(value)
        if getattr(model.binauralizer, "reflected_arrival", None) is not None:
            model.binauralizer.reflected_arrival.zero_()
    return model


def test_behind_a_wall_the_first_sound_comes_by_the_reflection_that_passes_the_opening(renderer):
    """A partition at x = 3 (y < 2, open above) between a listener facing +x and a source straight ahead:
    with ``reflected_arrival`` the direct sound arrives along the y = 4 wall's reflection, which passes the
    opening (its path / c, the ITD of its image source on the left: the right ear later), or with its
    direction alone; off, along the straight line with no ITD. The quick room's own training has no pair
    behind a wall: its fit says so and keeps the straight line."""
    assert renderer.config.rir.reflected_arrival and renderer.model.binauralizer.reflected_arrival.tolist() == [0.0, 0.0]
    model = _partition_model(renderer)
    b = model.binauralizer
    u = np.arange(0.0, 6.05, 0.1)
    xx, zz = np.meshgrid(u, u[u <= 2.5])
    wall = np.stack([xx.ravel(), np.full(xx.size, 4.0), zz.ravel()], -1)  # the y = 4 wall
    model.points.X.data = torch.cat([model.points.X.data, torch.as_tensor(wall, dtype=model.points.X.dtype)])
    with torch.no_grad():
        for name, value in (("sight_radius", 0.2), ("sight_margin", 0.3), ("sight_blocked", 20.0), ("reflection_radius", 0.3),
                            ("reflection_points", 3.0), ("reflection_band", 0.3), ("reflected_arrival", 1.0)):  # both
            getattr(b, name).fill_(value)
        b.reflecting_walls.zero_()
        b.reflecting_walls[0] = torch.tensor([0.0, 1.0, 4.0])
    # 5 cm off the points' 10 cm grid: no point lies at the test's radius exactly, where float rounding
    # alone would say whether it counts (at z = 1.5, 8 of the partitions' points are 0.2 from the path)
    listener = torch.tensor([[2.0, 1.5, 1.55]])
    source = torch.tensor([[5.5, 1.5, 1.55]])
    yaw = torch.zeros(1)
    c = model.rir.sound_speed
    with torch.no_grad():
        direct = model.direct_sound(listener, yaw, source)
        assert direct.arrival.item() == pytest.approx(math.hypot(3.5, 5.0) / c)
        image_theta = math.atan2(6.5 - 1.5, 5.5 - 2.0)  # the image source (5.5, 6.5): left of the facing
        tau = float(model.head_itd(torch.tensor(image_theta)))
        assert tau > 2e-4  # on the left: the right ear later
        assert direct.delays[0].tolist() == pytest.approx([0.0, tau])
        assert math.isnan(direct.ild[0].item())  # behind a wall the early ILD stays B's
        b.reflected_arrival.copy_(torch.tensor([1.0, 0.0]))  # its direction, the straight line's delay
        direction = model.direct_sound(listener, yaw, source)
        b.reflected_arrival.zero_()
        straight = model.direct_sound(listener, yaw, source)
    assert direction.arrival.item() == pytest.approx(3.5 / c) and direction.delays[0].tolist() == pytest.approx([0.0, tau])
    assert straight.arrival.item() == pytest.approx(3.5 / c)
    assert straight.delays[0].abs().max().item() < 1e-6  # straight ahead: no ITD


def test_behind_a_wall_the_first_sound_arrives_the_fitted_lag_after_the_straight_line(renderer):
    """With ``blocked_lag`` the direct sound of a pose behind the partition arrives at distance / c plus the
    lag, with the ITD of its direction as before; a pose in sight (its path passes above the partition's
    end) keeps distance / c. The quick room has no pair behind a wall: training fits no lag."""
    assert renderer.config.rir.blocked_lag and float(renderer.model.binauralizer.blocked_lag) == 0.0
    model = _partition_model(renderer)
    listener = torch.tensor([[2.0, 1.55, 1.55], [2.0, 3.05, 1.55]])  # 5 cm off the points' grid (see above)
    source = torch.tensor([[5.5, 1.0, 1.55], [5.5, 3.55, 1.55]])
    yaw = torch.zeros(2)
    c = model.rir.sound_speed
    distance = torch.linalg.vector_norm(source - listener, dim=-1).double()
    with torch.no_grad():
        plain = model.direct_sound(listener, yaw, source)
        model.binauralizer.blocked_lag.fill_(0.004)
        lagged = model.direct_sound(listener, yaw, source)
    assert plain.arrival.tolist() == pytest.approx((distance / c).tolist())
    assert lagged.arrival.tolist() == pytest.approx([float(distance[0]) / c + 0.004, float(distance[1]) / c])
    assert torch.equal(lagged.delays, plain.delays)


@pytest.mark.parametrize("through_the_wall", [False, True])
def test_the_lag_is_fitted_to_the_training_pairs_behind_a_wall(renderer, through_the_wall):
    """Training pairs on both sides of the partition whose onsets are distance / c, and, behind it, 3 ms later
    (a first sound that goes around) or not (one that comes through): the fit finds 3 ms, or no lag."""
    from types import SimpleNamespace

    from avgs.train.impulse_responses import ImpulseResponseTraining

    model = _partition_model(renderer)
    rng = np.random.default_rng(5)
    n = 40
    receiver = np.stack([rng.uniform(0.5, 2.5, n), rng.uniform(0.2, 3.8, n), np.full(n, 1.55)], -1)
    source = np.tile([5.5, 1.0, 1.55], (n, 1))
    task = SimpleNamespace(train_set=SimpleNamespace(receiver=receiver, source=source, yaw=rng.uniform(0, 360, n)),
                           _log=None)
    task._counts_on_paths = lambda m, r, g: ImpulseResponseTraining._counts_on_paths(task, m, r, g)
    task._behind_a_wall = lambda m: ImpulseResponseTraining._behind_a_wall(task, m)
    blocked = task._counts_on_paths(model, 0.2, 0.3) >= 20
    assert 10 <= int(blocked.sum()) <= n - 10  # both sides hold pairs
    c = model.rir.sound_speed
    onsets = np.linalg.norm(source - receiver, axis=-1) / c
    task._onsets = onsets + np.where(blocked & (not through_the_wall), 0.003 + rng.uniform(-2e-4, 2e-4, n), 0.0)
    ImpulseResponseTraining.fit_lag(task, model)
    assert float(model.binauralizer.blocked_lag) == pytest.approx(0.0 if through_the_wall else 0.003, abs=2.5e-4)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_the_points_on_a_path_by_the_compiled_loop_are_the_matrix_products_count(dtype):
    """points_on_path on the CPU (one compiled loop, float64) counts what its torch reference (the CUDA path,
    matrix products in the points' precision) counts, with and without a mask of the points that may count,
    for segments of every length (none shorter than twice the margin counts anything)."""
    from avgs.acoustics.line_of_sight import points_on_path, points_on_path_torch

    rng = np.random.default_rng(11)
    points = torch.from_numpy(rng.uniform(-2.0, 2.0, (3000, 3))).to(dtype)
    a = torch.from_numpy(rng.uniform(-2.0, 2.0, (64, 3)))
    b = a + torch.from_numpy(rng.normal(0.0, 1.0, (64, 3)))
    keep = torch.from_numpy(rng.random((3000, 64)) < 0.7)
    for mask in (None, keep):
        fast = points_on_path(points, a, b, 0.2, 0.3, mask)
        reference = points_on_path_torch(points, a, b, 0.2, 0.3, mask)
        assert fast.dtype == torch.int64 and fast.shape == (64,)
        assert torch.equal(fast, reference) and int(fast.sum()) > 100
    short = points_on_path(points, a, a + 0.1, 0.2, 0.3)
    assert not bool(short.any())


def _waves(model, listener, yaw, source, length):
    """The model's responses [B, 2, L] (the checkpoint's phase, the direct sound placed) of a batch of poses."""
    from avgs.acoustics.rir_model import response_waveform

    rc = model.rir
    with torch.no_grad():
        mags = model.magnitudes(model.log_magnitudes(listener, yaw, source, model.precompute())[0])
        return response_waveform(mags, length, model.stft, rc.phase, rc.phase_iterations,
                                 direct=model.direct_sound(listener, yaw, source)).numpy()


def test_behind_a_wall_the_early_ild_is_b_s_own_times_the_factor(renderer):
    """With ``blocked_ild`` a pose behind the partition keeps B's response but its first 5 ms's ILD is B's own
    times the factor (what the metric reads); a pose in sight is unchanged. The quick room has no pair behind a
    wall: training keeps B's own (1)."""
    from avgs.evaluation import spatial

    assert renderer.config.rir.blocked_ild and float(renderer.model.binauralizer.blocked_ild) == 1.0
    model = _partition_model(renderer)
    with torch.no_grad():
        model.binauralizer.mean[0] += math.log(2.0)  # B's left ear 6 dB louder: an ILD to scale
    listener = torch.tensor([[2.0, 1.55, 1.55], [2.0, 3.05, 1.55]])  # behind the partition; in sight (see above)
    source = torch.tensor([[5.5, 1.0, 1.55], [5.5, 3.55, 1.55]])
    yaw = torch.zeros(2)
    length, fs = renderer.config.rir.length, renderer.sample_rate
    own = _waves(model, listener, yaw, source, length)
    model.binauralizer.blocked_ild.fill_(0.3)
    scaled = _waves(model, listener, yaw, source, length)
    ild_own, ild_scaled = spatial.early_ild(own[0], fs), spatial.early_ild(scaled[0], fs)
    assert ild_own > 2.5  # B's own, its left ear louder
    assert ild_scaled == pytest.approx(0.3 * ild_own, abs=0.25)
    assert np.array_equal(scaled[1], own[1])
    with torch.no_grad():
        arrival = float(model.direct_sound(listener, yaw, source).arrival[0]) * fs  # samples
    changed = np.nonzero(np.abs(scaled[0] - own[0]).max(0) > 0)[0]
    assert arrival - 30 <= changed.min() and changed.max() < arrival + 0.01 * fs  # the early stretch and its fade only


@pytest.mark.parametrize("most", [256, 9])
def test_the_early_ild_factor_is_fitted_to_the_training_pairs_behind_a_wall(renderer, most, monkeypatch):
    """Training pairs on both sides of the partition whose early ILDs behind it are 0.3 of what B's own
    responses have: the fit finds 0.3 (of 0, 0.1, .. 1); with their own ILDs it keeps 1. Scoring only some
    of the pairs behind the wall (``MOST_PAIRS``, evenly spaced) finds the same."""
    from types import SimpleNamespace

    from avgs.evaluation import spatial
    from avgs.train import blocked_ild
    from avgs.train.impulse_responses import ImpulseResponseTraining

    monkeypatch.setattr(blocked_ild, "MOST_PAIRS", most)

    model = _partition_model(renderer)
    with torch.no_grad():
        model.binauralizer.mean[0] += math.log(2.0)  # B's left ear 6 dB louder: an ILD to scale
    rng = np.random.default_rng(6)
    n = 30
    receiver = np.stack([rng.uniform(0.5, 2.5, n), rng.uniform(0.2, 3.8, n), np.full(n, 1.55)], -1)
    source = np.tile([5.5, 1.0, 1.55], (n, 1))
    yaw = rng.uniform(0, 360, n)
    task = SimpleNamespace(train_set=SimpleNamespace(receiver=receiver, source=source, yaw=yaw), _log=None,
                           _cfg=SimpleNamespace(rir=renderer.config.rir, stft=renderer.stft),
                           responses=SimpleNamespace(length=renderer.config.rir.length))
    task._counts_on_paths = lambda m, r, g: ImpulseResponseTraining._counts_on_paths(task, m, r, g)
    task._behind_a_wall = lambda m: ImpulseResponseTraining._behind_a_wall(task, m)
    blocked = task._counts_on_paths(model, 0.2, 0.3) >= 20
    assert 10 <= int(blocked.sum()) <= n - 10  # both sides hold pairs
    waves = _waves(model, torch.as_tensor(receiver, dtype=torch.float32), torch.as_tensor(np.radians(yaw), dtype=torch.float32),
                   torch.as_tensor(source, dtype=torch.float32), renderer.config.rir.length)
    own = np.array([spatial.early_ild(w, renderer.sample_rate) for w in waves])
    for factor, expected in ((0.3, 0.3), (1.0, 1.0)):
        task._ilds = np.where(blocked, factor * own, own + 5.0)  # in sight: not what the fit reads
        ImpulseResponseTraining.fit_blocked_ild(task, model)
        assert float(model.binauralizer.blocked_ild) == pytest.approx(expected, abs=0.051)


def test_the_straight_paths_tests_are_fitted_again_on_the_points_stage_2_left(renderer):
    """Training's start fits the straight path's test (and the lag) on G_a as stage 1 left it; stage 2 adds points
    (the partition at twice the density, and a cluster in the open where some paths in sight pass), so the start's
    threshold puts paths in sight behind a wall. ``refit_geometry`` (training's end) fits both again on the final
    points: every pair is told as its onset says again, and the lag is refitted; on unchanged points it gives what
    the start gave."""
    from types import SimpleNamespace

    from avgs.train.impulse_responses import ImpulseResponseTraining

    model = _partition_model(renderer)
    model.binauralizer.reflecting_walls = None  # the walls' fit has its own tests (test_early_reflections.py)
    model.binauralizer.reflected_arrival = None
    rng = np.random.default_rng(7)
    receiver = np.stack([rng.uniform(0.5, 2.5, 400), rng.uniform(0.2, 3.8, 400), np.full(400, 1.55)], -1)
    crossing = receiver[:, 1] + (1.0 - receiver[:, 1]) * (3.06 - receiver[:, 0]) / (5.5 - receiver[:, 0])  # y at the partition
    receiver = np.concatenate([receiver[crossing < 1.5][:30], receiver[crossing > 2.5][:30]])  # clear of its end
    n = len(receiver)
    source = np.tile([5.5, 1.0, 1.55], (n, 1))
    records = []
    task = SimpleNamespace(train_set=SimpleNamespace(receiver=receiver, source=source, yaw=rng.uniform(0, 360, n)),
                           scene=SimpleNamespace(frame=SimpleNamespace(scale=1.0)), _before_walls=([0.0], None),
                           _log=SimpleNamespace(write=records.append))
    for name in ("_counts_on_paths", "_behind_a_wall", "_fit_sight", "fit_lag", "refit_geometry"):
        setattr(task, name, getattr(ImpulseResponseTraining, name).__get__(task))
    task._in_sight = task._counts_on_paths(model, 0.2, 0.3) == 0  # the onsets' truth: across the partition is behind it
    assert int((~task._in_sight).sum()) == 30
    c = model.rir.sound_speed
    task._onsets = np.linalg.norm(source - receiver, axis=-1) / c + np.where(task._in_sight, 0.0, 0.003)
    task._fit_sight(model)
    task.fit_lag(model)
    start = float(model.binauralizer.sight_blocked)
    assert float(model.binauralizer.blocked_lag) == pytest.approx(0.003)

    task.refit_geometry(model)  # nothing moved: the same test and lag
    assert records[-1]["stage"] == "geometry" and float(model.binauralizer.sight_blocked) == start
    assert float(model.binauralizer.blocked_lag) == pytest.approx(0.003)

    u = np.arange(0.0, 6.05, 0.05)
    yy, zz = np.meshgrid(u[u <= 2.0], u[u <= 2.5])
    denser = [np.stack([np.full(yy.size, x), yy.ravel(), zz.ravel()], -1) for x in (3.0, 3.12)]
    cluster = np.array([2.9, 3.3, 1.55]) + rng.uniform(-0.12, 0.12, (int(start) + 10, 3))  # in the open, beside the partition
    model.points.X.data = torch.as_tensor(np.concatenate(denser + [cluster]), dtype=model.points.X.dtype)
    counts = task._counts_on_paths(model, float(model.binauralizer.sight_radius), float(model.binauralizer.sight_margin))
    assert (task._in_sight & (counts >= start)).sum() >= 2  # the start's threshold now puts paths in sight behind a wall
    task._onsets = task._onsets + np.where(task._in_sight, 0.0, 0.002)  # (and the lag it fits is the final pairs')
    task.refit_geometry(model)
    assert np.array_equal(counts >= float(model.binauralizer.sight_blocked), ~task._in_sight)
    assert float(model.binauralizer.blocked_lag) == pytest.approx(0.005)
    assert records[-1] == {"stage": "geometry", "event": "refit", "points": len(model.points.X)}
