"""The Qt main window: composition only.

It owns the 3D view (:class:`~avgs_viewer.canvas.SceneCanvas`, which draws on demand,
coalesced) and hands it to :class:`~avgs_viewer.scene_view.SceneView`; forwards its mouse
events to :class:`~avgs_viewer.mouse.ViewMouse` (the Qt-free
:class:`~avgs_viewer.drag.DragController` behind it); mirrors the
:class:`~avgs_viewer.state.ViewerState` in the side panel
(:class:`~avgs_viewer.control_panel.ControlPanel`). Its other parts: the menus
(:mod:`avgs_viewer.menus`), the file and error dialogs (:mod:`avgs_viewer.file_dialogs`), the
checkpoint loader (:mod:`avgs_viewer.loading`) and the audio path
(:class:`~avgs_viewer.audio_path.AudioPath`). A pose change goes to the audio path
first (:class:`~avgs_viewer.worker.LiveAudio`: the pose's filter on a worker, then the audio
engine's next block) and only asks for a repaint; results come back to the GUI thread with a
queued signal. The model never runs on the GUI thread: checkpoints load on a background
thread too, so the window shows before torch is even imported. Under the 3D view, the
:class:`~avgs_viewer.response_view.ResponsePanel` shows the impulse response the engine plays
(the worker's filter: nothing is computed for it but its decay curves) and plays it on request.
A scene trained with one source position (``SceneRenderer.source_aware`` False) keeps its source
where it is, and the pose panel says why.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from PySide6 import QtCore, QtGui, QtWidgets

from . import audio, export, file_dialogs
from .audio_path import AudioPath
from .canvas import NativeCanvas, make_canvas
from .control_panel import ControlPanel
from .audition import Audition
from .drag import DragController
from .export_actions import ExportActions
from .help import key as help_key
from .loading import SceneLoader, settle_heap
from .head_tracking import DEFAULT_PORT, HeadTracker, Reference, tracked_position, tracked_yaw
from .menus import MenuCommands, add_action, build_menus, help_dialog
from .mouse import ViewMouse
from .navigation import Navigation
from .propagation_view import MapControls
from .response_view import ResponsePanel
from .scene_view import SceneView
from .sources import Sources
from .sources_panel import ONE_SOURCE_REASON, SourcesPanel
from .state import ViewerState
from .trained_scene import TrainedScene
from .undo import PoseHistory

if TYPE_CHECKING:  # imported when a scene first needs them
    from .sound_output import AudioOutput
    from .worker import LiveAudio

RESPONSE_HEIGHT = 200  # the impulse-response panel's height under the 3D view at start, pixels
FIXED_SOURCE_REASON = ("Trained with one source position (RWAVS task): the sound is only known for that source, "
                       "so the source stays fixed. Train with --task rir to move it.")


class MainWindow(QtWidgets.QMainWindow):
    """The explorer: a 3D view of the scene's audio points, two draggable handles, live audio."""

    scene_loaded = QtCore.Signal(object)  # the SceneRenderer, after the scene is on screen

    def __init__(self, clip_path: str | Path | None = None, start_audio: bool = True):
        super().__init__()
        self.setWindowTitle("AV-GS explorer")
        self.resize(1280, 680)  # fits a 1366 x 768 screen with a task bar (minimum: MIN_SIZE)
        self.renderer: TrainedScene | None = None
        self.scene_path: Path | None = None
        self.state: ViewerState | None = None
        self.view: SceneView | None = None
        self.drag: DragController | None = None
        self.error_dialog: QtWidgets.QMessageBox | None = None
        self.help_dialog: QtWidgets.QMessageBox | None = None
        self._clip_path = Path(clip_path) if clip_path else None
        self._loading = False

        self.loader = SceneLoader()  # checkpoints load on a thread of their own
        self.loader.loaded.connect(self._on_loaded)
        self.loader.load_failed.connect(self._on_load_failed)

        self.plotter = make_canvas(self)  # no render timer; renders coalesced into repaints
        self.plotter.setMinimumSize(320, 240)  # the window's minimum stays under 700 px tall (a 1366 x 768 screen)
        self.mouse = ViewMouse(self.plotter)  # handle drags, and the X pointer during one
        self.plotter.installEventFilter(self)
        self.plotter.iren.add_observer("StartInteractionEvent", lambda *_: self._camera_moving(True))
        self.plotter.iren.add_observer("EndInteractionEvent", lambda *_: self._camera_moving(False))
        self.panel = ControlPanel()
        self.map_controls = MapControls(self)  # propagation map toggle (panel) and listener-view inset
        self.panel.layout().insertWidget(self.panel.layout().count() - 1, self.map_controls.box)
        self.sources_panel = SourcesPanel(lambda: file_dialogs.ask_clip(self))  # several sources (source-aware)
        self.panel.layout().insertWidget(self.panel.layout().count() - 1, self.sources_panel.box)
        self.sources: Sources | None = None
        self.response = ResponsePanel(key_text=help_key("play_response").keys[0])
        self.view_split = QtWidgets.QSplitter(QtCore.Qt.Orientation.Vertical)  # the 3D view over the response
        self.view_split.addWidget(self.plotter)
        self.view_split.addWidget(self.response)
        self.view_split.setStretchFactor(0, 1)
        self.view_split.setCollapsible(0, False)
        self.view_split.setSizes([680 - RESPONSE_HEIGHT, RESPONSE_HEIGHT])
        self.panel_scroll = QtWidgets.QScrollArea()  # the side panel scrolls on a short screen
        self.panel_scroll.setWidget(self.panel)
        self.panel_scroll.setWidgetResizable(True)
        self.panel_scroll.setFrameShape(QtWidgets.QFrame.Shape.NoFrame)
        self.panel_scroll.setHorizontalScrollBarPolicy(QtCore.Qt.ScrollBarPolicy.ScrollBarAlwaysOff)
        self.panel_scroll.setMinimumWidth(self.panel.minimumSizeHint().width()
                                          + self.panel_scroll.verticalScrollBar().sizeHint().width())
        splitter = QtWidgets.QSplitter()
        splitter.addWidget(self.view_split)
        splitter.addWidget(self.panel_scroll)
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
        self.setStatusBar(QtWidgets.QStatusBar(self))  # made here: see menus.build_menus on Qt's getters
        self.statusBar().addPermanentWidget(self.position_notice)
        self.audio_status = QtWidgets.QLabel()
        self.statusBar().addPermanentWidget(self.audio_status)
        self.statusBar().addPermanentWidget(self.progress)
        # engine, output, the scene's LiveAudio, meters, and the pose heard shown in the widgets
        self.audio_path = AudioPath(self, self.plotter, self.panel, self.response, self.audio_status, start_audio)
        self.response.play.connect(self.audio_path.play_response)
        self.exports = ExportActions(self)  # File > Export impulse response, grid, fly-through; Record path
        menus = build_menus(self, MenuCommands(  # keys from help.KEYS (the Help dialog lists the same table)
            choose_scene=self.choose_scene, choose_clip=self.choose_clip, choose_screenshot=self.choose_screenshot,
            choose_audio_export=self.choose_audio_export, quit=self.close, camera_preset=self.camera_preset,
            toggle_playing=lambda: self.state and self.state.toggle_playing(),
            turn=lambda degrees: self.state and self.state.turn(degrees),
            play_response=self.audio_path.play_response, show_response=self.response.setVisible,
            show_help=self.show_help, choose_impulse_export=self.exports.choose_impulse_export,
            choose_grid_export=self.exports.choose_grid_export, record_path=self.exports.record_path,
            choose_path_save=self.exports.choose_path_save, choose_flythrough=self.exports.choose_flythrough))
        self.key_actions = menus.key_actions
        self.export_shot_action, self.export_audio_action = menus.export_shot_action, menus.export_audio_action
        self.response_action = menus.response_action
        self.record_path_action, self.export_actions = menus.record_path_action, menus.export_actions
        self._add_tools(menus.menus)
        # A window holding an OpenGL widget (the 3D view) is composed by OpenGL: a repaint of any
        # other widget in it (a meter, a level, a pose field, the response plot) redraws and swaps
        # the whole window, which with software GL costs ~20 ms of CPU each time (the meters alone:
        # 5 % of a core while sound plays). In native windows of their own these widgets repaint
        # by plain raster copies of their own area; the 3D view's composition is untouched.
        for widget in (self.panel_scroll, self.response, self.statusBar()):
            widget.setAttribute(QtCore.Qt.WidgetAttribute.WA_DontCreateNativeAncestors)
            widget.setAttribute(QtCore.Qt.WidgetAttribute.WA_NativeWindow)

        self._relayout_timer = QtCore.QTimer(self)  # the 3D view's overlays placed again after a resize
        self._relayout_timer.setSingleShot(True)
        self._relayout_timer.setInterval(0)
        self._relayout_timer.timeout.connect(self._relayout)

    def _add_tools(self, menus: dict) -> None:
        """Undo of poses, A/B audition, viewpoints, recent files, drops, point size, FPS, head tracking."""
        self.history = PoseHistory(self)
        view_menu = menus["view"]
        view_menu.addSeparator()
        add_action(self, view_menu, "&Undo pose change", self.history.stack.undo, "undo", self.key_actions)
        add_action(self, view_menu, "&Redo pose change", self.history.stack.redo, "redo", self.key_actions)
        self.audition = Audition(self, self.menuBar(), self.key_actions)
        self.navigation = Navigation(self, menus, self.key_actions)
        self.panel.layout().insertWidget(self.panel.layout().count() - 1, self.navigation.point_box)
        self.panel.pose.left.connect(lambda: self.plotter.setFocus())
        self.head_tracker = HeadTracker(self)
        self.head_tracker.ypr.connect(self._tracked_ypr)
        self.head_tracker.xyz.connect(self._tracked_xyz)
        self._tracking_reference: Reference | None = None
        view_menu.addSeparator()
        self.tracking_action = add_action(self, view_menu, f"&Head tracking (OSC /ypr, /xyz on UDP {DEFAULT_PORT})",
                                          lambda: self.set_head_tracking(self.tracking_action.isChecked()))
        self.tracking_action.setCheckable(True)
        self.osc_port = DEFAULT_PORT

    def set_head_tracking(self, on: bool, port: int | None = None) -> int | None:
        """Listen for a head tracker's OSC messages (head_tracking: /ypr, /xyz) on UDP ``port``, or stop.
        The listener's pose now is the tracker's zero. Returns the port, or None when off."""
        self.head_tracker.stop()
        self._tracking_reference = None
        if on:
            try:
                self.osc_port = self.head_tracker.start(self.osc_port if port is None else port)
            except OSError as exc:
                self.show_error("Cannot start head tracking", str(exc))
                on = False
            else:
                if self.state is not None:
                    self._tracking_reference = Reference(self.state.yaw, self.state.listener)
                self.statusBar().showMessage(f"Head tracking: OSC /ypr and /xyz on UDP port {self.osc_port}", 5000)
        with QtCore.QSignalBlocker(self.tracking_action):
            self.tracking_action.setChecked(on)
        self.tracking_action.setText(f"&Head tracking (OSC /ypr, /xyz on UDP {self.osc_port})")
        return self.osc_port if on else None

    def _reference(self) -> Reference | None:
        if self._tracking_reference is None and self.state is not None:
            self._tracking_reference = Reference(self.state.yaw, self.state.listener)
        return self._tracking_reference

    def _tracked_ypr(self, yaw: float, _pitch: float, _roll: float) -> None:
        ref = self._reference()
        if ref is not None and self.head_tracker.running:
            with self.history.quiet():  # a stream of poses, not undo steps
                self.state.set_yaw(tracked_yaw(ref, yaw))

    def _tracked_xyz(self, x: float, y: float, z: float) -> None:
        ref = self._reference()
        if ref is not None and self.head_tracker.running:
            with self.history.quiet():
                self.state.set_listener(tracked_position(ref, (x, y, z)), keep_height=False)

    # ------------------------------------------------------------------ drops
    def dragEnterEvent(self, event: QtGui.QDragEnterEvent) -> None:  # noqa: N802
        if self.navigation.accepts(event.mimeData()):
            event.acceptProposedAction()

    def dragMoveEvent(self, event: QtGui.QDragMoveEvent) -> None:  # noqa: N802
        if self.navigation.accepts(event.mimeData()):
            event.acceptProposedAction()

    def dropEvent(self, event: QtGui.QDropEvent) -> None:  # noqa: N802
        if self.navigation.accepts(event.mimeData()):
            event.acceptProposedAction()
            self.navigation.drop(event.mimeData())

    # ------------------------------------------------------------------ the audio path's parts
    @property
    def live(self) -> LiveAudio | None:
        """The scene's LiveAudio: pose -> filter -> engine (None without a scene)."""
        return self.audio_path.live

    @property
    def engine(self) -> audio.StreamEngine | None:
        return self.audio_path.engine

    @property
    def output(self) -> AudioOutput | None:
        """What pulls the engine: the sound card or a simulated clock."""
        return self.audio_path.output

    @property
    def meter_timer(self) -> QtCore.QTimer:
        """Polls the engine's output level for the meters while sound plays."""
        return self.audio_path.meter_timer

    # ------------------------------------------------------------------ view commands
    def _relayout(self) -> None:
        if self.view is not None:
            self.map_controls.relayout()
            self.plotter.render()

    def camera_preset(self, name: str) -> None:
        """One of the view's camera presets: camera_home, camera_top, camera_front, camera_listener."""
        if self.view is not None:
            getattr(self.view, name)()
            self.navigation.preset_done(name)  # the top view orthographic, the others perspective
            self.plotter.render()

    def show_help(self) -> None:
        """Every key and mouse action (``help.KEYS`` and ``help.MOUSE``), non-blocking."""
        if self.help_dialog is None:
            self.help_dialog = help_dialog(self)
        self.help_dialog.show()
        self.help_dialog.raise_()

    def show_error(self, title: str, message: str) -> None:
        """A non-blocking error dialog (kept as ``error_dialog`` for tests)."""
        self.error_dialog = file_dialogs.error_dialog(self, title, message)

    # ------------------------------------------------------------------ file actions
    def choose_scene(self) -> None:
        path = file_dialogs.ask_scene(self)
        if path:
            self.open_scene(path)

    def choose_clip(self) -> None:
        path = file_dialogs.ask_clip(self)
        if path:
            self.open_clip(path)

    def open_clip(self, path: str | Path) -> None:
        """Loop another mono clip (down-mixed and resampled to the scene's rate)."""
        if self.renderer is None:
            self._clip_path = Path(path)
            return
        try:
            clip = self.audio_path.read_clip(path, self.renderer.sample_rate)  # what it changed: status bar
        except (ValueError, FileNotFoundError) as exc:
            self.show_error("Cannot open clip", str(exc))
            return
        self._clip_path = Path(path)
        self.audio_path.set_clip(clip)
        self.navigation.opened(path)
        self.statusBar().showMessage(f"Looping {path} ({len(clip) / self.renderer.sample_rate:.1f} s)", 5000)

    def _load_clip(self, sample_rate: int) -> np.ndarray:
        if self._clip_path is not None:
            try:
                return self.audio_path.read_clip(self._clip_path, sample_rate)
            except (ValueError, FileNotFoundError) as exc:
                self.show_error("Cannot open clip", str(exc))
                self._clip_path = None
        self.audio_path.show_clip_notes([])
        return export.default_clip(sample_rate)

    def choose_screenshot(self) -> None:
        if self.view is None:
            return
        chosen = file_dialogs.ask_screenshot(self)
        if chosen is not None:
            path, options = chosen
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
        path = file_dialogs.ask_audio(self)
        if path:
            self.export_audio(path)

    def export_audio(self, path: str | Path) -> Path | None:
        """Write the whole clip as heard now (the pose's filter, or the renderer's synthesis once settled) as a WAV."""
        if self.live is None or self.live.heard is None:
            self.show_error("Cannot export audio", "No binaural render yet: wait for the scene to load.")
            return None
        try:
            out = export.write_wav(path, self.audio_path.export_audio(), self.renderer.sample_rate,
                                   inputs=(self.scene_path, self._clip_path))
        except (ValueError, OSError) as exc:
            self.show_error("Cannot export audio", str(exc))
            return None
        self.statusBar().showMessage(f"Wrote {out}", 5000)
        return out

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
        self.loader.load(path)

    def _on_load_failed(self, path: Path, message: str) -> None:
        self._loading = False
        self.progress.hide()
        self.show_error("Cannot open scene", f"Could not open {path}:\n{message}")
        if self.renderer is None:  # an empty window that says how to go on (the view is usable, not "loading")
            self.response.show_no_scene()
            self.statusBar().showMessage(f"Could not open {path}: open a checkpoint with File > Open scene")
        else:
            self.statusBar().showMessage(f"Could not open {path}; still showing {self.scene_path}", 5000)

    def _on_loaded(self, path: Path, renderer: TrainedScene) -> None:
        self._loading = False
        self.progress.hide()
        try:
            self._install_scene(renderer)
        except Exception as exc:  # a checkpoint the viewer cannot draw
            self.show_error("Cannot show scene", f"Could not show {path}:\n{type(exc).__name__}: {exc}")
            return
        self.scene_path = Path(path)
        self.navigation.opened(path)
        self.navigation.scene_changed()  # its viewpoints, the point size
        self.setWindowTitle(f"AV-GS explorer - {Path(path).name}")
        self.statusBar().showMessage(f"Loaded {path}: {len(renderer.points)} audio points", 5000)
        self.scene_loaded.emit(renderer)
        settle_heap()  # no long collection walks the scene during a drag

    def _install_scene(self, renderer: TrainedScene) -> None:
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
                                  audio_busy=self.audio_path.busy)
        self.audio_path.use_rate(renderer.sample_rate)
        state.events.clamped.connect(self._show_position_notice)
        state.events.refused.connect(self._show_position_notice)
        state.events.wall.connect(self._show_position_notice)  # a source put in a wall
        state.events.interacting.connect(self.audio_path.interaction_changed)
        self.response.show_response(None, renderer.sample_rate)
        self.audio_path.bind(state)
        clip = self._load_clip(renderer.sample_rate)
        # LiveAudio subscribes to the state's pose event; the view's handlers before it only ask
        # for a repaint (SceneCanvas), so a move reaches the audio path before anything is drawn.
        self.audio_path.start(renderer, state, view, clip)
        self.sources = Sources(state.source, clip, can_add=renderer.source_aware, why_not=ONE_SOURCE_REASON)
        self.sources_panel.bind(self.sources, state, view, self.live, self.map_controls,
                                lambda path: self.audio_path.read_clip(path, renderer.sample_rate))
        self.history.bind(state)
        self.audition.scene_changed()
        self.engine.bypass = self.audition.bypass_action.isChecked()
        self._tracking_reference = None  # the tracker's zero: the new scene's pose
        self.plotter.render()

    def _show_position_notice(self, message: str) -> None:
        """Say for 5 s that a dragged position was kept inside the scene (ViewerState's ``clamped``)."""
        self.position_notice.setText(message)
        self.position_notice.setToolTip(message)  # whole, where a narrow window clips it
        self._notice_timer.start()

    def _teardown_scene(self) -> None:
        self.map_controls.teardown()
        self.mouse.stop()
        self.sources_panel.unbind()
        self.audio_path.stop()
        if self.view is not None:
            self.view.close()
            self.view = None
        self.drag = None

    # ------------------------------------------------------------------ mouse
    def _camera_moving(self, moving: bool) -> None:
        if self.state is not None:
            self.state.set_interacting(moving)

    def eventFilter(self, obj: QtCore.QObject, event: QtCore.QEvent) -> bool:  # noqa: N802
        """Forward left-button drags that start on a handle to the drag logic; the rest to VTK."""
        if obj is self.plotter:
            if event.type() == QtCore.QEvent.Type.Resize and self.view is not None:
                self._relayout_timer.start()  # once the render window has its new size
            if self.drag is not None:
                taken = self.mouse.event(event, self.drag, self.live)
                if taken is not None:
                    return taken
        return super().eventFilter(obj, event)

    def grab(self, rect: QtCore.QRect = QtCore.QRect(0, 0, -1, -1)) -> QtGui.QPixmap:  # noqa: B008
        """``QWidget.grab`` with the 3D view's pixels in it: Qt leaves a native view's area unpainted
        (:meth:`avgs_viewer.canvas.NativeCanvas.grab` reads the view back from VTK)."""
        pix = super().grab(rect)
        view = self.plotter
        if isinstance(view, NativeCanvas) and view.isVisible():
            origin = rect.topLeft() if rect.isValid() else QtCore.QPoint(0, 0)
            painter = QtGui.QPainter(pix)
            painter.drawPixmap(view.mapTo(self, QtCore.QPoint(0, 0)) - origin, view.grab())
            painter.end()
        return pix

    # ------------------------------------------------------------------ closing
    def closeEvent(self, event: QtGui.QCloseEvent) -> None:  # noqa: N802
        self.meter_timer.stop()
        self.head_tracker.stop()
        self._teardown_scene()
        self.mouse.close()
        self.audio_path.close()
        self.plotter.close()
        super().closeEvent(event)
