"""The propagation map (avgs.propagation_map) against the single-pose path, on the bundled demo scene."""

from __future__ import annotations

import math
import threading
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch

from avgs import SceneRenderer
from avgs.inference import HeadroomLimited
from avgs.propagation_map import (
    coarse_to_fine, compute_map, ear_power, floor_grid, pose_levels, power_levels, propagation_map,
)

DEMO = Path(__file__).resolve().parents[1] / "assets" / "demo" / "scene.ckpt"
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


def decay_of(r):
    tail = None if r.task == "rir" else r.model.binauralizer.reverb
    return None if tail is None else tail.decay()


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
    pmap = compute_map(r, source=source, yaw=30.0, z=1.5, size=8, batch=16, chunk=3)
    assert pmap.complete and np.all(np.isfinite(pmap.level)) and np.all(np.isfinite(pmap.ild))
    positions = pmap.grid.positions()
    for flat in (0, 9, 27, 40, 63):
        level, ild = pose_levels(r.masks(positions[flat], 30.0, source=source), decay_of(r))
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
    pmap = compute_map(r, yaw=0.0, z=1.5, size=2)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", HeadroomLimited)
        level, ild = pose_levels(r.masks(pmap.grid.positions()[3], 0.0), decay_of(r))
    assert pmap.level[1, 1] == pytest.approx(level, abs=1e-4) and pmap.ild[1, 1] == pytest.approx(ild, abs=1e-4)


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
