"""``SceneRenderer``: the one object the CLI, the benchmarks and the viewer use.

Public coordinates are the scene's **world** frame, yaw in **degrees** counter-clockwise
from +x (ARCHITECTURE.md); the conversion to the model's normalised frame and radians
happens here and nowhere else. Rendering runs the model's own code
(:meth:`AVGSModel.masks <avgs.acoustics.model.AVGSModel.masks>`) under
``torch.inference_mode`` with its caches: the pose-independent parts of F and B
(:meth:`~avgs.acoustics.model.AVGSModel.precompute`) and the source context C_S, kept
until the source moves. The masks are time-invariant, so a pose is a filter, its binaural
impulse response (:meth:`SceneRenderer.binaural_filter`, :mod:`avgs.acoustics.impulse_response`).
By default (:class:`~avgs.config.SynthesisConfig`) a render is B's predicted ear magnitudes
with one phase that fast Griffin-Lim retrieves for their mid, for any length, and
:meth:`SceneRenderer.stream` gives the same block by block; ``method="filter"`` is the
convolution alone (what the explorer plays), ``phase="filter"`` the filter output's phase,
``phase="source"`` the paper's synthesis (:mod:`avgs.acoustics.synthesis`).

Bounded sound: the listener and the source are kept inside the room (its outline's floor
plan and height, within the scene's box :attr:`SceneRenderer.bounds`, which holds its audio
points, G, the training poses and the source; the one clamp the explorer uses too), with a :class:`PositionClamped` warning naming the position asked for and the one
used; the ear filter of a pose never gains more than :data:`HEADROOM_DB` over the input in
any frequency bin (masks scaled down otherwise, with a :class:`HeadroomLimited` warning),
and a render's peak never exceeds the input's peak by more than that either. Non-finite
masks or output raise ValueError naming the checkpoint. Inputs are processed at unit peak
and scaled back, so any finite input (1e-30 or 1e30) renders without underflow or overflow.

Thread safety: :meth:`render` and :meth:`masks` serialise on an internal lock, so one
worker thread may render while another thread reads the point arrays (read-only numpy).

Two tasks (:mod:`avgs.tasks`), one renderer: the checkpoint's task picks, once, the
:class:`~avgs.render.tasks.TaskModel` that turns a pose into a
:class:`~avgs.render.tasks.Response` and a response and a mono input into sound
(:mod:`avgs.render.binaural`: B's masks, one source; :mod:`avgs.render.impulse_responses`:
predicted responses, sources anywhere). A moved source (``source=``) of a one-source model
changes only the direction the ears hear it from and C_S; :meth:`render` says so once per
renderer (:class:`OneSourceModel` warning), and the explorer keeps the source fixed.
"""

from __future__ import annotations

import math
import threading
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import torch

from avgs.config import SynthesisConfig
from avgs.data.frame import SceneFrame, signed_direction
from avgs.gaussians.sh import sh_to_rgb
from avgs.io.checkpoint import config_of, load_checkpoint, stft_of
from avgs.render.tasks import HEADROOM_DB, BlockStream, HeadroomLimited, Pose, Response, TaskModel, peak, unit_input  # noqa: F401
from avgs.render.unit_scale_stream import UnitScaleStream
from avgs.tasks import Task, task_of


class PositionClamped(UserWarning):
    """A listener or source outside the scene's box was moved onto its edge."""


class OneSourceModel(UserWarning):
    """A moved source was asked of a model trained with one source position (the binaural task)."""


@dataclass(frozen=True)
class RenderResult:
    """What one listener pose gives: each ear's gains, the vicinity sets behind them, B's masks
    (the binaural task) and, from :meth:`SceneRenderer.render`, the binaural waveform."""

    gains: np.ndarray  # [2, F] float32 each ear's long-term gain for a white source (left, right), every task
    listener_vicinity: np.ndarray  # [k] int64 indices into SceneRenderer.points
    source_vicinity: np.ndarray  # [k] int64 indices into SceneRenderer.points
    theta: float  # degrees, direction to the source, positive = source on the listener's left
    mixture: np.ndarray | None = None  # [F] float32 B's mixture mask; None for a model of responses
    difference: np.ndarray | None = None  # [F] float32 in (-1, 1), > 0 means left louder; None likewise
    reverb: np.ndarray | None = None  # [2, F] float32 reverberant gains (left, right); None without a tail
    binaural: np.ndarray | None = None  # [2, T] float32, channel 0 = left ear; None from masks()
    magnitudes: np.ndarray | None = None  # [2, F, N_t] float32 predicted ear magnitudes; only when asked for
    impulse: np.ndarray | None = None  # [2, L] float32 binaural impulse response, from binaural_filter()
    listener: np.ndarray | None = None  # [3] world, the listener position used (inside the scene's box)
    source: np.ndarray | None = None  # [3] world, the source position used


@dataclass(frozen=True)
class GaussianCloud:
    """G for drawing: centres and colours."""

    means: np.ndarray  # [M, 3] float32 world
    rgb: np.ndarray  # [M, 3] float32 in [0, 1], from the SH DC term


def _readonly(a: np.ndarray) -> np.ndarray:
    a = np.ascontiguousarray(a)
    a.setflags(write=False)
    return a


def _position(value, what: str) -> np.ndarray:
    try:
        p = np.asarray(value, dtype=np.float64).reshape(3)
    except (TypeError, ValueError):
        raise ValueError(f"{what} must be 3 numbers (x, y, z), got {value!r}") from None
    if not np.all(np.isfinite(p)):
        raise ValueError(f"{what} must be finite, got {value!r}")
    return p


class SceneRenderer:
    """A trained AV-GS scene, ready to binauralise mono audio for any listener pose."""

    def __init__(
        self, ckpt: dict, device: str | torch.device = "cpu", path: str | Path | None = None,
        synthesis: SynthesisConfig | None = None, dtype: torch.dtype = torch.float32,
    ):
        from avgs.acoustics.points import AudioPoints

        self.path = Path(path) if path is not None else None
        self.device = torch.device(device)
        self.dtype = dtype
        "Precision of the networks (float32; others for measurement: CPUs without native support run them slower)."
        self.synthesis = synthesis or SynthesisConfig()
        "How :meth:`render` makes a waveform (:class:`~avgs.config.SynthesisConfig`; the binaural task's)."
        self.config = config_of(ckpt)
        self.stft = stft_of(ckpt)
        self.frame: SceneFrame = SceneFrame.from_dict(ckpt["frame"])
        self.history: list[dict] = list(ckpt.get("history", []))
        self.name: str = str(ckpt["scene"].get("name", ""))
        self.kind: Task = task_of(ckpt)
        "What the model was trained for (:mod:`avgs.tasks`)."
        pts = ckpt["audio_points"]
        fixed_k = ckpt.get("vicinity_k")  # set by pruning (avgs.render.prune): k kept from before
        points = AudioPoints(pts["X"], pts["alpha"])
        model = self.kind.part("model").build(points, self.config, self.stft, None if fixed_k is None else int(fixed_k))
        if model.field is not None:
            model.field.load_state_dict(ckpt["field"])
        model.binauralizer.load_state_dict(ckpt["binauralizer"])
        self.model = model.to(self.device, dtype).eval().requires_grad_(False)
        "The AV-GS model (G_a, F, B), for reading; :meth:`render` is the way to use it."
        self.cache = self.model.precompute()
        "Its pose-independent parts (:class:`~avgs.acoustics.model.ModelCache`)."
        self.source_normalised = ckpt["source"].detach().double().cpu().numpy().reshape(3)
        "The training source in the model's normalised frame."
        self._lock = threading.RLock()
        self._source_cache: tuple[tuple, tuple] | None = None  # (key, (C_S, idx))
        self._warned_one_source = False
        positions = ckpt.get("rir") or {}
        self._training_sources = (None if positions.get("sources") is None else _readonly(
            self.frame.to_world(positions["sources"].detach().double().cpu().numpy()).astype(np.float32)))

        X = pts["X"].detach().cpu().double().numpy()
        self._points = _readonly(self.frame.to_world(X).astype(np.float32))
        self._alpha = _readonly(pts["alpha"].detach().cpu().float().numpy())
        self._bounds = _readonly(ckpt["scene"]["bounds"].detach().cpu().float().numpy().reshape(2, 3))
        outline = ckpt["scene"].get("outline")
        self._outline = None if outline is None else _readonly(outline.detach().cpu().float().numpy().reshape(-1, 2, 3))
        self._gaussians = self._read_gaussians(ckpt.get("gaussians"))
        self.task_model: TaskModel = self.kind.part("renderer")(
            self.model, self.cache, self.stft, str(self.path or "this checkpoint"), self.source_context, self.frame,
            self._bounds)
        "The task's side of rendering (:class:`~avgs.render.tasks.TaskModel`), chosen from the checkpoint's task."

    @classmethod
    def load(
        cls, path: str | Path, device: str | torch.device = "cpu", synthesis: SynthesisConfig | None = None,
        dtype: torch.dtype = torch.float32,
    ) -> "SceneRenderer":
        """Load and validate ``scene.ckpt`` (``torch.load(weights_only=True)``)."""
        return cls(load_checkpoint(path, map_location="cpu"), device=device, path=path, synthesis=synthesis, dtype=dtype)

    def _read_gaussians(self, g: dict | None) -> GaussianCloud | None:
        if not g:
            return None
        means = self.frame.to_world(g["means"].detach().cpu().double().numpy().reshape(-1, 3)).astype(np.float32)
        if "sh" in g:
            dc = g["sh"].detach().cpu().float().reshape(len(means), -1, 3)[:, 0]  # [M, 3]
            rgb = np.clip(sh_to_rgb(dc).numpy(), 0.0, 1.0).astype(np.float32)
        else:
            rgb = np.full_like(means, 0.7)
        return GaussianCloud(_readonly(means), _readonly(rgb))

    # -- read-only scene data ---------------------------------------------------------

    @property
    def task(self) -> str:
        """The task's name (``binaural`` or ``rir``, :mod:`avgs.tasks`)."""
        return self.kind.name

    @property
    def points(self) -> np.ndarray:
        """Audio point positions ``[N, 3]`` float32, world (read-only)."""
        return self._points

    @property
    def alpha(self) -> np.ndarray:
        """Audio-guidance parameters ``[N, D]`` float32 (read-only)."""
        return self._alpha

    @property
    def source(self) -> np.ndarray:
        """The training source position ``[3]``, world."""
        return self.frame.to_world(self.source_normalised)

    @property
    def bounds(self) -> np.ndarray:
        """Scene box ``[2, 3]`` (min, max), world."""
        return self._bounds

    @property
    def gaussians(self) -> GaussianCloud | None:
        """G's centres and colours (world), or None when the checkpoint was saved without G."""
        return self._gaussians

    @property
    def outline(self) -> np.ndarray | None:
        """Room edges ``[K, 2, 3]`` world, or None (scenes without scene.json)."""
        return self._outline

    @property
    def rt60(self) -> np.ndarray | None:
        """The scene's learned reverberation time per frequency bin, seconds [F]; None without a reverberant tail."""
        tail = getattr(self.model.binauralizer, "reverb", None)
        return None if tail is None else tail.rt60().detach().float().cpu().numpy()

    @property
    def source_aware(self) -> bool:
        """Whether the model was trained on many source positions (the impulse-response task),
        so that a moved source is really heard; False for a one-source scene (the RWAVS task),
        where a moved source changes only the direction the ears hear it from."""
        return self.task_model.source_aware

    @property
    def training_sources(self) -> np.ndarray | None:
        """The source positions ``[S, 3]`` (world) of the responses a source-aware checkpoint was trained on; None otherwise."""
        return self._training_sources

    @property
    def sample_rate(self) -> int:
        return int(self.stft.sample_rate)

    @property
    def n_freq(self) -> int:
        return int(self.stft.n_freq)

    @property
    def vicinity_size(self) -> int:
        """k: points in each of the listener's and the source's vicinity."""
        return self.model.vicinity_k

    @property
    def post_conv(self):
        """B's time-frequency conv head (``--post-conv``), or None."""
        return self.model.binauralizer.post_conv

    @property
    def renders_beyond_filter(self) -> bool:
        """Whether :meth:`render` (with :attr:`synthesis`) differs from the pose's filter
        (:meth:`binaural_filter`) and streams: the binaural task's mid phase (the default) or
        filter's phase without iterations; never for a model of responses, whose render is the
        convolution with its response."""
        return self.task_model.beyond_filter(self.synthesis)

    # -- poses ------------------------------------------------------------------------

    @property
    def footprint(self):
        """Where positions may be: the room's floor plan and height inside the scene's box
        (:class:`avgs.data.floor_plan.Footprint`; the box alone without an outline)."""
        if getattr(self, "_footprint", None) is None:
            from avgs.data.floor_plan import Footprint

            self._footprint = Footprint.from_outline(self._outline, self._bounds)
        return self._footprint

    def inside(self, position, what: str = "listener") -> np.ndarray:
        """``position`` (world, 3 numbers) moved into the room (its floor plan and height, inside the
        scene's box: :func:`avgs.data.floor_plan.keep_inside`, as the explorer does) if outside
        it, with a :class:`PositionClamped` warning naming both positions."""
        from avgs.data.floor_plan import keep_inside

        p = _position(position, what)
        lo, hi = self._bounds.astype(np.float64)
        q = keep_inside(p, self.footprint, self._bounds)
        if not np.array_equal(p, q):
            warnings.warn(
                f"{what} ({', '.join(f'{v:.6g}' for v in p)}) is outside the scene "
                f"({', '.join(f'{v:.3g}' for v in lo)} .. {', '.join(f'{v:.3g}' for v in hi)}); "
                f"using ({', '.join(f'{v:.6g}' for v in q)})",
                PositionClamped, stacklevel=5,  # the caller of render(), masks() or stream()
            )
        return q

    def pose(self, listener, yaw: float, source=None) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """A public pose in the model's terms: (listener [1, 3], theta [1] radians, source [3]),
        normalised, in the model's dtype, both positions kept inside the scene (:meth:`inside`)."""
        p = self._pose(listener, yaw, source)
        return p.listener, p.theta, p.source

    def _pose(self, listener, yaw: float, source) -> Pose:
        listener_w = self.inside(listener, "listener")
        source_w = self.source if source is None else self.inside(source, "source")
        listener_n = self.frame.to_normalised(listener_w)
        source_n = self.source_normalised if source is None else self.frame.to_normalised(source_w)
        yaw = float(yaw)
        if not math.isfinite(yaw):
            raise ValueError(f"yaw must be a finite number of degrees, got {yaw!r}")
        lis = torch.tensor(listener_n[None], dtype=torch.float64)  # [1, 3]
        src = torch.tensor(source_n, dtype=torch.float64)  # [3]
        theta = signed_direction(lis, torch.tensor([math.radians(yaw)], dtype=torch.float64), src)  # [1]
        as_model = dict(device=self.device, dtype=self.dtype)
        return Pose(lis.to(**as_model), theta.to(**as_model), src.to(**as_model), yaw, listener_w, source_w)

    def source_context(self, source: torch.Tensor):
        """C_S and the source vicinity for ``source`` [3] (normalised), cached until the source moves."""
        key = tuple(source.tolist())
        cached = self._source_cache  # one read: another thread may replace it meanwhile
        if cached is None or cached[0] != key:
            cached = (key, self.model.source_context(source, self.cache))
            self._source_cache = cached
        return cached[1]

    def response(self, listener, yaw: float, source=None, impulse: bool = False) -> Response:
        """The task model's :class:`~avgs.render.tasks.Response` of a pose (tensors in the model's
        terms: B's masks for the binaural task, each ear's gains, the vicinity sets; ``impulse``:
        also the pose's filter). For tests and benchmarks; :meth:`masks` is the public result."""
        with self._lock, torch.inference_mode():
            return self._response(listener, yaw, source, impulse)[1]

    def _response(self, listener, yaw: float, source, impulse: bool = False, stop=None) -> tuple[Pose, Response]:
        """The pose and its task model's response (call under the lock and inference mode)."""
        pose = self._pose(listener, yaw, source)
        return pose, self.task_model.response(pose, impulse, stop)

    @staticmethod
    def _result(pose: Pose, r: Response, **extra) -> RenderResult:
        def np32(t):
            return None if t is None else t[0].float().cpu().numpy()

        m = r.masks
        return RenderResult(
            gains=np32(r.gains), listener_vicinity=r.listener_vicinity[0].cpu().numpy(),
            source_vicinity=r.source_vicinity.cpu().numpy(), theta=math.degrees(float(pose.theta[0])),
            mixture=None if m is None else np32(m.mixture), difference=None if m is None else np32(m.difference),
            reverb=None if m is None else np32(m.reverb), listener=pose.listener_world, source=pose.source_world, **extra,
        )

    def masks(self, listener, yaw: float, source=None) -> RenderResult:
        """A listener at ``listener`` (world) facing ``yaw`` degrees; ``source`` (world) defaults to
        the trained one: each ear's gains, the vicinity sets and B's masks, no waveform."""
        with self._lock, torch.inference_mode():
            return self._result(*self._response(listener, yaw, source))

    def binaural_filter(self, listener, yaw: float, source=None, stop: Callable[[], bool] | None = None) -> RenderResult:
        """The pose as a filter: :meth:`masks` and ``impulse``, its binaural impulse response ``[2, L]``
        (float32, channel 0 = left). Convolving a mono signal with it is :meth:`render` with
        ``method="filter"`` (the impulse-response task: with any synthesis), before the output's peak limit.

        Safe to call from several threads at once (the explorer's spare lane): it reads the model
        and the pose-independent cache only, so it does not take the renderer's lock. ``stop``: asked
        between its stages; True abandons the pose with :class:`avgs.threads.Stopped` (the
        explorer stops a move's filter that a newer pose has made stale)."""
        with torch.inference_mode():
            pose, r = self._response(listener, yaw, source, impulse=True, stop=stop)
            return self._result(pose, r, impulse=r.impulse)

    # -- sound ------------------------------------------------------------------------

    def render(
        self, listener, yaw: float, mono, source=None, magnitudes: bool = False, synthesis: SynthesisConfig | None = None
    ) -> RenderResult:
        """Binaural ``[2, T]`` float32 of ``mono [T]`` (any length >= 1) heard at ``listener`` facing ``yaw`` degrees.

        The binaural task makes the waveform as ``synthesis`` says, by default :attr:`synthesis`:
        the predicted ear magnitudes with one phase retrieved for their mid, with the filter's
        or the source's phase, or the input convolved with the pose's binaural impulse response
        (:meth:`binaural_filter`; :class:`avgs.config.SynthesisConfig`); the impulse-response task
        convolves with the predicted response. With ``magnitudes=True`` the result also holds the
        predicted ear magnitudes ``[2, F, N_t]`` (what AV-NeRF's MAGp scores; for responses, those
        of the output). ``source`` (world) moves the source; a one-source model says once
        (:class:`OneSourceModel`) that it hears only the new direction.
        """
        x, scale = unit_input(mono)  # processed at unit peak: no float32 under- or overflow
        synthesis = self.synthesis if synthesis is None else synthesis
        if source is not None and not self.source_aware:
            self.warn_one_source(source)
        with self._lock, torch.inference_mode():
            pose, r = self._response(listener, yaw, source)
            y, mags, top = self.task_model.render(r, x / np.float32(scale), synthesis, magnitudes)
        if not math.isfinite(top):
            raise ValueError(f"{self.path or 'this checkpoint'}: the render at listener {listener!r} is not finite")
        limit = 10.0 ** (HEADROOM_DB / 20.0)  # the output's peak, relative to the input's (1 here)
        if top > limit:
            warnings.warn(f"the render peaks {20 * math.log10(top):.1f} dB over the input; limited to the "
                          f"{HEADROOM_DB:g} dB headroom", HeadroomLimited, stacklevel=2)
            y *= np.float32(limit / top)
        y *= np.float32(scale)
        if mags is not None:
            mags = np.ascontiguousarray((mags * scale).astype(np.float32))
        return self._result(pose, r, binaural=y, magnitudes=mags)

    def warn_one_source(self, source) -> None:
        """Say once per renderer that a one-source model hears a moved source only by its direction."""
        if self._warned_one_source:
            return
        p = _position(source, "source")
        if np.allclose(p, self.source, rtol=0.0, atol=1e-6 * max(1.0, float(np.abs(self.source).max()))):
            return
        self._warned_one_source = True
        warnings.warn(
            f"{self.path or 'this checkpoint'} was trained with one source position (the binaural task): a moved "
            "source changes only the direction the ears hear it from, not its level or the room's response to it "
            "(train with 'avgs train --task rir' for a model of any source position)", OneSourceModel, stacklevel=3)

    def reach_frames(self, synthesis: SynthesisConfig | None = None, n_frames: int | None = None,
                     decay: torch.Tensor | None = None) -> int:
        """STFT frames of input before (or after) an output frame that it depends on, with
        ``synthesis`` (default: :attr:`synthesis`): a tail to its decay (causally; at most
        ``n_frames``), the STFT window, the phase iterations' reach (the window's per iteration)
        and a conv head's context. ``decay``: a tail decay [F] other than the model's."""
        return self.task_model.reach_frames(self.synthesis if synthesis is None else synthesis, n_frames, decay)

    def stream(self, listener, yaw: float, source=None, block_frames: int | None = None) -> BlockStream:
        """A stream for this pose: feed mono blocks of any size to ``process``, then ``flush()``;
        the concatenated output equals :meth:`render` of the whole input (float rounding),
        ``latency`` samples behind at most.

        The binaural task: with the default synthesis (phase ``mid``) a
        :class:`avgs.render.mid_phase_stream.MidPhaseStream` (0.39 s behind: the phase
        retrieval's reach and ``block_frames`` frames, default
        :data:`~avgs.render.mid_phase_stream.BLOCK_FRAMES`: more is less work per sample and more
        delay), with the filter's phase and no iterations a :class:`avgs.render.streaming.BinauralStream`
        (29 ms), with ``method="filter"`` a :class:`avgs.acoustics.convolution.ConvolutionStream`
        (one block), as the impulse-response task always. Iterations from the source's or the
        filter's phase need the whole signal: such renderers do not stream. Each block is processed
        at a power-of-two scale fixed by the first block that is not silent, as :meth:`render`
        processes its input at unit peak (:class:`avgs.render.unit_scale_stream.UnitScaleStream`):
        an input peaking at 1e30 or 1e-25 streams as a unit one does; a block 2^40 louder than that
        first one is refused with ValueError.
        """
        with self._lock, torch.inference_mode():
            _, r = self._response(listener, yaw, source)
            return UnitScaleStream(self.task_model.stream(r, self.synthesis, block_frames))

    def move_stream(self, stream: BlockStream, listener, yaw: float, source=None) -> RenderResult:
        """Switch a :meth:`stream` of this scene to another pose from its next block (crossfaded,
        no click; safe from another thread than the one feeding it). Returns the new pose's
        :meth:`binaural_filter`."""
        with self._lock, torch.inference_mode():
            pose, r = self._response(listener, yaw, source, impulse=True)
            self.task_model.move_stream(stream, r)
            return self._result(pose, r, impulse=r.impulse)

    def predict_responses(self, source, receiver, yaw) -> np.ndarray:
        """Predicted binaural responses ``[N, 2, L]`` float32 (channel 0 = left), batched (a source-aware model).

        source, receiver: ``[N, 3]`` in the model's **normalised** frame (the RIR scene's own
        coordinates, ``avgs.data.rir``); yaw: ``[N]`` degrees. No clamping and no headroom
        limit: the model's answer as it is, what ``avgs eval --task rir`` scores.
        """
        src = np.asarray(source, dtype=np.float64).reshape(-1, 3)
        rec = np.asarray(receiver, dtype=np.float64).reshape(-1, 3)
        yaws = np.asarray(yaw, dtype=np.float64).reshape(-1)
        if not (len(src) == len(rec) == len(yaws)):
            raise ValueError(f"source {src.shape}, receiver {rec.shape} and yaw {yaws.shape} must have the same length N")
        if not (np.all(np.isfinite(src)) and np.all(np.isfinite(rec)) and np.all(np.isfinite(yaws))):
            raise ValueError("source, receiver and yaw must be finite")
        with self._lock, torch.inference_mode():
            return self.task_model.predict_responses(src, rec, yaws)

    def __repr__(self) -> str:
        return f"SceneRenderer({self.name!r}: {len(self._points)} audio points, {self.sample_rate} Hz)"
