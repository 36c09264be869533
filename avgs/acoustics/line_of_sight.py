"""Whether the straight path from a source to a listener is free: the scene's points along it.

A wall between the source and the listener is a surface of the scene, and the audio points
G_a (taken from G's Gaussians) lie on it; a free path has few of them near it. The count of
points within :data:`RADIUS_M` of the segment, its first and last :data:`MARGIN_M` left out (the
listener's and the source's own surroundings), tells the two apart once a threshold is known,
and the training responses give it: a response whose first arrival is more than 1 ms after
distance / c has no straight path (:func:`fit_blocked_count`). On the two-room preset (20 000
points from SfM) the threshold fitted on the training pairs classifies the held-out pairs
79 / 88 in sight and 23 / 24 behind the wall. This is where the scene's points do what the
positions alone cannot.

Used by the impulse-response task's direct sound: the head shadow of the straight direction
(:func:`avgs.acoustics.interaural.ild_law`) only where that path is free; behind a wall the
first sound comes around it, from elsewhere, and B's learned ILD stays. And by B's wall term
(``RIRConfig.wall_loss``): the count along the path, within :func:`wall_radius`, in walls.
"""

from __future__ import annotations

import numpy as np
import torch
from numba import njit

RADIUS_M = 0.2
"Metres: points this close to the path count against it."

MARGIN_M = 0.3
"Metres at each end of the path where points do not count (the listener's and the source's surroundings)."

WALL_SPACINGS = 3.0
"The walls' count (:func:`wall_radius`) looks this many times the points' typical spacing around the path."

MIN_ACCURACY = 0.8
"The least balanced accuracy on the training pairs for a fitted threshold to be used."


def points_on_path(points: torch.Tensor, a: torch.Tensor, b: torch.Tensor, radius: float, margin: float,
                   keep: torch.Tensor | None = None) -> torch.Tensor:
    """How many of ``points [P, 3]`` lie within ``radius`` of each segment ``a [B, 3]`` -> ``b [B, 3]``,
    not within ``margin`` of its ends (all in one unit): ``[B]`` int64. ``keep [P, B]`` (bool): only
    those points count for each segment.

    On the CPU one compiled loop over the points and segments, in float64 (:func:`_count_near`; the
    explorer asks this a few times per pose: 10 torch passes over 8,000 points took 0.3 ms); elsewhere
    (CUDA) :func:`points_on_path_torch`, in ``points``' precision, which is also the loop's reference in
    the tests (they agree but for a point within rounding of the radius or the margins)."""
    tensors = (points, a, b) if keep is None else (points, a, b, keep)
    if not all(t.device.type == "cpu" for t in tensors):
        return points_on_path_torch(points, a, b, radius, margin, keep)
    out = np.zeros(a.shape[0], dtype=np.int64)
    k = np.zeros((0, 0), dtype=np.bool_) if keep is None else np.ascontiguousarray(keep.detach().numpy())
    xyz = np.ascontiguousarray(points.detach().numpy().T, dtype=np.float64)  # [3, P]
    _count_near(xyz, _f64(a), _f64(b), float(radius), float(margin), k, out)
    return torch.from_numpy(out)


def _f64(t: torch.Tensor) -> np.ndarray:
    return np.ascontiguousarray(t.detach().to(torch.float64).numpy())


@njit(cache=True, nogil=True, error_model="numpy", boundscheck=False)
def _count_near(xyz, a, b, radius, margin, keep, out):  # pragma: no cover - compiled
    """out[j] = the points xyz [3, P] (coordinate-major) within radius of segment a[j] -> b[j] [B, 3], farther
    than margin (along it) from both its ends; keep [P, B] (bool) or [0, 0] (all count). Branch-free over
    the points, so the loop is vectorised."""
    r2 = radius * radius
    px, py, pz = xyz[0], xyz[1], xyz[2]
    masked = keep.shape[0] > 0
    for j in range(a.shape[0]):
        ax, ay, az = a[j, 0], a[j, 1], a[j, 2]
        ux, uy, uz = b[j, 0] - ax, b[j, 1] - ay, b[j, 2] - az
        length = max(np.sqrt(ux * ux + uy * uy + uz * uz), 1e-12)
        ux, uy, uz = ux / length, uy / length, uz / length
        far = length - margin
        count = 0
        for i in range(px.shape[0]):
            dx, dy, dz = px[i] - ax, py[i] - ay, pz[i] - az
            along = dx * ux + dy * uy + dz * uz
            near = (along > margin) & (along < far) & (dx * dx + dy * dy + dz * dz - along * along < r2)
            if masked:
                near = near & keep[i, j]
            count += near
        out[j] = count


def points_on_path_torch(points: torch.Tensor, a: torch.Tensor, b: torch.Tensor, radius: float, margin: float,
                         keep: torch.Tensor | None = None) -> torch.Tensor:
    """:func:`points_on_path` by matrix products, on ``points``' device and in its precision."""
    a, b = a.to(points.dtype), b.to(points.dtype)
    ab = b - a  # [B, 3]
    length = torch.linalg.vector_norm(ab, dim=-1).clamp_min(1e-12)  # [B]
    unit = ab / length[:, None]  # [B, 3]
    along = points @ unit.T - (a * unit).sum(-1)  # [P, B] distance along each path from its a
    square = (points.square().sum(-1, keepdim=True) - 2.0 * points @ a.T + a.square().sum(-1))  # [P, B] |p - a|^2
    off = square - along.square()  # [P, B] squared distance from each line
    inner = (along > margin) & (along < length - margin)
    near = (off < radius * radius) & inner
    return (near if keep is None else near & keep).sum(0)


def wall_radius(points: torch.Tensor, radius: float) -> float:
    """The radius around a path within which its points count walls: ``radius``, or :data:`WALL_SPACINGS`
    times the median distance from each of ``points [P, 3]`` to its nearest neighbour where that is more
    (a sparse cloud: a wall's points then lie farther apart than ``radius``, and a path through the gaps
    between them would count no wall; three_rooms with 700 points, 0.14 m apart: at 0.2 m the path of
    docs/rir_level_distance.md's wall pair counted no point of the wall in one seed of three)."""
    from scipy.spatial import cKDTree

    p = points.detach().double().cpu().numpy()
    if len(p) < 2:
        return float(radius)
    spacing = float(np.median(cKDTree(p).query(p, k=2)[0][:, 1]))
    return max(float(radius), WALL_SPACINGS * spacing)


def fit_blocked_count(counts, in_sight) -> float | None:
    """The count from which a path is blocked (``counts >= threshold``) that best separates the training
    pairs' ``in_sight`` labels (balanced accuracy), or None where it cannot be told: fewer than three
    pairs of either kind, or a best balanced accuracy under :data:`MIN_ACCURACY`."""
    counts = np.asarray(counts, dtype=np.float64).reshape(-1)
    sight = np.asarray(in_sight, dtype=bool).reshape(-1)
    if sight.sum() < 3 or (~sight).sum() < 3:
        return None
    best, threshold = -1.0, None
    for t in np.unique(counts)[1:]:  # blocked when counts >= t: every split between two observed counts
        blocked = counts >= t
        accuracy = 0.5 * ((~blocked & sight).sum() / sight.sum() + (blocked & ~sight).sum() / (~sight).sum())
        if accuracy > best:
            best, threshold = accuracy, float(t)
    return threshold if best >= MIN_ACCURACY else None
