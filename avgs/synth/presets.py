"""Scene specs: the geometry, materials and source of one synthetic scene, in metres.

A :class:`SceneSpec` is plain data (JSON round-trip through :meth:`SceneSpec.to_dict` /
:meth:`SceneSpec.from_dict`), enough to rebuild the acoustic simulation and the images.
The room is a floor polygon (``footprint``, counter-clockwise, z = 0) extruded to
``height``; floor and ceiling are split into rectangles (``floors`` / ``ceilings``, each
with its own material); ``boxes`` are closed axis-aligned solids standing in the room
(furniture, and partition walls around a door opening).

Presets (:func:`make_spec`), each randomised mildly by the seed:

- ``office``: one shoebox room, plasterboard and a glass wall, carpet, acoustic ceiling tiles.
- ``house``: two rooms of different depth joined by a door opening in a partition wall.
- ``apartment``: a living room with furniture (sofa, table, bookshelf, cabinet).
- ``outdoor``: paved ground and two reflecting building facades at a corner; the other
  sides and the sky are an open (nearly anechoic) boundary.

Impulse-response presets (:data:`RIR_PRESETS`, for ``avgs synth --task rir``), mirroring the
six SoundSpaces layouts of the AV-GS paper, two per :data:`RIR_ENVIRONMENTS` kind; their
``environment`` is that kind ("rectangular", "non-rectangular", "multi-room"):

- ``rect_small``: a small absorbent shoebox room (carpet, curtains); ``rect_large``: a large
  shoebox hall (brick, glass, wooden floor, acoustic ceiling), more reverberant.
- ``l_room``: an L-shaped living room; ``u_room``: a U-shaped room (a courtyard notch in the
  middle of one side).
- ``two_rooms``: two rooms joined by a door opening in a partition wall; ``three_rooms``: three
  rooms in a row, each partition with its own door.

Every :class:`Surface` is oriented as pyroomacoustics requires: its normal (right-hand
rule over the corners) points out of the air, i.e. out of the room and into a box.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from avgs.synth.materials import material_info

PRESETS = ("office", "house", "apartment", "outdoor")
"The binaural (RWAVS-like) presets."
ENVIRONMENTS = {"office": "office", "house": "house", "apartment": "apartment", "outdoor": "outdoor"}
RIR_ENVIRONMENTS = ("rectangular", "non-rectangular", "multi-room")
"The kinds of room of the impulse-response task (the SoundSpaces layouts of the paper)."
RIR_PRESETS = ("rect_small", "rect_large", "l_room", "u_room", "two_rooms", "three_rooms")
"The impulse-response presets, two per kind of :data:`RIR_ENVIRONMENTS`."
ALL_PRESETS = PRESETS + RIR_PRESETS


@dataclass
class Region:
    """A convex floor or ceiling patch: ``corners`` [K, 2] counter-clockwise (x, y), metres."""

    name: str
    material: str
    corners: list[list[float]]


@dataclass
class Box:
    """A closed axis-aligned solid in the room; ``lo`` / ``hi`` are its [3] corners, metres."""

    name: str
    material: str
    lo: list[float]
    hi: list[float]
    kind: str = "furniture"  # "furniture" or "partition"


@dataclass
class Surface:
    """One planar polygon of the scene: ``corners`` [K, 3] in metres, normal out of the air."""

    name: str
    material: str
    kind: str  # wall, floor, ceiling, furniture, partition
    corners: np.ndarray  # [K, 3]
    hidden: bool = False  # lies against the floor, ceiling or a wall: acoustic bookkeeping only

    @property
    def visible(self) -> bool:
        return material_info(self.material).visible and not self.hidden

    def to_dict(self) -> dict:
        return {
            "name": self.name,
            "material": self.material,
            "kind": self.kind,
            "color": list(material_info(self.material).color),
            "corners": [[round(float(v), 6) for v in c] for c in self.corners],
        }


@dataclass
class SceneSpec:
    """Everything that defines one synthetic scene (metres, z up, yaw ccw from +x)."""

    preset: str
    environment: str
    seed: int
    footprint: list[list[float]]  # [K, 2] counter-clockwise floor polygon
    height: float  # floor to ceiling
    wall_materials: list[str]  # [K]: edge k runs from footprint[k] to footprint[k + 1]
    floors: list[Region]
    ceilings: list[Region]
    source: list[float]  # [3] the sound source
    boxes: list[Box] = field(default_factory=list)
    listener_height: float = 1.6
    "Ear height of every listener pose."
    walk_region: list[list[float]] | None = None
    "Optional [[x0, y0], [x1, y1]] rectangle the listener stays in (outdoor)."
    wall_clearance: float = 0.5
    "Minimum listener distance to the room walls and partitions."
    furniture_clearance: float = 0.3
    "Minimum listener distance to furniture."
    source_clearance: float = 0.5
    "Minimum listener distance to the source (in the xy plane)."

    # -- serialisation --------------------------------------------------------------

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> "SceneSpec":
        try:
            d = dict(d)
            d["floors"] = [Region(**r) for r in d["floors"]]
            d["ceilings"] = [Region(**r) for r in d["ceilings"]]
            d["boxes"] = [Box(**b) for b in d.get("boxes", [])]
            spec = cls(**d)
        except (KeyError, TypeError) as exc:
            raise ValueError(f"not a scene spec ({exc})") from None
        spec.validate()
        return spec

    def validate(self) -> None:
        """Raise ValueError naming the first inconsistent field."""
        fp = np.asarray(self.footprint, dtype=np.float64)
        if fp.ndim != 2 or fp.shape[1] != 2 or len(fp) < 3:
            raise ValueError(f"footprint must be [K >= 3, 2] corners, got shape {fp.shape}")
        if polygon_area(fp) <= 0:
            raise ValueError("footprint must be counter-clockwise with a positive area")
        if len(self.wall_materials) != len(fp):
            raise ValueError(f"wall_materials has {len(self.wall_materials)} entries, expected {len(fp)} (one per edge)")
        for name in [*self.wall_materials, *(r.material for r in self.floors + self.ceilings), *(b.material for b in self.boxes)]:
            material_info(name)
        if not self.height > 0:
            raise ValueError(f"height must be > 0, got {self.height}")
        if len(self.source) != 3:
            raise ValueError(f"source must be [x, y, z], got {self.source}")

    # -- geometry -------------------------------------------------------------------

    @property
    def is_shoebox(self) -> bool:
        """An axis-aligned box from the origin with no boxes inside (pyroomacoustics' fast path)."""
        fp = np.asarray(self.footprint, dtype=np.float64)
        if len(fp) != 4 or self.boxes or len(self.floors) != 1 or len(self.ceilings) != 1:
            return False
        w, d = fp[:, 0].max(), fp[:, 1].max()
        expected = np.array([[0, 0], [w, 0], [w, d], [0, d]], dtype=np.float64)
        return bool(np.allclose(fp, expected))

    def bounds(self) -> np.ndarray:
        """[2, 3] world box around the room."""
        fp = np.asarray(self.footprint, dtype=np.float64)
        return np.array([[*fp.min(0), 0.0], [*fp.max(0), self.height]])

    def surfaces(self) -> list[Surface]:
        """All acoustic surfaces (visible or not), each a quad or polygon oriented out of the air."""
        fp = np.asarray(self.footprint, dtype=np.float64)
        h = float(self.height)
        out: list[Surface] = []
        for k, material in enumerate(self.wall_materials):
            a, b = fp[k], fp[(k + 1) % len(fp)]
            # counter-clockwise footprint: this order gives an outward normal
            corners = np.array([[*a, 0.0], [*b, 0.0], [*b, h], [*a, h]])
            out.append(Surface(f"wall_{k}", material, "wall", corners))
        for r in self.floors:
            c = np.asarray(r.corners, dtype=np.float64)[::-1]  # clockwise from above: normal -z
            out.append(Surface(r.name, r.material, "floor", np.column_stack([c, np.zeros(len(c))])))
        for r in self.ceilings:
            c = np.asarray(r.corners, dtype=np.float64)
            out.append(Surface(r.name, r.material, "ceiling", np.column_stack([c, np.full(len(c), h)])))
        for box in self.boxes:
            out.extend(box_faces(box, fp, h))
        return out

    def visible_surfaces(self) -> list[Surface]:
        return [s for s in self.surfaces() if s.visible]


def polygon_area(poly) -> float:
    """Signed area of a 2D polygon ``[K, 2]`` (positive when counter-clockwise)."""
    p = np.asarray(poly, dtype=np.float64)
    x, y = p[:, 0], p[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def _on_boundary(point2d: np.ndarray, footprint: np.ndarray, tol: float = 1e-6) -> bool:
    for a, b in zip(footprint, np.roll(footprint, -1, axis=0)):
        ab, ap = b - a, point2d - a
        t = np.clip(np.dot(ap, ab) / max(np.dot(ab, ab), 1e-18), 0.0, 1.0)
        if np.linalg.norm(ap - t * ab) < tol:
            return True
    return False


def box_faces(box: Box, footprint: np.ndarray, height: float) -> list[Surface]:
    """The six faces of ``box`` with normals into the box. Faces lying on the floor, the
    ceiling or a room wall are marked ``hidden`` (not drawn) but kept: pyroomacoustics
    decides whether a point is in the room by counting wall crossings, which needs every
    box closed."""
    lo, hi = np.asarray(box.lo, dtype=np.float64), np.asarray(box.hi, dtype=np.float64)
    if np.any(hi <= lo):
        raise ValueError(f"box {box.name!r}: hi {box.hi} must exceed lo {box.lo} on every axis")
    centre = (lo + hi) / 2
    faces = []
    for axis in range(3):
        for side, value in (("min", lo[axis]), ("max", hi[axis])):
            u, v = [a for a in range(3) if a != axis]
            quad = np.zeros((4, 3))
            quad[:, axis] = value
            quad[:, u] = [lo[u], hi[u], hi[u], lo[u]]
            quad[:, v] = [lo[v], lo[v], hi[v], hi[v]]
            mid = quad.mean(0)
            if axis == 2:
                hidden = abs(value) < 1e-6 or abs(value - height) < 1e-6
            else:
                hidden = _on_boundary(mid[:2], footprint)
            normal = np.cross(quad[1] - quad[0], quad[2] - quad[0])
            if np.dot(normal, centre - mid) < 0:
                quad = quad[::-1]
            faces.append(Surface(f"{box.name}_{'xyz'[axis]}{side}", box.material, box.kind, quad.copy(), hidden))
    return faces


def _rect(x0, y0, x1, y1) -> list[list[float]]:
    return [[x0, y0], [x1, y0], [x1, y1], [x0, y1]]


def _r(v: float) -> float:
    return round(float(v), 3)


# -- presets -------------------------------------------------------------------------


def _office(rng: np.random.Generator, seed: int) -> SceneSpec:
    w, d, h = _r(rng.uniform(5.5, 7.5)), _r(rng.uniform(4.0, 5.5)), _r(rng.uniform(2.7, 3.1))
    source = [_r(rng.uniform(0.7, 0.35 * w)), _r(rng.uniform(0.8, d - 0.8)), _r(rng.uniform(1.1, 1.4))]
    return SceneSpec(
        preset="office",
        environment="office",
        seed=seed,
        footprint=_rect(0, 0, w, d),
        height=h,
        wall_materials=["plasterboard", "glass_window", "plasterboard", "brickwork"],
        floors=[Region("floor", "carpet_cotton", _rect(0, 0, w, d))],
        ceilings=[Region("ceiling", "ceiling_fissured_tile", _rect(0, 0, w, d))],
        source=source,
    )


def _house(rng: np.random.Generator, seed: int) -> SceneSpec:
    """Living room [0, w1] x [0, d1] and a shallower kitchen [w1, w1 + w2] x [0, d2],
    joined by a door opening in the partition at x = w1."""
    w1, d1 = _r(rng.uniform(4.2, 5.2)), _r(rng.uniform(4.2, 5.0))
    w2, d2 = _r(rng.uniform(3.4, 4.2)), _r(rng.uniform(3.0, 3.8))
    h, t, door_w, door_h = _r(rng.uniform(2.5, 2.7)), 0.12, 0.9, 2.1
    door_y = _r(rng.uniform(0.6, d2 - door_w - 0.6))
    sofa_y = _r(rng.uniform(0.8, d1 - 3.0))
    x0, x1 = w1, w1 + t  # on the kitchen side, flush with the living room's east wall
    boxes = [
        Box("partition_a", "plasterboard", [x0, 0.0, 0.0], [x1, door_y, h], "partition"),
        Box("partition_b", "plasterboard", [x0, door_y + door_w, 0.0], [x1, d2, h], "partition"),
        Box("lintel", "plasterboard", [x0, door_y, door_h], [x1, door_y + door_w, h], "partition"),
        Box("sofa", "chairs_upholstered_cloth", [0.05, sofa_y, 0.0], [0.95, _r(sofa_y + 2.1), 0.85]),
        Box("counter", "wood_1.6cm", [w1 + w2 - 0.65, 0.05, 0.0], [w1 + w2 - 0.05, _r(d2 - 0.6), 0.9]),
    ]
    footprint = [[0, 0], [w1, 0], [w1 + w2, 0], [w1 + w2, d2], [w1, d2], [w1, d1], [0, d1]]
    walls = ["brickwork", "ceramic_tiles", "plasterboard", "curtains_velvet", "plasterboard", "curtains_velvet", "wooden_lining"]
    source = [_r(rng.uniform(1.6, w1 - 1.2)), _r(rng.uniform(0.8, d1 - 0.8)), _r(rng.uniform(1.0, 1.3))]
    return SceneSpec(
        preset="house",
        environment="house",
        seed=seed,
        footprint=footprint,
        height=h,
        wall_materials=walls,
        floors=[
            Region("floor_living", "carpet_hairy", _rect(0, 0, w1, d1)),
            Region("floor_kitchen", "ceramic_tiles", _rect(w1, 0, w1 + w2, d2)),
        ],
        ceilings=[
            Region("ceiling_living", "ceiling_plasterboard", _rect(0, 0, w1, d1)),
            Region("ceiling_kitchen", "ceiling_plasterboard", _rect(w1, 0, w1 + w2, d2)),
        ],
        source=source,
        boxes=boxes,
    )


def _apartment(rng: np.random.Generator, seed: int) -> SceneSpec:
    w, d, h = _r(rng.uniform(6.5, 8.0)), _r(rng.uniform(5.0, 6.0)), _r(rng.uniform(2.5, 2.7))
    j = lambda a, b: _r(rng.uniform(a, b))  # noqa: E731  small placement jitter
    sofa_x, table_x, table_y, shelf_y, cab_x = j(1.5, 2.5), j(2.2, 3.0), j(1.9, 2.3), j(0.8, 1.6), j(0.3, 1.0)
    boxes = [
        Box("sofa", "chairs_upholstered_cloth", [sofa_x, d - 1.0, 0.0], [sofa_x + 2.1, d - 0.05, 0.85]),
        Box("table", "wood_1.6cm", [table_x, table_y, 0.0], [table_x + 1.6, table_y + 0.9, 0.75]),
        Box("bookshelf", "wood_1.6cm", [w - 0.45, shelf_y, 0.0], [w - 0.05, shelf_y + 1.4, 1.9]),
        Box("cabinet", "wooden_door", [cab_x, 0.05, 0.0], [cab_x + 1.2, 0.55, 0.9]),
    ]
    source = [_r(w - 0.9), _r(rng.uniform(3.2, d - 1.5)), _r(rng.uniform(1.0, 1.3))]
    return SceneSpec(
        preset="apartment",
        environment="apartment",
        seed=seed,
        footprint=_rect(0, 0, w, d),
        height=h,
        wall_materials=["plasterboard", "plasterboard", "curtains_velvet", "wooden_lining"],
        floors=[Region("floor", "carpet_hairy", _rect(0, 0, w, d))],
        ceilings=[Region("ceiling", "ceiling_plasterboard", _rect(0, 0, w, d))],
        source=source,
        boxes=boxes,
    )


def _outdoor(rng: np.random.Generator, seed: int) -> SceneSpec:
    """A courtyard corner: facades on the north and west edges, open elsewhere."""
    w, d, h = _r(rng.uniform(16.0, 20.0)), _r(rng.uniform(12.0, 15.0)), 8.0
    walk = [[0.5, _r(d - 9.0)], [10.0, _r(d - 0.5)]]
    source = [_r(rng.uniform(2.0, 4.0)), _r(d - rng.uniform(2.0, 4.0)), _r(rng.uniform(1.0, 1.4))]
    return SceneSpec(
        preset="outdoor",
        environment="outdoor",
        seed=seed,
        footprint=_rect(0, 0, w, d),
        height=h,
        wall_materials=["open", "open", "brickwork", "glass_window"],
        floors=[Region("ground", "rough_concrete", _rect(0, 0, w, d))],
        ceilings=[Region("sky", "open", _rect(0, 0, w, d))],
        source=source,
        walk_region=walk,
    )


# -- impulse-response presets (the six SoundSpaces-like layouts) ------------------------------


def _walls_floor(footprint, walls, floor, ceiling, floor_rects):
    floors = [Region(f"floor_{i}", floor, r) for i, r in enumerate(floor_rects)]
    ceilings = [Region(f"ceiling_{i}", ceiling, r) for i, r in enumerate(floor_rects)]
    return dict(footprint=footprint, wall_materials=walls, floors=floors, ceilings=ceilings)


def _rect_small(rng: np.random.Generator, seed: int) -> SceneSpec:
    """A small absorbent room: carpet, a curtained wall, acoustic ceiling tiles."""
    w, d, h = _r(rng.uniform(4.2, 4.8)), _r(rng.uniform(3.4, 3.8)), _r(rng.uniform(2.5, 2.7))
    return SceneSpec(
        preset="rect_small",
        environment="rectangular",
        seed=seed,
        height=h,
        source=[_r(w / 3), _r(d / 2), 1.5],
        **_walls_floor(_rect(0, 0, w, d), ["plasterboard", "curtains_velvet", "plasterboard", "wooden_lining"],
                       "carpet_hairy", "ceiling_fissured_tile", [_rect(0, 0, w, d)]),
    )


def _rect_large(rng: np.random.Generator, seed: int) -> SceneSpec:
    """A large hall: brick, a window, wood lining and plasterboard, a wooden floor, acoustic ceiling tiles."""
    w, d, h = _r(rng.uniform(8.5, 9.5)), _r(rng.uniform(6.0, 6.8)), _r(rng.uniform(3.0, 3.3))
    return SceneSpec(
        preset="rect_large",
        environment="rectangular",
        seed=seed,
        height=h,
        source=[_r(w / 3), _r(d / 2), 1.5],
        **_walls_floor(_rect(0, 0, w, d), ["brickwork", "glass_window", "curtains_velvet", "plasterboard"],
                       "wood_16mm", "ceiling_fissured_tile", [_rect(0, 0, w, d)]),
    )


def _l_room(rng: np.random.Generator, seed: int) -> SceneSpec:
    """An L: a wide arm [0, w] x [0, a] and a tall arm [0, b] x [a, d]."""
    w, d, h = _r(rng.uniform(6.6, 7.4)), _r(rng.uniform(5.6, 6.4)), _r(rng.uniform(2.6, 2.8))
    a, b = _r(rng.uniform(2.8, 3.2)), _r(rng.uniform(3.0, 3.6))
    footprint = [[0, 0], [w, 0], [w, a], [b, a], [b, d], [0, d]]
    walls = ["plasterboard", "glass_window", "plasterboard", "wooden_lining", "plasterboard", "brickwork"]
    return SceneSpec(
        preset="l_room",
        environment="non-rectangular",
        seed=seed,
        height=h,
        source=[_r(b / 2), _r(a / 2), 1.5],
        **_walls_floor(footprint, walls, "wood_16mm", "ceiling_fissured_tile", [_rect(0, 0, w, a), _rect(0, a, b, d)]),
    )


def _u_room(rng: np.random.Generator, seed: int) -> SceneSpec:
    """A U: a base [0, w] x [0, a] and two arms [0, c] x [a, d] and [w - c, w] x [a, d]."""
    w, d, h = _r(rng.uniform(7.6, 8.4)), _r(rng.uniform(5.6, 6.4)), _r(rng.uniform(2.7, 2.9))
    a, c = _r(rng.uniform(2.8, 3.2)), _r(rng.uniform(2.4, 2.7))
    footprint = [[0, 0], [w, 0], [w, d], [w - c, d], [w - c, a], [c, a], [c, d], [0, d]]
    walls = ["brickwork", "plasterboard", "glass_window", "plasterboard", "glass_window", "plasterboard", "glass_window", "plasterboard"]
    rects = [_rect(0, 0, w, a), _rect(0, a, c, d), _rect(w - c, a, w, d)]
    return SceneSpec(
        preset="u_room",
        environment="non-rectangular",
        seed=seed,
        height=h,
        source=[_r(w / 2), _r(a / 2), 1.5],
        **_walls_floor(footprint, walls, "carpet_cotton", "ceiling_fissured_tile", rects),
    )


def _rooms_in_a_row(preset: str, widths, d: float, h: float, rng, seed: int, walls, floor, ceiling) -> SceneSpec:
    """Rooms [x_k, x_k + widths[k]] x [0, d] side by side; the partition after room k (a box
    ``t`` thick, on the next room's side) has a door opening ``door_w`` wide, ``door_h`` high."""
    t, door_w, door_h = 0.12, 0.9, 2.1
    xs = np.concatenate([[0.0], np.cumsum(widths)])
    boxes = []
    for k, x in enumerate(xs[1:-1]):
        y = _r(rng.uniform(0.6, d - door_w - 0.6))
        x0, x1 = _r(x), _r(x + t)
        boxes += [
            Box(f"partition_{k}a", "plasterboard", [x0, 0.0, 0.0], [x1, y, h], "partition"),
            Box(f"partition_{k}b", "plasterboard", [x0, _r(y + door_w), 0.0], [x1, d, h], "partition"),
            Box(f"lintel_{k}", "plasterboard", [x0, y, door_h], [x1, _r(y + door_w), h], "partition"),
        ]
    total = _r(xs[-1])
    rects = [_rect(_r(a), 0, _r(b), d) for a, b in zip(xs[:-1], xs[1:])]
    return SceneSpec(
        preset=preset,
        environment="multi-room",
        seed=seed,
        height=h,
        source=[_r(widths[0] / 2), _r(d / 2), 1.5],
        boxes=boxes,
        **_walls_floor(_rect(0, 0, total, d), walls, floor, ceiling, rects),
    )


def _two_rooms(rng: np.random.Generator, seed: int) -> SceneSpec:
    widths = [_r(rng.uniform(4.2, 4.8)), _r(rng.uniform(3.6, 4.2))]
    d, h = _r(rng.uniform(4.2, 4.8)), _r(rng.uniform(2.5, 2.7))
    walls = ["plasterboard", "brickwork", "glass_window", "wooden_lining"]
    return _rooms_in_a_row("two_rooms", widths, d, h, rng, seed, walls, "carpet_cotton", "ceiling_plasterboard")


def _three_rooms(rng: np.random.Generator, seed: int) -> SceneSpec:
    widths = [_r(rng.uniform(3.6, 4.0)), _r(rng.uniform(3.0, 3.4)), _r(rng.uniform(3.6, 4.0))]
    d, h = _r(rng.uniform(3.8, 4.2)), _r(rng.uniform(2.6, 2.8))
    walls = ["brickwork", "plasterboard", "glass_window", "plasterboard"]
    return _rooms_in_a_row("three_rooms", widths, d, h, rng, seed, walls, "carpet_cotton", "ceiling_plasterboard")


_BUILDERS = {
    "office": _office,
    "house": _house,
    "apartment": _apartment,
    "outdoor": _outdoor,
    "rect_small": _rect_small,
    "rect_large": _rect_large,
    "l_room": _l_room,
    "u_room": _u_room,
    "two_rooms": _two_rooms,
    "three_rooms": _three_rooms,
}


def make_spec(preset: str, seed: int) -> SceneSpec:
    """The spec of preset ``preset`` drawn with ``seed`` (same seed, same spec)."""
    if preset not in _BUILDERS:
        raise ValueError(f"unknown preset {preset!r}; expected one of {', '.join(ALL_PRESETS)}")
    rng = np.random.default_rng([int(seed), ALL_PRESETS.index(preset), 0])
    spec = _BUILDERS[preset](rng, int(seed))
    spec.validate()
    return spec

