"""The room's floor plan, from a scene's outline: where a listener and a source may be.

``SceneRenderer.outline`` is every edge of the room's surfaces, ``[K, 2, 3]`` world segments:
walls, floor and ceiling, partitions and furniture alike. The floor plan is the outer
boundary of the edges that lie on the floor: they are split where they meet or overlap,
joined into a planar graph, and each connected piece's outer face is traced (faces are
walked with the face on the left, so the outer face is the one that comes out clockwise).
Pieces inside another (furniture, a partition's foot) add nothing to the boundary, but are
walls all the same (:meth:`Footprint.wall_distance`). With no outline the plan is the scene's box.

:func:`keep_inside` is the one clamp of positions: ``avgs render`` (``SceneRenderer.inside``),
the explorer's window and its headless export all move a position with it, so the same
position asked for gives the same position used.
"""

from __future__ import annotations

import numpy as np


def _signed_area(ring: np.ndarray) -> float:
    x, y = ring[:, 0], ring[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def _nearest_on_segments(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, float]:
    """The point of segments a[i]-b[i] ([M, 2] each) nearest to p [2], and its distance."""
    d = b - a
    length2 = np.einsum("ij,ij->i", d, d)
    t = np.where(length2 > 0, np.einsum("ij,ij->i", p - a, d) / np.where(length2 > 0, length2, 1.0), 0.0)
    q = a + np.clip(t, 0.0, 1.0)[:, None] * d
    dist = np.linalg.norm(q - p, axis=1)
    i = int(np.argmin(dist))
    return q[i], float(dist[i])


def _crossings(p: np.ndarray, ring: np.ndarray) -> int:
    """How many edges of ``ring`` [V, 2] a ray from p towards +x crosses (half-open rule)."""
    a, b = ring, np.roll(ring, -1, axis=0)
    straddles = (a[:, 1] > p[1]) != (b[:, 1] > p[1])
    with np.errstate(divide="ignore", invalid="ignore"):
        x = a[:, 0] + (p[1] - a[:, 1]) * (b[:, 0] - a[:, 0]) / (b[:, 1] - a[:, 1])
    return int(np.sum(straddles & (x > p[0])))


def _split(segs: np.ndarray, tol: float) -> list[tuple[np.ndarray, np.ndarray]]:
    """Segments [M, 2, 2] cut wherever another one ends on them or crosses them."""
    a, b = segs[:, 0], segs[:, 1]
    ends = segs.reshape(-1, 2)
    pieces = []
    for i in range(len(segs)):
        p, d = a[i], b[i] - a[i]
        length = float(np.linalg.norm(d))
        if length <= tol:
            continue
        u = d / length
        ts = [0.0, length]
        # Other segments' ends lying on this one (collinear overlaps, T junctions).
        rel = ends - p
        along = rel @ u
        off = np.abs(rel[:, 0] * u[1] - rel[:, 1] * u[0])
        ts += list(along[(off <= tol) & (along > tol) & (along < length - tol)])
        # Proper crossings.
        e = b - a
        denom = d[0] * e[:, 1] - d[1] * e[:, 0]
        ok = np.abs(denom) > 1e-12
        w = a - p
        with np.errstate(divide="ignore", invalid="ignore"):
            s = (w[:, 0] * e[:, 1] - w[:, 1] * e[:, 0]) / denom   # along this segment, 0..1
            r = (w[:, 0] * d[1] - w[:, 1] * d[0]) / denom          # along the other one, 0..1
        hit = ok & (s > 0) & (s < 1) & (r >= -1e-9) & (r <= 1 + 1e-9)
        ts += list(s[hit] * length)
        ts = np.unique(np.round(np.asarray(ts) / tol) * tol)
        for t0, t1 in zip(ts[:-1], ts[1:]):
            if t1 - t0 > tol:
                pieces.append((p + t0 * u, p + t1 * u))
    return pieces


def outer_rings(segments_xy: np.ndarray, tol: float) -> list[np.ndarray]:
    """The outer boundaries ([V, 2] rings, counter-clockwise) of the planar graph of segments,
    one per connected piece that no other piece encloses."""
    pieces = _split(np.asarray(segments_xy, dtype=np.float64), tol)
    keys: dict[tuple[int, int], int] = {}
    coords: list[np.ndarray] = []

    def vertex(q: np.ndarray) -> int:
        key = (int(round(q[0] / tol)), int(round(q[1] / tol)))
        if key not in keys:
            keys[key] = len(coords)
            coords.append(q)
        return keys[key]

    edges = {tuple(sorted((vertex(p), vertex(q)))) for p, q in pieces}
    edges = {e for e in edges if e[0] != e[1]}
    if not edges:
        return []
    xy = np.array(coords)
    neighbours: dict[int, list[int]] = {}
    for u, v in edges:
        neighbours.setdefault(u, []).append(v)
        neighbours.setdefault(v, []).append(u)
    for v, ns in neighbours.items():  # counter-clockwise order around each vertex
        ns.sort(key=lambda w, v=v: np.arctan2(*(xy[w] - xy[v])[::-1]))

    seen: set[tuple[int, int]] = set()
    outer: list[np.ndarray] = []
    for u0, v0 in [(u, v) for e in edges for (u, v) in (e, e[::-1])]:
        if (u0, v0) in seen:
            continue
        ring, (u, v) = [], (u0, v0)
        while (u, v) not in seen:
            seen.add((u, v))
            ring.append(u)
            ns = neighbours[v]
            w = ns[(ns.index(u) - 1) % len(ns)]  # the next edge clockwise from the way back
            u, v = v, w
        ring = xy[ring]
        if len(ring) >= 3 and _signed_area(ring) < -tol * tol:
            outer.append(ring[::-1])  # an outer face, walked clockwise: keep it counter-clockwise
    # A piece inside another (a table's feet, a partition) is no boundary of the floor.
    outer.sort(key=lambda r: -abs(_signed_area(r)))
    kept: list[np.ndarray] = []
    for ring in outer:
        if not any(_crossings(ring[0], k) % 2 for k in kept):
            kept.append(ring)
    return kept


class Footprint:
    """Where positions may go: inside the floor plan's rings (xy) and a height range (z)."""

    def __init__(self, rings: list[np.ndarray], z_range: tuple[float, float], from_outline: bool,
                 walls: np.ndarray | None = None):
        self.rings = [np.asarray(r, dtype=np.float64) for r in rings]
        self.z_range = (float(z_range[0]), float(z_range[1]))
        self.from_outline = from_outline
        "True when the rings come from the room's outline, False for the scene's box."
        self.walls = np.zeros((0, 2, 2)) if walls is None else np.asarray(walls, dtype=np.float64).reshape(-1, 2, 2)
        "Every floor edge [M, 2, 2] (xy), the boundary's and those inside it (partitions, furniture)."
        self._a = np.concatenate(self.rings)
        self._b = np.concatenate([np.roll(r, -1, axis=0) for r in self.rings])
        span = np.ptp(self._a, axis=0).max() if len(self._a) else 1.0
        self.tol = 1e-9 * max(float(span), 1.0)

    @classmethod
    def box(cls, bounds: np.ndarray) -> "Footprint":
        lo, hi = np.asarray(bounds, dtype=np.float64)
        ring = np.array([[lo[0], lo[1]], [hi[0], lo[1]], [hi[0], hi[1]], [lo[0], hi[1]]])
        return cls([ring], (lo[2], hi[2]), from_outline=False)

    @classmethod
    def from_outline(cls, outline: np.ndarray | None, bounds: np.ndarray) -> "Footprint":
        """The floor plan of ``outline`` [K, 2, 3]; the box ``bounds`` [2, 3] when there is none."""
        bounds = np.asarray(bounds, dtype=np.float64)
        if outline is None:
            return cls.box(bounds)
        outline = np.asarray(outline, dtype=np.float64).reshape(-1, 2, 3)
        if len(outline) == 0 or not np.all(np.isfinite(outline)):
            return cls.box(bounds)
        z = outline[..., 2]
        extent = float(np.ptp(outline.reshape(-1, 3), axis=0).max()) or 1.0
        tol = 1e-4 * extent
        floor = outline[np.all(np.abs(z - z.min()) <= 10 * tol, axis=1)][..., :2]
        rings = outer_rings(floor, tol) if len(floor) else []
        if not rings:  # no closed floor plan (a flat or open outline): the box
            return cls.box(bounds)
        lo, hi = max(z.min(), bounds[0, 2]), min(z.max(), bounds[1, 2])
        if hi - lo <= 10 * tol:  # a floor plan alone says nothing of the height: the box's
            lo, hi = bounds[0, 2], bounds[1, 2]
        return cls(rings, (lo, hi), from_outline=True, walls=floor)

    def contains(self, xy) -> bool:
        """True when the point (x, y) lies inside the floor plan or on its boundary."""
        p = np.asarray(xy, dtype=np.float64)[:2]
        if any(_crossings(p, r) % 2 for r in self.rings):
            return True
        return _nearest_on_segments(p, self._a, self._b)[1] <= self.tol

    def wall_distance(self, xy) -> float:
        """How far the point (x, y) is from the nearest wall on the floor (inf without an outline)."""
        if not len(self.walls):
            return float("inf")
        p = np.asarray(xy, dtype=np.float64)[:2]
        return _nearest_on_segments(p, self.walls[:, 0], self.walls[:, 1])[1]

    def clamp(self, xyz) -> np.ndarray:
        """``xyz`` [3] moved to the nearest point of the floor plan (xy) and height range (z)."""
        out = np.array(xyz, dtype=np.float64)
        if not self.contains(out[:2]):
            out[:2] = _nearest_on_segments(out[:2], self._a, self._b)[0]
        out[2] = min(max(out[2], self.z_range[0]), self.z_range[1])
        return out


def keep_inside(xyz, footprint: Footprint, bounds) -> np.ndarray:
    """``xyz`` [3] (world) moved to the nearest point inside ``footprint`` (the room's floor plan
    and height) and the scene's box ``bounds`` [2, 3]; unchanged when already inside."""
    bounds = np.asarray(bounds, dtype=np.float64)
    reach = 1e6 * max(float(np.ptp(bounds, axis=0).max()), 1.0)  # 1e300 first comes this near: no overflow
    near = np.clip(np.asarray(xyz, dtype=np.float64), bounds[0] - reach, bounds[1] + reach)
    return np.clip(footprint.clamp(near), bounds[0], bounds[1])
