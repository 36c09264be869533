"""The panel's "Sources" group: add, remove and select sources, each one's gain and clip, and
whether the propagation map shows the selected source or all of them (Qt).

Per scene, :meth:`SourcesPanel.bind` ties a :class:`~avgs_viewer.sources.Sources` to the
state (the selected source is the state's source: the handle a drag moves), to the audio
(:meth:`LiveAudio.attach_sources <avgs_viewer.worker.LiveAudio.attach_sources>`: every source
heard), to the 3D view (a yellow sphere per other source) and to the map.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Callable

import numpy as np
from PySide6 import QtCore, QtWidgets

from .sources import Sources

if TYPE_CHECKING:
    from .propagation_view import MapControls
    from .scene_view import SceneView
    from .state import ViewerState
    from .worker import LiveAudio

ONE_SOURCE_REASON = ("This checkpoint was trained with one source position (RWAVS task): its sound is only "
                     "known for that source. Train with --task rir for several sources.")


class SourcesPanel:
    """The group box (``box``) and, while a scene is shown, its sources (``sources``)."""

    def __init__(self, choose_clip: Callable[[], str | None] | None = None):
        self.box = QtWidgets.QGroupBox("Sources")
        self.list = QtWidgets.QListWidget()
        self.list.setMaximumHeight(90)
        self.add_button = QtWidgets.QPushButton("Add source")
        self.remove_button = QtWidgets.QPushButton("Remove")
        self.clip_button = QtWidgets.QPushButton("Clip...")
        self.clip_button.setToolTip("Loop another audio file from the selected source")
        self.gain = QtWidgets.QSlider(QtCore.Qt.Orientation.Horizontal)
        self.gain.setRange(0, 200)  # percent
        self.gain.setToolTip("The selected source's gain (100 %: as loaded)")
        self.gain_label = QtWidgets.QLabel("100 %")
        self.map_all = QtWidgets.QCheckBox("Map: all sources")
        self.map_all.setToolTip("The propagation map of the sum of every source's power (else the selected one's)")
        buttons = QtWidgets.QHBoxLayout()
        for b in (self.add_button, self.remove_button, self.clip_button):
            buttons.addWidget(b)
        gain_row = QtWidgets.QHBoxLayout()
        gain_row.addWidget(QtWidgets.QLabel("Gain"))
        gain_row.addWidget(self.gain, 1)
        gain_row.addWidget(self.gain_label)
        layout = QtWidgets.QVBoxLayout(self.box)
        layout.addWidget(self.list)
        layout.addLayout(buttons)
        layout.addLayout(gain_row)
        layout.addWidget(self.map_all)
        self.add_button.clicked.connect(self.add)
        self.remove_button.clicked.connect(self.remove)
        self.clip_button.clicked.connect(self._choose_clip)
        self.list.currentRowChanged.connect(self._selected)
        self.gain.valueChanged.connect(self._gain_changed)
        self.map_all.toggled.connect(self._map_changed)
        self._choose = choose_clip
        self.read_clip: Callable[[str], np.ndarray] | None = None
        self.sources: Sources | None = None
        self._state: ViewerState | None = None
        self._view: SceneView | None = None
        self._map: MapControls | None = None
        self.box.setEnabled(False)

    # ------------------------------------------------------------------ a scene
    def bind(self, sources: Sources, state: ViewerState, view: SceneView, live: LiveAudio, map_controls: MapControls,
             read_clip: Callable[[str], np.ndarray]) -> None:
        """Show and edit ``sources``: the selected one is ``state``'s source; ``live`` plays them all."""
        self.unbind()
        self.sources, self._state, self._view, self._map, self.read_clip = sources, state, view, map_controls, read_clip
        sources.follow(state)
        live.attach_sources(sources)
        sources.changed.append(self._refresh)
        state.events.interacting.connect(self._moved)
        self.add_button.setEnabled(sources.can_add)
        self.add_button.setToolTip("Add a source 1 m from the selected one, playing its clip" if sources.can_add
                                   else sources.why_not)
        self.box.setEnabled(True)
        self._map_changed(self.map_all.isChecked())
        self._refresh()

    def unbind(self) -> None:
        if self.sources is not None:
            self.sources.unfollow()
            self.sources.changed.remove(self._refresh)
            self._state.events.interacting.disconnect(self._moved)
        self.sources = self._state = self._view = self._map = None
        self.box.setEnabled(False)

    # ------------------------------------------------------------------ commands
    def add(self) -> int | None:
        """A new source next to the selected one, selected (the handle a drag moves); its index."""
        if self.sources is None or not self.sources.can_add:
            return None
        try:
            return self.sources.add()
        except ValueError as exc:
            QtWidgets.QToolTip.showText(self.add_button.mapToGlobal(QtCore.QPoint(0, 0)), str(exc))
            return None

    def remove(self) -> None:
        if self.sources is not None and len(self.sources) > 1:
            self.sources.remove()

    def open_clip(self, path: str) -> None:
        """The selected source loops the audio file at ``path`` (errors: ValueError, FileNotFoundError)."""
        if self.sources is not None and self.read_clip is not None:
            self.sources.set_clip(self.sources.selected, self.read_clip(path))

    def _choose_clip(self) -> None:
        path = self._choose() if self._choose is not None else None
        if path:
            try:
                self.open_clip(path)
            except (ValueError, FileNotFoundError) as exc:
                QtWidgets.QMessageBox.warning(self.box, "Cannot open clip", str(exc))

    # ------------------------------------------------------------------ shown
    def _label(self, i: int) -> str:
        s = self.sources.items[i]
        x, y, z = s.position
        return f"Source {i + 1}: ({x:.2f}, {y:.2f}, {z:.2f})  x{s.gain:.2f}"

    def _refresh(self) -> None:
        sources = self.sources
        if sources is None:
            return
        with QtCore.QSignalBlocker(self.list):
            self.list.clear()
            self.list.addItems([self._label(i) for i in range(len(sources))])
            self.list.setCurrentRow(sources.selected)
        with QtCore.QSignalBlocker(self.gain):
            self.gain.setValue(int(round(100 * sources.current.gain)))
        self.gain_label.setText(f"{100 * sources.current.gain:.0f} %")
        self.remove_button.setEnabled(len(sources) > 1)
        self._view.show_sources([s.position for i, s in enumerate(sources.items) if i != sources.selected])
        self._refresh_map()

    def _moved(self, moving: bool) -> None:
        """A drag ended: the selected source's position in the list (not on every step of a drag)."""
        if not moving and self.sources is not None:
            item = self.list.item(self.sources.selected)
            if item is not None:
                item.setText(self._label(self.sources.selected))
            self._refresh_map()

    def _refresh_map(self) -> None:
        view = None if self._map is None else self._map.view
        if view is not None and view.all_sources is not None:
            view.request()

    def _selected(self, row: int) -> None:
        if self.sources is not None and row >= 0:
            self.sources.select(row)

    def _gain_changed(self, percent: int) -> None:
        if self.sources is not None:
            self.sources.set_gain(self.sources.selected, percent / 100.0)

    def _map_changed(self, every: bool) -> None:
        view = None if self._map is None else self._map.view
        if view is not None:
            sources = self.sources
            view.set_all_sources((lambda: tuple((s.position, s.gain) for s in sources.items))
                                 if every and sources is not None else None)
