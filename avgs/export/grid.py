"""A grid of binaural responses: listener positions x yaws, for one source or for several.

A source-aware checkpoint (``SceneRenderer.source_aware``: ``avgs train --task rir``) gives
every response of the grid in batches (:meth:`~avgs.render.renderer.SceneRenderer.predict_responses`);
any other gives the trained source's, one pose at a time, as the explorer hears it
(:meth:`~avgs.render.renderer.SceneRenderer.binaural_filter`). Both are the same numbers for the
same pose (``tests/test_export_sofa.py``). Positions are world coordinates, yaws degrees.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

BATCH = 32
"Poses per predict_responses call (a progress step)."


@dataclass(frozen=True)
class GridSpec:
    """Which responses a grid holds."""

    spacing: float = 0.5
    "Distance between neighbouring listener positions in x and y (world units, metres for generated scenes)."
    yaws: tuple[float, ...] = (0.0, 90.0, 180.0, 270.0)
    "Listener facings at every position (degrees ccw from +x)."
    height: float | None = None
    "Listener height z (world); None: the source's height, kept inside the scene."
    sources: tuple[tuple[float, float, float], ...] = ()
    "Source positions (world); empty: the trained source. More than one needs a source-aware checkpoint."


@dataclass(frozen=True)
class ResponseGrid:
    """Responses ``ir [S, P, Y, 2, L]`` float32 (channel 0 = left) of sources x listener positions x yaws."""

    sources: np.ndarray  # [S, 3] float64 world
    listeners: np.ndarray  # [P, 3] float64 world
    yaws: np.ndarray  # [Y] float64 degrees
    ir: np.ndarray  # [S, P, Y, 2, L] float32
    sample_rate: int
    bounds: np.ndarray = field(default_factory=lambda: np.zeros((2, 3)))  # [2, 3] the scene's box, world

    @property
    def shape(self) -> tuple[int, int, int]:
        return len(self.sources), len(self.listeners), len(self.yaws)


def _finite(values, what: str) -> np.ndarray:
    a = np.asarray(values, dtype=np.float64)
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{what} must be finite numbers, got {values!r}")
    return a


def check_spec(spec: GridSpec) -> GridSpec:
    """``spec`` checked: a positive spacing, at least one yaw, finite numbers; one ValueError otherwise."""
    if not (isinstance(spec.spacing, (int, float)) and math.isfinite(spec.spacing) and spec.spacing > 0):
        raise ValueError(f"grid spacing must be a positive number of metres, got {spec.spacing!r}")
    if len(spec.yaws) == 0:
        raise ValueError("a grid needs at least one yaw (degrees)")
    _finite(spec.yaws, "grid yaws")
    if spec.height is not None:
        _finite(spec.height, "grid height")
    for s in spec.sources:
        if np.asarray(s).shape != (3,):
            raise ValueError(f"each grid source must be 3 numbers (x, y, z), got {s!r}")
        _finite(s, "grid source")
    return spec


def listener_grid(bounds, spacing: float, height: float, max_points: int = 100_000) -> np.ndarray:
    """Listener positions ``[P, 3]`` (world): a square grid of ``spacing`` over the box's floor,
    centred in it, at ``height``; ValueError when it would hold more than ``max_points``."""
    lo, hi = np.asarray(bounds, dtype=np.float64)
    counts = np.floor((hi[:2] - lo[:2]) / spacing).astype(int) + 1  # [2] positions along x and y
    if int(np.prod(counts)) > max_points:
        raise ValueError(f"a grid of spacing {spacing:g} over this scene holds {int(np.prod(counts))} positions "
                         f"(at most {max_points}): choose a larger spacing")
    start = (lo[:2] + hi[:2]) / 2.0 - (counts - 1) * spacing / 2.0  # centred in the box
    xs, ys = (start[i] + spacing * np.arange(counts[i]) for i in range(2))
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    return np.stack([gx.ravel(), gy.ravel(), np.full(gx.size, float(height))], axis=1)


def compute_grid(renderer, spec: GridSpec, progress: Callable[[int, int], object] | None = None) -> ResponseGrid:
    """Every response of ``spec``: ``renderer`` is a :class:`~avgs.render.renderer.SceneRenderer`;
    ``progress(done, total)`` is called after each batch of poses. Listener and source positions
    outside the scene are moved onto its box (a PositionClamped warning)."""
    spec = check_spec(spec)
    if len(spec.sources) > 1 and not renderer.source_aware:
        raise ValueError(f"{renderer.path or 'this checkpoint'} was trained with one source position: a grid of "
                         f"{len(spec.sources)} sources needs a checkpoint of 'avgs train --task rir'")
    sources = (np.stack([renderer.inside(s, "grid source") for s in spec.sources]) if spec.sources
               else renderer.source[None].astype(np.float64))  # [S, 3]
    height = float(sources[0, 2] if spec.height is None else spec.height)
    height = float(np.clip(height, renderer.bounds[0, 2], renderer.bounds[1, 2]))
    listeners = listener_grid(renderer.bounds, float(spec.spacing), height)  # [P, 3]
    yaws = np.asarray(spec.yaws, dtype=np.float64)  # [Y]
    S, P, Y = len(sources), len(listeners), len(yaws)
    si, pi, yi = (a.ravel() for a in np.meshgrid(np.arange(S), np.arange(P), np.arange(Y), indexing="ij"))  # [M] each
    total, rows = S * P * Y, []
    for start in range(0, total, BATCH):
        sl = slice(start, min(start + BATCH, total))
        if renderer.source_aware:
            rows.append(renderer.predict_responses(renderer.frame.to_normalised(sources[si[sl]]),
                                                   renderer.frame.to_normalised(listeners[pi[sl]]), yaws[yi[sl]]))
        else:  # the trained source, pose by pose
            rows.append(np.stack([renderer.binaural_filter(listeners[p], yaws[y]).impulse
                                  for p, y in zip(pi[sl], yi[sl])]))
        if progress is not None:
            progress(sl.stop, total)
    length = max(r.shape[-1] for r in rows)
    ir = np.zeros((total, 2, length), dtype=np.float32)  # [M, 2, L]
    at = 0
    for r in rows:
        ir[at : at + len(r), :, : r.shape[-1]] = r
        at += len(r)
    return ResponseGrid(sources, listeners, yaws, ir.reshape(S, P, Y, 2, length), int(renderer.sample_rate),
                        np.asarray(renderer.bounds, dtype=np.float64))
