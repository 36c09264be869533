"""``SceneRenderer``: the one object the CLI, the benchmarks and the viewer use.

Public coordinates are the scene's **world** frame, yaw in **degrees** counter-clockwise
from +x (ARCHITECTURE.md); the conversion to the model's normalised frame and radians
happens here and nowhere else. Rendering runs under ``torch.inference_mode`` through the
fast path of :mod:`avgs.acoustics.fast` (same numbers as the model: precomputed parts of F
and B, a partial selection for the vicinity, work buffers kept between calls), with the
source context C_S cached until the source moves; all 257 frequency queries go through B
in one batch, and the masks are time-invariant, so any input length costs one STFT, one
multiply and one iSTFT (:meth:`SceneRenderer.stream` does the same block by block).

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

from avgs.acoustics.fast import FastMasks, signed_direction
from avgs.checkpoint import config_of, load_checkpoint, stft_of
from avgs.config import SynthesisConfig
from avgs.data.frame import SceneFrame

MAX_NORMALISED = 1e9
"Positions farther than this from the scene's centre (normalised units; the scene spans ~[-1, 1]) are rejected: squared distances would overflow float32."
SH_C0 = 0.28209479177387814
"Degree-0 spherical-harmonics constant: rgb = 0.5 + SH_C0 * DC coefficient."


@dataclass(frozen=True)
class MaskResult:
    """Masks for one listener pose, and the vicinity sets behind them."""

    mixture: np.ndarray  # [F] float32
    difference: np.ndarray  # [F] float32 in (-1, 1); > 0 means left louder
    listener_vicinity: np.ndarray  # [k] int64 indices into SceneRenderer.points
    source_vicinity: np.ndarray  # [k] int64 indices into SceneRenderer.points
    theta: float  # degrees, direction to the source, positive = source on the listener's left
    reverb: np.ndarray | None = None  # [2, F] float32 reverberant gains (left, right); None without a tail


@dataclass(frozen=True)
class RenderResult(MaskResult):
    """:class:`MaskResult` plus the binaural waveform."""

    binaural: np.ndarray = None  # [2, T] float32, channel 0 = left ear
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
        synthesis: SynthesisConfig | None = None,
    ):
        from avgs.acoustics.model import AVGSModel
        from avgs.acoustics.points import AudioPoints

        self.path = Path(path) if path is not None else None
        self.device = torch.device(device)
        self.synthesis = synthesis or SynthesisConfig()
        "How :meth:`render` makes a waveform of the predicted magnitudes (phase iterations)."
        self.config = config_of(ckpt)
        self.stft = stft_of(ckpt)
        self.frame: SceneFrame = SceneFrame.from_dict(ckpt["frame"])
        self.history: list[dict] = list(ckpt.get("history", []))
        self.name: str = str(ckpt["scene"].get("name", ""))
        pts = ckpt["audio_points"]
        fixed_k = ckpt.get("vicinity_k")  # set by pruning (avgs.acoustics.prune): k kept from before
        model = AVGSModel(
            AudioPoints(pts["X"], pts["alpha"]),
            self.config.acoustic,
            self.stft.n_freq,
            vicinity_k=None if fixed_k is None else int(fixed_k),
            stft=self.stft,
        )
        if model.field is not None:
            model.field.load_state_dict(ckpt["field"])
        model.binauralizer.load_state_dict(ckpt["binauralizer"])
        self._model = model.to(self.device).eval().requires_grad_(False)
        self._fast = FastMasks(self._model)
        self._source_n = ckpt["source"].detach().double().cpu().numpy().reshape(3)  # normalised
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
        cls, path: str | Path, device: str | torch.device = "cpu", synthesis: SynthesisConfig | None = None
    ) -> "SceneRenderer":
        """Load and validate ``scene.ckpt`` (``torch.load(weights_only=True)``)."""
        return cls(load_checkpoint(path, map_location="cpu"), device=device, path=path, synthesis=synthesis)

    def _read_gaussians(self, g: dict | None) -> GaussianCloud | None:
        if not g:
            return None
        means = self.frame.to_world(g["means"].detach().cpu().double().numpy().reshape(-1, 3)).astype(np.float32)
        if "sh" in g:
            dc = g["sh"].detach().cpu().float().reshape(len(means), -1, 3)[:, 0]  # [M, 3]
            rgb = np.clip(0.5 + SH_C0 * dc.numpy(), 0.0, 1.0).astype(np.float32)
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
        return self.frame.to_world(self._source_n)

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
        tail = self._model.binauralizer.reverb
        return None if tail is None else tail.rt60().detach().cpu().numpy()

    @property
    def sample_rate(self) -> int:
        return int(self.stft.sample_rate)

    @property
    def n_freq(self) -> int:
        return int(self.stft.n_freq)

    @property
    def vicinity_size(self) -> int:
        """k: points in each of the listener's and the source's vicinity."""
        return self._model.vicinity_k

    # -- rendering --------------------------------------------------------------------

    def _cached_source(self, source_n: np.ndarray):
        key = tuple(float(v) for v in source_n)
        if self._source_cache is None or self._source_cache[0] != key:
            self._source_cache = (key, self._fast.source_context(key))
        return self._source_cache[1]

    def _masks(self, listener, yaw: float, source):
        """(PoseMasks, source vicinity [k], theta radians)."""
        listener_n = self.frame.to_normalised(_position(listener, "listener"))
        source_n = self._source_n if source is None else self.frame.to_normalised(_position(source, "source"))
        yaw = float(yaw)
        if not math.isfinite(yaw):
            raise ValueError(f"yaw must be a finite number of degrees, got {yaw!r}")
        lis = tuple(float(v) for v in listener_n)
        for what, value, p in (("listener", listener, lis), ("source", source, source_n)):
            if not all(abs(float(v)) <= MAX_NORMALISED for v in p):
                raise ValueError(
                    f"{what} {value!r} is {max(abs(float(v)) for v in p):.3g} normalised units from the scene's "
                    f"centre; expected at most {MAX_NORMALISED:g} (the scene spans about [-1, 1])"
                )
        theta = signed_direction(lis, math.radians(yaw), source_n)
        cached = self._cached_source(source_n)
        return self._fast.masks(lis, theta, cached), cached[1], theta

    def masks(self, listener, yaw: float, source=None) -> MaskResult:
        """Masks for a listener at ``listener`` (world) facing ``yaw`` degrees; ``source`` (world) defaults to the trained one."""
        with self._lock, torch.inference_mode():
            m, src_idx, theta = self._masks(listener, yaw, source)
            return MaskResult(**self._mask_fields(m, src_idx, theta))

    @staticmethod
    def _mask_fields(m, src_idx: torch.Tensor, theta: float) -> dict:
        return dict(
            mixture=m.mixture.cpu().numpy(),
            difference=m.difference.cpu().numpy(),
            listener_vicinity=m.listener_vicinity.cpu().numpy(),
            source_vicinity=src_idx.cpu().numpy(),
            theta=math.degrees(theta),
            reverb=None if m.reverb is None else m.reverb.cpu().numpy(),
        )

    def render(
        self, listener, yaw: float, mono, source=None, magnitudes: bool = False, synthesis: SynthesisConfig | None = None
    ) -> RenderResult:
        """Binaural ``[2, T]`` float32 of ``mono [T]`` (any length >= 1) heard at ``listener`` facing ``yaw`` degrees.

        With ``magnitudes=True`` the result also holds the predicted ear magnitudes
        ``[2, F, N_t]`` that the waveform was synthesised from (what AV-NeRF's MAG scores).
        The waveform is made of them as ``synthesis`` says, by default :attr:`synthesis`:
        a few fast Griffin-Lim iterations from the source's phase (:class:`avgs.config.SynthesisConfig`).
        """
        from avgs import dsp
        from avgs.acoustics.model import binaural_spectrogram, synthesise

        x = np.asarray(mono, dtype=np.float32)
        if x.ndim == 2 and 1 in x.shape:
            x = x.reshape(-1)
        if x.ndim != 1 or x.size == 0:
            raise ValueError(f"mono must be a 1-D signal with at least one sample, got shape {x.shape}")
        if not np.all(np.isfinite(x)):
            raise ValueError("mono holds NaN or Inf samples")
        with self._lock, torch.inference_mode():
            m, src_idx, theta = self._masks(listener, yaw, source)
            spec = dsp.stft(torch.from_numpy(x).to(self.device)[None], self.stft)  # [1, F, N_t]
            reverb = None if m.reverb is None else m.reverb[None]  # [1, 2, F]
            ears = binaural_spectrogram(spec, m.mixture[None], m.difference[None],
                                        self._model.binauralizer.post_conv, reverb, self._fast.decay)  # [1, 2, F, N_t]
            y = synthesise(ears, x.size, self.stft, self.synthesis if synthesis is None else synthesis)[0]  # [2, T]
            mags = np.ascontiguousarray(ears[0].abs().float().cpu().numpy()) if magnitudes else None
            return RenderResult(
                **self._mask_fields(m, src_idx, theta), binaural=np.ascontiguousarray(y.float().cpu().numpy()),
                magnitudes=mags,
            )

    def stream(self, listener, yaw: float, source=None):
        """A :class:`avgs.streaming.BinauralStream` for this pose: feed mono blocks, then ``flush()``.

        The concatenated output equals :meth:`render` of the whole input (float rounding)
        made with the source's phase (``SynthesisConfig(phase_iterations=0)``): phase
        iterations need the whole signal, a stream keeps the source's phase.
        """
        from avgs.streaming import BinauralStream

        if self._model.binauralizer.post_conv is not None:
            raise ValueError(
                f"{self.path or 'this checkpoint'}: trained with the time-frequency conv head (--post-conv), whose "
                "output depends on neighbouring frames; block streaming supports only the mask model. "
                "Use render() on the whole signal."
            )
        m = self.masks(listener, yaw, source)
        decay = None if self._fast.decay is None else self._fast.decay.cpu().numpy()
        return BinauralStream(m.mixture, m.difference, self.stft, reverb=m.reverb, decay=decay)

    def __repr__(self) -> str:
        return f"SceneRenderer({self.name!r}: {len(self._points)} audio points, {self.sample_rate} Hz)"
