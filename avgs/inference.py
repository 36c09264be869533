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

Bounded sound: the listener and the source are kept inside the scene's box
(:attr:`SceneRenderer.bounds`, which holds its audio points, G, the training poses and the
source), with a :class:`PositionClamped` warning naming the position asked for and the one
used; the ear filter of a pose never gains more than :data:`HEADROOM_DB` over the input in
any frequency bin (masks scaled down otherwise, with a :class:`HeadroomLimited` warning),
and a render's peak never exceeds the input's peak by more than that either. Non-finite
masks or output raise ValueError naming the checkpoint. Inputs are processed at unit peak
and scaled back, so any finite input (1e-30 or 1e30) renders without underflow or overflow.

Thread safety: :meth:`render` and :meth:`masks` serialise on an internal lock, so one
worker thread may render while another thread reads the point arrays (read-only numpy).

Two tasks (:attr:`SceneRenderer.task`, the checkpoint's ``task``):

- ``binaural`` (RWAVS): one source position in training. A moved source (``source=``)
  changes only the direction the ears hear it from (theta) and C_S; the model never heard a
  source elsewhere, so its level and room response do not follow. :meth:`render` says so
  once per renderer (:class:`OneSourceModel` warning); the explorer keeps the source fixed.
- ``rir`` (impulse responses, ``avgs train --task rir``): trained on many source positions,
  so the source is an input (:attr:`SceneRenderer.source_aware`). A pose's filter is the
  predicted binaural response itself (:class:`~avgs.acoustics.rir_model.RIRModel`: log
  magnitudes, and a waveform by ``RIRConfig.phase``); :meth:`render` convolves the input
  with it (FFT; ``synthesis`` does not apply), :meth:`stream` is a
  :class:`~avgs.acoustics.convolution.ConvolutionStream`, :meth:`masks` (and the mixture /
  difference of every result) hold the response's long-term ear gains, so the propagation
  map and the explorer's colours work unchanged; :meth:`predict_responses` is the batched
  path ``avgs eval --task rir`` scores. Continuous yaw: the network reads the facing
  through cos / sin of the yaw and of the direction to the source
  (:mod:`avgs.acoustics.rir_binauralizer`); the yaw is taken modulo 360 first, so yaw 360
  and yaw 0 give the same response exactly, and between the four trained facings the
  network interpolates smoothly. A response is kept within :data:`HEADROOM_DB` as a
  binaural filter is.
"""

from __future__ import annotations

import math
import threading
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from avgs import dsp
from avgs.data.frame import signed_direction
from avgs.acoustics.impulse_response import TailShaper, convolve, impulse_response
from avgs.acoustics.synthesis import (Masks, SourceParts, ear_gains, ear_spectrogram, mid_phase_waveform, source_parts,
                                      unit_phase, waveform)
from avgs.checkpoint import config_of, load_checkpoint, stft_of
from avgs.config import SynthesisConfig
from avgs.data.frame import SceneFrame
from avgs.gaussians.sh import sh_to_rgb

HEADROOM_DB = 24.0
"Most a pose's ear filter may gain over the input, in any frequency bin, and a render's peak over the input's peak (dB)."


RENDER_BLOCK_FRAMES = 2048
"Frames per block when a long input is rendered (about 12 s at AV-NeRF's hop): memory stays bounded."

MAX_REACH_FRAMES = 1 << 14
"The tail's reach counted at most this many frames (95 s at AV-NeRF's hop) when no input length bounds it."


class PositionClamped(UserWarning):
    """A listener or source outside the scene's box was moved onto its edge."""


class HeadroomLimited(UserWarning):
    """A pose's ear filter gained more than HEADROOM_DB and was scaled down."""


class OneSourceModel(UserWarning):
    """A moved source was asked of a model trained with one source position (the binaural task)."""


RESPONSE_CHUNK = 32
"Poses per batch of :meth:`SceneRenderer.predict_responses`."


@dataclass(frozen=True)
class RenderResult:
    """What one listener pose gives: the masks, the vicinity sets behind them and, from
    :meth:`SceneRenderer.render`, the binaural waveform."""

    mixture: np.ndarray  # [F] float32
    difference: np.ndarray  # [F] float32 in (-1, 1); > 0 means left louder
    listener_vicinity: np.ndarray  # [k] int64 indices into SceneRenderer.points
    source_vicinity: np.ndarray  # [k] int64 indices into SceneRenderer.points
    theta: float  # degrees, direction to the source, positive = source on the listener's left
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


def _peak(a: np.ndarray, chunk: int = 1 << 20) -> float:
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
        from avgs.acoustics.model import AVGSModel
        from avgs.acoustics.points import AudioPoints
        from avgs.acoustics.rir_model import RIRModel

        self.path = Path(path) if path is not None else None
        self.device = torch.device(device)
        self.dtype = dtype
        "Precision of the networks (float32; others for measurement: CPUs without native support run them slower)."
        self.synthesis = synthesis or SynthesisConfig()
        "How :meth:`render` makes a waveform (:class:`~avgs.config.SynthesisConfig`)."
        self.config = config_of(ckpt)
        self.stft = stft_of(ckpt)
        self.frame: SceneFrame = SceneFrame.from_dict(ckpt["frame"])
        self.history: list[dict] = list(ckpt.get("history", []))
        self.name: str = str(ckpt["scene"].get("name", ""))
        self.task: str = str(ckpt.get("task", "binaural"))
        "What the model was trained for: ``binaural`` (RWAVS: one source) or ``rir`` (impulse responses, sources anywhere)."
        pts = ckpt["audio_points"]
        fixed_k = ckpt.get("vicinity_k")  # set by pruning (avgs.prune): k kept from before
        points = AudioPoints(pts["X"], pts["alpha"])
        k = None if fixed_k is None else int(fixed_k)
        if self.task == "rir":
            model = RIRModel(points, self.config.acoustic, self.config.rir, self.stft, vicinity_k=k)
        else:
            model = AVGSModel(points, self.config.acoustic, self.stft, vicinity_k=k)
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
        self._clip: tuple[np.ndarray, torch.Tensor | None, SourceParts] | None = None  # (input, decay, its parts)
        self._warned_one_source = False
        rir = ckpt.get("rir") or {}
        self._training_sources = (None if rir.get("sources") is None else
                                  _readonly(self.frame.to_world(rir["sources"].detach().double().cpu().numpy()).astype(np.float32)))
        tail = self.model.binauralizer.reverb
        self._tail = None if tail is None else TailShaper(tail.decay().detach(), self.stft)
        "The reverberant tail's decaying noise (scene-wide), shaped per pose by :meth:`binaural_filter`."

        X = pts["X"].detach().cpu().double().numpy()
        self._points = _readonly(self.frame.to_world(X).astype(np.float32))
        self._alpha = _readonly(pts["alpha"].detach().cpu().float().numpy())
        self._bounds = _readonly(ckpt["scene"]["bounds"].detach().cpu().float().numpy().reshape(2, 3))
        outline = ckpt["scene"].get("outline")
        self._outline = None if outline is None else _readonly(outline.detach().cpu().float().numpy().reshape(-1, 2, 3))
        self._gaussians = self._read_gaussians(ckpt.get("gaussians"))

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
        tail = self.model.binauralizer.reverb
        return None if tail is None else tail.rt60().detach().float().cpu().numpy()

    @property
    def source_aware(self) -> bool:
        """Whether the model was trained on many source positions (the impulse-response task),
        so that a moved source is really heard; False for a one-source scene (the RWAVS task),
        where a moved source changes only the direction the ears hear it from."""
        return self.task == "rir"

    @property
    def training_sources(self) -> np.ndarray | None:
        """The source positions ``[S, 3]`` (world) of the responses an RIR checkpoint was trained on; None otherwise."""
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

    # -- rendering --------------------------------------------------------------------

    def inside(self, position, what: str = "listener") -> np.ndarray:
        """``position`` (world, 3 numbers) moved onto the scene's box if outside it, with a
        :class:`PositionClamped` warning naming both positions."""
        p = _position(position, what)
        lo, hi = self._bounds.astype(np.float64)
        q = np.clip(p, lo, hi)
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
        return self._pose(listener, yaw, source)[0]

    def _pose(self, listener, yaw: float, source):
        """(:meth:`pose`, (listener, source) world positions used [3] float64)."""
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
        return (lis.to(**as_model), theta.to(**as_model), src.to(**as_model)), (listener_w, source_w)

    def source_context(self, source: torch.Tensor):
        """C_S and the source vicinity for ``source`` [3] (normalised), cached until the source moves."""
        key = tuple(source.tolist())
        if self._source_cache is None or self._source_cache[0] != key:
            self._source_cache = (key, self.model.source_context(source, self.cache))
        return self._source_cache[1]

    def _masks(self, listener, yaw: float, source) -> tuple[Masks, float, np.ndarray, np.ndarray]:
        """(masks within the headroom, theta radians, listener and source used [3], world)."""
        if self.task == "rir":
            m, _, theta, listener_w, source_w = self._rir_pose(listener, yaw, source)
            return m, theta, listener_w, source_w
        (lis, theta, src), (listener_w, source_w) = self._pose(listener, yaw, source)
        masks = self.model.masks(lis, theta, src, self.source_context(src), self.cache)
        tensors = [t for t in (masks.mixture, masks.difference, masks.reverb, masks.decay) if t is not None]
        if not all(bool(torch.isfinite(t).all()) for t in tensors):
            raise ValueError(f"{self.path or 'this checkpoint'}: the model gives NaN or Inf masks at listener "
                             f"{listener!r}, yaw {yaw!r}: its weights are not usable")
        return self._within_headroom(masks), float(theta[0]), listener_w, source_w

    def _rir_pose(self, listener, yaw: float, source):
        """Task rir: (masks of the response's ear gains, response [2, L] float32, both within the headroom;
        theta radians; listener and source used [3], world). Call under the lock and inference mode."""
        from avgs.acoustics.rir_model import ear_transfer, masks_of_gains, response_waveform

        (lis, theta, src), (listener_w, source_w) = self._pose(listener, yaw, source)
        yaw_rad = torch.tensor([math.radians(float(yaw) % 360.0)], dtype=torch.float64).to(self.device, self.dtype)  # [1]
        log_mag, lis_idx, src_idx = self.model.log_magnitudes(lis, yaw_rad, src, self.cache, self.source_context(src))
        mag = self.model.magnitudes(log_mag.float()).cpu()  # [1, 2, F, N]
        rc = self.config.rir
        h = response_waveform(mag, rc.length, self.stft, rc.phase, rc.phase_iterations)[0]  # [2, L]
        gains = ear_transfer(mag, self.stft)[0].double()  # [2, F]
        if not (bool(torch.isfinite(h).all()) and bool(torch.isfinite(gains).all())):
            raise ValueError(f"{self.path or 'this checkpoint'}: the model gives a NaN or Inf response at listener "
                             f"{listener!r}, yaw {yaw!r}: its weights are not usable")
        peak_db = 10.0 * math.log10(max(float(gains.square().max()), 1e-300))
        if peak_db > HEADROOM_DB:
            c = 10.0 ** ((HEADROOM_DB - peak_db) / 20.0)
            warnings.warn(f"the response at this pose gains {peak_db:.1f} dB in its loudest bin; scaled to "
                          f"the {HEADROOM_DB:g} dB headroom", HeadroomLimited, stacklevel=4)
            h, gains = h * c, gains * c
        mixture, difference = masks_of_gains(gains[None])  # [1, F] each
        m = Masks(mixture, difference, listener_vicinity=lis_idx, source_vicinity=src_idx[0])
        return m, np.ascontiguousarray(h.numpy(), dtype=np.float32), float(theta[0]), listener_w, source_w

    def predict_responses(self, source, receiver, yaw) -> np.ndarray:
        """Task rir: predicted binaural responses ``[N, 2, L]`` float32 (channel 0 = left), batched.

        source, receiver: ``[N, 3]`` in the model's **normalised** frame (the RIR scene's own
        coordinates, ``avgs.data.rir``); yaw: ``[N]`` degrees. No clamping and no headroom
        limit: the model's answer as it is, what ``avgs eval --task rir`` scores.
        """
        from avgs.acoustics.rir_model import response_waveform

        if self.task != "rir":
            raise ValueError(f"{self.path or 'this checkpoint'}: trained for the {self.task} task; "
                             "impulse responses need a checkpoint of 'avgs train --task rir'")
        src = np.asarray(source, dtype=np.float64).reshape(-1, 3)
        rec = np.asarray(receiver, dtype=np.float64).reshape(-1, 3)
        yaws = np.asarray(yaw, dtype=np.float64).reshape(-1)
        if not (len(src) == len(rec) == len(yaws)):
            raise ValueError(f"source {src.shape}, receiver {rec.shape} and yaw {yaws.shape} must have the same length N")
        if not (np.all(np.isfinite(src)) and np.all(np.isfinite(rec)) and np.all(np.isfinite(yaws))):
            raise ValueError("source, receiver and yaw must be finite")
        rc = self.config.rir
        out = np.empty((len(src), 2, rc.length), dtype=np.float32)
        as_model = dict(device=self.device, dtype=self.dtype)
        with self._lock, torch.inference_mode():
            for i in range(0, len(src), RESPONSE_CHUNK):
                sl = slice(i, i + RESPONSE_CHUNK)
                log_mag, _, _ = self.model.log_magnitudes(
                    torch.from_numpy(rec[sl]).to(**as_model), torch.from_numpy(np.radians(yaws[sl] % 360.0)).to(**as_model),
                    torch.from_numpy(src[sl]).to(**as_model), self.cache)
                h = response_waveform(self.model.magnitudes(log_mag.float()).cpu(), rc.length, self.stft, rc.phase,
                                      rc.phase_iterations)
                out[sl] = h.numpy()
        if not np.all(np.isfinite(out)):
            raise ValueError(f"{self.path or 'this checkpoint'}: the model gives NaN or Inf responses")
        return out

    def _within_headroom(self, m: Masks) -> Masks:
        """The masks, scaled down when the pose's ear filter would gain more than HEADROOM_DB in a bin.

        A bin's energy gain is at most ``g_ear^2 + r_ear^2 w / (1 - w)`` (direct gain, plus the
        tail's geometric sum of decayed power, w its decay per frame); scaling the mixture and
        reverberant gains by c scales it by c^2.
        """
        power = ear_gains(m.mixture, m.difference).double().square()  # [1, 2, F]
        if m.reverb is not None:
            w = m.decay.double().clamp(max=1.0 - 1e-9)
            power = power + m.reverb.double().square() * (w / (1.0 - w))
        peak_db = 10.0 * math.log10(max(float(power.max()), 1e-300))
        if peak_db <= HEADROOM_DB:
            return m
        c = 10.0 ** ((HEADROOM_DB - peak_db) / 20.0)
        warnings.warn(f"the ear filter at this pose gains {peak_db:.1f} dB in its loudest bin; scaled to "
                      f"the {HEADROOM_DB:g} dB headroom", HeadroomLimited, stacklevel=4)  # the caller of render() etc.
        reverb = None if m.reverb is None else m.reverb * c
        return Masks(m.mixture * c, m.difference, reverb, m.decay, m.listener_vicinity, m.source_vicinity)

    @staticmethod
    def _result(m: Masks, theta: float, listener: np.ndarray, source: np.ndarray, **extra) -> RenderResult:
        def np32(t):
            return None if t is None else t[0].float().cpu().numpy()

        return RenderResult(
            mixture=np32(m.mixture), difference=np32(m.difference), reverb=np32(m.reverb),
            listener_vicinity=m.listener_vicinity[0].cpu().numpy(), source_vicinity=m.source_vicinity.cpu().numpy(),
            theta=math.degrees(theta), listener=listener, source=source, **extra,
        )

    def masks(self, listener, yaw: float, source=None) -> RenderResult:
        """Masks for a listener at ``listener`` (world) facing ``yaw`` degrees; ``source`` (world)
        defaults to the trained one. ``binaural`` is None."""
        with self._lock, torch.inference_mode():
            m, theta, lis, src = self._masks(listener, yaw, source)
            return self._result(m, theta, lis, src)

    def render(
        self, listener, yaw: float, mono, source=None, magnitudes: bool = False, synthesis: SynthesisConfig | None = None
    ) -> RenderResult:
        """Binaural ``[2, T]`` float32 of ``mono [T]`` (any length >= 1) heard at ``listener`` facing ``yaw`` degrees.

        The waveform is made as ``synthesis`` says, by default :attr:`synthesis`: the
        predicted ear magnitudes with one phase retrieved for their mid, with the filter's
        or the source's phase, or the input convolved with the pose's binaural impulse
        response (:meth:`binaural_filter`; :class:`avgs.config.SynthesisConfig`). With ``magnitudes=True`` the result also holds
        the predicted ear magnitudes ``[2, F, N_t]`` (what AV-NeRF's MAGp scores).

        ``source`` (world) moves the source. Task rir: the input convolved (FFT) with the
        predicted binaural response for this listener, yaw and source (:meth:`binaural_filter`;
        ``synthesis`` does not apply; ``magnitudes``: those of the output). Task binaural: the
        model knows one source position, so a moved source changes only the direction; said
        once per renderer by a :class:`OneSourceModel` warning.
        """
        x = np.asarray(mono, dtype=np.float32)
        if x.ndim == 2 and 1 in x.shape:
            x = x.reshape(-1)
        if x.ndim != 1 or x.size == 0:
            raise ValueError(f"mono must be a 1-D signal with at least one sample, got shape {x.shape}")
        peak = _peak(x)
        if not math.isfinite(peak):
            raise ValueError("mono holds NaN or Inf samples")
        scale = peak if peak > 0 else 1.0  # processed at unit peak: no float32 under- or overflow
        synthesis = self.synthesis if synthesis is None else synthesis
        if source is not None and not self.source_aware:
            self._warn_one_source(source)
        with self._lock, torch.inference_mode():
            if self.task == "rir":
                m, h, theta, lis, src = self._rir_pose(listener, yaw, source)
                y = convolve(torch.from_numpy(x / np.float32(scale)), torch.from_numpy(h)).numpy()  # [2, T]
                top = _peak(y)
                mags = None
                if magnitudes and math.isfinite(top):
                    mags = np.ascontiguousarray((dsp.magnitude(torch.from_numpy(y), self.stft).double().numpy()
                                                 * scale).astype(np.float32))
            else:
                m, theta, lis, src = self._masks(listener, yaw, source)
                y, mags, top = self._synthesise(x, scale, m, synthesis, magnitudes)
        if not math.isfinite(top):
            raise ValueError(f"{self.path or 'this checkpoint'}: the render at listener {listener!r} is not finite")
        limit = 10.0 ** (HEADROOM_DB / 20.0)  # the output's peak, relative to the input's (1 here)
        if top > limit:
            warnings.warn(f"the render peaks {20 * math.log10(top):.1f} dB over the input; limited to the "
                          f"{HEADROOM_DB:g} dB headroom", HeadroomLimited, stacklevel=2)
            y *= np.float32(limit / top)
        y *= np.float32(scale)
        return self._result(m, theta, lis, src, binaural=y, magnitudes=mags)

    def _warn_one_source(self, source) -> None:
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

    def _synthesise(self, x: np.ndarray, scale: float, m: Masks, synthesis: SynthesisConfig, magnitudes: bool = False,
                    impulse: np.ndarray | None = None):
        """(binaural [2, T] float32 of ``x / scale``, predicted magnitudes [2, F, N_t] times ``scale`` or
        None, the output's peak): the synthesis of one pose's masks ``m``; ``impulse``: its
        response when already made (:meth:`_impulse`)."""
        m32 = m.to(torch.float32)
        y = np.empty((2, x.size), dtype=np.float32)  # [2, T]
        mags, top = None, 0.0
        mid = synthesis.method == "spectrogram" and synthesis.phase == "mid" and self.post_conv is None
        filtered = None  # [2, T] the input through the pose's filter, when the synthesis uses it
        if self.post_conv is None and (synthesis.method == "filter" or synthesis.phase == "filter"):
            h = self._impulse(m) if impulse is None else impulse
            filtered = convolve(torch.from_numpy(x) / np.float32(scale), torch.from_numpy(h))
        if synthesis.method == "filter" and filtered is not None:
            y[:] = filtered.numpy()
            top = _peak(y)
            pieces = [(0, x.size, 0, x.size)] if magnitudes else []  # the predicted magnitudes only
        else:
            pieces = self._pieces(x.size, m32, synthesis, whole=magnitudes)
        for lo, hi, start, stop in pieces:
            piece = torch.from_numpy(x[start:stop] / np.float32(scale)).to(self.device)  # [stop - start]
            if mid:  # one retrieved phase for both ears (the default)
                kept = stop - start == x.size and dsp.n_frames(x.size, self.stft) <= RENDER_BLOCK_FRAMES  # a clip, not a file
                parts = self._clip_parts(x, piece, m32.decay) if kept else None
                spec = None if parts is not None else dsp.stft(piece[None], self.stft)
                wave, ears = mid_phase_waveform(spec, m32, stop - start, self.stft, synthesis,
                                                start // self.stft.hop_length, parts)
                if magnitudes:
                    mags = np.ascontiguousarray((ears[0].double().cpu().numpy() * scale).astype(np.float32))
                y[:, lo:hi] = wave[0, :, lo - start : hi - start].float().cpu().numpy()
                top = max(top, _peak(y[:, lo:hi]))
                continue
            if filtered is None:  # the source's phase
                ears = ear_spectrogram(dsp.stft(piece[None], self.stft), m32, self.post_conv,
                                       start // self.stft.hop_length)  # [1, 2, F, N]
                target = ears[0].abs() if magnitudes else None
            else:  # the predicted magnitudes with the filter's phase: the input and its filtered copy in one STFT
                both = torch.cat([piece[None], filtered[:, start:stop].to(self.device)])  # [3, stop - start]
                spec = dsp.stft(both, self.stft)  # [3, F, N]
                ears = ear_spectrogram(spec[:1], m32, phase=unit_phase(spec[1:])[None])  # [1, 2, F, N]
                target = ears[0].abs() if magnitudes else None
            if magnitudes:
                mags = np.ascontiguousarray((target.double().cpu().numpy() * scale).astype(np.float32))
            if synthesis.method == "filter" and filtered is not None:
                break
            wave = waveform(ears, stop - start, self.stft, synthesis)[0]  # [2, stop - start]
            y[:, lo:hi] = wave[:, lo - start : hi - start].float().cpu().numpy()
            top = max(top, _peak(y[:, lo:hi]))  # NaN once any sample is not finite
            del piece, ears, wave
        return y, mags, top

    def _clip_parts(self, x: np.ndarray, unit: torch.Tensor, decay: torch.Tensor | None) -> SourceParts:
        """:func:`~avgs.acoustics.synthesis.source_parts` of the whole input ``x`` (``unit``: it at unit
        peak, [T]), kept for the next render of the same clip: the explorer and the benchmarks
        hear one clip from many poses, and only the pose's part of the synthesis changes. One
        clip of at most RENDER_BLOCK_FRAMES frames is kept (about 12 s, 11 MB)."""
        kept = self._clip
        if (kept is not None and kept[0].shape == x.shape and np.array_equal(kept[0], x)
                and (kept[1] is None) == (decay is None) and (decay is None or torch.equal(kept[1], decay))):
            return kept[2]
        parts = source_parts(dsp.stft(unit[None], self.stft), decay)
        self._clip = (x.copy(), None if decay is None else decay.clone(), parts)
        return parts

    def _impulse(self, m: Masks) -> np.ndarray:
        """The binaural impulse response ``[2, L]`` float32 of one pose's masks."""
        return impulse_response(m, self.stft, self._tail)[0].float().numpy()

    def binaural_filter(self, listener, yaw: float, source=None) -> RenderResult:
        """The pose as a filter: masks and ``impulse``, its binaural impulse response ``[2, L]``
        (float32, channel 0 = left; :mod:`avgs.acoustics.impulse_response`).

        Convolving a mono signal with it is :meth:`render` with the default synthesis, before
        the output's peak limit. Positions are kept inside the scene and the filter within
        the headroom, as for :meth:`render`.
        """
        if self.post_conv is not None:
            raise ValueError(f"{self.path or 'this checkpoint'}: trained with the time-frequency conv head "
                             "(--post-conv), whose output depends on the input: it is not a filter")
        with self._lock, torch.inference_mode():
            if self.task == "rir":  # the predicted response is the filter
                m, h, theta, lis, src = self._rir_pose(listener, yaw, source)
                return self._result(m, theta, lis, src, impulse=h)
            m, theta, lis, src = self._masks(listener, yaw, source)
            return self._result(m, theta, lis, src, impulse=self._impulse(m))

    def _pieces(self, length: int, masks: Masks, synthesis: SynthesisConfig, whole: bool = False):
        """Yield (lo, hi, start, stop): output samples [lo, hi) are those of the input's samples
        [start, stop), a stretch with enough margin for the result to equal one pass.

        The filter of a pose is fixed, and output frame t depends only on input frames within
        a reach: the STFT window (a frame either side), the tail (its decay to NEGLIGIBLE_POWER,
        causally), the phase iterations (the window's reach per iteration) and the conv head.
        So a long input is rendered in blocks of RENDER_BLOCK_FRAMES with that reach as margin:
        memory stays bounded by the block, and the result equals one pass to float rounding.
        """
        hop = self.stft.hop_length
        n = dsp.n_frames(length, self.stft)
        margin = self.reach_frames(synthesis, n, masks.decay)
        block = RENDER_BLOCK_FRAMES
        if whole or n <= block + 2 * margin:
            yield 0, length, 0, length
            return
        for s in range(0, n, block):
            e = min(n, s + block)
            a, b = max(0, s - margin), min(n, e + margin)
            start, stop = a * hop, (length if b == n else b * hop)  # centred frames a .. b-1 of the piece
            yield s * hop, (length if e == n else e * hop), start, stop

    def reach_frames(self, synthesis: SynthesisConfig | None = None, n_frames: int | None = None,
                     decay: torch.Tensor | None = None) -> int:
        """STFT frames of input before (or after) an output frame that it depends on, with
        ``synthesis`` (default: :attr:`synthesis`): the tail to its decay to NEGLIGIBLE_POWER
        (causally; at most ``n_frames``), the STFT window, the phase iterations' reach (the window's
        per iteration) and the conv head's context. ``decay``: the scene's tail decay [F] (default:
        the model's; binaural task)."""
        from avgs.acoustics.post_conv import CONTEXT_FRAMES
        from avgs.acoustics.reverb_tail import tail_length

        synthesis = self.synthesis if synthesis is None else synthesis
        if decay is None and self.task != "rir" and self.model.binauralizer.reverb is not None:
            decay = self.model.binauralizer.reverb.decay().detach()
        tail = 0 if decay is None else tail_length(decay, MAX_REACH_FRAMES if n_frames is None else n_frames)
        window = -(-self.stft.n_fft // self.stft.hop_length)  # frames one window overlaps on each side, plus one
        return tail + window * (synthesis.iterations + 2) + (CONTEXT_FRAMES if self.post_conv is not None else 0)

    @property
    def post_conv(self):
        """B's time-frequency conv head (``--post-conv``), or None for the mask model."""
        return self.model.binauralizer.post_conv

    def stream(self, listener, yaw: float, source=None, block_frames: int | None = None):
        """A stream for this pose: feed mono blocks of any size to ``process``, then ``flush()``;
        the concatenated output equals :meth:`render` of the whole input (float rounding),
        ``latency`` samples behind at most.

        With the default synthesis (phase ``mid``) a :class:`avgs.mid_phase_stream.MidPhaseStream`
        (0.39 s behind: the phase retrieval's reach and ``block_frames`` frames, default
        :data:`~avgs.mid_phase_stream.BLOCK_FRAMES`: more is less work per sample and more
        delay), with the filter's phase and no iterations
        a :class:`avgs.streaming.BinauralStream` (29 ms), with ``method="filter"`` a
        :class:`avgs.acoustics.convolution.ConvolutionStream` (one block). Iterations from the
        source's or the filter's phase need the whole signal: such renderers do not stream.
        """
        from avgs.acoustics.convolution import ConvolutionStream
        from avgs.mid_phase_stream import MidPhaseStream
        from avgs.streaming import BinauralStream

        where = self.path or "this checkpoint"
        if self.post_conv is not None:
            raise ValueError(
                f"{where}: trained with the time-frequency conv head (--post-conv), whose "
                "output depends on neighbouring frames; block streaming supports only the mask model. "
                "Use render() on the whole signal."
            )
        if self.task == "rir":  # the predicted response is the filter: convolution, whatever the synthesis
            with self._lock, torch.inference_mode():
                return ConvolutionStream(self._rir_pose(listener, yaw, source)[1])
        s = self.synthesis
        if s.method == "spectrogram" and s.phase != "mid" and s.iterations > 0:
            raise ValueError(f"{where}: a stream cannot do {s.iterations} phase iterations from the {s.phase}'s "
                             "phase (they need the whole signal); stream with SynthesisConfig() or method='filter'")
        if s.method == "spectrogram" and s.phase == "source":
            raise ValueError(f"{where}: the source's phase does not stream; stream with SynthesisConfig() or method='filter'")
        with self._lock, torch.inference_mode():
            m, *_ = self._masks(listener, yaw, source)
            if s.method == "spectrogram" and s.phase == "mid":
                return MidPhaseStream(m, self.stft, s, **({} if block_frames is None else {"block_frames": block_frames}))
            impulse = self._impulse(m)
            return ConvolutionStream(impulse) if s.method == "filter" else BinauralStream(m.to(torch.float32), impulse, self.stft)

    def move_stream(self, stream, listener, yaw: float, source=None) -> RenderResult:
        """Switch a :meth:`stream` of this scene to another pose from its next block (crossfaded,
        no click; safe from another thread than the one feeding it). Returns the new pose's
        masks and ``impulse``, as :meth:`binaural_filter`."""
        with self._lock, torch.inference_mode():
            if self.task == "rir":
                m, impulse, theta, lis, src = self._rir_pose(listener, yaw, source)
            else:
                m, theta, lis, src = self._masks(listener, yaw, source)
                impulse = self._impulse(m)
            stream.set_pose(m.to(torch.float32), impulse)
            return self._result(m, theta, lis, src, impulse=impulse)

    def __repr__(self) -> str:
        return f"SceneRenderer({self.name!r}: {len(self._points)} audio points, {self.sample_rate} Hz)"
