"""The numbers of one listener pose that the propagation map shows, and what its fast path evaluates.

Each ear's power gain per bin for a stationary white source (:func:`ear_power`), the level and
interaural level difference of ear powers (:func:`power_levels`), and the pieces the task models'
fast cells take (:class:`FastMap`: a subset of the bins and, for responses, of the frames; the
listener's context computed in small chunks). :mod:`avgs.render.propagation_map` explains the map.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

LEVEL_FLOOR_DB = -120.0
"Level (and each ear's level in the ILD) of a filter that passes nothing: silence is a number, not -inf."

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


def pose_levels(result) -> tuple[float, float]:
    """``(level dB, ILD dB)`` of one pose: a :class:`~avgs.render.renderer.RenderResult`
    (``renderer.masks(...)``), whose ``gains`` [2, F] are each ear's long-term gain, whatever the task."""
    level, ild = power_levels(np.asarray(result.gains, dtype=np.float64) ** 2)
    return float(level), float(ild)


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
