"""The seam between :class:`~avgs.render.renderer.SceneRenderer` and a task's model.

Each task (:mod:`avgs.tasks`) has one :class:`TaskModel`, chosen once from the checkpoint's
``task`` when it loads: :class:`~avgs.render.binaural.BinauralTaskModel` (the paper's RWAVS
task: masks of one source's sound) and
:class:`~avgs.render.impulse_responses.ImpulseResponseTaskModel` (binaural impulse responses of
sources anywhere). The renderer owns what is the same for every task (world coordinates,
degrees, clamping, locking, input scaling, the output's peak limit, results); the task model
owns what differs: how a pose becomes a :class:`Response`, and a response and a mono input
become sound. The propagation map, the explorer's colours and ``avgs render`` see tasks only
through this protocol.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Protocol

import numpy as np
import torch

from avgs.acoustics.synthesis import Masks
from avgs.config import SynthesisConfig

HEADROOM_DB = 24.0
"Most a pose's ear filter may gain over the input, in any frequency bin, and a render's peak over the input's peak (dB)."


class HeadroomLimited(UserWarning):
    """A pose's ear filter gained more than HEADROOM_DB and was scaled down."""


@dataclass(frozen=True)
class Pose:
    """One listener pose in the model's terms (normalised frame, radians, the model's dtype)."""

    listener: torch.Tensor  # [1, 3] normalised
    theta: torch.Tensor  # [1] radians, direction to the source, > 0 on the listener's left
    source: torch.Tensor  # [3] normalised
    yaw: float  # degrees, as asked (the facing; ccw from +x)
    listener_world: np.ndarray  # [3] float64, the position used (inside the scene's box)
    source_world: np.ndarray  # [3] float64


@dataclass(frozen=True)
class Response:
    """What a task's model gives for one pose, within the headroom.

    ``gains`` is every task's: each ear's long-term gain per frequency bin for a stationary
    white source (the square root of its power gain: the direct part and a tail's steady
    state), what the propagation map and the meters read. ``masks`` is the binaural task's
    (B's mixture and difference masks, the tail's gains), None for a model that predicts the
    response itself. ``impulse`` is the pose as a filter, when asked for or free.
    """

    gains: torch.Tensor  # [1, 2, F] float64
    listener_vicinity: torch.Tensor  # [1, k] int64 indices into the audio points
    source_vicinity: torch.Tensor  # [k] int64
    masks: Masks | None = None
    impulse: np.ndarray | None = None  # [2, L] float32, channel 0 = left


class BlockStream(Protocol):
    """A pose's sound block by block (:class:`~avgs.render.mid_phase_stream.MidPhaseStream`,
    :class:`~avgs.render.streaming.BinauralStream`, :class:`~avgs.acoustics.convolution.ConvolutionStream`):
    the concatenated output equals a one-shot render, ``latency`` samples behind at most."""

    @property
    def latency(self) -> int: ...

    def process(self, x) -> np.ndarray:
        """Output ``[2, m]`` (m may be 0) for the next mono input samples ``x [n]``."""

    def flush(self) -> np.ndarray:
        """The rest of the output ``[2, m]``; the stream takes no more input."""

    def set_pose(self, masks: Masks | None, impulse: np.ndarray | None) -> None:
        """Go on with another pose from the next block."""


class TaskModel(Protocol):
    """What the renderer asks of a task's model. Made once per checkpoint from (the model, its
    cache, the STFT, the checkpoint's name for errors, the renderer's cached C_S of a source, the
    scene's frame and box). Calls come under the renderer's lock and ``torch.inference_mode``;
    positions are normalised, already inside the scene."""

    model: torch.nn.Module
    "G_a + F + the task's B (read only)."
    source_aware: bool
    "Whether the model was trained on many source positions, so that a moved source is really heard."

    def response(self, pose: Pose, impulse: bool = False, stop: Callable[[], bool] | None = None) -> Response:
        """The pose's :class:`Response` within :data:`HEADROOM_DB` (a :class:`HeadroomLimited`
        warning when scaled); ``impulse``: also its binaural impulse response. ``stop``: asked
        between the stages (after the network, and in the waveform); True abandons the pose
        (:class:`avgs.threads.Stopped`)."""

    def render(self, response: Response, x: np.ndarray, synthesis: SynthesisConfig,
               magnitudes: bool) -> tuple[np.ndarray, np.ndarray | None, float]:
        """``(binaural [2, T] float32, ear magnitudes [2, F, N_t] or None, the output's peak)`` of
        ``x`` [T] float32 at unit peak (NaN peak when a sample is not finite)."""

    def stream(self, response: Response, synthesis: SynthesisConfig, block_frames: int | None) -> BlockStream:
        """A block stream of this response (``process``, ``flush``, ``set_pose``, ``latency``)."""

    def beyond_filter(self, synthesis: SynthesisConfig) -> bool:
        """Whether a render with ``synthesis`` differs from the pose's filter and still streams (so
        that the explorer, which plays the filter while a pose moves, renders a settled pose anew)."""

    def move_stream(self, stream: BlockStream, response: Response) -> None:
        """Switch ``stream`` to ``response`` from its next block."""

    def reach_frames(self, synthesis: SynthesisConfig, n_frames: int | None = None,
                     decay: torch.Tensor | None = None) -> int:
        """STFT frames of input before (or after) an output frame that it depends on (:func:`reach_frames`)."""

    def cell_power(self, listener: torch.Tensor, theta: torch.Tensor, yaw: float, source: torch.Tensor,
                   cached_source, bins: torch.Tensor | None = None, fast=None) -> np.ndarray:
        """Each ear's power gain ``[n, 2, f]`` float64 at ``listener`` [n, 3] (the propagation map's cells):
        ``bins`` [f] a subset of the bins (all when None); ``fast``: a :class:`~avgs.render.cells.FastMap`
        whose approximations the model may take (None: exactly as :meth:`response`)."""

    def predict_responses(self, source: np.ndarray, receiver: np.ndarray, yaw: np.ndarray) -> np.ndarray:
        """Binaural responses ``[N, 2, L]`` float32 at normalised positions, no clamping or limit."""


def unit_input(mono) -> tuple[np.ndarray, float]:
    """``mono`` as a 1-D float32 array and the scale it is rendered at (its peak; 1 for silence):
    a render is processed at unit peak, so that no float32 under- or overflows. ValueError for
    anything but a non-empty 1-D signal, or NaN / Inf samples."""
    x = np.asarray(mono, dtype=np.float32)
    if x.ndim == 2 and 1 in x.shape:
        x = x.reshape(-1)
    if x.ndim != 1 or x.size == 0:
        raise ValueError(f"mono must be a 1-D signal with at least one sample, got shape {x.shape}")
    top = peak(x)
    if not math.isfinite(top):
        raise ValueError("mono holds NaN or Inf samples")
    return x, (top if top > 0 else 1.0)


def peak(a: np.ndarray, chunk: int = 1 << 20) -> float:
    """max |a| (NaN if any sample is NaN or Inf), in chunks: no temporary as large as ``a``."""
    flat = a.reshape(-1) if a.flags.c_contiguous else a.ravel()
    top = 0.0
    for i in range(0, flat.size, chunk):
        part = flat[i : i + chunk]
        hi, lo = float(part.max()), float(part.min())
        if not (math.isfinite(hi) and math.isfinite(lo)):
            return math.nan
        top = max(top, hi, -lo)
    return top


MAX_REACH_FRAMES = 1 << 14
"A tail's reach counted at most this many frames (95 s at AV-NeRF's hop) when no input length bounds it."


def reach_frames(stft, synthesis: SynthesisConfig, decay: torch.Tensor | None = None, n_frames: int | None = None,
                 context_frames: int = 0) -> int:
    """STFT frames of input before (or after) an output frame that it depends on: a tail of decay
    ``decay`` [F] to its NEGLIGIBLE_POWER (causally; at most ``n_frames``), the STFT window, the
    phase iterations' reach (the window's per iteration) and ``context_frames`` of a conv head."""
    from avgs.acoustics.reverb_tail import tail_length

    tail = 0 if decay is None else tail_length(decay, MAX_REACH_FRAMES if n_frames is None else n_frames)
    window = -(-stft.n_fft // stft.hop_length)  # frames one window overlaps on each side, plus one
    return tail + window * (synthesis.iterations + 2) + context_frames


def check_finite(tensors, where: str, what: str) -> None:
    """ValueError naming ``where`` unless every tensor of ``tensors`` is finite."""
    if not all(all_finite(t) for t in tensors if t is not None):
        raise ValueError(f"{where}: the model gives NaN or Inf {what}: its weights are not usable")


def all_finite(t: torch.Tensor) -> bool:
    """Whether every value of ``t`` is finite. A NaN or an Inf makes the sum NaN or Inf, so a finite sum
    says so in one pass (a response's 40,000 samples: 10 us against 120 for ``isfinite(t).all()`` on the
    CPU); a sum that is not finite (or that overflowed) is checked value by value."""
    return t.numel() == 0 or bool(torch.isfinite(t.sum())) or bool(torch.isfinite(t).all())
