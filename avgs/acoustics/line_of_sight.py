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
    not within ``margin`` of its ends (all in one unit): ``[B]`` int64. In ``points``' precision, by
    matrix products (the explorer asks once per pose of a drag). ``keep [P, B]`` (bool): only those
    points count for each segment."""
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
