"""The dialogs of File > Export impulse response / response grid / fly-through video, and of
saving a recorded path: what to export, then where (each ``ask_*`` returns None when cancelled)."""

from __future__ import annotations

from dataclasses import dataclass

from PySide6 import QtWidgets

from avgs.export.flythrough import FlythroughConfig
from avgs.export.grid import GridSpec


def _buttons(dialog: QtWidgets.QDialog) -> QtWidgets.QDialogButtonBox:
    buttons = QtWidgets.QDialogButtonBox(QtWidgets.QDialogButtonBox.StandardButton.Ok
                                         | QtWidgets.QDialogButtonBox.StandardButton.Cancel)
    buttons.accepted.connect(dialog.accept)
    buttons.rejected.connect(dialog.reject)
    return buttons


class GridDialog(QtWidgets.QDialog):
    """Spacing, yaws and height of a response grid (for the source where it is now)."""

    def __init__(self, height: float, parent: QtWidgets.QWidget | None = None):
        super().__init__(parent)
        self.setWindowTitle("Response grid")
        layout = QtWidgets.QFormLayout(self)
        self.spacing = QtWidgets.QDoubleSpinBox()
        self.spacing.setRange(0.05, 100.0)
        self.spacing.setSingleStep(0.25)
        self.spacing.setValue(GridSpec().spacing)
        self.yaws = QtWidgets.QLineEdit(" ".join(f"{y:g}" for y in GridSpec().yaws))
        self.height = QtWidgets.QDoubleSpinBox()
        self.height.setRange(-1e4, 1e4)
        self.height.setDecimals(2)
        self.height.setValue(height)
        layout.addRow("Spacing (m)", self.spacing)
        layout.addRow("Yaws (degrees)", self.yaws)
        layout.addRow("Listener height (m)", self.height)
        layout.addRow(_buttons(self))

    def spec(self, source) -> GridSpec:
        """The grid asked for (ValueError naming a yaw that is not a number)."""
        try:
            yaws = tuple(float(v) for v in self.yaws.text().replace(",", " ").split())
        except ValueError:
            raise ValueError(f"yaws must be numbers of degrees separated by spaces, got {self.yaws.text()!r}") from None
        return GridSpec(spacing=self.spacing.value(), yaws=yaws, height=self.height.value(),
                        sources=(tuple(float(v) for v in source),))


@dataclass(frozen=True)
class FlythroughChoice:
    config: FlythroughConfig
    picture: str  # "scene" (the 3D view) or "listener" (G from the listener's head)
    path_file: str  # "" : the path recorded in the window


class FlythroughDialog(QtWidgets.QDialog):
    """Which path (the recorded one or a file), frame rate, size and picture of a fly-through."""

    def __init__(self, has_recording: bool, has_gaussians: bool, parent: QtWidgets.QWidget | None = None):
        super().__init__(parent)
        self.setWindowTitle("Fly-through video")
        layout = QtWidgets.QFormLayout(self)
        self.path = QtWidgets.QComboBox()
        if has_recording:
            self.path.addItem("The recorded path", "")
        self.path.addItem("A path file (JSON)...", "file")
        d = FlythroughConfig()
        self.fps = QtWidgets.QDoubleSpinBox()
        self.fps.setRange(1, 120)
        self.fps.setValue(d.fps)
        self.width_px, self.height_px = QtWidgets.QSpinBox(), QtWidgets.QSpinBox()
        for box, value in ((self.width_px, d.width), (self.height_px, d.height)):
            box.setRange(16, 8192)
            box.setSingleStep(2)
            box.setValue(value)
        self.picture = QtWidgets.QComboBox()
        self.picture.addItem("The 3D view", "scene")
        if has_gaussians:
            self.picture.addItem("What the listener sees (G)", "listener")
        layout.addRow("Path", self.path)
        layout.addRow("Frames per second", self.fps)
        layout.addRow("Width (px)", self.width_px)
        layout.addRow("Height (px)", self.height_px)
        layout.addRow("Picture", self.picture)
        layout.addRow(_buttons(self))


def ask_grid(parent: QtWidgets.QWidget, height: float, source) -> tuple[GridSpec, str] | None:
    dialog = GridDialog(height, parent)
    if dialog.exec() != QtWidgets.QDialog.DialogCode.Accepted:
        return None
    spec = dialog.spec(source)
    path, _ = QtWidgets.QFileDialog.getSaveFileName(parent, "Export response grid", "responses.sofa", "SOFA (*.sofa)")
    return (spec, path) if path else None


def ask_flythrough(parent: QtWidgets.QWidget, has_recording: bool, has_gaussians: bool
                   ) -> tuple[FlythroughChoice, str] | None:
    dialog = FlythroughDialog(has_recording, has_gaussians, parent)
    if dialog.exec() != QtWidgets.QDialog.DialogCode.Accepted:
        return None
    path_file = ""
    if dialog.path.currentData() == "file":
        path_file, _ = QtWidgets.QFileDialog.getOpenFileName(parent, "Open path", "", "Path (*.json);;All files (*)")
        if not path_file:
            return None
    config = FlythroughConfig(fps=dialog.fps.value(), width=dialog.width_px.value(), height=dialog.height_px.value())
    out, _ = QtWidgets.QFileDialog.getSaveFileName(parent, "Export fly-through video", "flythrough.mp4", "MP4 (*.mp4)")
    return (FlythroughChoice(config, dialog.picture.currentData(), path_file), out) if out else None


def ask_save(parent: QtWidgets.QWidget, title: str, default: str, filter_text: str) -> str:
    """Where to write (empty if nowhere)."""
    path, _ = QtWidgets.QFileDialog.getSaveFileName(parent, title, default, filter_text)
    return path
