"""Source and receiver grids of an impulse-response scene, and its split by (source, receiver) pair.

Receivers stand on a regular grid (``receiver_spacing`` metres, cells centred at
``lo + (k + 1/2) spacing`` of the room's box) at the listener's ear height; sources on a
coarser one (``source_spacing``) at ``source_height``. With ``source_spacing = 2 x
receiver_spacing`` (the defaults) every source sits in the middle of four receivers, never on
one. Both keep to the walkable area (:func:`avgs.synth.poses.is_walkable`: inside the
room, clear of walls, partitions and furniture). Source 0 is the one nearest the preset's own
source (the binaural task's source), and is always a training source.

Split (seeded): ``heldout_fraction`` of the other sources (at least one when there are two or
more sources) are held out: all their pairs are ``heldout`` and they appear in no train or val
pair. The pairs of the remaining sources are shuffled and split ``1 - val_fraction`` :
``val_fraction`` into ``train`` and ``val`` (at least one of each when there are two or more).
Pairs closer than ``min_distance`` metres are left out of every split.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from avgs.synth.poses import is_walkable
from avgs.synth.presets import SceneSpec

SPLITS = ("train", "val", "heldout")


@dataclass(frozen=True)
class GridConfig:
    """Where the sources and receivers of an impulse-response scene stand."""

    receiver_spacing: float = 1.0
    "Receiver grid spacing in metres."
    source_spacing: float = 2.0
    "Source grid spacing in metres."
    source_height: float = 1.5
    "Height of every source in metres (receivers stand at the preset's ear height)."
    max_sources: int | None = None
    "Keep at most this many sources, evenly spread over the grid (None: all)."
    max_receivers: int | None = None
    "Keep at most this many receivers, evenly spread over the grid (None: all)."
    heldout_fraction: float = 0.2
    "Share of the sources held out (only in heldout pairs)."
    val_fraction: float = 0.2
    "Share of the training sources' pairs kept for validation."
    min_distance: float = 0.3
    "Pairs closer than this (metres) are left out."

    def validate(self) -> None:
        if not (self.receiver_spacing > 0 and self.source_spacing > 0):
            raise ValueError(f"grid spacings must be > 0, got {self.receiver_spacing} and {self.source_spacing}")
        for name in ("max_sources", "max_receivers"):
            v = getattr(self, name)
            if v is not None and v < 1:
                raise ValueError(f"{name} must be >= 1 or None, got {v}")
        if not 0 <= self.heldout_fraction < 1:
            raise ValueError(f"heldout fraction must be in [0, 1), got {self.heldout_fraction}")
        if not 0 < self.val_fraction < 1:
            raise ValueError(f"val fraction must be in (0, 1), got {self.val_fraction}")


@dataclass(frozen=True)
class RIRGrid:
    """Positions (world metres) and the split of an impulse-response scene."""

    sources: np.ndarray  # [S, 3]
    receivers: np.ndarray  # [R, 3]
    splits: dict  # {"train" | "val" | "heldout": [N, 2] int64 (source, receiver) pairs}

    @property
    def heldout_sources(self) -> list[int]:
        return sorted({int(s) for s, _ in self.splits["heldout"]})

    def pairs(self) -> np.ndarray:
        """[N, 2] every pair of any split, sorted by receiver then source."""
        allp = np.concatenate([self.splits[k] for k in SPLITS])
        return allp[np.lexsort((allp[:, 0], allp[:, 1]))]


def grid_points(spec: SceneSpec, spacing: float, height: float) -> np.ndarray:
    """``[K, 3]`` walkable points of the grid of ``spacing`` metres over the room's box, row by row (y, then x)."""
    walk = dataclasses.replace(spec, source_clearance=0.0)  # the grid's own source is not an obstacle
    (x0, y0), (x1, y1) = spec.bounds()[:, :2]
    xs = np.arange(x0 + spacing / 2, x1, spacing)
    ys = np.arange(y0 + spacing / 2, y1, spacing)
    pts = [(x, y, height) for y in ys for x in xs if is_walkable(walk, (x, y))]
    return np.round(np.array(pts, dtype=np.float64).reshape(-1, 3), 6)


def _spread(points: np.ndarray, keep: int | None) -> np.ndarray:
    if keep is None or len(points) <= keep:
        return points
    return points[np.unique(np.round(np.linspace(0, len(points) - 1, keep)).astype(int))]


def make_grid(spec: SceneSpec, cfg: GridConfig, seed: int) -> RIRGrid:
    """The grids of ``spec`` and their split (module docstring); same seed, same grid."""
    cfg.validate()
    receivers = _spread(grid_points(spec, cfg.receiver_spacing, spec.listener_height), cfg.max_receivers)
    sources = _spread(grid_points(spec, cfg.source_spacing, cfg.source_height), cfg.max_sources)
    if not len(receivers) or not len(sources):
        raise ValueError(
            f"{spec.preset}: {len(sources)} source(s) and {len(receivers)} receiver(s) fit the walkable area "
            f"at spacings {cfg.source_spacing} / {cfg.receiver_spacing} m; use smaller spacings"
        )
    first = int(np.argmin(np.linalg.norm(sources[:, :2] - np.asarray(spec.source[:2]), axis=-1)))
    sources = np.concatenate([sources[first : first + 1], np.delete(sources, first, axis=0)])  # source 0 first

    rng = np.random.default_rng([int(seed), 2])
    n_held = 0 if len(sources) < 2 else min(len(sources) - 1, max(1, int(round(cfg.heldout_fraction * len(sources)))))
    if cfg.heldout_fraction == 0:
        n_held = 0
    held = set((1 + rng.permutation(len(sources) - 1)[:n_held]).tolist())
    dist = np.linalg.norm(sources[:, None, :] - receivers[None, :, :], axis=-1)  # [S, R]
    ok = dist >= cfg.min_distance
    heldout = [(s, r) for s in sorted(held) for r in range(len(receivers)) if ok[s, r]]
    trainable = [(s, r) for s in range(len(sources)) if s not in held for r in range(len(receivers)) if ok[s, r]]
    order = rng.permutation(len(trainable))
    n_val = 0 if len(trainable) < 2 else min(len(trainable) - 1, max(1, int(round(cfg.val_fraction * len(trainable)))))
    val = sorted(trainable[i] for i in order[:n_val])
    train = sorted(trainable[i] for i in order[n_val:])
    as_array = lambda pairs: np.array(pairs, dtype=np.int64).reshape(-1, 2)  # noqa: E731
    return RIRGrid(sources, receivers, {"train": as_array(train), "val": as_array(val), "heldout": as_array(heldout)})
