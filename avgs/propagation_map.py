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
  :class:`~avgs.inference.SceneRenderer` also bounds by its headroom). 0 dB: the filter
  passes a white source at its own power.
- **ILD** (dB): ``10 log10(sum_f P_left / sum_f P_right)``, positive when the left ear
  is louder (the source on the listener's left, :func:`avgs.data.frame.signed_direction`).

Two ways to compute a cell (``exact``):

- **exact** (``exact=True``): cells are
  :meth:`AVGSModel.masks <avgs.acoustics.model.AVGSModel.masks>` of the very poses
  :meth:`SceneRenderer.masks <avgs.inference.SceneRenderer.masks>` builds (the same world to
  normalised map and the same ``signed_direction`` in float64, cast to the model's dtype),
  with the same headroom limit (a pose whose loudest bin gains more than
  :data:`~avgs.inference.HEADROOM_DB` is scaled down to it), so ``pose_levels`` of
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
from avgs.inference import HEADROOM_DB

LEVEL_FLOOR_DB = -120.0
"Level (and each ear's level in the ILD) of a filter that passes nothing: silence is a number, not -inf."

KINDS = ("level", "ild")
"What a map can show: ``level`` (dB) and ``ild`` (dB, left minus right)."


# -- the two numbers of one pose ---------------------------------------------------------


def ear_power(mixture, difference, reverb=None, decay=None) -> np.ndarray:
    """Each ear's power gain per bin for a stationary white source: ``[..., 2, F]`` float64.

    mixture, difference: ``[..., F]``; reverb: ``[..., 2, F]`` or None; decay: ``[F]`` (with
    reverb). ``g_ear^2 + r_ear^2 w / (1 - w)``: the direct part and the tail's steady state.
    """
    m = np.asarray(mixture, dtype=np.float64)
    d = np.asarray(difference, dtype=np.float64)
    power = np.stack([m * (1.0 + d), m * (1.0 - d)], axis=-2) ** 2  # [..., 2, F]
    if reverb is not None:
        if decay is None:
            raise ValueError("ear_power: reverberant gains need the tail's decay per frame")
        w = np.minimum(np.asarray(decay, dtype=np.float64), 1.0 - 1e-9)  # [F], as the headroom limit
        power = power + np.asarray(reverb, dtype=np.float64) ** 2 * (w / (1.0 - w))
    return power


def _db(x: np.ndarray) -> np.ndarray:
    with np.errstate(divide="ignore"):
        return np.maximum(10.0 * np.log10(x), LEVEL_FLOOR_DB)


def power_levels(power: np.ndarray, weights: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``(level dB, ILD dB)``, each ``[...]``, of ear powers ``[..., 2, F]`` (:func:`ear_power`);
    ``weights`` [F] (summing to 1): a weighted mean over the bins instead of the plain mean."""
    per_ear = power.mean(axis=-1) if weights is None else power @ weights  # [..., 2]
    level = _db(per_ear.mean(axis=-1))
    ild = _db(per_ear[..., 0]) - _db(per_ear[..., 1])
    return level, ild


def pose_levels(masks, decay=None) -> tuple[float, float]:
    """``(level dB, ILD dB)`` of one pose's masks: a :class:`~avgs.inference.RenderResult`
    (``renderer.masks(...)``: mixture, difference [F], reverb [2, F] or None) and, with a
    tail, its decay per frame [F] (``renderer.model.binauralizer.reverb.decay()``)."""
    if masks.reverb is not None and decay is None:
        raise ValueError("pose_levels: masks with a reverberant tail need its decay per frame")
    dec = None if masks.reverb is None else _numpy(decay)
    level, ild = power_levels(ear_power(_numpy(masks.mixture), _numpy(masks.difference), _numpy(masks.reverb), dec))
    return float(level), float(ild)


def _numpy(t):
    if t is None:
        return None
    if isinstance(t, torch.Tensor):
        return t.detach().double().cpu().numpy()
    return np.asarray(t, dtype=np.float64)


# -- what the fast map evaluates -------------------------------------------------------------


@dataclass(frozen=True)
class FastMap:
    """What the fast map evaluates of each cell (see the module docstring); ``exact=True`` evaluates all."""

    bin_stride: int = 8
    "Every bin_stride-th frequency bin, and the last (33 of 257 bins at 8)."
    tail_frames: int = 10
    "Task rir: frames evaluated after the early ones (:func:`early_frames`), geometrically spaced to the last."

    def __post_init__(self):
        for name in ("bin_stride", "tail_frames"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"FastMap.{name} must be a positive integer, got {getattr(self, name)!r}")


def bin_subset(n_freq: int, stride: int) -> tuple[torch.Tensor, np.ndarray]:
    """(bins [f] int64: every ``stride``-th and the last, weights [f] float64 summing to 1): the
    trapezoid rule over the bin index, so that ``power @ weights`` estimates the mean over all bins."""
    bins = np.unique(np.append(np.arange(0, n_freq, stride), n_freq - 1))  # [f]
    if len(bins) == 1:
        return torch.from_numpy(bins), np.ones(1)
    gaps = np.diff(bins).astype(np.float64)
    weights = np.zeros(len(bins))
    weights[:-1] += gaps / 2
    weights[1:] += gaps / 2
    return torch.from_numpy(bins), weights / weights.sum()


def early_frames(renderer) -> int:
    """Frames of the response to evaluate one by one: until the direct sound from the scene's
    farthest corner (the box's diagonal) has arrived, plus the analysis window's length in
    frames and one: after that a response is its decaying tail (task rir)."""
    b, stft = renderer.model.binauralizer, renderer.stft
    lo, hi = renderer.frame.to_normalised(np.asarray(renderer.bounds, dtype=np.float64))
    speed = b.cfg.sound_speed if b.cfg.sound_speed > 0 else 343.0 * renderer.frame.scale  # normalised units / s
    hop = stft.hop_length / stft.sample_rate
    arrival = float(np.linalg.norm(hi - lo)) / speed / hop  # frames
    return int(math.ceil(arrival)) + -(-stft.win_length // stft.hop_length) + 1


def frame_nodes(n_frames: int, early: int, tail: int) -> torch.Tensor:
    """Frames [n] int64 to evaluate: ``0 .. early - 1``, then ``tail`` geometrically spaced up to
    the last frame (fewer where they round to the same frame); all frames when that is as many."""
    if early + tail >= n_frames:
        return torch.arange(n_frames)
    later = np.rint(np.geomspace(early, n_frames - 1, tail)).astype(np.int64)
    return torch.from_numpy(np.unique(np.concatenate([np.arange(early), later])))


def frame_interpolation(nodes: torch.Tensor, n_frames: int) -> torch.Tensor:
    """``[n, N]`` float32: ``y_nodes @ M`` interpolates values at the frames ``nodes`` (increasing,
    from 0 to N - 1) linearly to every frame."""
    x = nodes.double().numpy()
    frames = np.arange(n_frames, dtype=np.float64)
    right = np.clip(np.searchsorted(x, frames, side="right"), 1, len(x) - 1)  # [N]
    left = right - 1
    w = np.clip((frames - x[left]) / np.maximum(x[right] - x[left], 1e-12), 0.0, 1.0)
    M = np.zeros((len(x), n_frames))
    M[left, np.arange(n_frames)] += 1.0 - w
    M[right, np.arange(n_frames)] += w
    return torch.from_numpy(M).float()


PEAK_MARGIN = 10.0 ** (12.0 / 10.0)
"""A fast cell whose loudest evaluated bin is within 12 dB (power ratio) of the headroom is evaluated
again at every bin: the limit needs the loudest of all, and learned spectra can peak between the
evaluated bins (3.5 dB above them next to the source on a two-room scene, which then missed the limit)."""

CONTEXT_CHUNK = 4
"Listener contexts per call of F: F's per-point temporaries ([4 k, width]) stay in cache (2.5x faster than 64 on the demo)."


def listener_contexts(model, cache, listener: torch.Tensor) -> torch.Tensor:
    """C_L [n, c] of listener [n, 3] (normalised): the vicinity search and F, as :meth:`AVGSModel.masks`
    computes them, :data:`CONTEXT_CHUNK` listeners at a time."""
    parts = []
    for i in range(0, len(listener), CONTEXT_CHUNK):
        pos = listener[i : i + CONTEXT_CHUNK]  # [m, 3]
        parts.append(model.context_at(pos, model.vicinity(pos, cache), cache))  # [m, c]
    return torch.cat(parts)


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
    """Compute the map of ``renderer`` (a :class:`~avgs.inference.SceneRenderer`) for a source
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
    rir = getattr(renderer, "task", "binaural") == "rir"  # the impulse-response task: the response's own ear gains
    with torch.inference_mode():
        cached_source = model.source_context(src, cache)
        tail = None if rir else model.binauralizer.reverb
        decay = None if tail is None else tail.decay().double().cpu().numpy()  # [F]

    ny, nx = grid.shape
    order = coarse_to_fine(ny, nx)
    level = np.full((ny, nx), np.nan)
    ild = np.full((ny, nx), np.nan)
    source_w = np.asarray(source_w, dtype=np.float64)
    lo, hi = np.asarray(renderer.bounds, dtype=np.float64)  # cells outside the box: on its edge, as render() puts them
    lis64 = torch.from_numpy(frame.to_normalised(np.clip(grid.positions(), lo, hi)))  # [ny * nx, 3] float64
    theta = signed_direction(lis64, torch.full((ny * nx,), math.radians(yaw), dtype=torch.float64), src64)  # [ny * nx]
    cell_power = (_ExactCells if exact else _FastCells)(renderer, yaw, src, cached_source, decay, fast)
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


class _ExactCells:
    """Each ear's power per bin ``[n, 2, F]`` of cells, as the single-pose path computes them."""

    weights = None  # the plain mean over all bins

    def __init__(self, renderer, yaw: float, source: torch.Tensor, cached_source, decay, fast=None):
        self.renderer, self.yaw, self.source, self.cached_source, self.decay = renderer, yaw, source, cached_source, decay
        self.as_model = dict(device=renderer.device, dtype=renderer.dtype)

    def __call__(self, lis64: torch.Tensor, theta: torch.Tensor) -> np.ndarray:
        r = self.renderer
        listener = lis64.to(**self.as_model)
        if r.task == "rir":
            return _response_power(r, listener, self.yaw, self.source, self.cached_source)
        m = r.model.masks(listener, theta.to(**self.as_model), self.source, self.cached_source, r.cache)
        return ear_power(_numpy(m.mixture), _numpy(m.difference), _numpy(m.reverb), self.decay)


class _FastCells:
    """Each ear's power ``[n, 2, f]`` at a subset of the bins (:attr:`weights` [f]; ``every_bin``:
    all, [n, 2, F]) and, task rir, from a subset of the frames (:class:`FastMap`); the listener's
    context is exact."""

    def __init__(self, renderer, yaw: float, source: torch.Tensor, cached_source, decay, fast: FastMap):
        self.renderer, self.source, self.cached_source = renderer, source, cached_source
        self.as_model = dict(device=renderer.device, dtype=renderer.dtype)
        b = renderer.model.binauralizer
        self.rir = renderer.task == "rir"
        self.bins, self.weights = bin_subset(b.n_freq, fast.bin_stride)  # [f], [f]
        self.full_decay, self.decay = decay, None if decay is None else decay[self.bins.numpy()]
        if self.rir:
            self.frames = frame_nodes(b.n_frames, early_frames(renderer), fast.tail_frames)  # [n_t]
            self.interpolate = frame_interpolation(self.frames, b.n_frames).to(**self.as_model)  # [n_t, N]
            self.yaw_rad = math.radians(yaw % 360.0)  # as SceneRenderer poses a response

    def __call__(self, lis64: torch.Tensor, theta: torch.Tensor, every_bin: bool = False) -> np.ndarray:
        r = self.renderer
        model, b = r.model, r.model.binauralizer
        bins, decay = (None, self.full_decay) if every_bin else (self.bins, self.decay)
        listener = lis64.to(**self.as_model)  # [n, 3]
        n = len(listener)
        context = None
        if model.field is not None:
            c_s = self.cached_source[0][None].expand(n, -1)  # [n, c]
            context = torch.cat([c_s, listener_contexts(model, r.cache, listener)], dim=-1)  # [n, 2c] = C_S (+) C_L
        if not self.rir:
            m = b(listener[:, :2], theta.to(**self.as_model), context, r.cache.frequency, bins)
            return ear_power(_numpy(m.mixture), _numpy(m.difference), _numpy(m.reverb), decay)
        from avgs.acoustics.rir_model import ear_transfer

        source = self.source[None].expand(n, -1)  # [n, 3]
        yaw = torch.full((n,), self.yaw_rad, **self.as_model)
        theta_r = signed_direction(listener, yaw, source)  # [n], as RIRModel.log_magnitudes
        log_mag = b(listener, source, theta_r, yaw, context, r.cache.frequency, self.frames, bins)  # [n, 2, f, n_t]
        gains = ear_transfer(model.magnitudes(log_mag @ self.interpolate).float().cpu(), r.stft)  # [n, 2, f]
        return gains.double().numpy() ** 2


def _response_power(renderer, listener: torch.Tensor, yaw: float, source: torch.Tensor, cached_source) -> np.ndarray:
    """Task rir: each ear's power per bin ``[n, 2, F]`` of the predicted responses at ``listener`` [n, 3]
    (normalised), the same gains :meth:`SceneRenderer.masks` reports for one pose."""
    from avgs.acoustics.rir_model import ear_transfer

    model = renderer.model
    yaw_rad = torch.full((len(listener),), math.radians(yaw % 360.0), dtype=torch.float64).to(listener.device, listener.dtype)
    log_mag = model.log_magnitudes(listener, yaw_rad, source, renderer.cache, cached_source)[0]  # [n, 2, F, N]
    gains = ear_transfer(model.magnitudes(log_mag.float()).cpu(), renderer.stft)  # [n, 2, F]
    return gains.double().numpy() ** 2


def compute_map(renderer, source=None, yaw: float = 0.0, z: float | None = None, size=64, **kw) -> PropagationMap:
    """The whole map at once (:func:`propagation_map`, exhausted)."""
    last = None
    for last in propagation_map(renderer, source, yaw, z, size, **kw):
        pass
    return last
