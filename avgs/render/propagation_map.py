"""The propagation map: the predicted level and interaural level difference over the floor.

For one source position and one listener yaw, every cell of a grid over the scene's floor
plan (:func:`floor_grid`, at the listener's height) is a listener pose, and the map holds
two numbers per cell, both of the pose's ear filter (:mod:`avgs.acoustics.synthesis`):

- **level** (dB): the ear filter's long-term power gain for a stationary flat-spectrum
  (white) source, averaged over both ears and the F frequency bins::

      P_ear,f = g_ear,f^2 + r_ear,f^2 w_f / (1 - w_f)        (ear_power)
      level   = 10 log10(mean over ears and bins of P)

  with ``g = m_m (1 +- m_d)`` the direct gains and, with the reverberant tail, ``r`` its
  per-ear gains and ``w`` its power decay per frame: the tail of a stationary source
  settles at ``r^2 w / (1 - w)`` times the source's power (the geometric sum that
  :class:`~avgs.render.renderer.SceneRenderer` also bounds by its headroom). 0 dB: the filter
  passes a white source at its own power.
- **ILD** (dB): ``10 log10(sum_f P_left / sum_f P_right)``, positive when the left ear
  is louder (the source on the listener's left, :func:`avgs.data.frame.signed_direction`).

Two ways to compute a cell (``exact``):

- **exact** (``exact=True``): cells are
  :meth:`AVGSModel.masks <avgs.acoustics.model.AVGSModel.masks>` of the very poses
  :meth:`SceneRenderer.masks <avgs.render.renderer.SceneRenderer.masks>` builds (the same world to
  normalised map and the same ``signed_direction`` in float64, cast to the model's dtype),
  with the same headroom limit (a pose whose loudest bin gains more than
  :data:`~avgs.render.renderer.HEADROOM_DB` is scaled down to it), so ``pose_levels`` of
  ``renderer.masks(...)`` gives the cell's numbers to float rounding. On the demo (impulse
  responses) a cell is about 135 MFLOP: the RIR network's time MLP and head over all
  N = 158 frames and F = 257 bins (124 MFLOP), F over the listener's k = 1200 points (10);
  a 64x64 map about 550 GFLOP.
- **fast** (the default; :class:`FastMap`): the same network on less of its input, since
  the map needs energies only, summed over frames and averaged over bins:

  * bins: every ``bin_stride``-th bin and the last (33 of 257), weighted by the bins each
    stands for (:func:`bin_subset`, the trapezoid rule) in the level and ILD. The models
    predict mostly smooth spectra (the RIR targets are smoothed over 9 bins; on the demo a
    log magnitude changes by a median 0.006 nats a bin) but can hold narrow peaks, so a
    cell that may reach the headroom limit is evaluated at every bin (:data:`PEAK_MARGIN`).
  * frames (task rir): every frame until the direct sound from the scene's farthest corner
    has arrived and the analysis window has passed it (:func:`early_frames`: 11 on the
    demo, which hold about four fifths of a response's energy), then ``tail_frames`` more,
    geometrically spaced to the last (:func:`frame_nodes`). The network is a continuous
    function of its time input; the log magnitudes of the frames in between are
    interpolated linearly (:func:`frame_interpolation`; exact for an exponential decay),
    then silenced and summed over all frames as :func:`~avgs.acoustics.rir_model.ear_transfer`
    does. What is lost is the frame-to-frame fine structure of the tail.
  * the listener's context C_L stays exact (:func:`listener_contexts`). Interpolating it
    between cells was measured and left out: C_L changes sharply near walls, and on a
    two-room scene a bilinear C_L from every 2nd cell a side was 1.4 dB off next to the
    dividing wall (benchmarks/propagation_map.md).

  About 13 MFLOP of the RIR network a cell on the demo (21 frames x 33 bins) and F's 10,
  against 135: a 64x64 map about 94 GFLOP. The error against the exact map is measured by
  ``scripts/bench_propagation_map.py`` and bounded in tests/test_propagation_map.py.

Order: the model runs ``chunk`` cells at a time and the grid is visited coarse to fine
(:func:`coarse_to_fine`): every 16th cell first, then every 8th, ..., so that a partial map
(:meth:`PropagationMap.filled`) already covers the whole floor. :func:`propagation_map`
yields after every ``batch`` cells and stops as soon as ``cancel()`` says so; ``workers``
threads compute a batch's chunks side by side. Measured: benchmarks/propagation_map.md.
"""

from __future__ import annotations

import math
import threading
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Callable, Iterator

import numpy as np
import torch

from avgs.data.frame import signed_direction
from avgs.render.cells import PEAK_MARGIN, FastMap, bin_subset, power_levels
from avgs.render.tasks import HEADROOM_DB

KINDS = ("level", "ild")
"What a map can show: ``level`` (dB) and ``ild`` (dB, left minus right)."


# -- the grid ------------------------------------------------------------------------------


@dataclass(frozen=True)
class MapGrid:
    """Cell centres of a regular grid over the floor plan (world), at height ``z``."""

    x: np.ndarray  # [nx] cell centres, increasing
    y: np.ndarray  # [ny]
    z: float  # the listener height of every cell

    @property
    def shape(self) -> tuple[int, int]:
        """``(ny, nx)``: maps are indexed ``[iy, ix]``."""
        return len(self.y), len(self.x)

    @property
    def extent(self) -> tuple[float, float, float, float]:
        """``(x0, x1, y0, y1)``: the outer edges of the cells (world)."""
        hx = 0.5 * (self.x[-1] - self.x[0]) / max(len(self.x) - 1, 1) if len(self.x) > 1 else 0.5
        hy = 0.5 * (self.y[-1] - self.y[0]) / max(len(self.y) - 1, 1) if len(self.y) > 1 else 0.5
        return float(self.x[0] - hx), float(self.x[-1] + hx), float(self.y[0] - hy), float(self.y[-1] + hy)

    def positions(self, flat: np.ndarray | None = None) -> np.ndarray:
        """Listener positions ``[n, 3]`` float64 (world) of flat cell indices ``iy * nx + ix`` (all: None)."""
        ny, nx = self.shape
        flat = np.arange(ny * nx) if flat is None else np.asarray(flat)
        iy, ix = np.divmod(flat, nx)
        return np.column_stack([self.x[ix], self.y[iy], np.full(len(flat), self.z)])


def floor_grid(renderer, z: float, size: int | tuple[int, int] = 64) -> MapGrid:
    """``size`` cells a side (or ``(nx, ny)``) over the room outline's floor plan, or the scene's box
    when the checkpoint has no outline, at listener height ``z`` (kept inside the box)."""
    nx, ny = (size, size) if isinstance(size, (int, np.integer)) else size
    nx, ny = int(nx), int(ny)
    if nx < 1 or ny < 1:
        raise ValueError(f"a map needs at least one cell a side, got {nx} x {ny}")
    lo, hi = np.asarray(renderer.bounds, dtype=np.float64)
    a, b = lo[:2].copy(), hi[:2].copy()
    outline = renderer.outline
    if outline is not None and len(outline):
        xy = np.asarray(outline, dtype=np.float64).reshape(-1, 3)[:, :2]
        a, b = np.maximum(xy.min(0), a), np.minimum(xy.max(0), b)
        if np.any(b <= a):
            a, b = lo[:2].copy(), hi[:2].copy()
    z = float(np.clip(float(z), lo[2], hi[2]))
    if not math.isfinite(z):
        raise ValueError(f"map height must be finite, got {z!r}")

    def centres(lo_, hi_, n):
        step = (hi_ - lo_) / n
        return lo_ + step * (np.arange(n) + 0.5)

    return MapGrid(centres(a[0], b[0], nx), centres(a[1], b[1], ny), z)


def coarse_to_fine(ny: int, nx: int, coarsest: int = 16) -> np.ndarray:
    """Flat cell indices ``[ny * nx]``, each once: the cells on every ``coarsest``-th row and
    column first, then every half of that, ... down to every cell (row-major within a level)."""
    iy, ix = np.divmod(np.arange(ny * nx), nx)
    stride = np.ones(ny * nx, dtype=np.int64)
    s = 2
    while s <= coarsest:
        stride[(iy % s == 0) & (ix % s == 0)] = s
        s *= 2
    return np.argsort(-stride, kind="stable")


# -- the map -------------------------------------------------------------------------------


@dataclass
class PropagationMap:
    """Level and ILD over a :class:`MapGrid`, as far as computed (NaN where not yet)."""

    grid: MapGrid
    source: np.ndarray  # [3] world, the source position used
    yaw: float  # degrees
    level: np.ndarray  # [ny, nx] dB, NaN where not computed
    ild: np.ndarray  # [ny, nx] dB, left minus right
    done: int = 0  # cells computed, a prefix of ``order``
    order: np.ndarray = field(default=None, repr=False)  # [ny * nx] the visiting order (coarse_to_fine)
    coarsest: int = 16

    @property
    def complete(self) -> bool:
        return self.done == self.level.size

    def values(self, kind: str) -> np.ndarray:
        """The ``level`` or ``ild`` array [ny, nx] (NaN where not computed)."""
        if kind not in KINDS:
            raise ValueError(f"map kind must be one of {KINDS}, got {kind!r}")
        return self.level if kind == "level" else self.ild

    def filled(self, kind: str) -> np.ndarray:
        """``values(kind)`` with every cell not yet computed showing the computed cell at the
        corner of its block of the finest level done so far (a coarse map before the fine one)."""
        v = self.values(kind)
        if self.complete or self.done == 0:
            return v.copy()
        ny, nx = v.shape
        block = self.coarsest  # the finest level all of whose cells are done
        while block > 1 and -(-ny // (block // 2)) * -(-nx // (block // 2)) <= self.done:
            block //= 2
        iy = (np.arange(ny) // block) * block
        ix = (np.arange(nx) // block) * block
        out = v[iy[:, None], ix[None, :]]
        mask = np.isfinite(v)
        out[mask] = v[mask]
        return out

    def range(self, kind: str) -> tuple[float, float]:
        """(min, max) over the computed cells of ``kind`` (0, 0 before any)."""
        v = self.values(kind)
        v = v[np.isfinite(v)]
        return (float(v.min()), float(v.max())) if v.size else (0.0, 0.0)


def propagation_map(
    renderer, source=None, yaw: float = 0.0, z: float | None = None, size: int | tuple[int, int] = 64,
    batch: int = 256, chunk: int | None = None, cancel: Callable[[], bool] | threading.Event | None = None,
    grid: MapGrid | None = None, exact: bool = False, fast: FastMap = FastMap(), workers: int = 1,
) -> Iterator[PropagationMap]:
    """Compute the map of ``renderer`` (a :class:`~avgs.render.renderer.SceneRenderer`) for a source
    (world; None: the trained one) and a listener ``yaw`` (degrees), batch by batch.

    Yields a snapshot (its own arrays) after every ``batch`` cells, coarse to fine; the last
    one is :attr:`~PropagationMap.complete`. ``z``: the listener height (default: the middle
    of the scene's box); ``grid``: a ready :class:`MapGrid` instead of ``size`` and ``z``.
    ``exact``: every bin and frame (the single-pose path's numbers); else what ``fast`` says
    (the module docstring). ``chunk``: cells per model call (default 4 exact, where small
    blocks keep F's per-point temporaries in cache, and 32 fast). ``workers``: threads that
    compute a batch's chunks side by side (each runs torch ops with torch's own thread count;
    threads, not OpenMP's intra-op pool, because they do not spin-wait on a busy machine).
    ``cancel``: a callable or ``threading.Event``, checked before every chunk (on the worker
    that computes it): when set, the generator returns without yielding again. Runs without
    the renderer's lock (the model is read only), so a viewer can run it on a background
    thread while another renders audio.
    """
    chunk = (4 if exact else 32) if chunk is None else chunk
    if batch < 1 or chunk < 1 or workers < 1:
        raise ValueError(f"batch, chunk and workers must be positive, got {batch}, {chunk} and {workers}")
    stop = cancel.is_set if isinstance(cancel, threading.Event) else (cancel or (lambda: False))
    if grid is None:
        if z is None:
            z = float(np.mean(np.asarray(renderer.bounds, dtype=np.float64)[:, 2]))
        grid = floor_grid(renderer, z, size)
    yaw = float(yaw)
    if not math.isfinite(yaw):
        raise ValueError(f"yaw must be a finite number of degrees, got {yaw!r}")
    model, cache, frame = renderer.model, renderer.cache, renderer.frame
    as_model = dict(device=renderer.device, dtype=renderer.dtype)
    if source is None:
        source_w, source_n = renderer.source, renderer.source_normalised
    else:
        source_w = renderer.inside(source, "source")
        source_n = frame.to_normalised(source_w)
    src64 = torch.tensor(source_n, dtype=torch.float64)  # [3], as SceneRenderer.pose makes it
    src = src64.to(**as_model)
    with torch.inference_mode():
        cached_source = model.source_context(src, cache)

    ny, nx = grid.shape
    order = coarse_to_fine(ny, nx)
    level = np.full((ny, nx), np.nan)
    ild = np.full((ny, nx), np.nan)
    source_w = np.asarray(source_w, dtype=np.float64)
    lo, hi = np.asarray(renderer.bounds, dtype=np.float64)  # cells outside the box: on its edge, as render() puts them
    lis64 = torch.from_numpy(frame.to_normalised(np.clip(grid.positions(), lo, hi)))  # [ny * nx, 3] float64
    theta = signed_direction(lis64, torch.full((ny * nx,), math.radians(yaw), dtype=torch.float64), src64)  # [ny * nx]
    cell_power = _Cells(renderer, yaw, src, cached_source, None if exact else fast)
    headroom = 10.0 ** (HEADROOM_DB / 10.0)  # power

    def limited_levels(power: np.ndarray, weights) -> tuple[np.ndarray, np.ndarray]:
        """(level, ILD) [n] of ear powers [n, 2, f], with SceneRenderer's headroom limit."""
        if not np.all(np.isfinite(power)):
            raise ValueError(f"{renderer.path or 'this checkpoint'}: the model gives NaN or Inf masks on the map")
        peak = power.reshape(len(power), -1).max(axis=-1)  # [n]
        power *= np.minimum(1.0, headroom / np.maximum(peak, 1e-300))[:, None, None]
        return power_levels(power, weights)

    def levels(flat: np.ndarray):
        """(level, ILD) [n] of the cells ``flat``, or None once cancelled."""
        if stop():
            return None
        with torch.inference_mode():
            power = cell_power(lis64[flat], theta[flat])  # [n, 2, F] (fast: [n, 2, f])
        near = power.reshape(len(flat), -1).max(axis=-1) > headroom / PEAK_MARGIN if not exact else None  # [n]
        level_, ild_ = limited_levels(power, cell_power.weights)
        if near is not None and near.any():  # the limit needs the loudest of all bins: evaluate them all
            with torch.inference_mode():
                power = cell_power(lis64[flat[near]], theta[flat[near]], every_bin=True)  # [m, 2, F]
            level_[near], ild_[near] = limited_levels(power, None)
        return level_, ild_

    pool = ThreadPoolExecutor(workers, thread_name_prefix="avgs-map") if workers > 1 else None
    try:
        for b0 in range(0, len(order), batch):
            cells = order[b0 : b0 + batch]
            chunks = [cells[c0 : c0 + chunk] for c0 in range(0, len(cells), chunk)]
            for flat, result in zip(chunks, map(levels, chunks) if pool is None else pool.map(levels, chunks)):
                if result is None:
                    return
                iy, ix = np.divmod(flat, nx)
                level[iy, ix], ild[iy, ix] = result
            done = min(b0 + batch, len(order))
            yield PropagationMap(grid, source_w, yaw, level.copy(), ild.copy(), done, order)
    finally:
        if pool is not None:
            pool.shutdown(wait=True, cancel_futures=True)


class _Cells:
    """Each ear's power ``[n, 2, F]`` of cells, from the renderer's task model
    (:meth:`~avgs.render.tasks.TaskModel.cell_power`): exact, as the single-pose path computes them,
    or fast (``fast``: a subset of the bins, :attr:`weights` [f], and what else the model may
    leave out; ``every_bin``: all bins)."""

    def __init__(self, renderer, yaw: float, source: torch.Tensor, cached_source, fast: FastMap | None):
        self.task, self.yaw, self.source, self.cached_source, self.fast = renderer.task_model, yaw, source, cached_source, fast
        self.as_model = dict(device=renderer.device, dtype=renderer.dtype)
        self.bins, self.weights = (None, None) if fast is None else bin_subset(renderer.n_freq, fast.bin_stride)  # [f], [f]

    def __call__(self, lis64: torch.Tensor, theta: torch.Tensor, every_bin: bool = False) -> np.ndarray:
        return self.task.cell_power(lis64.to(**self.as_model), theta.to(**self.as_model), self.yaw, self.source,
                                    self.cached_source, None if every_bin else self.bins, self.fast)


def compute_map(renderer, source=None, yaw: float = 0.0, z: float | None = None, size=64, **kw) -> PropagationMap:
    """The whole map at once (:func:`propagation_map`, exhausted)."""
    last = None
    for last in propagation_map(renderer, source, yaw, z, size, **kw):
        pass
    return last
