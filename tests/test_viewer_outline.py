"""The room's floor plan from its outline, and positions kept inside it (no Qt, no VTK)."""

from __future__ import annotations

import numpy as np
import pytest

from avgs_viewer.outline import Footprint
from avgs_viewer.state import ViewerState

H = 2.5
L_SHAPE = [(0, 0), (5, 0), (8, 0), (8, 3), (5, 3), (5, 4), (0, 4)]  # two rooms side by side, 8 x 4 m


def walls(corners, z0=0.0, z1=H) -> list:
    """A room's wall quads as edges: bottom, top and vertical edges, as a checkpoint stores them."""
    segs = []
    for a, b in zip(corners, corners[1:] + corners[:1]):
        segs += [[[*a, z0], [*b, z0]], [[*a, z1], [*b, z1]], [[*a, z0], [*a, z1]]]
    return segs


def box(lo, hi) -> list:
    (x0, y0, z0), (x1, y1, z1) = lo, hi
    return walls([(x0, y0), (x1, y0), (x1, y1), (x0, y1)], z0, z1)


def house() -> np.ndarray:
    """An L-shaped floor plan whose outline also holds what a real one does: a partition wall
    with a door across the middle (overlapping the outer walls' corners), a chord of the floor
    split in two, a table standing on the floor and a shelf touching a wall."""
    segs = walls(L_SHAPE)
    segs += [[[5, 4, 0], [5, 0, 0]], [[5, 0, 0], [5, 3, 0]]]            # the floor's chords, overlapping
    segs += box((5.0, 0.0, 0.0), (5.1, 1.0, H)) + box((5.0, 2.0, 0.0), (5.1, 3.0, H))  # partition, door 1..2
    segs += box((1.0, 1.0, 0.0), (2.0, 2.0, 0.8))                        # a table
    segs += box((7.5, 0.5, 0.0), (8.0, 2.5, 0.9))                        # a shelf against the east wall
    return np.array(segs, dtype=np.float64)


BOUNDS = np.array([[-0.5, -0.5, -0.5], [8.5, 4.5, H + 0.5]])  # the renderer's box: 0.5 m past the walls


def test_floor_plan_of_a_house_is_its_outer_walls():
    f = Footprint.from_outline(house(), BOUNDS)
    assert f.from_outline and len(f.rings) == 1
    ring = f.rings[0]
    area = 0.5 * np.sum(ring[:, 0] * np.roll(ring[:, 1], -1) - np.roll(ring[:, 0], -1) * ring[:, 1])
    assert area == pytest.approx(8 * 4 - 3 * 1)  # counter-clockwise, the L's area
    assert f.z_range == (0.0, H)
    for inside in [(1, 1), (1.5, 1.5), (6, 1), (5.05, 1.5), (2, 3.9), (7.8, 1.0), (0, 0), (5, 3.5)]:
        assert f.contains(inside), inside  # furniture and partitions are inside the room
    for outside in [(6, 3.5), (-0.1, 2), (8.2, 1), (4, 4.1), (7.9, 3.01)]:
        assert not f.contains(outside), outside


@pytest.mark.parametrize("point, expected", [
    ((6.0, 3.8, 1.0), (6.0, 3.0, 1.0)),     # in the box but outside the L: onto the nearer wall
    ((5.4, 3.9, 1.0), (5.0, 3.9, 1.0)),     # nearer the inner corner's other wall
    ((-3.0, -2.0, 1.0), (0.0, 0.0, 1.0)),   # past a corner: the corner
    ((2.0, 2.0, 9.0), (2.0, 2.0, H)),       # above the ceiling: under it
    ((2.0, 2.0, 1.2), (2.0, 2.0, 1.2)),     # inside: untouched
])
def test_clamp_moves_to_the_nearest_place_inside(point, expected):
    f = Footprint.from_outline(house(), BOUNDS)
    out = f.clamp(point)
    assert np.allclose(out, expected, atol=1e-9)
    assert f.contains(out[:2])


def test_no_outline_or_no_floor_falls_back_to_the_box():
    assert not Footprint.from_outline(None, BOUNDS).from_outline
    flat = np.array([[[0, 0, 0], [0, 0, H]], [[1, 0, 0], [1, 0, H]]], dtype=float)  # no closed floor
    f = Footprint.from_outline(flat, BOUNDS)
    assert not f.from_outline and np.allclose(f.clamp((20, -20, 1)), (8.5, -0.5, 1))


def test_state_keeps_positions_inside_the_room_and_says_so():
    state = ViewerState(BOUNDS, (2.0, 2.0, 1.2), listener=(6.0, 1.0, 1.2), outline=house())
    notes = []
    state.events.clamped.connect(notes.append)
    state.set_listener((6.0, 3.8, 0.0))  # a drag into the missing corner of the L
    assert np.allclose(state.listener, (6.0, 3.0, 1.2))
    assert notes[-1] == "listener kept inside the room: (6.00, 3.80, 1.20) -> (6.00, 3.00, 1.20)"
    state.set_source((9.0, 2.0, 5.0))
    assert np.allclose(state.source, (8.0, 2.0, H))
    assert notes[-1].startswith("source kept inside the room: (9.00, 2.00, 5.00)")
    state.set_listener((3.0, 2.0, 0.4), keep_height=False)  # a typed position sets the height too
    assert np.allclose(state.listener, (3.0, 2.0, 0.4)) and len(notes) == 2
    # Without an outline the box is the limit, and the note says "scene".
    boxed = ViewerState(BOUNDS, (2.0, 2.0, 1.2))
    boxed.events.clamped.connect(notes.append)
    boxed.set_listener((6.0, 3.8, 0.0))
    assert np.allclose(boxed.listener[:2], (6.0, 3.8)) and len(notes) == 2
    boxed.set_listener((60.0, 3.8, 0.0))
    assert notes[-1].startswith("listener kept inside the scene:")


def test_demo_scene_floor_plan():
    from pathlib import Path

    import torch

    ckpt = Path(__file__).resolve().parents[1] / "assets" / "demo" / "scene.ckpt"
    if not ckpt.is_file():
        pytest.skip("no bundled demo scene")
    scene = torch.load(ckpt, weights_only=True)["scene"]
    f = Footprint.from_outline(scene["outline"].numpy(), scene["bounds"].numpy())
    assert f.from_outline and len(f.rings) == 1  # two rooms and a door: one floor plan
    lo, hi = f._a.min(0), f._a.max(0)
    mid_y = (lo[1] + hi[1]) / 2
    for x in (lo[0] + 0.25 * (hi[0] - lo[0]), lo[0] + 0.75 * (hi[0] - lo[0])):  # in each room
        assert f.contains((x, mid_y))
    assert not f.contains((hi[0] + 0.5, mid_y)) and not f.contains((lo[0] - 0.5, mid_y))
