"""The walls' first reflections: the early ILD of a response's first 5 ms, and the first sound behind a wall.

The early ILD (:func:`avgs.evaluation.spatial.early_ild`) reads both ears' energy over the 5 ms
after the onset. Where the straight path is free, that stretch holds the direct sound and every
reflection whose path is at most 5 ms (1.7 m) longer: in rooms of a few metres, the walls beside
the listener and the source. Each arrives from its own direction, so the head shadows each its own
way, and the stretch's ILD is their energy-weighted mix. A law of the straight direction alone
(:func:`avgs.acoustics.interaural.ild_law`), fitted and scored on the simulator's own responses in
sight of the source, is 1.4-2.0 dB off on the val pairs and 1.0-2.5 dB at held-out sources; the
direct sound and the walls' first-order reflections, each given the law at its own direction,
0.7-1.1 and 0.7-1.0 dB (six presets, their walls from scene.json: scripts/early_ild_surfaces.py).
The floor's and the ceiling's reflections come from the straight path's own azimuth: they change
nothing here.

- :func:`find_walls`: the walls in G_a's points, as vertical planes ``[P, 3]`` (a unit normal in
  the floor plan and its offset, ``n . (x, y) = d``) found by RANSAC (Open3D's ``segment_plane`` rule
  in NumPy, seeded: Open3D's own varies from call to call); planes within :data:`MERGE_M` and
  :data:`MERGE_DEG` of a larger one are its other face.
- :func:`wall_reflections`: for a batch of poses, each wall's first-order image source, where its
  reflection point is, and whether the reflection happens: the points say there is a wall at that
  point (at least :data:`SURFACE_POINTS` of them within :data:`SURFACE_RADIUS_M`: a door is a gap),
  and neither leg is behind a wall (:mod:`avgs.acoustics.line_of_sight`'s test, the reflecting
  wall's own points left out).
- :func:`first_reflection`: behind a wall, the shortest of those reflections that happens: in a simulator
  without diffraction or transmission the first sound to arrive (a reflection that passes the door), and
  :func:`reflection_first`, whether the training pairs behind a wall say so, for its direction (the ITD)
  and for its delay (the onset), each on its own.
- :func:`early_ild`: the stretch's ILD from the direct sound and the reflections inside the window,
  each weighted by ``gain^2 / path^2`` (the direct sound's gain 1), its energy shared between the
  ears by the law at its direction. :func:`fit_early_ild` fits the law and the walls' gain together
  to the training responses in sight of the source.

All lengths are in the caller's unit (the model's normalised one: the frame's scale converts).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from avgs.acoustics.interaural import ILD_HARMONICS, ild_law
from avgs.acoustics.line_of_sight import points_on_path
from avgs.data.frame import signed_direction

PLANE_THRESHOLD_M = 0.1
"RANSAC's inlier distance (metres): a wall's Gaussians lie within about this of its plane."
PLANE_ITERATIONS = 1000
"RANSAC's iterations per plane."
MAX_PLANES = 24
"Planes taken out of the points, one after the other, walls or not (floor, ceiling, furniture)."
MAX_WALLS = 16
"Walls kept, the largest first."
MIN_WALL_FRACTION = 0.01
"A plane with fewer inliers than this share of the points (and fewer than :data:`MIN_WALL_POINTS`) ends the search."
MIN_WALL_POINTS = 50
"See :data:`MIN_WALL_FRACTION`."
VERTICAL_NZ = 0.2
"A plane is a wall when its normal's vertical part is under this (12 degrees from upright)."
MERGE_M = 0.4
"Parallel planes closer than this (metres) are one wall's two faces, or its Gaussians' spread."
MERGE_DEG = 10.0
"How far from parallel two planes may be to merge."
SURFACE_RADIUS_M = 0.3
"A reflection point is on a wall when G_a has :data:`SURFACE_POINTS` points within this (metres)."
SURFACE_POINTS = 3
"See :data:`SURFACE_RADIUS_M`."
WALL_BAND_M = 0.3
"A reflecting wall's own points (within this of its plane, metres) are left out of its legs' test."
WINDOW_S = 0.005
"Reflections whose path is at most this longer than the straight one (seconds, the early stretch) count."
GAIN_START = 0.8
"The walls' amplitude gain the fit starts from (a plasterboard wall keeps about 0.9 of the amplitude)."
GAIN_MAX = 1.5
"The fit's bound on that gain."


def _open3d_planes(seed: int):
    """Open3D's RANSAC (``segment_plane``) as ``segment(xyz [n, 3], threshold) -> ((a, b, c, d), inliers)``, or None
    where Open3D cannot be imported."""
    try:
        import open3d as o3d
    except ImportError:
        return None
    o3d.utility.random.seed(int(seed))

    def segment(xyz: np.ndarray, threshold: float):
        cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(xyz))
        model, inliers = cloud.segment_plane(distance_threshold=threshold, ransac_n=3, num_iterations=PLANE_ITERATIONS)
        return tuple(float(v) for v in model), np.asarray(inliers, dtype=np.int64)

    return segment


def _numpy_planes(seed: int):
    """The same rule as :func:`_open3d_planes` in NumPy, repeatable for a given seed (and on machines without
    Open3D, such as a minimal GPU image):
    :data:`PLANE_ITERATIONS` planes through three random points, the one with the most points within the
    threshold kept and refitted to them by least squares (its inliers taken again)."""
    rng = np.random.default_rng(seed)

    def segment(xyz: np.ndarray, threshold: float):
        triples = xyz[rng.integers(0, xyz.shape[0], size=(PLANE_ITERATIONS, 3))]  # [I, 3, 3]
        normal = np.cross(triples[:, 1] - triples[:, 0], triples[:, 2] - triples[:, 0])  # [I, 3]
        length = np.linalg.norm(normal, axis=-1)
        normal = normal[length > 0] / length[length > 0, None]
        offset = -(normal * triples[length > 0, 0]).sum(-1)  # [I']
        counts = np.zeros(len(normal), dtype=np.int64)
        for i in range(0, len(normal), 64):  # [64, n] distances at a time
            counts[i : i + 64] = (np.abs(normal[i : i + 64] @ xyz.T + offset[i : i + 64, None]) <= threshold).sum(-1)
        if len(normal) == 0:
            return (0.0, 0.0, 1.0, 0.0), np.zeros(0, dtype=np.int64)
        best = int(np.argmax(counts))
        inliers = np.nonzero(np.abs(xyz @ normal[best] + offset[best]) <= threshold)[0]
        centre = xyz[inliers].mean(0)
        refined = np.linalg.svd(xyz[inliers] - centre, full_matrices=False)[2][-1]  # the smallest spread's direction
        model = (*refined, -float(refined @ centre))
        return model, np.nonzero(np.abs(xyz @ refined + model[3]) <= threshold)[0]

    return segment


def find_walls(points, unit: float, seed: int = 0, backend: str = "numpy") -> torch.Tensor:
    """The walls in ``points [N, 3]`` (z up; ``unit``: the points' units per metre): ``[P, 3]`` float64
    rows ``(n_x, n_y, d)`` with ``n_x x + n_y y = d`` on the wall and ``|n| = 1``, the largest first;
    ``[0, 3]`` when there are none. ``backend``: "numpy" (the default: the same for a given ``seed``, as a
    training run and its resumed copy need), or "open3d" (Open3D's RANSAC: the same walls, a test holds
    the two together, but its samples vary from call to call, its seed and one thread notwithstanding: a
    wall's normal by a few thousandths, and now and then a second plane through a thick partition, tilted
    from it by more than :data:`MERGE_DEG`: 3 of 40 calls on the test's 0.12 m partition)."""
    if backend not in ("open3d", "numpy"):
        raise ValueError(f"plane backend must be 'open3d' or 'numpy', got {backend!r}")
    segment = _numpy_planes(seed) if backend == "numpy" else _open3d_planes(seed)
    if segment is None:
        raise ImportError("find_walls(backend='open3d') needs Open3D (pip install open3d-cpu)")
    xyz = np.asarray(points.detach().double().cpu() if isinstance(points, torch.Tensor) else points, dtype=np.float64)
    xyz = xyz[np.all(np.isfinite(xyz), axis=-1)]
    least = max(MIN_WALL_POINTS, int(MIN_WALL_FRACTION * xyz.shape[0]))
    found: list[tuple[int, np.ndarray]] = []  # (inliers, (n_x, n_y, d)) of each vertical plane
    rest = xyz
    for _ in range(MAX_PLANES):
        if rest.shape[0] < least:
            break
        (a, b, c, d), inliers = segment(rest, PLANE_THRESHOLD_M * unit)
        if len(inliers) < least:
            break
        horizontal = math.hypot(a, b)
        if abs(c) < VERTICAL_NZ * math.sqrt(a * a + b * b + c * c) and horizontal > 0:
            # a x + b y + c z + d = 0 with c ~ 0: the floor plan's line n . (x, y) = -d / |(a, b)|
            found.append((len(inliers), np.array([a / horizontal, b / horizontal, -d / horizontal])))
        keep = np.ones(rest.shape[0], dtype=bool)
        keep[inliers] = False
        rest = rest[keep]
    walls: list[np.ndarray] = []
    cos_merge = math.cos(math.radians(MERGE_DEG))
    for _, plane in sorted(found, key=lambda item: -item[0]):
        for kept in walls:
            dot = float(plane[:2] @ kept[:2])
            if abs(dot) >= cos_merge and abs(plane[2] * math.copysign(1.0, dot) - kept[2]) < MERGE_M * unit:
                break
        else:
            walls.append(plane)
        if len(walls) >= MAX_WALLS:
            break
    return torch.tensor(np.array(walls).reshape(-1, 3), dtype=torch.float64)


@dataclass(frozen=True)
class WallReflections:
    """The first-order reflections of a batch of poses off each wall."""

    image: torch.Tensor  # [B, P, 3] the image source (the source mirrored in the wall's plane)
    path: torch.Tensor  # [B, P] the reflection's path length (image source to listener)
    happens: torch.Tensor  # [B, P] bool: both on the wall's side, a wall at the reflection point, both legs free


@dataclass(frozen=True)
class ReflectionTest:
    """What :func:`wall_reflections` needs to tell a reflection that happens (the model's units)."""

    surface_radius: float  # a wall at the reflection point: G_a's points within this ...
    surface_points: int  # ... at least this many
    wall_band: float  # the reflecting wall's own points (within this of its plane) are not on its legs
    sight_radius: float  # the legs' test: line_of_sight.points_on_path's radius and margin ...
    sight_margin: float
    sight_blocked: float  # ... and the count from which a leg is behind a wall

    @classmethod
    def at_scale(cls, unit: float, sight_radius: float, sight_margin: float, sight_blocked: float) -> "ReflectionTest":
        """This module's thresholds in a model's units (``unit`` per metre), with the straight path's fitted test."""
        return cls(SURFACE_RADIUS_M * unit, SURFACE_POINTS, WALL_BAND_M * unit, float(sight_radius), float(sight_margin),
                   float(sight_blocked))


def wall_point_sets(points: torch.Tensor, walls: torch.Tensor, test: "ReflectionTest") -> tuple[list[torch.Tensor], torch.Tensor]:
    """For each of ``walls [P, 3]``, the ``points [N, 3]`` within ``test.surface_radius`` of its plane (all that
    the reflection point's test can find), and ``[N, P]`` bool: the points farther than ``test.wall_band``
    from each plane (what may stand on a leg of its reflection). The same for every pose:
    :func:`wall_reflections` takes them from a caller that keeps them."""
    points = points.detach()
    off = (points[:, :2] @ walls[:, :2].to(points).T - walls[:, 2].to(points)).abs()  # [N, P] from each plane
    return [points[off[:, p] <= test.surface_radius] for p in range(walls.shape[0])], off > test.wall_band


LEGS_AT_ONCE = 256
"Legs tested in one product of :func:`~avgs.acoustics.line_of_sight.points_on_path` ([N, legs] at a time)."


def _images(listener: torch.Tensor, source: torch.Tensor, walls: torch.Tensor):
    """The mirror geometry in float64: each wall's image source ``[B, P, 3]``, path ``[B, P]``, whether both
    are on the wall's side ``[B, P]`` and the reflection point ``[B, P, 3]`` (listener -> image meets the plane)."""
    n = torch.nn.functional.pad(walls[:, :2], (0, 1))  # [P, 3] the normals, z = 0
    side_s = source @ n.T - walls[:, 2]  # [B, P] signed distances to each wall's plane
    side_l = listener @ n.T - walls[:, 2]
    image = source[:, None, :] - 2.0 * side_s[..., None] * n  # [B, P, 3]
    path = torch.linalg.vector_norm(image - listener[:, None, :], dim=-1)  # [B, P]
    facing = (side_s * side_l > 0) & (side_s.abs() > 0) & (side_l.abs() > 0)
    t = side_l / (side_l + side_s).where(facing, torch.ones_like(side_l))  # [B, P] along listener -> image
    at = listener[:, None, :] + t[..., None] * (image - listener[:, None, :])  # [B, P, 3]
    return image, path, facing, at


def _happens(listener: torch.Tensor, source: torch.Tensor, at: torch.Tensor, b_idx: torch.Tensor, p_idx: torch.Tensor,
             points: torch.Tensor, test: ReflectionTest, point_sets: tuple[list[torch.Tensor], torch.Tensor]) -> torch.Tensor:
    """Whether each candidate ``(b_idx, p_idx) [m]`` (pose, wall) happens ``[m]``: the points put a wall at its
    reflection point ``at [B, P, 3]`` and neither leg is behind a wall (the wall's own points aside)."""
    ok = torch.zeros(b_idx.shape[0], dtype=torch.bool, device=listener.device)
    on_wall, off_wall = point_sets
    for p in torch.unique(p_idx).tolist():  # a wall at the reflection point: its own points near it
        sel = torch.nonzero(p_idx == p, as_tuple=True)[0]
        d = on_wall[p][None] - at[b_idx[sel], p].to(points.dtype)[:, None]  # [m, n, 3]
        square = d[..., 0].square() + d[..., 1].square() + d[..., 2].square()  # [m, n] (not .sum(-1): slow over 3 on the CPU)
        ok[sel] = (square <= test.surface_radius**2).sum(-1) >= test.surface_points
    legs = torch.nonzero(ok, as_tuple=True)[0]  # both legs free: source -> x and x -> listener, the wall's own points aside
    if points.shape[0] >= test.sight_blocked:  # (fewer points than block a path: every leg is free)
        for i in range(0, legs.shape[0], LEGS_AT_ONCE // 2):
            c = legs[i : i + LEGS_AT_ONCE // 2]
            x, m = at[b_idx[c], p_idx[c]], c.shape[0]
            along = points_on_path(points, torch.cat([source[b_idx[c]], x]), torch.cat([x, listener[b_idx[c]]]),
                                   test.sight_radius, test.sight_margin, keep=off_wall[:, p_idx[c].repeat(2)])  # [2 m]
            ok[c] = (along[:m] < test.sight_blocked) & (along[m:] < test.sight_blocked)
    return ok


def wall_reflections(listener: torch.Tensor, source: torch.Tensor, walls: torch.Tensor, points: torch.Tensor,
                     test: ReflectionTest, longest: torch.Tensor | None = None,
                     point_sets: tuple[list[torch.Tensor], torch.Tensor] | None = None) -> WallReflections:
    """Each wall's first-order reflection for poses ``listener, source [B, 3]`` (``walls [P, 3]`` of
    :func:`find_walls`, ``points [N, 3]`` G_a's, all in one unit). ``longest [B]``: paths longer than
    this cannot count (the early window), so their tests are skipped (``happens`` False). ``point_sets``:
    :func:`wall_point_sets` of these points, walls and test, when the caller keeps them. The points' tests
    run in the points' precision, the geometry in float64."""
    dtype = torch.float64
    listener, source = listener.to(dtype), source.to(dtype)
    walls, points = walls.to(listener.device, dtype), points.detach().to(listener.device)
    image, path, happens, at = _images(listener, source, walls)
    if longest is not None:
        happens &= path <= longest.to(dtype)[:, None]
    if walls.shape[0] == 0 or not bool(happens.any()):
        return WallReflections(image, path, happens)
    b_idx, p_idx = torch.nonzero(happens, as_tuple=True)  # the candidates, tested one wall at a time
    sets = wall_point_sets(points, walls, test) if point_sets is None else point_sets
    happens = happens.clone()
    happens[b_idx, p_idx] = _happens(listener, source, at, b_idx, p_idx, points, test, sets)
    return WallReflections(image, path, happens)


@dataclass(frozen=True)
class FirstReflection:
    """The shortest first-order reflection that happens, per pose (a straight path behind a wall)."""

    found: torch.Tensor  # [B] bool: some wall's reflection happens
    image: torch.Tensor  # [B, 3] its image source (the source where none)
    path: torch.Tensor  # [B] its path length (the straight one where none)


def first_reflection(listener: torch.Tensor, source: torch.Tensor, walls: torch.Tensor, points: torch.Tensor,
                     test: ReflectionTest, point_sets: tuple[list[torch.Tensor], torch.Tensor] | None = None) -> FirstReflection:
    """For poses ``listener, source [B, 3]``, the shortest of the walls' first-order reflections that happen
    (:func:`wall_reflections`' test, whatever their length): where the straight path is behind a wall, the
    first sound to arrive in a simulator without diffraction or transmission (a reflection that passes the
    door), when one wall's reflection is enough. The candidates are tested shortest first, and a pose's
    search stops at the first that happens: a few tests a pose, not one per wall. Float64."""
    dtype = torch.float64
    listener, source = listener.to(dtype), source.to(dtype)
    walls, points = walls.to(listener.device, dtype), points.detach().to(listener.device)
    straight = torch.linalg.vector_norm(source - listener, dim=-1)  # [B]
    found = torch.zeros_like(straight, dtype=torch.bool)
    image, path = source.clone(), straight.clone()
    if walls.shape[0] == 0:
        return FirstReflection(found, image, path)
    images, paths, facing, at = _images(listener, source, walls)
    order = torch.where(facing, paths, torch.full_like(paths, math.inf)).argsort(-1)  # [B, P] shortest first
    sets = wall_point_sets(points, walls, test) if point_sets is None else point_sets
    for rank in range(walls.shape[0]):
        wall = order[:, rank]  # [B]
        b_idx = torch.nonzero(~found & facing.gather(1, wall[:, None])[:, 0], as_tuple=True)[0]
        if b_idx.numel() == 0:
            break
        p_idx = wall[b_idx]
        ok = _happens(listener, source, at, b_idx, p_idx, points, test, sets)
        b_ok, p_ok = b_idx[ok], p_idx[ok]
        found[b_ok], image[b_ok], path[b_ok] = True, images[b_ok, p_ok], paths[b_ok, p_ok]
    return FirstReflection(found, image, path)


ARRIVAL_PAIRS = 8
"Pairs behind a wall, each with a first-order reflection, that :func:`reflection_first` needs to choose it."


def reflection_first(measured, straight, reflected) -> tuple[bool, float | None, float | None]:
    """Whether pairs behind a wall hear their first sound from the first reflection: what it predicts,
    ``reflected [M]`` (the head's ITD at its direction, or its path / c), closer to what was measured,
    ``measured [M]`` (the early ITDs, or the onsets; NaN: left out), than what the straight line predicts,
    ``straight [M]``, by the median absolute error, over at least :data:`ARRIVAL_PAIRS` pairs; with the two
    medians (None with fewer pairs)."""
    measured, straight, reflected = (torch.as_tensor(np.asarray(a, dtype=np.float64)) for a in (measured, straight, reflected))
    keep = torch.isfinite(measured)
    if int(keep.sum()) < ARRIVAL_PAIRS:
        return False, None, None
    e_straight = float((straight - measured)[keep].abs().median())
    e_reflected = float((reflected - measured)[keep].abs().median())
    return e_reflected < e_straight, e_straight, e_reflected


def image_directions(listener: torch.Tensor, yaw: torch.Tensor, image: torch.Tensor) -> torch.Tensor:
    """Each image source's direction ``[B, P]`` radians from listeners ``[B, 3]`` facing ``yaw [B]`` (radians),
    for ``image [B, P, 3]`` (:class:`WallReflections`): :func:`~avgs.data.frame.signed_direction`'s convention."""
    P = image.shape[1]
    return signed_direction(listener.to(image)[:, None].expand(-1, P, -1), yaw.to(image)[:, None].expand(-1, P), image)


def ear_shares(ild_db: torch.Tensor) -> torch.Tensor:
    """The left ear's share ``[...]`` of an arrival's energy with an ILD of ``ild_db [...]`` (left over right)."""
    return torch.sigmoid(ild_db * (math.log(10.0) / 10.0))


def early_ild(theta: torch.Tensor, distance: torch.Tensor, reflected: torch.Tensor, path: torch.Tensor,
              counts: torch.Tensor, law: torch.Tensor, gain) -> torch.Tensor:
    """The early stretch's ILD ``[B]`` dB (left over right): the direct sound (direction ``theta [B]``
    radians, path ``distance [B]``) and the reflections (directions ``reflected [B, P]``, paths ``path [B,
    P]``) where ``counts [B, P]`` (bool), each with the energy ``gain^2 / path^2`` (the direct sound's gain
    1) shared between the ears by :func:`~avgs.acoustics.interaural.ild_law` ``law [K]`` at its direction."""
    law = law.to(theta)
    weight = torch.cat([distance[:, None].clamp_min(1e-9) ** -2,
                        torch.as_tensor(gain, dtype=theta.dtype, device=theta.device) ** 2
                        * path.clamp_min(1e-9) ** -2 * counts.to(theta.dtype)], dim=-1)  # [B, 1 + P]
    share = ear_shares(ild_law(torch.cat([theta[:, None], reflected], dim=-1), law))  # [B, 1 + P]
    left, right = (weight * share).sum(-1), (weight * (1.0 - share)).sum(-1)
    return 10.0 * torch.log10(left.clamp_min(1e-300) / right.clamp_min(1e-300))


def fit_early_ild(theta, distance, reflected, path, counts, ild_db, start, harmonics: int = ILD_HARMONICS):
    """Least-squares ``(law [harmonics], gain)`` of :func:`early_ild` for measured early ILDs ``ild_db [M]``
    (dB) of poses with the arguments of :func:`early_ild` (``[M]``, ``[M, P]``), from the law ``start``;
    a soft L1 loss (scale 1 dB) keeps the responses whose first 5 ms hold what no first-order reflection
    explains from pulling it. None with fewer than ``4 * harmonics + 1`` finite measurements, no
    reflection in the window, or a fit that is not finite."""
    from scipy.optimize import least_squares

    ild_db = torch.as_tensor(np.asarray(ild_db, dtype=np.float64))
    keep = torch.isfinite(ild_db)
    counts = torch.as_tensor(counts).bool()
    if int(keep.sum()) < 4 * harmonics + 1 or not bool(counts[keep].any()):
        return None
    args = [torch.as_tensor(a).double()[keep] for a in (theta, distance, reflected, path)] + [counts[keep]]
    target = ild_db[keep]

    def residual(q: np.ndarray) -> np.ndarray:
        q = torch.as_tensor(q)
        return (early_ild(*args, law=q[:harmonics], gain=q[harmonics]) - target).numpy()

    start = np.concatenate([np.asarray(start, dtype=np.float64).reshape(-1)[:harmonics], [GAIN_START]])
    lower = np.concatenate([np.full(harmonics, -60.0), [0.0]])
    upper = np.concatenate([np.full(harmonics, 60.0), [GAIN_MAX]])
    try:
        solution = least_squares(residual, np.clip(start, lower, upper), loss="soft_l1", f_scale=1.0, bounds=(lower, upper))
    except ValueError:  # a residual that is not finite at the start
        return None
    if not np.all(np.isfinite(solution.x)):
        return None
    return solution.x[:harmonics].copy(), float(solution.x[harmonics])
