"""The window's file dialogs and error dialogs: which checkpoint or clip to open, where to export.

Each ``ask_*`` function shows a modal dialog and returns what was chosen ("" or None when
cancelled); :class:`ExportOptions` asks how a screenshot is drawn; :func:`error_dialog` says
what went wrong without blocking. The window does the opening and exporting itself.
"""

from __future__ import annotations

from PySide6 import QtCore, QtWidgets

from . import export


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


def ask_scene(parent: QtWidgets.QWidget) -> str:
    """A checkpoint to open ("" if none)."""
    path, _ = QtWidgets.QFileDialog.getOpenFileName(parent, "Open scene", "",
                                                    "AV-GS checkpoints (*.ckpt);;All files (*)")
    return path


def ask_clip(parent: QtWidgets.QWidget) -> str:
    """An audio file to loop ("" if none)."""
    path, _ = QtWidgets.QFileDialog.getOpenFileName(parent, "Open clip", "",
                                                    "Audio (*.wav *.flac *.ogg);;All files (*)")
    return path


def ask_screenshot(parent: QtWidgets.QWidget) -> tuple[str, ExportOptions] | None:
    """How to draw a screenshot, then where to write it (None if either is cancelled)."""
    options = ExportOptions(parent)
    if options.exec() != QtWidgets.QDialog.DialogCode.Accepted:
        return None
    path, _ = QtWidgets.QFileDialog.getSaveFileName(parent, "Export screenshot", "scene.png", "PNG (*.png)")
    return (path, options) if path else None


def ask_audio(parent: QtWidgets.QWidget) -> str:
    """Where to write the audio heard now ("" if nowhere)."""
    path, _ = QtWidgets.QFileDialog.getSaveFileName(parent, "Export audio", "binaural.wav", "WAV (*.wav)")
    return path


def error_dialog(parent: QtWidgets.QWidget, title: str, message: str) -> QtWidgets.QMessageBox:
    """A non-blocking error dialog, open (deleted when closed)."""
    box = QtWidgets.QMessageBox(QtWidgets.QMessageBox.Icon.Critical, title, message,
                                QtWidgets.QMessageBox.StandardButton.Ok, parent)
    box.setAttribute(QtCore.Qt.WidgetAttribute.WA_DeleteOnClose)
    box.open()
    return box
