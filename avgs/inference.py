"""``SceneRenderer``: the one object the CLI, the benchmarks and the viewer use.

Public coordinates are the scene's **world** frame, yaw in **degrees** counter-clockwise
from +x (ARCHITECTURE.md); the conversion to the model's normalised frame and radians
happens here and nowhere else. Rendering runs the model's own code
(:meth:`AVGSModel.masks <avgs.acoustics.model.AVGSModel.masks>`) under
``torch.inference_mode`` with its caches: the pose-independent parts of F and B
(:meth:`~avgs.acoustics.model.AVGSModel.precompute`) and the source context C_S, kept
until the source moves. The masks are time-invariant, so any input length costs one STFT,
one multiply and the synthesis of :mod:`avgs.acoustics.synthesis`
(:meth:`SceneRenderer.stream` does the same block by block).

Thread safety: :meth:`render` and :meth:`masks` serialise on an internal lock, so one
worker thread may render while another thread reads the point arrays (read-only numpy).
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from avgs import dsp
from avgs.data.frame import signed_direction
from avgs.acoustics.synthesis import Masks, ear_spectrogram, waveform
from avgs.checkpoint import config_of, load_checkpoint, stft_of
from avgs.config import SynthesisConfig
from avgs.data.frame import SceneFrame
from avgs.gaussians.sh import sh_to_rgb

MAX_NORMALISED = 1e9
"Positions farther than this from the scene's centre (normalised units; the scene spans ~[-1, 1]) are rejected: squared distances would overflow float32."


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
        from avgs.acoustics.model import AVGSModel
        from avgs.acoustics.points import AudioPoints

        self.path = Path(path) if path is not None else None
        self.device = torch.device(device)
        self.dtype = dtype
        "Precision of the networks (float32; others for measurement: CPUs without native support run them slower)."
        self.synthesis = synthesis or SynthesisConfig()
        "How :meth:`render` makes a waveform of the predicted magnitudes (phase iterations)."
        self.config = config_of(ckpt)
        self.stft = stft_of(ckpt)
        self.frame: SceneFrame = SceneFrame.from_dict(ckpt["frame"])
        self.history: list[dict] = list(ckpt.get("history", []))
        self.name: str = str(ckpt["scene"].get("name", ""))
        pts = ckpt["audio_points"]
        fixed_k = ckpt.get("vicinity_k")  # set by pruning (avgs.prune): k kept from before
        model = AVGSModel(
            AudioPoints(pts["X"], pts["alpha"]), self.config.acoustic, self.stft,
            vicinity_k=None if fixed_k is None else int(fixed_k),
        )
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

    def pose(self, listener, yaw: float, source=None) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """A public pose in the model's terms: (listener [1, 3], theta [1] radians, source [3]),
        normalised, in the model's dtype. Raises ValueError for positions or yaws it cannot take."""
        listener_n = self.frame.to_normalised(_position(listener, "listener"))
        source_n = self.source_normalised if source is None else self.frame.to_normalised(_position(source, "source"))
        yaw = float(yaw)
        if not math.isfinite(yaw):
            raise ValueError(f"yaw must be a finite number of degrees, got {yaw!r}")
        for what, value, p in (("listener", listener, listener_n), ("source", source, source_n)):
            if not np.all(np.abs(p) <= MAX_NORMALISED):
                raise ValueError(
                    f"{what} {value!r} is {np.max(np.abs(p)):.3g} normalised units from the scene's "
                    f"centre; expected at most {MAX_NORMALISED:g} (the scene spans about [-1, 1])"
                )
        lis = torch.tensor(listener_n[None], dtype=torch.float64)  # [1, 3]
        src = torch.tensor(source_n, dtype=torch.float64)  # [3]
        theta = signed_direction(lis, torch.tensor([math.radians(yaw)], dtype=torch.float64), src)  # [1]
        as_model = dict(device=self.device, dtype=self.dtype)
        return lis.to(**as_model), theta.to(**as_model), src.to(**as_model)

    def source_context(self, source: torch.Tensor):
        """C_S and the source vicinity for ``source`` [3] (normalised), cached until the source moves."""
        key = tuple(source.tolist())
        if self._source_cache is None or self._source_cache[0] != key:
            self._source_cache = (key, self.model.source_context(source, self.cache))
        return self._source_cache[1]

    def _masks(self, listener, yaw: float, source) -> tuple[Masks, float]:
        lis, theta, src = self.pose(listener, yaw, source)
        masks = self.model.masks(lis, theta, src, self.source_context(src), self.cache)
        return masks, float(theta[0])

    @staticmethod
    def _result(m: Masks, theta: float, **extra) -> RenderResult:
        def np32(t):
            return None if t is None else t[0].float().cpu().numpy()

        return RenderResult(
            mixture=np32(m.mixture), difference=np32(m.difference), reverb=np32(m.reverb),
            listener_vicinity=m.listener_vicinity[0].cpu().numpy(), source_vicinity=m.source_vicinity.cpu().numpy(),
            theta=math.degrees(theta), **extra,
        )

    def masks(self, listener, yaw: float, source=None) -> RenderResult:
        """Masks for a listener at ``listener`` (world) facing ``yaw`` degrees; ``source`` (world)
        defaults to the trained one. ``binaural`` is None."""
        with self._lock, torch.inference_mode():
            m, theta = self._masks(listener, yaw, source)
            return self._result(m, theta)

    def render(
        self, listener, yaw: float, mono, source=None, magnitudes: bool = False, synthesis: SynthesisConfig | None = None
    ) -> RenderResult:
        """Binaural ``[2, T]`` float32 of ``mono [T]`` (any length >= 1) heard at ``listener`` facing ``yaw`` degrees.

        With ``magnitudes=True`` the result also holds the predicted ear magnitudes
        ``[2, F, N_t]`` that the waveform was synthesised from (what AV-NeRF's MAG scores).
        The waveform is made of them as ``synthesis`` says, by default :attr:`synthesis`:
        a few fast Griffin-Lim iterations from the source's phase (:class:`avgs.config.SynthesisConfig`).
        """
        x = np.asarray(mono, dtype=np.float32)
        if x.ndim == 2 and 1 in x.shape:
            x = x.reshape(-1)
        if x.ndim != 1 or x.size == 0:
            raise ValueError(f"mono must be a 1-D signal with at least one sample, got shape {x.shape}")
        if not np.all(np.isfinite(x)):
            raise ValueError("mono holds NaN or Inf samples")
        with self._lock, torch.inference_mode():
            m, theta = self._masks(listener, yaw, source)
            m32 = self.float32(m)
            spec = dsp.stft(torch.from_numpy(x).to(self.device)[None], self.stft)  # [1, F, N_t]
            ears = ear_spectrogram(spec, m32, self.post_conv)  # [1, 2, F, N_t]
            y = waveform(ears, x.size, self.stft, self.synthesis if synthesis is None else synthesis)[0]  # [2, T]
            mags = np.ascontiguousarray(ears[0].abs().float().cpu().numpy()) if magnitudes else None
            return self._result(m, theta, binaural=np.ascontiguousarray(y.float().cpu().numpy()), magnitudes=mags)

    @property
    def post_conv(self):
        """B's time-frequency conv head (``--post-conv``), or None for the mask model."""
        return self.model.binauralizer.post_conv

    @staticmethod
    def float32(m: Masks) -> Masks:
        """The masks in float32, the precision of the synthesis (a no-op for a float32 model)."""
        def f(t):
            return t.float() if t is not None and t.is_floating_point() else t

        return Masks(f(m.mixture), f(m.difference), f(m.reverb), f(m.decay), m.listener_vicinity, m.source_vicinity)

    def stream(self, listener, yaw: float, source=None):
        """A :class:`avgs.streaming.BinauralStream` for this pose: feed mono blocks, then ``flush()``.

        The concatenated output equals :meth:`render` of the whole input (float rounding)
        made with the source's phase (``SynthesisConfig(phase_iterations=0)``): phase
        iterations need the whole signal, a stream keeps the source's phase.
        """
        from avgs.streaming import BinauralStream

        if self.model.binauralizer.post_conv is not None:
            raise ValueError(
                f"{self.path or 'this checkpoint'}: trained with the time-frequency conv head (--post-conv), whose "
                "output depends on neighbouring frames; block streaming supports only the mask model. "
                "Use render() on the whole signal."
            )
        with self._lock, torch.inference_mode():
            m, _ = self._masks(listener, yaw, source)
            return BinauralStream(self.float32(m), self.stft)

    def __repr__(self) -> str:
        return f"SceneRenderer({self.name!r}: {len(self._points)} audio points, {self.sample_rate} Hz)"
