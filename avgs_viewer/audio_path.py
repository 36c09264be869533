"""The window's audio path: the engine and its output, the scene's LiveAudio, the meters, and
the pose heard shown back on the GUI thread.

:class:`AudioPath` runs one :class:`~avgs_viewer.audio.StreamEngine` (started again only when
a scene's sample rate differs) from a :class:`~avgs_viewer.sound_output.AudioOutput` (the
sound card, or a simulated clock where there is none, which the status bar says in plain
words: :func:`audio_status_text`). Per scene it runs a :class:`~avgs_viewer.worker.LiveAudio`,
which subscribes to the state's pose event after the view's handlers (which only ask for a
repaint), so a pose change reaches the engine before anything is drawn; paints wait while its
filter is on the way (the canvas' ``hold``). Results come back from the worker threads through
queued signals: the vicinity colours, levels, what is heard and the response panel are updated
at most every ``SHOW_MS`` while a handle moves, and like the paints, an update waits (at most
``SHOW_WAIT_MAX_S``) while a filter is on its way (:meth:`AudioPath.sound_pending`). The meters
poll the engine's output only while sound plays.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING

import numpy as np
from PySide6 import QtCore, QtWidgets

from .audio import SILENCE_DB, StreamEngine
from .sound_output import AudioOutput
from .trained_scene import TrainedScene

if TYPE_CHECKING:  # imported when a scene first needs them
    from .canvas import SceneCanvas
    from .control_panel import ControlPanel
    from .refine import Refined
    from .response_view import ResponsePanel
    from .scene_view import SceneView
    from .state import ViewerState
    from .worker import Heard, LiveAudio, PoseRequest

METER_INTERVAL_MS = 500
SHOW_MS = 150
SHOW_WAIT_MS = 2
"While a filter is on its way, a due update of the panels tries again this much later."
SHOW_WAIT_MAX_S = 0.1
"Longest a due update of the panels waits for the audio path (so a long drag still shows its poses)."


def audio_status_text(message: str | None, sample_rate: int) -> str:
    """The status bar's audio field in plain words (the technical reason goes in its tooltip)."""
    if not message:
        return f"Audio: {sample_rate} Hz"
    if message == "Audio output off":
        return "Audio output off: the meters show what would play"
    return "No audio: no sound card found (the meters show what would play)"


class _Bridge(QtCore.QObject):
    """Signals emitted from worker threads, delivered on the GUI thread (queued)."""

    rendered = QtCore.Signal(object)            # worker.Heard: the pose the engine now plays
    refined = QtCore.Signal(object)             # refine.Refined: that pose's loop rendered in full
    render_failed = QtCore.Signal(object, str)  # (PoseRequest, message)


class AudioPath(QtCore.QObject):
    """The sound of ``window``'s scene, shown in its ``panel`` (levels, meters, what is heard), its
    ``response`` panel, its status bar and ``audio_status`` label; paints of ``plotter`` wait for
    it. ``start_audio`` False: no sound card (a simulated clock)."""

    def __init__(self, window: QtWidgets.QMainWindow, plotter: SceneCanvas, panel: ControlPanel,
                 response: ResponsePanel, audio_status: QtWidgets.QLabel, start_audio: bool = True):
        super().__init__(window)  # its results and timers go with the window
        self.window, self.plotter, self.panel, self.response = window, plotter, panel, response
        self.audio_status = audio_status
        self.engine: StreamEngine | None = None
        self.output: AudioOutput | None = None
        self.live: LiveAudio | None = None
        self.renderer: TrainedScene | None = None  # the scene heard (with its state and view) while live
        self._state: ViewerState | None = None
        self._view: SceneView | None = None
        self._start_audio = start_audio
        self._bridge = _Bridge()
        self._bridge.rendered.connect(self._on_rendered)
        self._bridge.refined.connect(self._on_refined)
        self._bridge.render_failed.connect(self._on_render_failed)
        # Vicinity colours and levels of the newest pose, coalesced: while a handle moves, every
        # repaint delays the mouse events behind it, so at most one update per SHOW_MS.
        self._shown_heard: Heard | None = None
        self._show_timer = QtCore.QTimer(self)
        self._show_timer.setSingleShot(True)
        self._show_timer.timeout.connect(self._show_heard)
        self._show_held_since: float | None = None  # perf_counter when a due update first waited for the sound
        self._meters_shown: tuple[float, float] | None = None
        self.clip: np.ndarray | None = None  # the whole clip [T] looped now (what Export audio renders)
        # What reading the clip changed (down-mixed, resampled, cut), for as long as it loops.
        self.clip_notice = QtWidgets.QLabel()
        window.statusBar().addPermanentWidget(self.clip_notice)
        self.meter_timer = QtCore.QTimer(self)  # runs only while sound plays
        self.meter_timer.setInterval(METER_INTERVAL_MS)
        self.meter_timer.timeout.connect(self._update_meters)

    # ------------------------------------------------------------------ a scene's sound
    def use_rate(self, sample_rate: int) -> None:
        """An engine at ``sample_rate`` (a new one only if the rate differs), its make-up gain fitted anew."""
        if self.engine is None or self.engine.sample_rate != sample_rate:
            self._start_engine(sample_rate)
        self.engine.reset_gain()

    def bind(self, state: ViewerState) -> None:
        """The engine follows the state's volume and play / pause."""
        state.events.volume.connect(lambda v: setattr(self.engine, "volume", v))
        state.events.playing.connect(self._set_playing)
        self.engine.volume = state.volume
        self._set_playing(state.playing)

    def start(self, renderer: TrainedScene, state: ViewerState, view: SceneView, clip: np.ndarray) -> None:
        """Play ``clip`` through the filter of each of ``state``'s poses, shown in ``view``; paints wait
        for the sound.

        Call after the view is made: LiveAudio subscribes to the state's pose event after the
        view's handlers, which only ask for a repaint (SceneCanvas), so a move reaches the
        audio path before anything is drawn."""
        from .worker import LiveAudio

        self.renderer, self._state, self._view = renderer, state, view
        self.clip = np.asarray(clip, dtype=np.float32)
        self.live = LiveAudio(renderer, state, self.engine, clip, on_result=self._bridge.rendered.emit,
                              on_error=lambda req, exc: self._bridge.render_failed.emit(req, f"{type(exc).__name__}: {exc}"),
                              on_refined=self._bridge.refined.emit)
        self.live.request()
        self.plotter.hold = self.sound_pending  # sound first: paints wait for it

    def sound_pending(self) -> bool:
        """Whether a pose's filter is being made, or waits for its first block to leave the engine: the
        3D view's paints and the panels' updates wait then (each composes the whole window, which with
        software GL takes the CPU from the filter and the audio clock)."""
        live, engine = self.live, self.engine
        return live is not None and (not live.worker.wait_idle(0.0) or engine.switch_pending)

    def read_clip(self, path, sample_rate: int) -> np.ndarray:
        """The clip at ``path`` as the explorer loops it; what reading changed (down-mixed, resampled,
        cut at :data:`CLIP_SECONDS`) is said in the status bar (whole in its tooltip). Raises
        ValueError or FileNotFoundError naming the file."""
        clip, notes = load_clip_noted(path, sample_rate)
        self.show_clip_notes(notes)
        return clip

    def show_clip_notes(self, notes: list[str]) -> None:
        text = "; ".join(notes)
        self.clip_notice.setText(text)
        self.clip_notice.setToolTip(text)
        if text:
            self.window.statusBar().showMessage(text, 10000)

    def set_clip(self, clip: np.ndarray) -> None:
        """Loop another clip [T] (at the scene's rate) from the next block."""
        self.clip = np.asarray(clip, dtype=np.float32)
        self.live.set_clip(self.clip)

    def export_audio(self) -> np.ndarray:
        """[2, T] float32: the whole clip heard at the pose playing now (:func:`export_clip`)."""
        if self.live is None or self.renderer is None:
            raise ValueError("no binaural render yet: wait for the scene to load")
        return export_clip(self.renderer, self.live, self.clip)

    def stop(self) -> None:
        """The scene's LiveAudio closed (the engine plays on)."""
        if self.live is not None:
            self.plotter.hold = None
            self.live.close()
            self.live = None
        self.renderer, self._state, self._view = None, None, None

    def busy(self) -> bool:
        """Whether the worker is computing a pose's filter (the propagation map waits)."""
        return self.live is not None and not self.live.worker.wait_idle(0.0)

    def close(self) -> None:
        """The sound card or the clock stopped (the window closes)."""
        if self.output is not None:
            self.output.close()

    def _start_engine(self, sample_rate: int) -> None:
        if self.output is not None:
            self.output.close()
        self.engine = StreamEngine(sample_rate)
        # Without a sound card (or with audio off) a simulated clock pulls the engine's blocks,
        # so meters, tests and the benchmark see the same output a card would play.
        self.output = AudioOutput(self.engine, device=self._start_audio)
        message = self.output.start()
        self.audio_status.setText(audio_status_text(message, sample_rate))
        self.audio_status.setToolTip(message or "")
        if message:
            self.window.statusBar().showMessage(audio_status_text(message, sample_rate), 10000)

    def _set_playing(self, playing: bool) -> None:
        """Play or pause the engine (it ramps over one block); the meters run only while sound plays."""
        self.engine.playing = playing
        if playing:
            self.meter_timer.start()
        # when paused, the timer stops itself once the meters have fallen silent (_update_meters)

    def play_response(self) -> None:
        """Play the current pose's impulse response once through the engine, then the clip again."""
        heard = None if self.live is None else self.live.heard
        if heard is None or self.engine is None:
            self.window.statusBar().showMessage("No impulse response yet: wait for the scene to load", 3000)
            return
        impulse = heard.result.impulse
        self.engine.play_once(impulse)
        self.meter_timer.start()
        self.window.statusBar().showMessage(
            f"Playing this pose's impulse response ({1000 * impulse.shape[1] / self.engine.sample_rate:.0f} ms)", 3000)

    # ------------------------------------------------------------------ results (GUI thread)
    def _passing(self, heard: Heard) -> bool:
        """Whether ``heard`` is a pose passed through: a handle is dragged, or a newer pose's filter
        is on its way (after a release, the moves' filters still arrive while the released pose's is
        made). Such a pose is shown light (no T60), at most every SHOW_MS, so the GUI thread never
        takes the CPU from the filter the user waits for."""
        state, live = self._state, self.live
        return (state is not None and state.interacting) or (live is not None and heard.request.seq != live.seq)

    def _on_rendered(self, heard: Heard) -> None:
        """A new pose is playing: show its vicinity sets and levels, at most every SHOW_MS while moving."""
        self._shown_heard = heard
        if not self._passing(heard):
            self._show_timer.start(0)  # the pose the user stopped at: at once, in full
        elif not self._show_timer.isActive():
            self._show_timer.start(SHOW_MS)

    def interaction_changed(self, moving: bool) -> None:
        """A move ended: show the pose heard now in full (the response's T60 is measured only then)."""
        live = self.live
        if not moving and live is not None and live.heard is not None and live.worker.wait_idle(0.0):
            self._on_rendered(live.heard)  # (when a newer pose is on its way, that one is shown in full)

    def _show_heard(self) -> None:
        heard = self._shown_heard
        if self._view is None or self.live is None or heard is None or heard is not self.live.heard:
            self._show_held_since = None
            return  # a newer pose (or another scene) has replaced it
        if self.sound_pending():  # the sound first, for at most SHOW_WAIT_MAX_S
            now = time.perf_counter()
            if self._show_held_since is None:
                self._show_held_since = now
            if now - self._show_held_since < SHOW_WAIT_MAX_S:
                self._show_timer.start(SHOW_WAIT_MS)
                return
        self._show_held_since = None
        self._view.set_vicinity(heard.result.listener_vicinity, heard.result.source_vicinity)
        self.panel.show_levels(*heard.levels)  # the clip through this pose's filter, at full volume
        refined = self.live.refined
        self.panel.show_heard(None if self.live.refiner is None else
                              refined is not None and refined.seq == heard.request.seq)
        self.response.show_response(heard.result.impulse, self.renderer.sample_rate,  # the filter it plays
                                    moving=self._passing(heard))

    def _on_refined(self, refined: Refined) -> None:
        """The pose heard now plays its loop rendered in full."""
        live = self.live
        if live is not None and live.heard is not None and live.heard.request.seq == refined.seq:
            self.panel.show_heard(True)

    def _on_render_failed(self, request: PoseRequest | None, message: str) -> None:
        self.window.statusBar().showMessage(f"Render failed: {message}", 10000)

    def _update_meters(self) -> None:
        """The engine's output level (sound card or simulated clock); stops when paused and silent."""
        if self.engine is None:
            self.meter_timer.stop()
            return
        left, right = self.engine.block_levels
        # Every repaint of any widget recomposes the whole window (it holds an OpenGL view): with
        # software GL that costs tens of ms, so the meters move twice a second, when a level changed by 1.5 dB.
        shown = self._meters_shown
        if shown is None or max(abs(left - shown[0]), abs(right - shown[1])) >= 1.5:
            self.panel.show_meters(left, right)
            self._meters_shown = (left, right)
        self.panel.show_peaks(*self.engine.take_peaks())  # peak hold and clip light (repaint only on a change)
        if not self.engine.playing and max(left, right) <= SILENCE_DB:
            self.meter_timer.stop()


CLIP_SECONDS = 30.0
"The longest clip the explorer loops; a longer one is cut, and says so."


def load_clip_noted(path, sample_rate: int, max_seconds: float = CLIP_SECONDS) -> tuple[np.ndarray, list[str]]:
    """A clip as the explorer loops it (mono float32 [T] at ``sample_rate``, at most ``max_seconds``)
    and notes on what reading changed (down-mixed, resampled, cut), each naming the file."""
    from pathlib import Path

    from avgs.io.audio_input import read_mono_noted

    mono, notes = read_mono_noted(path, sample_rate, max_seconds=max_seconds)
    return mono, [f"clip {Path(path).name}: {note}" for note in notes]


def export_clip(renderer: TrainedScene, live: LiveAudio, clip: np.ndarray) -> np.ndarray:
    """[2, T] float32: the whole ``clip`` [T] (not the loop the engine plays, which its seam's
    crossfade makes shorter) as heard at the pose playing now: through the pose's filter, or
    rendered in full by the renderer's own synthesis once that pose's loop has been (a settled pose
    of a model whose render is not its filter)."""
    from avgs.config import SynthesisConfig

    heard, refined = live.heard, live.refined
    if heard is None:
        raise ValueError("no binaural render yet: wait for the scene to load")
    pose = heard.request.pose
    full = refined is not None and refined.seq == heard.request.seq
    result = renderer.render(listener=pose.listener, yaw=pose.yaw, mono=np.asarray(clip, dtype=np.float32),
                             source=pose.source if renderer.source_aware else None, synthesis=None if full else SynthesisConfig(method="filter"))
    return np.asarray(result.binaural, dtype=np.float32)
