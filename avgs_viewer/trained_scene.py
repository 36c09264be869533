"""What the explorer needs of a trained scene: :class:`TrainedScene`, each member avgs_viewer reads or calls.
:class:`avgs.render.renderer.SceneRenderer` provides it (tests/test_viewer_typing.py checks that it does)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Callable, Protocol, TypeAlias

import numpy as np

if TYPE_CHECKING:  # avgs.render.renderer imports torch, which the window loads off the GUI thread only
    from avgs.config import STFTConfig, SynthesisConfig
    from avgs.render.renderer import GaussianCloud, RenderResult, SceneRenderer

Position: TypeAlias = Sequence[float] | np.ndarray
"A point in the scene's world frame: 3 numbers (x, y, z), a ``Pose``'s tuple or an array [3]."


class BlockStream(Protocol):
    """A pose's stream (:meth:`TrainedScene.stream`): mono blocks in, binaural out, a latency behind
    (:class:`avgs.acoustics.convolution.ConvolutionStream`, :class:`avgs.render.streaming.BinauralStream`,
    :class:`avgs.render.mid_phase_stream.MidPhaseStream`)."""

    def process(self, block: np.ndarray, /) -> np.ndarray:
        """The output so far ``[2, m]`` float32 (m may be 0) for the next input samples ``block [n]``."""
        ...


class TrainedScene(Protocol):
    """A trained AV-GS scene as the explorer uses it: world coordinates, yaw in degrees.

    The window loads one (``avgs.SceneRenderer.load``) and hands it to the scene view (points,
    colours, room), the pose's filter path (:class:`~avgs_viewer.worker.LiveAudio`:
    :meth:`binaural_filter` on a worker thread, its ``impulse`` to the audio engine), the
    settled-pose refiner (:mod:`avgs_viewer.refine`: :meth:`stream`), the headless export
    (:meth:`render`) and the propagation map. The map itself
    (:func:`avgs.render.propagation_map.propagation_map`) and the listener's view read the
    model inside the renderer, so there it has to be a ``SceneRenderer`` in fact.
    """

    # -- what is drawn -----------------------------------------------------------------
    @property
    def name(self) -> str:
        """The scene's name (its folder's, as trained), for titles of what is exported."""
        ...

    @property
    def points(self) -> np.ndarray:
        """Audio point positions ``[N, 3]`` float32, world (read-only)."""
        ...

    @property
    def alpha(self) -> np.ndarray:
        """Audio-guidance parameters ``[N, D]`` float32 (read-only), coloured by their projection."""
        ...

    @property
    def gaussians(self) -> GaussianCloud | None:
        """G's centres ``[M, 3]`` and colours ``[M, 3]``, or None for a checkpoint saved without G."""
        ...

    @property
    def bounds(self) -> np.ndarray:
        """The scene's box ``[2, 3]`` (min, max), world: the listener and the source stay inside."""
        ...

    @property
    def outline(self) -> np.ndarray | None:
        """The room's edges ``[K, 2, 3]`` world segments, or None (the box is the room then)."""
        ...

    @property
    def source(self) -> np.ndarray:
        """The training source position ``[3]``, world."""
        ...

    @property
    def source_aware(self) -> bool:
        """Whether a moved source is really heard (the impulse-response task); False keeps it fixed."""
        ...

    @property
    def path(self) -> Path | None:
        """The checkpoint it was loaded from (the listener's view loads G from it), or None."""
        ...

    # -- sound -------------------------------------------------------------------------
    @property
    def sample_rate(self) -> int:
        """Hz of every signal in and out: the clip is resampled to it, the engine runs at it."""
        ...

    @property
    def stft(self) -> STFTConfig:
        """The model's STFT (``hop_length``, ``n_fft``: how far back a loop's render reaches)."""
        ...

    @property
    def renders_beyond_filter(self) -> bool:
        """Whether :meth:`render` differs from the pose's filter: a settled pose is then rendered anew."""
        ...

    def binaural_filter(self, listener: Position, yaw: float, source: Position | None = None,
                        stop: Callable[[], bool] | None = None) -> RenderResult:
        """The pose as a filter: ``impulse`` ``[2, L]`` float32 (channel 0 = left), the vicinity sets
        ``listener_vicinity`` / ``source_vicinity`` (indices into :attr:`points`) and each ear's gains;
        ``stop`` True after the network abandons it (``avgs.threads.Stopped``)."""
        ...

    def render(self, listener: Position, yaw: float, mono: np.ndarray, source: Position | None = None, *,
               synthesis: SynthesisConfig | None = None) -> RenderResult:
        """``binaural`` ``[2, T]`` float32 of ``mono [T]`` heard at the pose, made as ``synthesis`` says."""
        ...

    def stream(self, listener: Position, yaw: float, source: Position | None = None,
               block_frames: int | None = None) -> BlockStream:
        """A stream of the pose: its output concatenated is :meth:`render` of the whole input."""
        ...

    def reach_frames(self) -> int:
        """STFT frames of input before an output frame that it depends on (tail, window, phase retrieval)."""
        ...


if TYPE_CHECKING:
    def _provided(renderer: SceneRenderer) -> TrainedScene:
        """The library's renderer is a :class:`TrainedScene`: a type checker checks this assignment.
        (pyright rejects it while ``SceneRenderer.stream`` declares no return type: it infers None
        from the stub of ``avgs.render.tasks.TaskModel.stream``; mypy takes it as Any.)"""
        return renderer
