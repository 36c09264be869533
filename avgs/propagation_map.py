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

Exact with respect to the single-pose path: cells are
:meth:`AVGSModel.masks <avgs.acoustics.model.AVGSModel.masks>` of the very poses
:meth:`SceneRenderer.masks <avgs.inference.SceneRenderer.masks>` builds (the same world to
normalised map and the same ``signed_direction`` in float64, cast to the model's dtype),
with the same headroom limit (a pose whose loudest bin gains more than
:data:`~avgs.inference.HEADROOM_DB` is scaled down to it), so ``pose_levels`` of
``renderer.masks(...)`` gives the cell's numbers to float rounding (tests/test_propagation_map.py).

Cost and order: one cell costs what one pose's masks cost (the vicinity search, F over the
k nearest points, B over the F bins: about 95 MFLOP on the demo scene, so a 64x64 map is
about 390 GFLOP). The model runs a few cells at a time (``chunk``: small blocks keep F's
per-point temporaries in cache, faster on a CPU than one large batch) and the grid is
visited coarse to fine (:func:`coarse_to_fine`): every 16th cell first, then every 8th,
..., so that a partial map (:meth:`PropagationMap.filled`) already covers the whole floor.
:func:`propagation_map` yields after every ``batch`` cells and stops as soon as ``cancel()``
says so. Measured: benchmarks/propagation_map.md (``scripts/bench_propagation_map.py``).
"""

from __future__ import annotations

import math
import threading
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


def power_levels(power: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(level dB, ILD dB)``, each ``[...]``, of ear powers ``[..., 2, F]`` (:func:`ear_power`)."""
    per_ear = power.mean(axis=-1)  # [..., 2]
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
    batch: int = 256, chunk: int = 4, cancel: Callable[[], bool] | threading.Event | None = None,
    grid: MapGrid | None = None,
) -> Iterator[PropagationMap]:
    """Compute the map of ``renderer`` (a :class:`~avgs.inference.SceneRenderer`) for a source
    (world; None: the trained one) and a listener ``yaw`` (degrees), batch by batch.

    Yields a snapshot (its own arrays) after every ``batch`` cells, coarse to fine; the last
    one is :attr:`~PropagationMap.complete`. ``z``: the listener height (default: the middle
    of the scene's box); ``grid``: a ready :class:`MapGrid` instead of ``size`` and ``z``.
    ``cancel``: a callable or ``threading.Event``, checked before every chunk of ``chunk``
    cells: when set, the generator returns without yielding again. Runs on the calling
    thread, without the renderer's lock (the model is read only), so a viewer can run it on a
    background thread while another renders audio.
    """
    if batch < 1 or chunk < 1:
        raise ValueError(f"batch and chunk must be positive, got {batch} and {chunk}")
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
    yaw_rad = math.radians(yaw)
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
    headroom = 10.0 ** (HEADROOM_DB / 10.0)  # power
    for b0 in range(0, len(order), batch):
        cells = order[b0 : b0 + batch]
        for c0 in range(0, len(cells), chunk):
            if stop():
                return
            flat = cells[c0 : c0 + chunk]
            lis64 = torch.from_numpy(frame.to_normalised(np.clip(grid.positions(flat), lo, hi)))  # [n, 3] float64
            theta = signed_direction(lis64, torch.full((len(flat),), yaw_rad, dtype=torch.float64), src64)  # [n]
            with torch.inference_mode():
                if rir:
                    power = _response_power(renderer, lis64.to(**as_model), yaw, src, cached_source)  # [n, 2, F]
                else:
                    m = model.masks(lis64.to(**as_model), theta.to(**as_model), src, cached_source, cache)
                    power = ear_power(_numpy(m.mixture), _numpy(m.difference), _numpy(m.reverb), decay)  # [n, 2, F]
            if not np.all(np.isfinite(power)):
                raise ValueError(f"{renderer.path or 'this checkpoint'}: the model gives NaN or Inf masks on the map")
            peak = power.reshape(len(flat), -1).max(axis=-1)  # [n]
            power *= np.minimum(1.0, headroom / np.maximum(peak, 1e-300))[:, None, None]  # SceneRenderer's limit
            lv, il = power_levels(power)
            iy, ix = np.divmod(flat, nx)
            level[iy, ix], ild[iy, ix] = lv, il
        done = min(b0 + batch, len(order))
        yield PropagationMap(grid, source_w, yaw, level.copy(), ild.copy(), done, order)


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
