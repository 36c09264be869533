"""The side panel: pose fields, colour mode and its legend, slice height, yaw dial, playback and meters.

:class:`ControlPanel` mirrors the :class:`~avgs_viewer.state.ViewerState` in its widgets and
writes what the user sets back into it (:meth:`ControlPanel.bind`); the window inserts the
propagation map's group (:class:`~avgs_viewer.propagation_view.MapControls`) above its stretch
and hands it the levels, the meters and what is heard (the filter or the full render).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Callable

from PySide6 import QtCore, QtWidgets

from .meters import FLOOR_DB, ClipLight, LevelMeter, peak_db
from .pose_panel import PosePanel
from .state import ColourMode, Event, ViewerState

if TYPE_CHECKING:
    from .scene_view import SceneView

COLOUR_MODE_NAMES = {ColourMode.VICINITY: "Vicinity sets", ColourMode.ALPHA: "Learned alpha (PCA)",
                     ColourMode.RGB: "G's colour (RGB)"}
METER_FLOOR_DB = FLOOR_DB
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
        self.meter_left, self.meter_right = LevelMeter(), LevelMeter()  # RMS bar, dB scale, peak hold
        self.clip_light = ClipLight()
        meters = QtWidgets.QWidget()
        meter_grid = QtWidgets.QGridLayout(meters)
        meter_grid.setContentsMargins(0, 0, 0, 0)
        for row, (meter, name, ear) in enumerate(((self.meter_left, "L", "left"), (self.meter_right, "R", "right"))):
            meter.setRange(int(METER_FLOOR_DB * 10), 0)
            meter.setValue(int(METER_FLOOR_DB * 10))  # silent until the first levels arrive
            meter.setToolTip(f"{ear} ear: RMS level, {METER_FLOOR_DB:.0f} to 0 dB full scale; "
                             "the white line: the highest sample peak, held 1.5 s")
            label = QtWidgets.QLabel(f"<b>{name}</b>")
            label.setToolTip(f"{ear} ear")
            meter_grid.addWidget(label, row, 0)
            meter_grid.addWidget(meter, row, 1)
        meter_grid.addWidget(self.clip_light, 0, 2, 2, 1)
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
        self.pose.bind(state, getattr(view.plotter, "with_frame", None))  # the pose fields move with the view's frames
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

    def show_peaks(self, left: float, right: float) -> None:
        """Each ear's sample peak (|x|) since the last call: the held peak lines, and the clip light at full scale."""
        self.meter_left.show_peak(peak_db(left))
        self.meter_right.show_peak(peak_db(right))
        if max(left, right) >= 1.0:
            self.clip_light.set_lit(True)

