"""scripts/rir_level_distance.py: the geometry of its two experiments, on the presets' own specs (no simulation)."""

import importlib.util
import sys
from pathlib import Path

import numpy as np

from avgs.synth.grid import grid_points
from avgs.synth.poses import is_walkable
from avgs.synth.presets import make_spec


def _script():
    file = Path(__file__).resolve().parents[1] / "scripts" / "rir_level_distance.py"
    spec = importlib.util.spec_from_file_location(file.stem, file)
    module = importlib.util.module_from_spec(spec)
    sys.modules[file.stem] = module  # dataclasses look their module up while the script runs
    spec.loader.exec_module(module)
    return module


def test_the_source_line_reaches_5_m_in_the_large_room_and_stays_walkable():
    m = _script()
    spec = make_spec("rect_large", 0)
    receivers = grid_points(spec, 1.25, spec.listener_height)
    line = m.source_line(spec, receivers, 1.5, np.arange(0.5, 5.01, 0.5))
    assert np.allclose(line.distances, np.arange(0.5, 5.01, 0.5))
    assert any(np.allclose(line.listener, r) for r in receivers)  # a receiver of the grid
    got = np.linalg.norm(line.sources[:, :2] - line.listener[:2], axis=1)
    assert np.allclose(got, line.distances)
    assert np.allclose(line.sources[:, 2], 1.5)
    free = m._placeable(spec)
    assert all(is_walkable(free, s[:2]) for s in line.sources)


def test_the_wall_pair_hides_one_source_behind_the_partition_at_the_same_distance():
    m = _script()
    spec = make_spec("two_rooms", 0)
    receivers = grid_points(spec, 1.0, spec.listener_height)
    pair = m.wall_pair(spec, receivers, 1.5, 2.5)
    lis = pair.listener
    assert np.isclose(np.linalg.norm(pair.same_room[:2] - lis[:2]), 2.5)
    assert np.isclose(np.linalg.norm(pair.behind[:2] - lis[:2]), 2.5)
    assert m.room_of(spec, pair.same_room) == m.room_of(spec, lis) != m.room_of(spec, pair.behind)
    assert not m.crosses_partition(spec, lis, pair.same_room, 1.5)
    assert m.crosses_partition(spec, lis, pair.behind, 1.5)
    assert pair.margin >= 0.5  # not at the doorway's edge


def test_a_line_through_the_doorway_crosses_no_partition():
    m = _script()
    spec = make_spec("two_rooms", 0)
    door = [b for b in spec.boxes if b.kind == "partition" and b.lo[2] > spec.listener_height]  # the lintel
    assert door, "two_rooms has a doorway under a lintel"
    lo, hi = np.asarray(door[0].lo), np.asarray(door[0].hi)
    mid_y = (lo[1] + hi[1]) / 2
    assert not m.crosses_partition(spec, (lo[0] - 1.0, mid_y), (hi[0] + 1.0, mid_y), 1.5)
    assert m.crosses_partition(spec, (lo[0] - 1.0, 0.5), (hi[0] + 1.0, 0.5), 1.5)  # through the wall beside it
