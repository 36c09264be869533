"""Where a listener may stand, and random listener poses there.

Walkable: inside the floor polygon (and the spec's ``walk_region`` if any), at least
``wall_clearance`` from every wall and partition, ``furniture_clearance`` from furniture
and ``source_clearance`` from the source (distances in the xy plane). Poses stand at the
spec's ear height with a uniform random yaw.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from avgs.synth.presets import SceneSpec


@dataclass(frozen=True)
class Pose:
    """One listener pose: world position [3] (metres) and yaw in degrees ccw from +x."""

    position: np.ndarray  # [3]
    yaw_deg: float


def _inside_polygon(p: np.ndarray, poly: np.ndarray) -> bool:
    x, y = p
    inside = False
    for (x0, y0), (x1, y1) in zip(poly, np.roll(poly, -1, axis=0)):
        if (y0 > y) != (y1 > y) and x < x0 + (y - y0) * (x1 - x0) / (y1 - y0):
            inside = not inside
    return inside


def _segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    ab, ap = b - a, p - a
    t = float(np.clip(np.dot(ap, ab) / max(float(np.dot(ab, ab)), 1e-18), 0.0, 1.0))
    return float(np.linalg.norm(ap - t * ab))


def _rect_distance(p: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> float:
    """0 inside the rectangle, else the distance to it."""
    d = np.maximum(np.maximum(lo - p, p - hi), 0.0)
    return float(np.linalg.norm(d))


def is_walkable(spec: SceneSpec, xy) -> bool:
    """True where a listener may stand (see the module docstring)."""
    p = np.asarray(xy, dtype=np.float64)[:2]
    fp = np.asarray(spec.footprint, dtype=np.float64)
    if not _inside_polygon(p, fp):
        return False
    if spec.walk_region is not None:
        (x0, y0), (x1, y1) = spec.walk_region
        if not (x0 <= p[0] <= x1 and y0 <= p[1] <= y1):
            return False
    for k, material in enumerate(spec.wall_materials):
        if material == "open":
            continue  # an open boundary is not a wall
        if _segment_distance(p, fp[k], fp[(k + 1) % len(fp)]) < spec.wall_clearance:
            return False
    for box in spec.boxes:
        if box.lo[2] > spec.listener_height + 0.3:
            continue  # a lintel overhead does not block walking
        clearance = spec.wall_clearance if box.kind == "partition" else spec.furniture_clearance
        if _rect_distance(p, np.asarray(box.lo[:2]), np.asarray(box.hi[:2])) < clearance:
            return False
    return float(np.linalg.norm(p - np.asarray(spec.source[:2]))) >= spec.source_clearance


def sample_poses(
    spec: SceneSpec,
    n: int,
    rng: np.random.Generator,
    avoid: list[Pose] | None = None,
    min_separation: float = 0.3,
    max_tries: int = 200_000,
) -> list[Pose]:
    """``n`` random walkable poses; each at least ``min_separation`` metres (xy) from the
    positions in ``avoid`` (val poses stay off the train positions). The separation is
    halved whenever the area is too crowded to honour it."""
    lo, hi = spec.bounds()[:, :2]
    taken = [p.position[:2] for p in (avoid or [])]
    out: list[Pose] = []
    tries, sep = 0, float(min_separation)
    while len(out) < n:
        tries += 1
        if tries > max_tries:
            raise ValueError(f"{spec.preset}: found only {len(out)} of {n} walkable listener positions")
        if tries % 5000 == 0:
            sep /= 2
        xy = rng.uniform(lo, hi)
        if not is_walkable(spec, xy):
            continue
        if taken and sep > 0 and min(float(np.linalg.norm(xy - t)) for t in taken) < sep:
            continue
        yaw = float(rng.uniform(-180.0, 180.0))
        out.append(Pose(np.array([xy[0], xy[1], spec.listener_height]), yaw))
    return out
