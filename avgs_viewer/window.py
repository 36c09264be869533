"""The Qt main window: composition only.

It owns the 3D view (:class:`~avgs_viewer.canvas.SceneCanvas`, which draws on demand,
coalesced) and hands it to :class:`~avgs_viewer.scene_view.SceneView`; forwards mouse
events to the Qt-free :class:`~avgs_viewer.drag.DragController`; mirrors the
:class:`~avgs_viewer.state.ViewerState` in its widgets. A pose change goes to the audio
path first (:class:`~avgs_viewer.worker.LiveAudio`: the pose's filter on a worker, then
the audio engine's next block) and only asks for a repaint; results come back to the GUI
thread with a queued signal. The model never runs on the GUI thread: checkpoints load on
a background thread too, so the window shows before torch is even imported. Under the 3D view,
the :class:`~avgs_viewer.response_view.ResponsePanel` shows the impulse response the engine plays
(the worker's filter: nothing is computed for it but its decay curves) and plays it on request.
A scene trained with one source position (``SceneRenderer.source_aware`` False) keeps its source
where it is, and the pose panel says why.
"""

from __future__ import annotations

import gc
import os
import threading
import traceback
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Literal

import numpy as np
from PySide6 import QtCore, QtGui, QtWidgets
from . import audio, export
from .canvas import SceneCanvas
from .drag import DragController
from .help import help_html
from .help import key as help_key
from .pose_panel import PosePanel
from .propagation_view import MapControls
from .response_view import ResponsePanel
from .scene_view import SceneView
from .state import ColourMode, Event, ViewerState
from .trained_scene import TrainedScene

if TYPE_CHECKING:  # imported when a scene or a drag first needs them
    from .pointer import PointerFollower
    from .refine import Refined
    from .worker import Heard, LiveAudio, PoseRequest

COLOUR_MODE_NAMES = {ColourMode.VICINITY: "Vicinity sets", ColourMode.ALPHA: "Learned alpha (PCA)",
                     ColourMode.RGB: "G's colour (RGB)"}
YAW_STEP = 15.0
METER_FLOOR_DB = -60.0
METER_INTERVAL_MS = 500
SHOW_MS = 150
RESPONSE_HEIGHT = 200  # the impulse-response panel's height under the 3D view at start, pixels
FIXED_SOURCE_REASON = ("Trained with one source position (RWAVS task): the sound is only known for that source, "
                       "so the source stays fixed. Train with --task rir to move it.")


class _Bridge(QtCore.QObject):
    """Signals emitted from worker threads, delivered on the GUI thread (queued)."""

    loaded = QtCore.Signal(object, object)      # (path, SceneRenderer)
    load_failed = QtCore.Signal(object, str)    # (path, message)
    rendered = QtCore.Signal(object)            # worker.Heard: the pose the engine now plays
    refined = QtCore.Signal(object)             # refine.Refined: that pose's loop rendered in full
    render_failed = QtCore.Signal(object, str)  # (PoseRequest, message)


def audio_status_text(message: str | None, sample_rate: int) -> str:
    """The status bar's audio field in plain words (the technical reason goes in its tooltip)."""
    if not message:
        return f"Audio: {sample_rate} Hz"
    if message == "Audio output off":
        return "Audio output off: the meters show what would play"
    return "No audio: no sound card found (the meters show what would play)"


HEARD_TEXT = {False: "Hearing: the pose's filter", True: "Hearing: the full render"}
HEARD_TIP = ("While a pose changes you hear its filter at once; once it holds, the loop rendered in full "
             "at it (what avgs render writes) is crossfaded in.")


def _swatches(rows: list[tuple[str, tuple[int, int, int]]]) -> str:
    return "<br>".join(f'<span style="color: rgb{tuple(c)}">&#9679;</span> {t}' for t, c in rows)


class ControlPanel(QtWidgets.QWidget):
    """Pose fields, colour mode, legend, slice height, yaw dial, playback and level meters."""

    def __init__(self, parent: QtWidgets.QWidget | None = None):
        super().__init__(parent)
        self.state: ViewerState | None = None
        form = QtWidgets.QVBoxLayout(self)

        self.pose = PosePanel()
        form.addWidget(self.pose)

        self.colour_mode = QtWidgets.QComboBox()
        self.legend = QtWidgets.QLabel()
        self.legend.setTextFormat(QtCore.Qt.TextFormat.RichText)
        self.legend.setWordWrap(True)
        form.addWidget(self._group("Colour", self.colour_mode, self.legend))

        self.slice = QtWidgets.QSlider(QtCore.Qt.Orientation.Horizontal)
        self.slice.setRange(0, 1000)
        self.slice_label = QtWidgets.QLabel()
        form.addWidget(self._group("Slice height (hide points above)", self.slice, self.slice_label))

        self.yaw = QtWidgets.QDial()
        self.yaw.setRange(0, 359)
        self.yaw.setWrapping(True)
        self.yaw.setNotchesVisible(True)
        self.yaw_label = QtWidgets.QLabel()
        form.addWidget(self._group("Listener yaw (Q / E, Left / Right)", self.yaw, self.yaw_label))

        self.play = QtWidgets.QPushButton("Pause")
        self.volume = QtWidgets.QSlider(QtCore.Qt.Orientation.Horizontal)
        self.volume.setRange(0, 100)
        self.meter_left, self.meter_right = QtWidgets.QProgressBar(), QtWidgets.QProgressBar()
        meters = QtWidgets.QWidget()
        meter_grid = QtWidgets.QGridLayout(meters)
        meter_grid.setContentsMargins(0, 0, 0, 0)
        for row, (meter, name, ear) in enumerate(((self.meter_left, "L", "left"), (self.meter_right, "R", "right"))):
            meter.setRange(int(METER_FLOOR_DB * 10), 0)
            meter.setValue(int(METER_FLOOR_DB * 10))  # silent until the first levels arrive
            meter.setFormat(f"{name} %v")
            meter.setTextVisible(False)
            meter.setToolTip(f"{ear} ear, {METER_FLOOR_DB:.0f} to 0 dB")
            label = QtWidgets.QLabel(f"<b>{name}</b>")
            label.setToolTip(f"{ear} ear")
            meter_grid.addWidget(label, row, 0)
            meter_grid.addWidget(meter, row, 1)
        self.meter_labels = [meter_grid.itemAtPosition(r, 0).widget() for r in range(2)]
        self.levels = QtWidgets.QLabel("L - dB   R - dB   ILD - dB")
        self.heard = QtWidgets.QLabel("")
        "What plays: the pose's filter (while moving) or its loop rendered in full (settled); hidden when that is one thing."
        self.heard.hide()
        form.addWidget(self._group("Playback", self.play, QtWidgets.QLabel("Volume"), self.volume,
                                   meters, self.levels, self.heard))
        form.addStretch(1)
        self.setEnabled(False)

        self.colour_mode.currentIndexChanged.connect(self._colour_mode_changed)
        self.slice.valueChanged.connect(self._slice_changed)
        self.yaw.valueChanged.connect(lambda v: self.state and self.state.set_yaw(float(v)))
        self.play.clicked.connect(lambda: self.state and self.state.toggle_playing())
        self.volume.valueChanged.connect(lambda v: self.state and self.state.set_volume(v / 100))

    @staticmethod
    def _group(title: str, *widgets: QtWidgets.QWidget) -> QtWidgets.QGroupBox:
        box = QtWidgets.QGroupBox(title)
        layout = QtWidgets.QVBoxLayout(box)
        for w in widgets:
            layout.addWidget(w)
        return box

    def bind(self, state: ViewerState, view: SceneView) -> None:
        """Mirror ``state`` in the widgets (and widgets into it)."""
        self.state, self.view = state, view
        self.pose.bind(state)
        with QtCore.QSignalBlocker(self.colour_mode):
            self.colour_mode.clear()
            for mode, name in COLOUR_MODE_NAMES.items():
                if mode is ColourMode.RGB and not state.has_rgb:
                    continue
                self.colour_mode.addItem(name, mode)
        event: Event[Any]  # each pair's own value type: colour mode, height, yaw, playing, volume
        cb: Callable[[Any], None]
        for event, cb in ((state.events.colour_mode, self._show_colour_mode),
                          (state.events.slice_height, self._show_slice),
                          (state.events.yaw, self._show_yaw),
                          (state.events.playing, self._show_playing),
                          (state.events.volume, self._show_volume)):
            event.connect(cb)
        self._show_colour_mode(state.colour_mode)
        self._show_slice(state.slice_height)
        self._show_yaw(state.yaw)
        self._show_playing(state.playing)
        self._show_volume(state.volume)
        self.setEnabled(True)

    def _slice_to_z(self, v: int) -> float:
        lo, hi = self.state.bounds[:, 2]
        return float(lo + (hi - lo) * v / 1000)

    def _colour_mode_changed(self, index: int) -> None:
        if self.state is not None and index >= 0:
            self.state.set_colour_mode(self.colour_mode.itemData(index))

    def _slice_changed(self, v: int) -> None:
        if self.state is not None:
            self.state.set_slice_height(self._slice_to_z(v))

    def _show_colour_mode(self, mode: ColourMode) -> None:
        with QtCore.QSignalBlocker(self.colour_mode):
            self.colour_mode.setCurrentIndex(self.colour_mode.findData(mode))
        self.legend.setText(_swatches(self.view.legend_rows()))

    def _show_slice(self, z: float) -> None:
        lo, hi = self.state.bounds[:, 2]
        with QtCore.QSignalBlocker(self.slice):
            self.slice.setValue(int(round(1000 * (z - lo) / (hi - lo))) if hi > lo else 1000)
        self.slice_label.setText(f"z <= {z:.2f}")

    def _show_yaw(self, yaw: float) -> None:
        with QtCore.QSignalBlocker(self.yaw):
            self.yaw.setValue(int(round(yaw)) % 360)
        self.yaw_label.setText(f"{yaw:.0f} deg ccw from +x")

    def _show_playing(self, playing: bool) -> None:
        self.play.setText("Pause" if playing else "Play")

    def _show_volume(self, volume: float) -> None:
        with QtCore.QSignalBlocker(self.volume):
            self.volume.setValue(int(round(100 * volume)))

    def show_levels(self, left: float, right: float, ild: float) -> None:
        self.levels.setText(f"L {left:.1f} dB   R {right:.1f} dB   ILD {ild:+.1f} dB")

    def show_heard(self, refined: bool | None) -> None:
        """Say what plays: None (a model whose filter is its render: nothing to say), the pose's
        filter (False) or its loop rendered in full (True). Set only on a change: a repaint costs."""
        text = "" if refined is None else HEARD_TEXT[refined]
        if self.heard.text() != text:
            self.heard.setText(text)
            self.heard.setToolTip("" if refined is None else HEARD_TIP)
            self.heard.setVisible(bool(text))

    def show_meters(self, left: float, right: float) -> None:
        self.meter_left.setValue(int(10 * max(left, METER_FLOOR_DB)))
        self.meter_right.setValue(int(10 * max(right, METER_FLOOR_DB)))


class ExportOptions(QtWidgets.QDialog):
    """Scale, transparent background, legend and pose caption for a screenshot."""

    def __init__(self, parent: QtWidgets.QWidget | None = None):
        super().__init__(parent)
        self.setWindowTitle("Screenshot options")
        layout = QtWidgets.QFormLayout(self)
        self.scale = QtWidgets.QSpinBox()
        self.scale.setRange(1, export.MAX_SCALE)
        self.transparent = QtWidgets.QCheckBox("Transparent background")
        self.legend = QtWidgets.QCheckBox("Legend of the colours")
        self.legend.setChecked(True)
        self.caption = QtWidgets.QCheckBox("Caption with the pose")
        self.caption.setChecked(True)
        layout.addRow("Scale", self.scale)
        layout.addRow(self.transparent)
        layout.addRow(self.legend)
        layout.addRow(self.caption)
        buttons = QtWidgets.QDialogButtonBox(QtWidgets.QDialogButtonBox.StandardButton.Ok
                                             | QtWidgets.QDialogButtonBox.StandardButton.Cancel)
        buttons.accepted.connect(self.accept)
        buttons.rejected.connect(self.reject)
        layout.addRow(buttons)


class MainWindow(QtWidgets.QMainWindow):
    """The explorer: a 3D view of the scene's audio points, two draggable handles, live audio."""

    scene_loaded = QtCore.Signal(object)  # the SceneRenderer, after the scene is on screen

    def __init__(self, clip_path: str | Path | None = None, start_audio: bool = True):
        super().__init__()
        self.setWindowTitle("AV-GS explorer")
        self.resize(1280, 800)
        self.renderer: TrainedScene | None = None
        self.scene_path: Path | None = None
        self.state: ViewerState | None = None
        self.view: SceneView | None = None
        self.drag: DragController | None = None
        self.live: LiveAudio | None = None
        self._follower: PointerFollower | Literal[False] | None = None  # made at the first drag; False: none (not X11)
        self.engine: audio.StreamEngine | None = None
        self.output: audio.AudioOutput | None = None
        self.error_dialog: QtWidgets.QMessageBox | None = None
        self._clip_path = Path(clip_path) if clip_path else None
        self._start_audio = start_audio
        self._loading = False

        self._bridge = _Bridge()
        self._bridge.loaded.connect(self._on_loaded)
        self._bridge.load_failed.connect(self._on_load_failed)
        self._bridge.rendered.connect(self._on_rendered)
        self._bridge.refined.connect(self._on_refined)
        self._bridge.render_failed.connect(self._on_render_failed)

        self.plotter = SceneCanvas(self)  # no render timer; renders coalesced into repaints
        self.plotter.installEventFilter(self)
        self.plotter.iren.add_observer("StartInteractionEvent", lambda *_: self._camera_moving(True))
        self.plotter.iren.add_observer("EndInteractionEvent", lambda *_: self._camera_moving(False))
        self.panel = ControlPanel()
        self.map_controls = MapControls(self)  # propagation map toggle (panel) and listener-view inset
        self.panel.layout().insertWidget(self.panel.layout().count() - 1, self.map_controls.box)
        self.response = ResponsePanel(key_text=help_key("play_response").keys[0])
        self.response.play.connect(self.play_response)
        self.view_split = QtWidgets.QSplitter(QtCore.Qt.Orientation.Vertical)  # the 3D view over the response
        self.view_split.addWidget(self.plotter)
        self.view_split.addWidget(self.response)
        self.view_split.setStretchFactor(0, 1)
        self.view_split.setCollapsible(0, False)
        self.view_split.setSizes([800 - RESPONSE_HEIGHT, RESPONSE_HEIGHT])
        splitter = QtWidgets.QSplitter()
        splitter.addWidget(self.view_split)
        splitter.addWidget(self.panel)
        splitter.setStretchFactor(0, 1)
        splitter.setSizes([1000, 280])
        self.setCentralWidget(splitter)

        self.progress = QtWidgets.QProgressBar()
        self.progress.setRange(0, 0)  # busy indicator while loading
        self.progress.setMaximumWidth(160)
        self.progress.hide()
        # Positions kept inside the scene are reported here, not as a temporary status message,
        # which Qt clears as soon as the pointer passes over any widget with a status tip.
        self.position_notice = QtWidgets.QLabel()
        self._notice_timer = QtCore.QTimer(self)
        self._notice_timer.setSingleShot(True)
        self._notice_timer.setInterval(5000)
        self._notice_timer.timeout.connect(lambda: (self.position_notice.clear(), self.position_notice.setToolTip("")))
        self.setStatusBar(QtWidgets.QStatusBar(self))  # made here: see _build_menus on Qt's getters
        self.statusBar().addPermanentWidget(self.position_notice)
        self.audio_status = QtWidgets.QLabel()
        self.statusBar().addPermanentWidget(self.audio_status)
        self.statusBar().addPermanentWidget(self.progress)
        self._build_menus()
        # A window holding an OpenGL widget (the 3D view) is composed by OpenGL: a repaint of any
        # other widget in it (a meter, a level, a pose field, the response plot) redraws and swaps
        # the whole window, which with software GL costs ~20 ms of CPU each time (the meters alone:
        # 5 % of a core while sound plays). In native windows of their own these widgets repaint
        # by plain raster copies of their own area; the 3D view's composition is untouched.
        for widget in (self.panel, self.response, self.statusBar()):
            widget.setAttribute(QtCore.Qt.WidgetAttribute.WA_DontCreateNativeAncestors)
            widget.setAttribute(QtCore.Qt.WidgetAttribute.WA_NativeWindow)

        # Vicinity colours and levels of the newest pose, coalesced: while a handle moves, every
        # repaint delays the mouse events behind it, so at most one update per SHOW_MS.
        self._shown_heard = None
        self._show_timer = QtCore.QTimer(self)
        self._show_timer.setSingleShot(True)
        self._show_timer.timeout.connect(self._show_heard)
        self._relayout_timer = QtCore.QTimer(self)  # the 3D view's overlays placed again after a resize
        self._relayout_timer.setSingleShot(True)
        self._relayout_timer.setInterval(0)
        self._relayout_timer.timeout.connect(self._relayout)
        self.meter_timer = QtCore.QTimer(self)  # runs only while sound plays
        self.meter_timer.setInterval(METER_INTERVAL_MS)
        self.meter_timer.timeout.connect(self._update_meters)

    # ------------------------------------------------------------------ menus
    def _build_menus(self) -> None:
        """Menus whose keys come from ``help.KEYS`` (the Help dialog lists the same table)."""
        self.key_actions: dict[str, QtGui.QAction] = {}
        # The bar and its menus are made here, not taken from Qt's getters: a wrapper PySide hands
        # back for a C++-made object can be a stale one of an object freed at the same address (a
        # QOffscreenSurface of pyvistaqt's, once, in a full test run).
        bar = QtWidgets.QMenuBar(self)
        self.setMenuBar(bar)

        def menu(title: str) -> QtWidgets.QMenu:
            m = QtWidgets.QMenu(title, bar)
            bar.addMenu(m)
            return m

        file_menu = menu("&File")
        self._action(file_menu, "&Open scene...", self.choose_scene, "open_scene")
        self._action(file_menu, "Open &clip...", self.choose_clip)
        file_menu.addSeparator()
        self.export_shot_action = self._action(file_menu, "Export &screenshot...", self.choose_screenshot)
        self.export_audio_action = self._action(file_menu, "Export &audio...", self.choose_audio_export)
        file_menu.addSeparator()
        self._action(file_menu, "&Quit", self.close, "quit")
        view_menu = menu("&View")
        for name, text in (("camera_home", "&Reset camera"), ("camera_top", "Camera from &top"),
                           ("camera_front", "Camera from &front"), ("camera_listener", "Camera from the &listener")):
            self._action(view_menu, text, lambda n=name: self.camera_preset(n), name)
        view_menu.addSeparator()
        self._action(view_menu, "Play / pause", lambda: self.state and self.state.toggle_playing(), "play")
        self._action(view_menu, "Turn left", lambda: self.state and self.state.turn(YAW_STEP), "turn_left")
        self._action(view_menu, "Turn right", lambda: self.state and self.state.turn(-YAW_STEP), "turn_right")
        view_menu.addSeparator()
        self._action(view_menu, "Play the &impulse response", self.play_response, "play_response")
        self.response_action = self._action(view_menu, "Impulse response &panel", self._toggle_response)
        self.response_action.setCheckable(True)
        self.response_action.setChecked(True)
        help_menu = menu("&Help")
        self._action(help_menu, "&Keys and mouse", self.show_help, "help")
        self.help_dialog: QtWidgets.QMessageBox | None = None

    def _relayout(self) -> None:
        if self.view is not None:
            self.map_controls.relayout()
            self.plotter.render()

    def _toggle_response(self) -> None:
        self.response.setVisible(self.response_action.isChecked())

    def play_response(self) -> None:
        """Play the current pose's impulse response once through the engine, then the clip again."""
        heard = None if self.live is None else self.live.heard
        if heard is None or self.engine is None:
            self.statusBar().showMessage("No impulse response yet: wait for the scene to load", 3000)
            return
        impulse = heard.result.impulse
        self.engine.play_once(impulse)
        self.meter_timer.start()
        self.statusBar().showMessage(
            f"Playing this pose's impulse response ({1000 * impulse.shape[1] / self.engine.sample_rate:.0f} ms)", 3000)

    def camera_preset(self, name: str) -> None:
        """One of the view's camera presets: camera_home, camera_top, camera_front, camera_listener."""
        if self.view is not None:
            getattr(self.view, name)()
            self.plotter.render()

    def show_help(self) -> None:
        """Every key and mouse action (``help.KEYS`` and ``help.MOUSE``), non-blocking."""
        if self.help_dialog is None:
            box = QtWidgets.QMessageBox(QtWidgets.QMessageBox.Icon.NoIcon, "AV-GS explorer: keys and mouse",
                                        help_html(), QtWidgets.QMessageBox.StandardButton.Close, self)
            box.setTextFormat(QtCore.Qt.TextFormat.RichText)
            self.help_dialog = box
        self.help_dialog.show()
        self.help_dialog.raise_()

    def _action(self, menu: QtWidgets.QMenu, text: str, slot, key_name: str | None = None) -> QtGui.QAction:
        """A menu entry; ``key_name`` names its keys in ``help.KEYS``."""
        act = QtGui.QAction(text, self)
        if key_name is not None:
            act.setShortcuts([QtGui.QKeySequence(k) for k in help_key(key_name).keys])
            act.setShortcutContext(QtCore.Qt.ShortcutContext.WindowShortcut)
            self.key_actions[key_name] = act
        act.triggered.connect(lambda _=False: slot())
        menu.addAction(act)
        return act

    # ------------------------------------------------------------------ loading
    def open_scene(self, path: str | Path) -> None:
        """Load a checkpoint on a background thread; the scene replaces the current one when ready."""
        path = Path(path)
        if self._loading:
            self.statusBar().showMessage("Still loading the previous scene", 3000)
            return
        self._loading = True
        self.progress.show()
        self.statusBar().showMessage(f"Loading {path} ...")

        def load() -> None:
            # A garbage collection run on this thread could delete Qt or VTK objects (a closed
            # window's cycles) off the GUI thread, which aborts the process: none runs while loading.
            collecting = gc.isenabled()
            gc.disable()
            try:
                from avgs import SceneRenderer  # torch is imported here, off the GUI thread
                from avgs.evaluation.metrics import rt60

                renderer = SceneRenderer.load(path)
                rt60(np.zeros(1))  # its imports too (the response panel's T60), not on the GUI thread
            except Exception as exc:  # every failure becomes a dialog, never a crash
                message = str(exc) if isinstance(exc, (ValueError, FileNotFoundError)) else \
                    f"{type(exc).__name__}: {exc}\n\n{traceback.format_exc(limit=3)}"
                self._bridge.load_failed.emit(path, message)
            else:
                self._bridge.loaded.emit(path, renderer)
            finally:
                if collecting:
                    gc.enable()

        gc.collect()  # here, on the GUI thread, what earlier scenes and windows left behind
        threading.Thread(target=load, name="avgs-load", daemon=True).start()

    def _on_load_failed(self, path: Path, message: str) -> None:
        self._loading = False
        self.progress.hide()
        self.statusBar().showMessage(f"Could not open {path}", 5000)
        self.show_error("Cannot open scene", f"Could not open {path}:\n{message}")

    def show_error(self, title: str, message: str) -> None:
        """A non-blocking error dialog (kept as ``error_dialog`` for tests)."""
        box = QtWidgets.QMessageBox(QtWidgets.QMessageBox.Icon.Critical, title, message,
                                    QtWidgets.QMessageBox.StandardButton.Ok, self)
        box.setAttribute(QtCore.Qt.WidgetAttribute.WA_DeleteOnClose)
        box.open()
        self.error_dialog = box

    def _on_loaded(self, path: Path, renderer: TrainedScene) -> None:
        self._loading = False
        self.progress.hide()
        try:
            self._install_scene(renderer)
        except Exception as exc:  # a checkpoint the viewer cannot draw
            self.show_error("Cannot show scene", f"Could not show {path}:\n{type(exc).__name__}: {exc}")
            return
        self.scene_path = Path(path)
        self.setWindowTitle(f"AV-GS explorer - {Path(path).name}")
        self.statusBar().showMessage(f"Loaded {path}: {len(renderer.points)} audio points", 5000)
        self.scene_loaded.emit(renderer)

    def _install_scene(self, renderer: TrainedScene) -> None:
        from .worker import LiveAudio

        self._teardown_scene()
        # Positions stay inside the room's floor plan; a model trained with one source position knows
        # its sound only for that source: the source stays there (keyed on the renderer alone).
        state = ViewerState(renderer.bounds, renderer.source, has_rgb=renderer.gaussians is not None,
                            outline=renderer.outline,
                            source_fixed=None if renderer.source_aware else FIXED_SOURCE_REASON)
        self.plotter.clear()
        view = SceneView(self.plotter, renderer, state)
        self.renderer, self.state, self.view = renderer, state, view
        self.drag = DragController(state, view.projector, view.handle_radius)
        self.panel.bind(state, view)
        self.map_controls.install(self.plotter, renderer, state,  # the map waits while audio renders
                                  audio_busy=lambda: self.live is not None and not self.live.worker.wait_idle(0.0))
        if self.engine is None or self.engine.sample_rate != renderer.sample_rate:
            self._start_engine(renderer.sample_rate)
        self.engine.reset_gain()
        state.events.clamped.connect(self._show_position_notice)
        state.events.refused.connect(self._show_position_notice)
        state.events.interacting.connect(self._interaction_changed)
        self.response.show_response(None, renderer.sample_rate)
        state.events.volume.connect(lambda v: setattr(self.engine, "volume", v))
        state.events.playing.connect(self._set_playing)
        self.engine.volume = state.volume
        self._set_playing(state.playing)
        clip = self._load_clip(renderer.sample_rate)
        # LiveAudio subscribes to the state's pose event; the view's handlers before it only ask
        # for a repaint (SceneCanvas), so a move reaches the audio path before anything is drawn.
        self.live = LiveAudio(renderer, state, self.engine, clip, on_result=self._bridge.rendered.emit,
                              on_error=lambda req, exc: self._bridge.render_failed.emit(req, f"{type(exc).__name__}: {exc}"),
                              on_refined=self._bridge.refined.emit)
        self.live.request()
        live = self.live
        engine = self.engine  # sound first: paints wait for the filter and for its first block to leave the engine
        self.plotter.hold = lambda: not live.worker.wait_idle(0.0) or engine.switch_pending
        self.plotter.render()

    def _set_playing(self, playing: bool) -> None:
        """Play or pause the engine (it ramps over one block); the meters run only while sound plays."""
        self.engine.playing = playing
        if playing:
            self.meter_timer.start()
        # when paused, the timer stops itself once the meters have fallen silent (_update_meters)

    def _load_clip(self, sample_rate: int) -> np.ndarray:
        if self._clip_path is not None:
            try:
                return audio.load_clip(self._clip_path, sample_rate)
            except (ValueError, FileNotFoundError) as exc:
                self.show_error("Cannot open clip", str(exc))
                self._clip_path = None
        return export.default_clip(sample_rate)

    def _show_position_notice(self, message: str) -> None:
        """Say for 5 s that a dragged position was kept inside the scene (ViewerState's ``clamped``)."""
        self.position_notice.setText(message)
        self.position_notice.setToolTip(message)  # whole, where a narrow window clips it
        self._notice_timer.start()

    def _start_engine(self, sample_rate: int) -> None:
        if self.output is not None:
            self.output.close()
        self.engine = audio.StreamEngine(sample_rate)
        # Without a sound card (or with audio off) a simulated clock pulls the engine's blocks,
        # so meters, tests and the benchmark see the same output a card would play.
        self.output = audio.AudioOutput(self.engine, device=self._start_audio)
        message = self.output.start()
        self.audio_status.setText(audio_status_text(message, sample_rate))
        self.audio_status.setToolTip(message or "")
        if message:
            self.statusBar().showMessage(audio_status_text(message, sample_rate), 10000)

    def _teardown_scene(self) -> None:
        self.map_controls.teardown()
        if self._follower:
            self._follower.stop()
        if self.live is not None:
            self.plotter.hold = None
            self.live.close()
            self.live = None
        if self.view is not None:
            self.view.close()
            self.view = None
        self.drag = None

    # ------------------------------------------------------------------ results
    def _on_rendered(self, heard: Heard) -> None:
        """A new pose is playing: show its vicinity sets and levels, at most every SHOW_MS while moving."""
        self._shown_heard = heard
        if not self._show_timer.isActive():
            moving = self.state is not None and self.state.interacting
            self._show_timer.start(SHOW_MS if moving else 0)

    def _interaction_changed(self, moving: bool) -> None:
        """A move ended: show the pose heard now in full (the response's T60 is measured only then)."""
        live = self.live
        if not moving and live is not None and live.heard is not None and live.worker.wait_idle(0.0):
            self._on_rendered(live.heard)  # (when a newer pose is on its way, that one is shown in full)

    def _show_heard(self) -> None:
        heard = self._shown_heard
        if self.view is None or self.live is None or heard is None or heard is not self.live.heard:
            return  # a newer pose (or another scene) has replaced it
        self.view.set_vicinity(heard.result.listener_vicinity, heard.result.source_vicinity)
        self.panel.show_levels(*heard.levels)  # the clip through this pose's filter, at full volume
        refined = self.live.refined
        self.panel.show_heard(None if self.live.refiner is None else
                              refined is not None and refined.seq == heard.request.seq)
        self.response.show_response(heard.result.impulse, self.renderer.sample_rate,  # the filter it plays
                                    moving=self.state.interacting)

    def _on_refined(self, refined: Refined) -> None:
        """The pose heard now plays its loop rendered in full."""
        live = self.live
        if live is not None and live.heard is not None and live.heard.request.seq == refined.seq:
            self.panel.show_heard(True)

    def _on_render_failed(self, request: PoseRequest | None, message: str) -> None:
        self.statusBar().showMessage(f"Render failed: {message}", 10000)

    def _update_meters(self) -> None:
        """The engine's output level (sound card or simulated clock); stops when paused and silent."""
        if self.engine is None:
            self.meter_timer.stop()
            return
        left, right = self.engine.block_levels
        # Every repaint of any widget recomposes the whole window (it holds an OpenGL view): with
        # software GL that costs tens of ms, so the meters move twice a second, when a level changed by 1.5 dB.
        shown = getattr(self, "_meters_shown", None)
        if shown is None or max(abs(left - shown[0]), abs(right - shown[1])) >= 1.5:
            self.panel.show_meters(left, right)
            self._meters_shown = (left, right)
        if not self.engine.playing and max(left, right) <= audio.SILENCE_DB:
            self.meter_timer.stop()

    # ------------------------------------------------------------------ mouse
    def _camera_moving(self, moving: bool) -> None:
        if self.state is not None:
            self.state.set_interacting(moving)

    def eventFilter(self, obj: QtCore.QObject, event: QtCore.QEvent) -> bool:  # noqa: N802
        """Forward left-button drags that start on a handle to the drag logic; the rest to VTK."""
        kind = event.type()
        if obj is self.plotter and kind == QtCore.QEvent.Type.Resize and self.view is not None:
            self._relayout_timer.start()  # once the render window has its new size
        if obj is self.plotter and self.drag is not None and kind in (
                QtCore.QEvent.Type.MouseButtonPress, QtCore.QEvent.Type.MouseMove,
                QtCore.QEvent.Type.MouseButtonRelease):
            pos = event.position()
            scale = self.plotter.devicePixelRatioF()
            x, y = pos.x() * scale, (self.plotter.height() - pos.y() - 1) * scale  # VTK display pixels
            if kind == QtCore.QEvent.Type.MouseButtonPress:
                if event.button() == QtCore.Qt.MouseButton.LeftButton:
                    grabbed = self.drag.press(x, y)
                    if grabbed and self.drag.dragging is not None:
                        self._follow_pointer(x, y)
                    return grabbed
            elif kind == QtCore.QEvent.Type.MouseMove:
                return self.drag.move(x, y)
            elif event.button() == QtCore.Qt.MouseButton.LeftButton:
                if self._follower:
                    self._follower.stop()
                taken = self.drag.release(x, y)
                if self.live is not None:
                    self.live.follow(False)  # the state's pose, unless the follower already asked for it
                return taken
        return super().eventFilter(obj, event)

    def _follow_pointer(self, x: float, y: float) -> None:
        """Hand the drag's moves and release to the audio path straight from the X server, ahead of
        the GUI thread (:mod:`avgs_viewer.pointer`); nothing where that is not possible."""
        from .pointer import PointerFollower, XPointer

        if self._follower is None:
            self._follower = False
            if QtGui.QGuiApplication.platformName() == "xcb" and not os.environ.get("AVGS_VIEWER_NO_POINTER"):
                try:
                    self._follower = PointerFollower(XPointer())
                except OSError:
                    pass
        live, pose_at = self.live, self.drag.follow_map(x, y)
        if not self._follower or live is None or pose_at is None:
            return
        scale, height = self.plotter.devicePixelRatioF(), self.plotter.height()
        origin = self.plotter.mapToGlobal(QtCore.QPoint(0, 0))

        def to_display(root_x: int, root_y: int) -> tuple[float, float]:  # as this filter maps Qt's positions
            lx, ly = root_x / scale - origin.x(), root_y / scale - origin.y()
            return lx * scale, (height - ly - 1) * scale

        def moved(px: float, py: float, final: bool) -> None:
            pose = pose_at(px, py)
            if pose is not None:
                live.request(pose)

        live.follow(True)
        if not self._follower.start(to_display, (x, y), moved, lambda exc: live.follow(False)):
            live.follow(False)

    # ------------------------------------------------------------------ file actions
    def choose_scene(self) -> None:
        path, _ = QtWidgets.QFileDialog.getOpenFileName(self, "Open scene", "", "AV-GS checkpoints (*.ckpt);;All files (*)")
        if path:
            self.open_scene(path)

    def choose_clip(self) -> None:
        path, _ = QtWidgets.QFileDialog.getOpenFileName(self, "Open clip", "", "Audio (*.wav *.flac *.ogg);;All files (*)")
        if path:
            self.open_clip(path)

    def open_clip(self, path: str | Path) -> None:
        """Loop another mono clip (down-mixed and resampled to the scene's rate)."""
        if self.renderer is None:
            self._clip_path = Path(path)
            return
        try:
            clip = audio.load_clip(path, self.renderer.sample_rate)
        except (ValueError, FileNotFoundError) as exc:
            self.show_error("Cannot open clip", str(exc))
            return
        self._clip_path = Path(path)
        self.live.set_clip(clip)
        self.statusBar().showMessage(f"Looping {path} ({len(clip) / self.renderer.sample_rate:.1f} s)", 5000)

    def choose_screenshot(self) -> None:
        if self.view is None:
            return
        options = ExportOptions(self)
        if options.exec() != QtWidgets.QDialog.DialogCode.Accepted:
            return
        path, _ = QtWidgets.QFileDialog.getSaveFileName(self, "Export screenshot", "scene.png", "PNG (*.png)")
        if path:
            self.export_screenshot(path, options.scale.value(), options.transparent.isChecked(),
                                   legend=options.legend.isChecked(), caption=options.caption.isChecked())

    def export_screenshot(self, path: str | Path, scale: int = 1, transparent: bool = False,
                          legend: bool = False, caption: bool = False) -> Path | None:
        """Write the 3D view as a PNG (``scale`` times the view's size), with the colour legend
        and a caption naming the pose if asked (placed where they cover no handle)."""
        try:
            with export.annotated(self.view, legend=legend, caption=caption):
                out = export.write_screenshot(self.plotter, path, scale=scale, transparent=transparent,
                                              inputs=(self.scene_path, self._clip_path))
        except (ValueError, OSError) as exc:
            self.show_error("Cannot export screenshot", str(exc))
            return None
        finally:
            self.plotter.render()
        self.statusBar().showMessage(f"Wrote {out}", 5000)
        return out

    def choose_audio_export(self) -> None:
        path, _ = QtWidgets.QFileDialog.getSaveFileName(self, "Export audio", "binaural.wav", "WAV (*.wav)")
        if path:
            self.export_audio(path)

    def export_audio(self, path: str | Path) -> Path | None:
        """Write the looped clip as heard now (the pose's filter, or its loop rendered in full once settled) as a WAV."""
        if self.live is None or self.live.heard is None:
            self.show_error("Cannot export audio", "No binaural render yet: wait for the scene to load.")
            return None
        try:
            out = export.write_wav(path, self.live.heard_clip(), self.renderer.sample_rate,
                                   inputs=(self.scene_path, self._clip_path))
        except (ValueError, OSError) as exc:
            self.show_error("Cannot export audio", str(exc))
            return None
        self.statusBar().showMessage(f"Wrote {out}", 5000)
        return out

    # ------------------------------------------------------------------ closing
    def closeEvent(self, event: QtGui.QCloseEvent) -> None:  # noqa: N802
        self.meter_timer.stop()
        self._teardown_scene()
        if self._follower:
            self._follower.close()
            self._follower = None
        if self.output is not None:
            self.output.close()
        self.plotter.close()
        super().closeEvent(event)
