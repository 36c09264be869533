"""A render thread that keeps only the newest request, and the pose -> audio pipeline on it.

The GUI thread never runs the model: it submits the latest pose and goes on. While a
render runs, newer poses overwrite each other; when it finishes, only the newest is
rendered next, so a fast drag costs one render per render time, not one per mouse event.
A pose is first heard as a draft with the source's phase (a few ms); once the user
stops, the same pose is rendered again with the renderer's phase iterations
(:class:`avgs.config.SynthesisConfig`) and swapped in.
No Qt here: results come back through plain callbacks on the worker thread; the window
forwards them to its own thread with a queued signal.
"""

from __future__ import annotations

import dataclasses
import threading
import time
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from .audio import LoopEngine, make_seamless_loop
from .state import Pose, ViewerState


class RenderWorker:
    """Runs ``render(request)`` on one daemon thread, newest request wins.

    ``on_result(seq, request, result)`` / ``on_error(seq, request, exc)`` are called on the
    worker thread; ``seq`` numbers submissions from 1, so a receiver can drop stale ones.
    """

    def __init__(self, render: Callable[[Any], Any], on_result: Callable[[int, Any, Any], None],
                 on_error: Callable[[int, Any, BaseException], None] | None = None, name: str = "avgs-render"):
        self._render = render
        self._on_result = on_result
        self._on_error = on_error
        self._cond = threading.Condition()
        self._request: Any = None
        self._has_request = False
        self._busy = False
        self._closed = False
        self.submitted = 0
        self.rendered = 0
        self.dropped = 0
        self._thread = threading.Thread(target=self._loop, name=name, daemon=True)
        self._thread.start()

    def submit(self, request: Any) -> int:
        """Queue ``request``, replacing any not yet started; returns its sequence number."""
        with self._cond:
            if self._closed:
                raise RuntimeError("render worker is closed")
            if self._has_request:
                self.dropped += 1
            self.submitted += 1
            self._request, self._has_request = (self.submitted, request), True
            self._cond.notify()
            return self.submitted

    def submit_if_idle(self, request: Any) -> int | None:
        """Queue ``request`` only if nothing is queued (a newer request always wins); its
        sequence number, or None when it was not queued."""
        with self._cond:
            if self._closed or self._has_request:
                return None
            self.submitted += 1
            self._request, self._has_request = (self.submitted, request), True
            self._cond.notify()
            return self.submitted

    def wait_idle(self, timeout: float = 10.0) -> bool:
        """Block until nothing is queued or running; False on timeout."""
        deadline = time.monotonic() + timeout
        with self._cond:
            while self._has_request or self._busy:
                left = deadline - time.monotonic()
                if left <= 0:
                    return False
                self._cond.wait(left)
        return True

    def close(self, timeout: float = 10.0) -> None:
        """Stop after the render in progress (queued requests are dropped)."""
        with self._cond:
            self._closed = True
            self._has_request = False
            self._cond.notify_all()
        if threading.current_thread() is not self._thread:
            self._thread.join(timeout)

    @property
    def alive(self) -> bool:
        return self._thread.is_alive()

    def _loop(self) -> None:
        while True:
            with self._cond:
                while not self._has_request and not self._closed:
                    self._cond.wait()
                if self._closed:
                    self._cond.notify_all()
                    return
                (seq, request), self._has_request = self._request, False
                self._request, self._busy = None, True
            try:
                result = self._render(request)
            except BaseException as exc:  # reported, never kills the thread
                if self._on_error is not None:
                    self._on_error(seq, request, exc)
            else:
                self.rendered += 1
                self._on_result(seq, request, result)
            finally:
                with self._cond:
                    self._busy = False
                    self._cond.notify_all()


@dataclass(frozen=True)
class PoseRequest:
    """One render: a pose and the clip (by generation number) it applies to."""

    pose: Pose
    clip_id: int
    submitted_at: float
    draft: bool = False  # with the source's phase, to be refined when no newer pose comes


class LiveRender:
    """State pose changes -> SceneRenderer.render on the worker -> the audio engine's buffer.

    ``renderer`` is an ``avgs.SceneRenderer`` (or anything with its ``render``);
    ``on_result(request, result)`` is called on the worker thread after the new buffer
    has been handed to the engine (the window forwards it to the GUI thread for the
    vicinity colours and meters). Call :meth:`set_clip` to change the looped clip; its
    tail is crossfaded into its head over ``seam_seconds`` so the loop has no seam.

    When the renderer makes its waveforms with phase iterations (``renderer.synthesis``),
    each pose is rendered first as a draft without them and then, if no newer pose has
    come, again with them: a drag answers as fast as the masks, the pose the user stops
    at sounds as ``render`` makes it.
    """

    def __init__(self, renderer: Any, state: ViewerState, engine: LoopEngine, clip: np.ndarray,
                 on_result: Callable[[PoseRequest, Any], None] | None = None,
                 on_error: Callable[[PoseRequest, BaseException], None] | None = None,
                 seam_seconds: float = 0.05):
        self.renderer = renderer
        self.state = state
        self.engine = engine
        self._on_result = on_result
        self._on_error = on_error
        self._seam = int(round(seam_seconds * engine.sample_rate))
        self._clip = self._as_loop(clip)
        self._clip_id = 0
        synthesis = getattr(renderer, "synthesis", None)
        self.draft_synthesis = (
            dataclasses.replace(synthesis, phase_iterations=0)
            if synthesis is not None and getattr(synthesis, "phase_iterations", 0) > 0 else None
        )
        "SynthesisConfig of the draft pass (no phase iterations), or None: one pass per pose."
        self.last_result: Any = None
        self.last_request: PoseRequest | None = None
        self.worker = RenderWorker(self._render, self._deliver, self._fail)
        state.events.pose.connect(self._pose_changed)

    def _as_loop(self, clip: np.ndarray) -> np.ndarray:
        clip = np.asarray(clip, dtype=np.float32)
        if clip.ndim != 1 or len(clip) == 0:
            raise ValueError(f"clip must be mono [T] with T > 0, got shape {clip.shape}")
        return make_seamless_loop(clip, self._seam)

    @property
    def clip(self) -> np.ndarray:
        """The looped mono clip [T] (seam already crossfaded)."""
        return self._clip

    def set_clip(self, clip: np.ndarray) -> None:
        """Loop another mono clip [T] (already at the renderer's sample rate)."""
        self._clip, self._clip_id = self._as_loop(clip), self._clip_id + 1
        self.engine.reset_gain()
        self.request()

    def request(self) -> int:
        """Render the state's current pose (called on every pose change)."""
        draft = self.draft_synthesis is not None
        return self.worker.submit(PoseRequest(self.state.pose, self._clip_id, time.perf_counter(), draft))

    def _pose_changed(self, pose: Pose) -> None:
        self.request()

    def _render(self, request: PoseRequest) -> Any:
        clip = self._clip
        pose = request.pose
        extra = {"synthesis": self.draft_synthesis} if request.draft else {}
        return self.renderer.render(listener=pose.listener, yaw=pose.yaw, mono=clip, source=pose.source, **extra)

    def _deliver(self, seq: int, request: PoseRequest, result: Any) -> None:
        if request.clip_id != self._clip_id:
            return  # rendered for a clip that has since been replaced
        self.engine.set_buffer(result.binaural)
        self.last_result, self.last_request = result, request
        if self._on_result is not None:
            self._on_result(request, result)
        if request.draft:
            self.worker.submit_if_idle(dataclasses.replace(request, draft=False))

    def _fail(self, seq: int, request: PoseRequest, exc: BaseException) -> None:
        if self._on_error is not None:
            self._on_error(request, exc)

    def close(self) -> None:
        self.state.events.pose.disconnect(self._pose_changed)
        self.worker.close()
