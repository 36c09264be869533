"""The pose -> filter -> audio path, on a thread that keeps only the newest request.

The GUI thread never runs the model: a pose change submits the pose and returns. While
a filter is computed, newer poses overwrite each other; when it is done only the newest
is computed next (:class:`~avgs_viewer.newest.RenderWorker`), so a fast drag costs one
filter per few milliseconds, not one per mouse event, and no work ever stands between
the newest pose and the audio.
A pose's filter (``SceneRenderer.binaural_filter``: B's masks as a binaural impulse
response) goes straight to the audio engine, which switches to it at its next block.
Where the renderer's own synthesis is not that filter (a binaural-task model), a pose that
holds is then rendered in full, loop and all, and the engine crossfades to it
(:mod:`avgs_viewer.refine`): moving, one hears the filter; settled, what ``avgs render`` writes.
No Qt here: results come back through plain callbacks on the worker thread; the window's
audio path (:mod:`avgs_viewer.audio_path`) forwards them to the GUI thread with a queued signal.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Callable

import numpy as np

from avgs.threads import stopped

from .audio import StreamEngine, filter_levels, make_seamless_loop
from .newest import RenderWorker
from .refine import SETTLE_SECONDS, LoopRefiner, Refined, refines
from .sources import Sources
from .state import Pose, ViewerState
from .trained_scene import TrainedScene

if TYPE_CHECKING:  # torch: imported off the GUI thread only
    from avgs.render.renderer import RenderResult


def same_pose(a: Pose | None, b: Pose | None, tolerance: float = 1e-6) -> bool:
    """Poses equal to ``tolerance`` (metres, degrees): the follower's and the GUI's arithmetic
    for one pointer position differ in the last digits."""
    if a is None or b is None:
        return False
    return (abs(a.yaw - b.yaw) <= tolerance and np.allclose(a.listener, b.listener, rtol=0.0, atol=tolerance)
            and np.allclose(a.source, b.source, rtol=0.0, atol=tolerance))


@dataclass(frozen=True)
class PoseRequest:
    """One filter to compute: a pose, its number (the engine's tag) and when it was asked for."""

    pose: Pose  # the first source's (several sources: :mod:`avgs_viewer.sources`)
    seq: int
    submitted_at: float
    voices: tuple = ()  # ((source id, (x, y, z)), ...) the other sources, each its own filter


@dataclass(frozen=True)
class Heard:
    """What the engine plays now: the request, the renderer's result (``impulse`` [2, L],
    vicinity sets, ...) and the levels the clip has through it at full volume."""

    request: PoseRequest
    result: RenderResult  # SceneRenderer.binaural_filter's: impulse [2, L] float32, vicinity sets, gains
    levels: tuple[float, float, float]  # (left dB, right dB, left - right dB)
    ready_at: float  # perf_counter when the engine was handed the filter
    voices: tuple = ()  # ((source id, RenderResult), ...) the other sources' filters, handed to the engine with it


def pose_filter(renderer: TrainedScene, pose: Pose, stop: Callable[[], bool] | None = None) -> RenderResult:
    """The pose's binaural filter: a ``RenderResult`` whose ``impulse`` is [2, L] float32 (left first);
    ``stop``: as :meth:`~avgs_viewer.trained_scene.TrainedScene.binaural_filter`'s."""
    return renderer.binaural_filter(pose.listener, pose.yaw, source=pose.source, stop=stop)


class LiveAudio:
    """State pose changes -> the pose's filter on the worker -> the audio engine.

    ``renderer``: the scene (:class:`~avgs_viewer.trained_scene.TrainedScene`, an ``avgs.SceneRenderer``);
    ``on_result(heard)`` is called on the worker thread once the engine has the new filter
    (the window's audio path forwards it to the GUI thread for the vicinity colours and levels). The
    pose event reaches this object before anything is drawn (the window draws on demand,
    after the event returns). :meth:`set_clip` changes the looped clip; its tail is
    crossfaded into its head over ``seam_seconds`` so the loop has no seam.

    A pose that holds ``settle`` seconds is rendered in full where the renderer's synthesis
    is not its filter (:func:`~avgs_viewer.refine.refines`; None: never): the engine then
    plays that loop (:attr:`refined`), and ``on_refined(refined)`` is called on the refiner's thread.
    """

    def __init__(self, renderer: TrainedScene, state: ViewerState, engine: StreamEngine, clip: np.ndarray,
                 on_result: Callable[[Heard], None] | None = None,
                 on_error: Callable[[PoseRequest | None, BaseException], None] | None = None,
                 seam_seconds: float = 0.05, settle: float | None = SETTLE_SECONDS,
                 on_refined: Callable[[Refined], None] | None = None):
        self.renderer = renderer
        self.state = state
        self.engine = engine
        self._on_result = on_result
        self._on_error = on_error
        self._seam = int(round(seam_seconds * engine.sample_rate))
        self._lock = threading.Lock()
        self.heard: Heard | None = None
        "The newest pose whose filter the engine has (None before the first)."
        self.seq = 0
        "Number of the newest pose submitted (the engine's tag for its filter)."
        self._requested: Pose | None = None  # the newest pose submitted
        self._following = False
        self.refined: Refined | None = None
        "The newest pose rendered in full and handed to the engine (None before the first)."
        self._on_refined = on_refined
        self.sources: Sources | None = None  # several sources (attach_sources); None: the state's one
        self._source_clip: np.ndarray | None = None  # the first source's clip the engine loops
        self._voiced: dict[int, tuple] = {}  # source id -> (its clip, gain) the engine has
        engine.set_clip(self._as_loop(clip))
        # A spare lane: a drag's release starts its pose's filter at once, not behind a move's (follow).
        self.worker: RenderWorker[PoseRequest, tuple[RenderResult, tuple]] = RenderWorker(
            self._render, self._deliver, self._fail, name="avgs-filter", spare=True)
        self.refiner: LoopRefiner | None = None
        if settle is not None and refines(renderer):
            self.refiner = LoopRefiner(renderer, lambda: self.seq, self._deliver_refined,
                                       lambda exc: self._fail(self.seq, self.last_request, exc), settle)
        state.events.pose.connect(self._pose_changed)

    def _as_loop(self, clip: np.ndarray) -> np.ndarray:
        clip = np.asarray(clip, dtype=np.float32)
        if clip.ndim != 1 or len(clip) == 0:
            raise ValueError(f"clip must be mono [T] with T > 0, got shape {clip.shape}")
        return make_seamless_loop(clip, self._seam)

    @property
    def clip(self) -> np.ndarray:
        """The looped mono clip [T] (seam already crossfaded)."""
        return self.engine.clip

    @property
    def last_result(self) -> RenderResult | None:
        """The renderer's result for the pose heard now (None before the first)."""
        heard = self.heard
        return None if heard is None else heard.result

    @property
    def last_request(self) -> PoseRequest | None:
        heard = self.heard
        return None if heard is None else heard.request

    def heard_clip(self) -> np.ndarray:
        """[2, T] float32: the looped clip as heard now (before volume and make-up gain): the pose's
        loop rendered in full once the engine has it, else the clip through the pose's filter."""
        import torch

        from avgs.acoustics.impulse_response import convolve

        heard, refined = self.heard, self.refined
        if heard is None:
            raise ValueError("no pose has been heard yet")
        if refined is not None and refined.seq == heard.request.seq:
            return refined.binaural.copy()
        with torch.inference_mode():
            y = convolve(torch.from_numpy(np.array(self.clip)), torch.from_numpy(np.array(heard.result.impulse)))
        return y.float().numpy()

    def set_clip(self, clip: np.ndarray) -> None:
        """Loop another mono clip [T] (already at the renderer's sample rate): crossfaded in at the
        next block, through the same filter; the levels are measured again."""
        self.engine.set_clip(self._as_loop(clip))
        if self.sources is not None:  # the first source's clip
            self.sources.items[0].clip = self._source_clip = np.asarray(clip, dtype=np.float32)
        self.request()

    # ------------------------------------------------------------------ several sources
    def attach_sources(self, sources: Sources) -> None:
        """Play every source of ``sources`` (the first through the engine's own path, the others as
        its voices), each its clip through its own filter at its gain; follows their changes."""
        self.sources = sources
        self._source_clip = sources.items[0].clip
        sources.changed.append(self._sources_changed)  # (a move of the selected source is a pose event)
        self._sources_changed()

    def _sources_changed(self) -> None:
        """The engine's sources made to match the list (clips, gains, voices), then every filter anew."""
        sources, engine = self.sources, self.engine
        first = sources.items[0]
        if first.clip is not self._source_clip:  # a clip set, or the first source removed
            self._source_clip = first.clip
            engine.set_clip(self._as_loop(first.clip))
        engine.source_gain = first.gain
        others = {s.id: s for s in sources.items[1:]}
        for key in [k for k in self._voiced if k not in others]:
            engine.remove_voice(key)
            del self._voiced[key]
        for key, s in others.items():
            had = self._voiced.get(key)
            new_clip = had is None or had[0] is not s.clip
            engine.set_voice(key, self._as_loop(s.clip) if new_clip else None, s.gain)
            self._voiced[key] = (s.clip, s.gain)
        self.request()

    def _split(self, pose: Pose) -> tuple[Pose, tuple]:
        """(the first source's pose, the other sources' (id, position)) of the state's ``pose``,
        whose source is the selected one."""
        sources = self.sources
        if sources is None or len(sources) == 1:
            return pose, ()
        where = [tuple(float(v) for v in s.position) for s in sources.items]
        where[sources.selected] = tuple(pose.source)
        first = Pose(pose.listener, pose.yaw, where[0])
        return first, tuple((s.id, p) for s, p in zip(sources.items[1:], where[1:]))

    def request(self, pose: Pose | None = None) -> int:
        """Compute the filter of ``pose`` (default: the state's current pose; called on every pose
        change); its number. Any thread. It starts at once: the filter being made, now stale, gives
        up at its next stop check, and this one runs on the spare lane meanwhile."""
        with self._lock:  # numbers follow submission order
            pose = self.state.pose if pose is None else pose
            first, voices = self._split(pose)
            self.seq = self.worker.submit(PoseRequest(first, self.worker.submitted + 1, time.perf_counter(), voices))
            self._requested = pose
            self.worker.expedite()
            return self.seq

    def follow(self, following: bool) -> None:
        """While True, poses come from a :class:`~avgs_viewer.pointer.PointerFollower` through
        :meth:`request` ahead of the state, and the state's pose events (the same moves, drawn
        later) are not requested again. Back to False (the drag's release on the GUI thread),
        the state's pose is requested unless the follower already asked for it."""
        self._following = bool(following)
        if not following:
            if not same_pose(self.state.pose, self._requested):
                self.request()
            self.worker.expedite()  # the released pose starts now, not after the move being computed

    def _pose_changed(self, pose: Pose) -> None:
        if self._following or same_pose(pose, self._requested):
            return
        self.request(pose)

    def _render(self, request: PoseRequest) -> tuple[RenderResult, tuple]:
        """The first source's filter and the other sources' ((id, RenderResult), ...); on either lane.
        A newer pose submitted meanwhile stops it at the next of its stage's checks (before and after the
        network, after the direct sound, before its placement: the worker's ``stopped``), and a filter made
        stale after its last check is not handed to the engine either (its hand-over and levels take
        ~3 ms of a core): the CPU goes to the pose the user is at."""
        pose = request.pose

        def stale() -> bool:
            return self.worker.stale(request.seq)

        voices = tuple((key, self.renderer.binaural_filter(pose.listener, pose.yaw, source=where, stop=stale))
                       for key, where in request.voices)
        result = pose_filter(self.renderer, pose, stale)
        stopped(stale, "the pose's filter: a newer pose is on its way")
        return result, voices

    def _deliver(self, seq: int, request: PoseRequest, rendered: tuple[RenderResult, tuple]) -> None:
        clip = self.engine.clip
        result, voices = rendered
        for key, res in voices:  # taken at the same block as the first source's
            if key in self.engine.voices:
                self.engine.set_voice_filter(key, res.impulse)
        self.engine.set_filter(result.impulse, tag=request.seq)
        ready = time.perf_counter()
        levels = filter_levels(result.impulse, self.engine.spectrum, self.engine.makeup_gain or 1.0)
        heard = Heard(request, result, levels, ready, voices)
        self.heard = heard
        if self.refiner is not None:  # (after self.heard: the loop is taken only for the pose heard)
            self.refiner.submit(request.seq, request.pose, clip, ready)
        if self._on_result is not None:
            self._on_result(heard)

    def _deliver_refined(self, refined: Refined) -> None:
        heard = self.heard
        if heard is None or heard.request.seq != refined.seq:
            return
        if self.engine.set_loop(refined.binaural, tag=refined.seq, clip=refined.clip):
            self.refined = refined
            if self._on_refined is not None:
                self._on_refined(refined)

    def _fail(self, seq: int, request: PoseRequest | None, exc: BaseException) -> None:
        if self._on_error is not None:
            self._on_error(request, exc)

    def close(self) -> None:
        if self.sources is not None:
            self.sources.changed.remove(self._sources_changed)
        self.state.events.pose.disconnect(self._pose_changed)
        self.worker.close()
        if self.refiner is not None:
            self.refiner.close()
