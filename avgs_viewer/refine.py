"""The settled pose heard as ``avgs render`` makes it: the whole loop in the renderer's own synthesis.

While the listener or source moves, the engine plays the pose's filter: a convolution,
heard one block after the filter is known. For a model whose synthesis is not that
filter (the binaural task: by default one phase retrieved for the mid magnitudes,
MAG 0.128 against the filter's 0.181 over our five scenes, benchmarks/syntheses.md) the
filter is the fast approximation. Once a pose has held for ``settle`` seconds,
:class:`LoopRefiner` renders the looped clip at it with the renderer's stream
(:meth:`avgs.render.renderer.SceneRenderer.stream`) and hands it to the engine
(:meth:`~avgs_viewer.audio.StreamEngine.set_loop`), which crossfades to it over one block.

The loop is periodic, so its render is too: the stream is fed the loop over and over
(enough copies first that the kept copy hears the previous copies' tail and the phase
retrieval's reach), and the copy after them is kept: sample for sample the render of an
endless repetition of the clip. The work goes in chunks, and stops at the first chunk
boundary after a newer pose is asked for: a drag never waits on it for more than a chunk.
No Qt here; :class:`avgs_viewer.worker.LiveAudio` drives it.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

from .newest import RenderWorker
from .state import Pose
from .trained_scene import Position, TrainedScene

SETTLE_SECONDS = 0.25
"A pose held this long (no newer pose asked for) is rendered in full."

CHUNK = 4096
"Input samples per stream call (0.19 s at 22050 Hz): a newer pose cancels the work at the next call."

BLOCK_FRAMES = 256
"""Frames per phase retrieval of the refiner's stream (1.5 s at AV-NeRF's hop): the retrieval's
reach on both sides is redone per block, so long blocks do the least work per second of loop
(delay does not matter here); a call that completes one takes a few milliseconds."""

SEAM_SECONDS = 0.05
"""The phase retrieval does not repeat with the loop (its frames fall elsewhere in each period), so
the render's next period starts differently from the kept one: its start is crossfaded into the
kept period's start over this long (equal power), as :func:`~avgs_viewer.audio.make_seamless_loop` does."""


def refines(renderer: TrainedScene) -> bool:
    """Whether ``renderer``'s own synthesis differs from the pose's filter and streams
    (:attr:`SceneRenderer.renders_beyond_filter <avgs.render.renderer.SceneRenderer.renders_beyond_filter>`):
    then a settled pose is rendered anew."""
    return bool(getattr(renderer, "renders_beyond_filter", False))


def periods_before(renderer: TrainedScene, period: int) -> int:
    """Periods of a loop ``period`` samples long that the one kept needs before it: those that
    reach it through the tail, the STFT window and the phase iterations (:meth:`SceneRenderer.reach_frames
    <avgs.render.renderer.SceneRenderer.reach_frames>`)."""
    stft = renderer.stft
    reach = renderer.reach_frames() * stft.hop_length + stft.n_fft  # input samples an output sample hears back
    return math.ceil(reach / period)


def render_loop(renderer: TrainedScene, listener: Position, yaw: float, source: Position | None, loop: np.ndarray,
                cancelled: Callable[[], bool] = lambda: False, chunk: int = CHUNK) -> np.ndarray | None:
    """``[2, T]`` float32: the endlessly repeated ``loop [T]`` rendered at the pose, one period
    (sample i heard with loop sample i), its start crossfaded from the next period's
    (:data:`SEAM_SECONDS`); None when ``cancelled()`` turns True between chunks."""
    loop = np.ascontiguousarray(loop, dtype=np.float32)
    T = len(loop)
    if loop.ndim != 1 or T == 0:
        raise ValueError(f"a loop must be mono [T] with T > 0, got shape {loop.shape}")
    stream = renderer.stream(listener, yaw, source=source, block_frames=BLOCK_FRAMES)
    copies = periods_before(renderer, T)
    seam = min(T // 4, round(SEAM_SECONDS * renderer.sample_rate))
    begin, end = copies * T, (copies + 1) * T + seam  # the kept period and the next one's start, in output samples
    pieces, have, fed = [], 0, 0
    while have < end:
        if cancelled():
            return None
        block = loop[(fed + np.arange(chunk)) % T]
        fed += chunk
        y = stream.process(block)  # [2, m]: the output so far, the stream's latency behind the input
        if have + y.shape[1] > begin:
            pieces.append(y[:, max(0, begin - have):])
        have += y.shape[1]
    out = np.concatenate(pieces, axis=1)[:, : T + seam].astype(np.float32)  # [2, T + seam]
    kept, after = out[:, :T], out[:, T:]
    if seam:  # playback goes from kept's end to its start: begin as the render went on, fade into kept
        t = (np.arange(seam) + 0.5) / seam
        kept[:, :seam] = kept[:, :seam] * np.sin(0.5 * np.pi * t) + after * np.cos(0.5 * np.pi * t)
    return np.ascontiguousarray(kept)


@dataclass(frozen=True)
class Refined:
    """A settled pose's loop in full: the pose's filter number (the engine's tag), the rendered
    loop [2, T], the mono loop it renders [T], and the seconds from the pose's filter reaching
    the engine to the rendered loop being ready."""

    seq: int
    binaural: np.ndarray  # [2, T] float32
    clip: np.ndarray  # [T] float32, the engine's looped clip it was rendered from
    after_filter: float


RefineJob = tuple[int, Pose, np.ndarray, float]
"""What :meth:`LoopRefiner.submit` queues: (filter number, pose, loop [T], the ``perf_counter``
time the pose's filter reached the engine)."""


class LoopRefiner:
    """Renders the loop at a settled pose on its own thread, newest pose wins.

    ``current()`` returns the newest pose's number (a newer one cancels the work in
    progress); ``deliver(refined)`` is called on the refiner's thread with the loop.
    """

    def __init__(self, renderer: TrainedScene, current: Callable[[], int], deliver: Callable[[Refined], None],
                 on_error: Callable[[BaseException], None] | None = None, settle: float = SETTLE_SECONDS):
        if settle < 0:
            raise ValueError(f"settle must be >= 0 seconds, got {settle}")
        self.renderer, self.settle = renderer, float(settle)
        self._current, self._deliver = current, deliver
        self.cancelled = 0
        "Refinements given up because a newer pose came (while settling or rendering)."
        self.worker: RenderWorker[RefineJob, Refined | None] = RenderWorker(
            self._run, self._done, lambda seq, job, exc: on_error and on_error(exc), name="avgs-refine")

    def submit(self, seq: int, pose: Pose, loop: np.ndarray, ready_at: float) -> None:
        """Render ``loop`` at ``pose`` (filter number ``seq``, in the engine since ``ready_at``,
        a ``perf_counter`` time) once it has held for ``settle`` seconds."""
        self.worker.submit((seq, pose, loop, ready_at))

    def _stale(self, seq: int) -> bool:
        return self._current() != seq

    def _run(self, job: RefineJob) -> Refined | None:
        seq, pose, loop, ready_at = job
        while (left := ready_at + self.settle - time.perf_counter()) > 0:  # let the pose settle
            if self._stale(seq):
                self.cancelled += 1
                return None
            time.sleep(min(left, 0.02))
        y = render_loop(self.renderer, pose.listener, pose.yaw, pose.source, loop, lambda: self._stale(seq))
        if y is None:
            self.cancelled += 1
            return None
        return Refined(seq, y, loop, time.perf_counter() - ready_at)

    def _done(self, _seq: int, _job: RefineJob, refined: Refined | None) -> None:
        if refined is not None and not self._stale(refined.seq):
            self._deliver(refined)

    def close(self) -> None:
        self.worker.close()
