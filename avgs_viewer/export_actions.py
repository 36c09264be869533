"""What File > Export impulse response / response grid / fly-through video and Record path do,
for the window (:class:`~avgs_viewer.window.MainWindow`, which only wires them to its menu).

Each ``choose_*`` asks (:mod:`avgs_viewer.export_dialogs`) and then calls the method that does
the work, which tests call directly: :meth:`ExportActions.export_impulse`,
:meth:`~ExportActions.export_grid`, :meth:`~ExportActions.export_flythrough`,
:meth:`~ExportActions.save_recorded_path`. Long exports show a progress dialog that can cancel
them (nothing is left written). Errors are shown in the window's error dialog.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from PySide6 import QtCore, QtWidgets

from avgs.export.flythrough import Cancelled, FlythroughConfig

from . import export_dialogs
from .path_recorder import PathRecorder


class ExportActions:
    def __init__(self, window: Any):
        """``window``: the :class:`~avgs_viewer.window.MainWindow` (its scene, state, status bar, error dialog)."""
        self.window = window
        self.recorder = PathRecorder()
        self.progress_dialog: QtWidgets.QProgressDialog | None = None

    def _inputs(self) -> tuple:
        return (self.window.scene_path, self.window._clip_path)

    def _done(self, out: Path) -> Path:
        self.window.statusBar().showMessage(f"Wrote {out}", 5000)
        return out

    # ------------------------------------------------------------------ the pose's response
    def choose_impulse_export(self) -> None:
        if self.window.state is not None:
            path = export_dialogs.ask_save(self.window, "Export impulse response", "response.wav", "WAV (*.wav)")
            if path:
                self.export_impulse(path)

    def export_impulse(self, path: str | Path) -> Path | None:
        """The current pose's binaural impulse response as a WAV (2 channels, float32, left first)."""
        from avgs.export.sofa import write_impulse_wav

        w = self.window
        if w.renderer is None or w.state is None:
            w.show_error("Cannot export impulse response", "No scene yet: wait for it to load.")
            return None
        pose = w.state.pose
        try:
            result = w.renderer.binaural_filter(pose.listener, pose.yaw, pose.source)
            return self._done(write_impulse_wav(path, result.impulse, w.renderer.sample_rate, inputs=self._inputs()))
        except (ValueError, OSError) as exc:
            w.show_error("Cannot export impulse response", str(exc))
            return None

    # ------------------------------------------------------------------ a grid as SOFA
    def choose_grid_export(self) -> None:
        w = self.window
        if w.state is None:
            return
        try:
            chosen = export_dialogs.ask_grid(w, float(w.state.listener[2]), w.state.source)
        except ValueError as exc:
            w.show_error("Cannot export response grid", str(exc))
            return
        if chosen is not None:
            self.export_grid(chosen[1], chosen[0])

    def export_grid(self, path: str | Path, spec) -> Path | None:
        """Responses over a grid of listener positions x yaws (``spec``: :class:`~avgs.export.grid.GridSpec`) as SOFA."""
        from avgs.export.grid import compute_grid
        from avgs.export.sofa import write_grid

        w = self.window
        if w.renderer is None:
            w.show_error("Cannot export response grid", "No scene yet: wait for it to load.")
            return None
        try:
            if Path(path).suffix.lower() != ".sofa":
                raise ValueError(f"a response grid must be written to a .sofa file, got {path}")
            from avgs.io.atomic import check_output

            check_output(path, inputs=self._inputs(), what="SOFA output")
            grid = compute_grid(w.renderer, spec, self._progress("Computing responses..."))
            return self._done(write_grid(path, grid, title=f"AV-GS scene {w.renderer.name!r}", inputs=self._inputs()))
        except Cancelled:
            return None
        except (ValueError, OSError) as exc:
            w.show_error("Cannot export response grid", str(exc))
            return None
        finally:
            self._close_progress()

    # ------------------------------------------------------------------ paths and videos
    def record_path(self, on: bool) -> None:
        """Start (``on``) or stop recording the listener's poses."""
        w = self.window
        if on and w.state is not None:
            self.recorder.start(w.state)
            w.statusBar().showMessage("Recording the path: move the listener, then uncheck File > Record path", 5000)
        elif not on and self.recorder.recording:
            frames = self.recorder.stop()
            w.statusBar().showMessage(f"Recorded {len(frames)} keyframes over {frames[-1].t:.1f} s", 5000)

    def choose_path_save(self) -> None:
        path = export_dialogs.ask_save(self.window, "Save recorded path", "path.json", "Path (*.json)")
        if path:
            self.save_recorded_path(path)

    def save_recorded_path(self, path: str | Path) -> Path | None:
        """The recorded path as keyframes JSON (:mod:`avgs.export.flypath`)."""
        from avgs.export.flypath import write_path

        if self.recorder.recording:
            self.recorder.stop()
        try:
            return self._done(write_path(path, self.recorder.keyframes, inputs=self._inputs()))
        except (ValueError, OSError) as exc:
            self.window.show_error("Cannot save the path", str(exc) if self.recorder.keyframes else
                                   "Nothing recorded: check File > Record path and move the listener first.")
            return None

    def choose_flythrough(self) -> None:
        w = self.window
        if w.renderer is None:
            return
        chosen = export_dialogs.ask_flythrough(w, len(self.recorder.keyframes) >= 2, w.renderer.gaussians is not None)
        if chosen is not None:
            choice, out = chosen
            self.export_flythrough(out, choice.path_file or None, choice.config, choice.picture)

    def export_flythrough(self, out: str | Path, path_file: str | Path | None = None,
                          config: FlythroughConfig = FlythroughConfig(), picture: str = "scene") -> Path | None:
        """A fly-through MP4 of ``path_file`` (None: the recorded path), the picture the 3D view
        (``"scene"``) or G from the listener's head (``"listener"``), the clip looping."""
        from avgs.export.flypath import read_path
        from avgs.export.flythrough import listener_frames, render_flythrough

        from .export import default_clip
        from .flythrough import SceneViewFrames

        w = self.window
        if w.renderer is None:
            w.show_error("Cannot export fly-through", "No scene yet: wait for it to load.")
            return None
        frames = None
        try:
            if self.recorder.recording:
                self.recorder.stop()
            keyframes = read_path(path_file) if path_file else self.recorder.keyframes
            clip = w.live.clip if w.live is not None else default_clip(w.renderer.sample_rate)
            if picture == "listener":
                from avgs.render.listener_view import ListenerView

                view = ListenerView.load(w.scene_path) if w.scene_path is not None else None
                if view is None:
                    raise ValueError("this scene was saved without G: nothing to see from the listener's head")
                frames = listener_frames(view, config.width, config.height)
            else:
                frames = SceneViewFrames(w.renderer, config.width, config.height)
            result = render_flythrough(w.renderer, keyframes, clip, out, frames, config,
                                       self._progress("Rendering the fly-through..."),
                                       inputs=(*self._inputs(), path_file))
            return self._done(result.path)
        except Cancelled:
            return None
        except (ValueError, OSError) as exc:
            w.show_error("Cannot export fly-through", str(exc))
            return None
        finally:
            self._close_progress()
            if isinstance(frames, SceneViewFrames):
                frames.close()
            w.plotter.render()

    # ------------------------------------------------------------------ progress
    def _progress(self, text: str):
        dialog = QtWidgets.QProgressDialog(text, "Cancel", 0, 1000, self.window)
        dialog.setWindowModality(QtCore.Qt.WindowModality.WindowModal)
        dialog.setMinimumDuration(500)
        self.progress_dialog = dialog

        def update(done: int, total: int) -> None:
            dialog.setValue(int(1000 * done / max(total, 1)))
            QtWidgets.QApplication.processEvents()
            if dialog.wasCanceled():
                raise Cancelled()

        return update

    def _close_progress(self) -> None:
        if self.progress_dialog is not None:
            self.progress_dialog.reset()
            self.progress_dialog.deleteLater()
            self.progress_dialog = None
