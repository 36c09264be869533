"""What a splat-viewer user expects of the 3D view: viewpoints, recent files, drops, point size, FPS,
an orthographic top view.

- **Viewpoints**: Ctrl+1..4 save the camera, 1..4 go back to it (kept per checkpoint in the
  settings, so they outlive the session).
- **Recent files**: File > Open recent, the last :data:`RECENT_MAX` scenes and clips.
- **Drops**: a ``.ckpt`` dropped on the window opens as the scene, a ``.wav`` (or other audio) as the clip.
- **Point size** of the audio points (the side panel's Points box), **FPS** (frames drawn in the
  last second) in the status bar.
- **Orthographic top view**: the top preset (T) draws with a parallel projection fitted to the
  room; every other preset goes back to perspective.

Settings live in ``QSettings(IniFormat, UserScope, ORGANISATION, APPLICATION)`` (:func:`settings`);
tests point ``QSettings.setPath`` at a temporary folder.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from PySide6 import QtCore, QtWidgets

from .menus import add_action

ORGANISATION, APPLICATION = "avgs", "avgs-viewer"
RECENT_MAX = 8
VIEWPOINTS = 4
SCENE_SUFFIXES = (".ckpt",)
CLIP_SUFFIXES = (".wav", ".flac", ".ogg", ".mp3", ".aiff", ".aif")
POINT_SIZES = (1, 20)  # the point-size control's range, pixels


def settings() -> QtCore.QSettings:
    """The explorer's settings (an INI file in the user's settings folder)."""
    return QtCore.QSettings(QtCore.QSettings.Format.IniFormat, QtCore.QSettings.Scope.UserScope,
                            ORGANISATION, APPLICATION)


def recent_files() -> list[str]:
    value = settings().value("recent_files", [])
    return [str(v) for v in ([value] if isinstance(value, str) else value or [])]


def add_recent(path: str | Path) -> list[str]:
    """Put ``path`` first in the recent files (once; at most RECENT_MAX); returns the list."""
    path = str(Path(path).resolve())
    files = [path] + [p for p in recent_files() if p != path]
    s = settings()
    s.setValue("recent_files", files[:RECENT_MAX])
    s.sync()
    return files[:RECENT_MAX]


def camera_of(vtk_renderer) -> dict:
    """The camera of a VTK renderer as plain values (a viewpoint)."""
    cam = vtk_renderer.GetActiveCamera()
    return {"position": list(cam.GetPosition()), "focal_point": list(cam.GetFocalPoint()),
            "view_up": list(cam.GetViewUp()), "view_angle": cam.GetViewAngle(),
            "parallel": bool(cam.GetParallelProjection()), "parallel_scale": cam.GetParallelScale()}


def set_camera(vtk_renderer, view: dict) -> None:
    cam = vtk_renderer.GetActiveCamera()
    cam.SetPosition(*view["position"])
    cam.SetFocalPoint(*view["focal_point"])
    cam.SetViewUp(*view["view_up"])
    cam.SetViewAngle(float(view["view_angle"]))
    cam.SetParallelProjection(bool(view["parallel"]))
    cam.SetParallelScale(float(view["parallel_scale"]))
    vtk_renderer.ResetCameraClippingRange()


def fit_orthographic(vtk_renderer, bounds: np.ndarray, aspect: float) -> None:
    """Parallel projection looking down, fitted so the room's floor plan ``bounds [2, 3]`` fills the view."""
    lo, hi = np.asarray(bounds, dtype=np.float64)
    half_h, half_w = 0.5 * (hi[1] - lo[1]), 0.5 * (hi[0] - lo[0])
    cam = vtk_renderer.GetActiveCamera()
    cam.SetParallelProjection(True)
    cam.SetParallelScale(1.08 * max(half_h, half_w / max(aspect, 1e-6), 1e-3))  # half the view's height
    vtk_renderer.ResetCameraClippingRange()


class Navigation(QtCore.QObject):
    """Viewpoints, recent files, drops, point size, FPS and the orthographic top view of ``window``."""

    def __init__(self, window, menus, key_actions: dict):
        super().__init__(window)
        self.window = window
        self.views: dict[int, dict] = {}
        file_menu, view_menu = menus["file"], menus["view"]
        self.recent_menu = QtWidgets.QMenu("Open &recent", file_menu)
        file_menu.insertMenu(file_menu.actions()[2], self.recent_menu)  # after Open scene, Open clip
        self.recent_menu.aboutToShow.connect(self._fill_recent)
        self._fill_recent()
        view_menu.addSeparator()
        for i in range(1, VIEWPOINTS + 1):
            add_action(window, view_menu, f"Save viewpoint {i}", lambda i=i: self.save_view(i), f"save_view_{i}", key_actions)
        for i in range(1, VIEWPOINTS + 1):
            add_action(window, view_menu, f"Go to viewpoint {i}", lambda i=i: self.recall_view(i), f"recall_view_{i}", key_actions)
        self.fps_label = QtWidgets.QLabel("FPS -")
        self.fps_label.setToolTip("Frames of the 3D view drawn in the last second (it draws only when something changes)")
        window.statusBar().addPermanentWidget(self.fps_label)
        self.fps = 0
        self._frames = 0
        window.plotter.frameSwapped.connect(self._count_frame)
        self._fps_timer = QtCore.QTimer(self)
        self._fps_timer.setInterval(1000)
        self._fps_timer.timeout.connect(self._show_fps)
        self._fps_timer.start()
        self.point_size = QtWidgets.QSpinBox()
        self.point_size.setRange(*POINT_SIZES)
        self.point_size.setSuffix(" px")
        self.point_size.setToolTip("The audio points' size on screen")
        self.point_size.valueChanged.connect(self.set_point_size)
        box = QtWidgets.QGroupBox("Points")
        row = QtWidgets.QHBoxLayout(box)
        row.addWidget(QtWidgets.QLabel("Size"))
        row.addWidget(self.point_size, 1)
        self.point_box = box
        window.setAcceptDrops(True)

    # ------------------------------------------------------------------ a scene
    def scene_changed(self) -> None:
        view = self.window.view
        with QtCore.QSignalBlocker(self.point_size):
            self.point_size.setValue(int(round(view.point_size)) if view is not None else 6)
        self.views = self._stored_views()

    # ------------------------------------------------------------------ viewpoints
    def _views_key(self) -> str | None:
        path = self.window.scene_path
        return None if path is None else "viewpoints/" + str(Path(path).resolve()).replace("/", "|")

    def _stored_views(self) -> dict[int, dict]:
        key = self._views_key()
        try:
            raw = json.loads(settings().value(key, "{}")) if key else {}
            return {int(k): v for k, v in raw.items()}
        except (TypeError, ValueError):
            return {}

    def save_view(self, i: int) -> None:
        if self.window.view is None:
            return
        self.views[i] = camera_of(self.window.plotter.renderer)
        key = self._views_key()
        if key:
            s = settings()
            s.setValue(key, json.dumps({str(k): v for k, v in self.views.items()}))
            s.sync()
        self.window.statusBar().showMessage(f"Saved viewpoint {i} (press {i} to come back to it)", 3000)

    def recall_view(self, i: int) -> None:
        view = self.views.get(i)
        if self.window.view is None or view is None:
            self.window.statusBar().showMessage(f"No viewpoint {i} saved yet (Ctrl+{i} saves one)", 3000)
            return
        set_camera(self.window.plotter.renderer, view)
        self.window.plotter.render()

    # ------------------------------------------------------------------ camera presets
    def preset_done(self, name: str) -> None:
        """After a camera preset: parallel projection for the top view, perspective for the others."""
        view = self.window.view
        if view is None:
            return
        vtk_renderer = self.window.plotter.renderer
        if name == "camera_top":
            size = self.window.plotter.render_window.GetSize()
            fit_orthographic(vtk_renderer, view.bounds, size[0] / max(size[1], 1))
        else:
            vtk_renderer.GetActiveCamera().SetParallelProjection(False)

    # ------------------------------------------------------------------ recent files
    def opened(self, path: str | Path) -> None:
        add_recent(path)
        self._fill_recent()

    def _fill_recent(self) -> None:
        self.recent_menu.clear()
        files = [f for f in recent_files() if Path(f).exists()]
        for f in files:
            act = self.recent_menu.addAction(Path(f).name)
            act.setToolTip(f)
            act.setStatusTip(f)
            act.triggered.connect(lambda _=False, f=f: self.open_path(f))
        self.recent_menu.setEnabled(bool(files))

    def open_path(self, path: str | Path) -> bool:
        """Open a checkpoint as the scene or an audio file as the clip, by its suffix; False for other files."""
        suffix = Path(path).suffix.lower()
        if suffix in SCENE_SUFFIXES:
            self.window.open_scene(path)
        elif suffix in CLIP_SUFFIXES:
            self.window.open_clip(path)
        else:
            self.window.statusBar().showMessage(
                f"{Path(path).name}: not a scene (.ckpt) or a clip ({', '.join(CLIP_SUFFIXES)})", 5000)
            return False
        return True

    # ------------------------------------------------------------------ drops
    @staticmethod
    def dropped_files(mime) -> list[Path]:
        return [Path(u.toLocalFile()) for u in mime.urls() if u.isLocalFile()] if mime.hasUrls() else []

    def accepts(self, mime) -> bool:
        return any(p.suffix.lower() in SCENE_SUFFIXES + CLIP_SUFFIXES for p in self.dropped_files(mime))

    def drop(self, mime) -> None:
        """A scene first (its clip after it, once loaded), else the clip."""
        files = self.dropped_files(mime)
        scenes = [p for p in files if p.suffix.lower() in SCENE_SUFFIXES]
        clips = [p for p in files if p.suffix.lower() in CLIP_SUFFIXES]
        if clips:
            self.open_path(clips[0])
        if scenes:
            self.open_path(scenes[0])

    # ------------------------------------------------------------------ points, FPS
    def set_point_size(self, size: int) -> None:
        if self.window.view is not None:
            self.window.view.set_point_size(float(size))
            self.window.plotter.render()

    def _count_frame(self) -> None:
        self._frames += 1

    def _show_fps(self) -> None:
        self.fps, self._frames = self._frames, 0
        self.fps_label.setText(f"FPS {self.fps}")
