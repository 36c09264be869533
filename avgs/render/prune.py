"""Model only what a scene needs: drop audio points no listener or source ever uses.

A point matters only if it lies in some vicinity (the k nearest points of a listener or
of the source). :func:`needed_points` keeps every point that can be among the k nearest
of **any** position inside a region (the walkable box), not only at sampled positions:

    cover the region by cells of half-diagonal delta, centres c. For q in a cell,
    kNN(q) lies within r_k(q) of q, and r_k(q) <= r_k(c) + delta (the k nearest of c
    are within r_k(c) + delta of q). So |p - c| <= r_k(c) + 2 delta for every p in
    kNN(q): keeping all points within r_k(c) + 2 delta of each centre keeps kNN(q).

With k kept fixed in absolute terms (``ckpt["vicinity_k"]``), the k nearest of q among
the kept points are then exactly its k nearest among all points, so the pruned model
gives **the same masks everywhere in the region** (and for the source, wherever it is
in the region). Outside the region the vicinities may differ.

:func:`subsample_checkpoint` is the other knob, a point *budget*: a random subset of
the points, with k back at its percentile of the new N, so that a vicinity still spans
about the same space and C = mean F(...) over it stays an estimate of the same mean.
That changes the output; the benchmark reports by how much.
"""

from __future__ import annotations

import io
import math

import numpy as np
import torch

from avgs.acoustics.vicinity import vicinity_size


def _checked_box(lo, hi) -> tuple[np.ndarray, np.ndarray]:
    lo = np.asarray(lo, dtype=np.float64).reshape(3)
    hi = np.asarray(hi, dtype=np.float64).reshape(3)
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)) and np.all(hi >= lo)):
        raise ValueError(f"region must be a finite box with max >= min, got min {lo.tolist()} max {hi.tolist()}")
    return lo, hi


def cell_centres(lo, hi, cell: float) -> tuple[np.ndarray, float]:
    """Centres ``[M, 3]`` of a grid of cubes of side ``cell`` covering the box, and their half-diagonal."""
    lo, hi = _checked_box(lo, hi)
    if not (cell > 0 and math.isfinite(cell)):
        raise ValueError(f"cell size must be a positive number, got {cell!r}")
    counts = np.maximum(1, np.ceil((hi - lo) / cell - 1e-9)).astype(int)  # [3]
    sides = (hi - lo) / counts  # [3] actual cell sides (<= cell)
    axes = [lo[i] + sides[i] * (np.arange(counts[i]) + 0.5) for i in range(3)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)  # [M, 3]
    return grid, 0.5 * float(np.linalg.norm(sides))


def needed_points(X, k: int, lo, hi, positions=(), cell: float | None = None, chunk: int = 64) -> np.ndarray:
    """Sorted indices of the points of ``X [N, 3]`` that can be among the k nearest of any
    position in the box ``[lo, hi]`` or of the given extra ``positions [P, 3]``.

    ``cell``: grid spacing (default: 1/16 of the box's largest side). Smaller cells keep
    fewer spare points and cost more distance evaluations (cells x N).
    """
    X = torch.as_tensor(np.asarray(X, dtype=np.float32)).reshape(-1, 3)  # [N, 3]
    n = len(X)
    if not 1 <= k <= n:
        raise ValueError(f"k must be in [1, {n}] for {n} points, got {k}")
    lo, hi = _checked_box(lo, hi)
    if cell is None:
        cell = max(float(np.max(hi - lo)) / 16.0, 1e-6)
    centres, delta = cell_centres(lo, hi, cell)
    keep = torch.zeros(n, dtype=torch.bool)
    if k == n:
        return np.arange(n)
    for i in range(0, len(centres), chunk):
        c = torch.as_tensor(centres[i : i + chunk], dtype=torch.float32)  # [m, 3]
        d = torch.cdist(c.double(), X.double())  # [m, N]
        r_k = torch.kthvalue(d, k, dim=1).values  # [m] distance to the k-th nearest
        keep |= (d <= (r_k + 2.0 * delta + 1e-9)[:, None]).any(0)
    extra = np.asarray(positions, dtype=np.float32).reshape(-1, 3)
    if len(extra):
        d = torch.cdist(torch.as_tensor(extra).double(), X.double())  # [P, N]
        r_k = torch.kthvalue(d, k, dim=1).values
        keep |= (d <= r_k[:, None] * (1 + 1e-6) + 1e-9).any(0)  # ties (to float32 rounding) all kept
    return torch.nonzero(keep).squeeze(1).numpy()


def _take_points(ckpt: dict, keep: np.ndarray) -> dict:
    out = dict(ckpt)
    pts = ckpt["audio_points"]
    idx = torch.as_tensor(np.asarray(keep, dtype=np.int64))
    out["audio_points"] = {"X": pts["X"][idx].clone(), "alpha": pts["alpha"][idx].clone()}
    out.pop("train_state", None)  # optimizer state is per point: it no longer fits
    return out


def current_k(ckpt: dict) -> int:
    """k of a checkpoint: its explicit ``vicinity_k`` (capped at N) or the percentile of N."""
    from avgs.io.checkpoint import config_of

    n = int(ckpt["audio_points"]["X"].shape[0])
    if ckpt.get("vicinity_k") is not None:
        return min(int(ckpt["vicinity_k"]), n)
    return vicinity_size(n, config_of(ckpt).acoustic.vicinity_percentile)


def prune_checkpoint(
    ckpt: dict,
    region_world=None,
    *,
    listeners_world=None,
    cell: float | None = None,
    keep_gaussians: bool = False,
) -> tuple[dict, dict]:
    """A checkpoint with only the audio points some vicinity in the region can use.

    ``region_world``: box ``[2, 3]`` (min, max), world, where listeners (and the source)
    may go; default the checkpoint's scene bounds. ``listeners_world [P, 3]``: extra
    positions that must stay exact. The trained source is always covered. k is stored as
    ``vicinity_k`` so it does not shrink with N. G is dropped unless ``keep_gaussians``
    (it is only for drawing). Returns (pruned checkpoint, summary dict).
    """
    from avgs.data.frame import SceneFrame

    frame = SceneFrame.from_dict(ckpt["frame"])
    box = ckpt["scene"]["bounds"] if region_world is None else region_world
    box_w = np.asarray(torch.as_tensor(box).detach().cpu().numpy() if isinstance(box, torch.Tensor) else box, dtype=np.float64).reshape(2, 3)
    corners = frame.to_normalised(box_w)  # [2, 3]
    lo, hi = corners.min(0), corners.max(0)
    extra = [ckpt["source"].detach().cpu().numpy().reshape(1, 3)]
    if listeners_world is not None:
        extra.append(frame.to_normalised(np.asarray(listeners_world, dtype=np.float64).reshape(-1, 3)))
    X = ckpt["audio_points"]["X"].detach().cpu().numpy()
    k = current_k(ckpt)
    if cell is not None:
        cell = float(cell) * frame.scale  # world -> normalised
    keep = needed_points(X, k, lo, hi, np.concatenate(extra), cell=cell)
    out = _take_points(ckpt, keep)
    out["vicinity_k"] = int(k)
    if not keep_gaussians:
        out.pop("gaussians", None)
    summary = {"points_before": int(len(X)), "points_after": int(len(keep)), "k": int(k),
               "gaussians_kept": bool(keep_gaussians and "gaussians" in ckpt)}
    return out, summary


def subsample_checkpoint(ckpt: dict, n_keep: int, seed: int = 0) -> dict:
    """A random ``n_keep``-point subset of the audio points, k back at its percentile of ``n_keep``."""
    n = int(ckpt["audio_points"]["X"].shape[0])
    if not 1 <= n_keep <= n:
        raise ValueError(f"point budget must be in [1, {n}], got {n_keep}")
    keep = np.sort(np.random.default_rng(seed).choice(n, size=n_keep, replace=False))
    out = _take_points(ckpt, keep)
    out.pop("vicinity_k", None)
    return out


def checkpoint_bytes(ckpt: dict) -> int:
    """Size in bytes of ``ckpt`` as ``torch.save`` writes it."""
    buf = io.BytesIO()
    torch.save(ckpt, buf)
    return buf.tell()


def scene_listener_box(scene_dir, margin: float) -> tuple[np.ndarray, np.ndarray]:
    """(World box [2, 3] around a scene's train and val listener positions widened by ``margin``,
    those positions [P, 3])."""
    from avgs.data.rwavs import RWAVSScene

    scene = RWAVSScene(scene_dir)
    clips = scene.train + scene.val
    if not clips:
        raise ValueError(f"{scene_dir}: no listener poses to take a region from")
    world = scene.frame.to_world(np.stack([c.listener for c in clips]).astype(np.float64))  # [P, 3]
    return np.stack([world.min(0) - margin, world.max(0) + margin]), world
