"""The propagation map (avgs.render.propagation_map): the exact map against the single-pose path, the fast
map against the exact one, on the bundled demo scene (impulse responses) and a one-source mask model."""

from __future__ import annotations

import math
import threading
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch

from avgs import SceneRenderer
from avgs.render.renderer import HeadroomLimited
from avgs.render.cells import FastMap, bin_subset, early_frames, ear_power, frame_interpolation, frame_nodes, pose_levels, power_levels
from avgs.render.propagation_map import coarse_to_fine, compute_map, floor_grid, propagation_map

DEMO = Path(__file__).resolve().parents[1] / "assets" / "demo" / "scene.ckpt"
FAST_TOLERANCE_DB = 0.3
"""The fast map's largest allowed error against the exact map, level and ILD (measured: at most 0.25 dB on six
checkpoints, benchmarks/propagation_map.md)."""
pytestmark = pytest.mark.skipif(not DEMO.is_file(), reason="the bundled demo checkpoint is missing")


@pytest.fixture(scope="module", params=["binaural", "rir"])
def renderer(request, one_source_ckpt):
    """Both tasks: a one-source (binaural) checkpoint, and the bundled demo (impulse responses)."""
    torch.set_num_threads(1)
    r = SceneRenderer.load(one_source_ckpt if request.param == "binaural" else DEMO)
    assert r.task == request.param
    return r


@pytest.fixture(scope="module")
def binaural(one_source_ckpt):
    torch.set_num_threads(1)
    return SceneRenderer.load(one_source_ckpt)


def test_ear_power_closed_forms():
    F = 5
    level, ild = power_levels(ear_power(np.ones(F), np.zeros(F)))
    assert level == pytest.approx(0.0) and ild == pytest.approx(0.0)
    level, ild = power_levels(ear_power(np.full(F, 0.5), np.full(F, 0.5)))  # gains 0.75 and 0.25
    assert ild == pytest.approx(20 * math.log10(3.0))
    assert level == pytest.approx(10 * math.log10((0.75**2 + 0.25**2) / 2))
    # The tail of a stationary source settles at r^2 w / (1 - w): w = 0.5 adds r^2.
    p = ear_power(np.zeros(F), np.zeros(F), np.stack([np.full(F, 2.0), np.full(F, 1.0)]), np.full(F, 0.5))
    assert np.allclose(p, [[4.0] * F, [1.0] * F])
    assert power_levels(p)[1] == pytest.approx(10 * math.log10(4.0))
    assert power_levels(ear_power(np.zeros(F), np.zeros(F)))[0] == -120.0  # silence is a number


def test_coarse_to_fine_visits_every_cell_once_coarse_first():
    order = coarse_to_fine(64, 64)
    assert sorted(order.tolist()) == list(range(64 * 64))
    iy, ix = np.divmod(order[:16], 64)
    assert np.all(iy % 16 == 0) and np.all(ix % 16 == 0)
    iy, ix = np.divmod(order[16:64], 64)
    assert np.all(iy % 8 == 0) and np.all(ix % 8 == 0)
    assert len(coarse_to_fine(5, 3)) == 15


def test_map_cells_equal_the_single_pose_masks(renderer):
    r = renderer
    source = (3.2, 2.2, 1.2)
    pmap = compute_map(r, source=source, yaw=30.0, z=1.5, size=8, batch=16, chunk=3, exact=True)
    assert pmap.complete and np.all(np.isfinite(pmap.level)) and np.all(np.isfinite(pmap.ild))
    positions = pmap.grid.positions()
    for flat in (0, 9, 27, 40, 63):
        level, ild = pose_levels(r.masks(positions[flat], 30.0, source=source))
        iy, ix = divmod(flat, 8)
        assert pmap.level[iy, ix] == pytest.approx(level, abs=1e-4)
        assert pmap.ild[iy, ix] == pytest.approx(ild, abs=1e-4)
    if r.source_aware:  # the demo, trained on many sources: the level falls away from the source
        d = np.hypot(positions[:, 0] - source[0], positions[:, 1] - source[1])
        assert np.corrcoef(d, pmap.level.ravel())[0, 1] < -0.3


def test_map_applies_the_renderers_headroom(one_source_ckpt):
    r = SceneRenderer.load(one_source_ckpt)
    with torch.no_grad():
        r.model.binauralizer.mix_head.bias += 40.0  # a filter far over the headroom
    pmap = compute_map(r, yaw=0.0, z=1.5, size=2, exact=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", HeadroomLimited)
        level, ild = pose_levels(r.masks(pmap.grid.positions()[3], 0.0))
    assert pmap.level[1, 1] == pytest.approx(level, abs=1e-4) and pmap.ild[1, 1] == pytest.approx(ild, abs=1e-4)
    fast = compute_map(r, yaw=0.0, z=1.5, size=2)  # near the limit: evaluated at every bin, as exact
    assert np.allclose(fast.level, pmap.level, atol=1e-4) and np.allclose(fast.ild, pmap.ild, atol=1e-4)


def test_a_narrow_peak_between_the_fast_bins_still_sets_the_headroom_limit():
    r = SceneRenderer.load(DEMO)
    b = r.model.binauralizer
    peak_bin = 57  # not one of the fast map's bins (every 8th)
    assert peak_bin not in bin_subset(b.n_freq, FastMap().bin_stride)[0].tolist()
    with torch.no_grad():
        b.head.bias += 1.5  # every bin 13 dB louder: the limit applies near the source
        b.head.bias[[peak_bin, b.n_freq + peak_bin]] += 1.0  # and one bin 8.7 dB more, both ears
    source = (3.0, 2.2, 1.5)
    exact = compute_map(r, source=source, yaw=0.0, z=1.5, size=16, exact=True)
    fast = compute_map(r, source=source, yaw=0.0, z=1.5, size=16)
    assert exact.level.max() > 10.0  # loud cells, limited by the peak bin
    assert np.abs(fast.level - exact.level).max() <= FAST_TOLERANCE_DB
    assert np.abs(fast.ild - exact.ild).max() <= FAST_TOLERANCE_DB


def test_ild_flips_when_the_source_moves_from_left_to_right():
    r = SceneRenderer.load(DEMO)  # trained on many sources: the source really moves
    grid = floor_grid(r, 1.5, size=1)  # one cell, at the middle of the floor plan
    x, y = float(grid.x[0]), float(grid.y[0])
    ilds = {}
    for side, dx in (("left", -1.5), ("right", 1.5)):  # facing +y: -x is on the left
        ilds[side] = compute_map(r, source=(x + dx, y, 1.2), yaw=90.0, grid=grid).ild[0, 0]
    assert ilds["left"] > 1.0 and ilds["right"] < -1.0


def test_partial_maps_cover_the_floor_and_cancel_stops(renderer):
    stop = threading.Event()
    parts = []
    for part in propagation_map(renderer, yaw=0.0, z=1.5, size=16, batch=16, cancel=stop):
        parts.append(part)
        if part.done >= 64:
            stop.set()
    assert [p.done for p in parts] == [16, 32, 48, 64]
    first = parts[0]
    assert np.isnan(first.level).sum() == 256 - 16  # 16 exact cells (every 4th row and column)
    assert np.all(np.isfinite(first.filled("level")))  # shown as a coarse map over the whole floor
    filled = parts[-1].filled("ild")  # every 2nd cell: 8x8 done
    assert np.all(np.isfinite(filled)) and filled[1, 1] == parts[-1].ild[0, 0]
    with pytest.raises(ValueError, match="kind"):
        first.values("loudness")


def test_grid_covers_the_outline_inside_the_box():
    renderer = SceneRenderer.load(DEMO)  # a scene with an outline
    g = floor_grid(renderer, 99.0, size=(6, 4))
    assert g.shape == (4, 6) and g.z == pytest.approx(float(renderer.bounds[1, 2]))
    x0, x1, y0, y1 = g.extent
    outline = renderer.outline.reshape(-1, 3)
    assert x0 == pytest.approx(outline[:, 0].min()) and x1 == pytest.approx(outline[:, 0].max())
    assert y0 == pytest.approx(outline[:, 1].min()) and y1 == pytest.approx(outline[:, 1].max())


# -- the fast map ----------------------------------------------------------------------------


@pytest.mark.parametrize("case", [(None, 0.0), ((2.0, 3.5, 1.2), 120.0), ((7.5, 1.0, 1.5), 250.0)])
def test_fast_map_is_within_tolerance_of_the_exact_map(renderer, case):
    source, yaw = case
    source = source if renderer.source_aware else None  # a one-source model: its trained source, at each yaw
    fast = compute_map(renderer, source=source, yaw=yaw, z=1.5, size=16)
    exact = compute_map(renderer, source=source, yaw=yaw, z=1.5, size=16, exact=True)
    assert fast.complete and np.all(np.isfinite(fast.level)) and np.all(np.isfinite(fast.ild))
    for kind in ("level", "ild"):
        error = np.abs(fast.values(kind) - exact.values(kind))
        assert error.max() <= FAST_TOLERANCE_DB, (kind, error.max())
        assert np.median(error) <= 0.1, (kind, np.median(error))
    span = exact.level.max() - exact.level.min()
    assert span > 10 * FAST_TOLERANCE_DB  # the tolerance is small against what the map shows


def test_worker_threads_give_the_same_map(renderer):
    one = compute_map(renderer, yaw=45.0, z=1.5, size=12, chunk=8)
    two = compute_map(renderer, yaw=45.0, z=1.5, size=12, chunk=8, workers=2)
    assert np.array_equal(one.level, two.level) and np.array_equal(one.ild, two.ild)
    stop = threading.Event()
    parts = []
    for part in propagation_map(renderer, yaw=0.0, z=1.5, size=16, batch=16, chunk=4, workers=2, cancel=stop):
        parts.append(part)
        stop.set()
    assert [p.done for p in parts] == [16] and np.isfinite(parts[0].level).sum() == 16


def test_subsets_of_frames_and_bins_are_those_entries_of_the_whole_output():
    r = SceneRenderer.load(DEMO)
    b = r.model.binauralizer
    g = torch.Generator().manual_seed(0)
    lis, src = torch.rand(3, 3, generator=g) - 0.5, torch.rand(3, 3, generator=g) - 0.5
    theta, yaw = torch.rand(3, generator=g) * 6, torch.rand(3, generator=g) * 6
    ctx = torch.randn(3, b.context_proj.in_features, generator=g)
    frames, bins = torch.tensor([0, 3, 40, b.n_frames - 1]), torch.tensor([1, 100, b.n_freq - 1])
    with torch.inference_mode():
        whole = b(lis, src, theta, yaw, ctx, r.cache.frequency)  # [3, 2, F, N]
        part = b(lis, src, theta, yaw, ctx, r.cache.frequency, frames, bins)  # [3, 2, 3, 4]
    assert part.shape == (3, 2, 3, 4)
    assert torch.allclose(part, whole[:, :, bins][..., frames], atol=1e-5)


def test_bin_subset_of_the_mask_model(binaural):
    b = binaural.model.binauralizer
    lis, theta = torch.tensor([[0.1, -0.2], [0.3, 0.4]]), torch.tensor([0.5, -1.0])
    bins = torch.tensor([0, 17, b.n_freq - 1])
    ctx = None if b.context_proj is None else torch.randn(2, b.context_proj.in_features, generator=torch.Generator().manual_seed(1))
    with torch.inference_mode():
        whole, part = b(lis, theta, ctx), b(lis, theta, ctx, bins=bins)
    for name in ("mixture", "difference"):
        assert torch.allclose(getattr(part, name), getattr(whole, name)[:, bins], atol=1e-6)
    if whole.reverb is not None:
        assert torch.allclose(part.reverb, whole.reverb[..., bins], atol=1e-6)
        assert torch.equal(part.decay, whole.decay[bins])


def test_quadrature_of_frames_and_bins():
    bins, weights = bin_subset(257, 8)
    assert bins[0] == 0 and bins[-1] == 256 and len(bins) == 33 and weights.sum() == pytest.approx(1.0)
    spectrum = np.linspace(1.0, 3.0, 257)  # a linear spectrum: the trapezoid rule is exact
    assert spectrum[bins.numpy()] @ weights == pytest.approx(spectrum.mean())
    nodes = frame_nodes(158, 10, 6)
    assert nodes[:10].tolist() == list(range(10)) and nodes[-1] == 157 and len(nodes) == 16
    assert frame_nodes(12, 10, 6).tolist() == list(range(12))  # as many as all: all
    M = frame_interpolation(nodes, 158)  # [16, 158]
    assert torch.allclose(M.sum(0), torch.ones(158))
    assert torch.allclose(M[:, nodes], torch.eye(len(nodes)))  # the evaluated frames as they are
    line = 0.25 * nodes.float() - 3.0  # a log magnitude falling linearly (an exponential decay)
    assert torch.allclose(line @ M, 0.25 * torch.arange(158.0) - 3.0, atol=1e-4)
    with pytest.raises(ValueError, match="bin_stride"):
        FastMap(bin_stride=0)


def test_early_frames_cover_the_direct_sound_from_the_farthest_corner():
    r = SceneRenderer.load(DEMO)
    diagonal = float(np.linalg.norm(r.bounds[1] - r.bounds[0]))  # metres
    arrival = diagonal / 343.0 / (r.stft.hop_length / r.sample_rate)  # frames, at the speed of sound
    window = r.stft.win_length / r.stft.hop_length
    assert arrival + window < early_frames(r) <= arrival + window + 3
