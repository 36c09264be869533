"""The pose panel: the listener's x, y, z and yaw and the source's x, y, z, shown and typed.

Each field mirrors the :class:`~avgs_viewer.state.ViewerState` (a drag or a key updates
it) and writes a typed value back when editing finishes (Enter or leaving the field). The
fields accept any number: the state keeps the position inside the room, and the panel
then shows where it went and says so in ``notice`` (the state's ``clamped`` event), rather
than the field silently refusing the value. When the state keeps the source fixed (a scene
trained with one source position) its fields are read-only and ``source_note`` says why.

Keys (:class:`FieldKeys`): a letter key (the window's single-letter shortcuts: T, Q, R, ...)
acts even while a field has focus, unless a value is being typed in it; Enter (the value
taken) or Escape (the value shown again unchanged) leaves the field (``left``: the window gives
the focus to the 3D view), and the keys act again.
"""

from __future__ import annotations

from typing import Any, Callable

from PySide6 import QtCore, QtWidgets

from .state import Event, ViewerState

_LETTERS = range(int(QtCore.Qt.Key.Key_A.value), int(QtCore.Qt.Key.Key_Z.value) + 1)
_NO_LETTER_MODIFIERS = (QtCore.Qt.KeyboardModifier.ControlModifier | QtCore.Qt.KeyboardModifier.AltModifier
                        | QtCore.Qt.KeyboardModifier.MetaModifier)


class FieldKeys(QtCore.QObject):
    """Letter keys pass through a number field to the window's shortcuts unless a value is being
    typed in it; Enter and Escape leave the field (calling ``leave``), Escape showing ``restore``'s value."""

    def __init__(self, parent: QtCore.QObject, leave: Callable[[], None]):
        super().__init__(parent)
        self.leave = leave
        self.editing: set[QtWidgets.QAbstractSpinBox] = set()

    def watch(self, box: QtWidgets.QAbstractSpinBox, restore: Callable[[], None]) -> None:
        box._restore = restore  # type: ignore[attr-defined]
        box.installEventFilter(self)
        box.lineEdit().installEventFilter(self)
        box.lineEdit().textEdited.connect(lambda _t, b=box: self.editing.add(b))
        box.editingFinished.connect(lambda b=box: self.editing.discard(b))

    def eventFilter(self, obj: QtCore.QObject, event: QtCore.QEvent) -> bool:  # noqa: N802
        box = obj if isinstance(obj, QtWidgets.QAbstractSpinBox) else obj.parent()
        if not isinstance(box, QtWidgets.QAbstractSpinBox):
            return False
        kind = event.type()
        if kind == QtCore.QEvent.Type.ShortcutOverride:
            letter = event.key() in _LETTERS and not (event.modifiers() & _NO_LETTER_MODIFIERS)
            if letter and box not in self.editing:
                event.ignore()
                return True  # not taken by the field: the window's shortcut acts
        elif kind == QtCore.QEvent.Type.KeyPress and obj is box:
            if event.key() == QtCore.Qt.Key.Key_Escape:
                self.editing.discard(box)
                box._restore()  # type: ignore[attr-defined]
                self.leave()
                return True
            if event.key() in (QtCore.Qt.Key.Key_Return, QtCore.Qt.Key.Key_Enter):
                QtCore.QTimer.singleShot(0, self.leave)  # after the field has taken the value
        elif kind == QtCore.QEvent.Type.FocusOut and obj is box:
            self.editing.discard(box)
        return False

LIMIT = 1e6  # what a field accepts; the state, not the field, decides what is inside the room
SOURCE_FIXED_NOTE = "<i>Source fixed:</i> the scene was trained with this source position only."
"The note under the fields when the state keeps the source fixed (its tooltip: the state's whole reason)."


def _field(suffix: str = "", decimals: int = 2) -> QtWidgets.QDoubleSpinBox:
    box = QtWidgets.QDoubleSpinBox()
    box.setRange(-LIMIT, LIMIT)
    box.setDecimals(decimals)
    box.setSingleStep(0.1)
    box.setKeyboardTracking(False)  # typing "2.5" is one value, not "2", "2.", "2.5"
    box.setSuffix(suffix)
    box.setAccelerated(True)
    return box


class PosePanel(QtWidgets.QGroupBox):
    """x, y, z of the listener and the source, the listener's yaw; a note when a position was clamped."""

    left = QtCore.Signal()  # Enter or Escape left a field: the keys are the window's again

    def __init__(self, parent: QtWidgets.QWidget | None = None):
        super().__init__("Pose (world coordinates)", parent)
        self.state: ViewerState | None = None
        self._with_frame: Callable[[str, Callable[[], None]], None] | None = None  # bind's
        grid = QtWidgets.QGridLayout(self)
        grid.setContentsMargins(6, 6, 6, 6)
        grid.setHorizontalSpacing(4)
        for col, name in enumerate(("", "x", "y", "z"), start=0):
            if name:
                grid.addWidget(QtWidgets.QLabel(name), 0, col, QtCore.Qt.AlignmentFlag.AlignHCenter)
        self.listener = [_field() for _ in range(3)]
        self.source = [_field() for _ in range(3)]
        for row, (label, fields) in enumerate((("Listener", self.listener), ("Source", self.source)), start=1):
            grid.addWidget(QtWidgets.QLabel(label), row, 0)
            for col, box in enumerate(fields, start=1):
                grid.addWidget(box, row, col)
        self.yaw = _field(" deg", decimals=1)
        self.yaw.setRange(-360.0, 720.0)
        self.yaw.setSingleStep(5.0)
        self.yaw.setWrapping(True)
        self.yaw.setToolTip("Degrees counter-clockwise from +x: 0 faces +x, 90 faces +y")
        grid.addWidget(QtWidgets.QLabel("Yaw"), 3, 0)
        grid.addWidget(self.yaw, 3, 1, 1, 2)
        self.source_note = QtWidgets.QLabel()  # why the source is fixed (a one-source scene); hidden otherwise
        self.source_note.setWordWrap(True)
        self.source_note.hide()
        grid.addWidget(self.source_note, 4, 0, 1, 4)
        self.notice = QtWidgets.QLabel()
        self.notice.setWordWrap(True)
        self.notice.setStyleSheet("color: #b35c00")
        grid.addWidget(self.notice, 5, 0, 1, 4)
        self._notice_timer = QtCore.QTimer(self)
        self._notice_timer.setSingleShot(True)
        self._notice_timer.setInterval(8000)
        self._notice_timer.timeout.connect(self.notice.clear)

        for box in self.listener:
            box.editingFinished.connect(self._listener_typed)
        for box in self.source:
            box.editingFinished.connect(self._source_typed)
        self.yaw.editingFinished.connect(self._yaw_typed)
        self.keys = FieldKeys(self, self._leave)
        for box in self.listener:
            self.keys.watch(box, lambda: self.state and self._show_listener(self.state.listener))
        for box in self.source:
            self.keys.watch(box, lambda: self.state and self._show_source(self.state.source))
        self.keys.watch(self.yaw, lambda: self.state and self._show_yaw(self.state.yaw))

    def _leave(self) -> None:
        focused = QtWidgets.QApplication.focusWidget()
        if focused is not None and self.isAncestorOf(focused):
            self.left.emit()

    def bind(self, state: ViewerState, with_frame: Callable[[str, Callable[[], None]], None] | None = None) -> None:
        """Mirror ``state`` in the fields (and typed values into it). ``with_frame(key, update)``: how a moving pose
        reaches the fields (the 3D view's :meth:`~avgs_viewer.canvas.SceneCanvas.with_frame`: with its frames
        during a drag); None: at once."""
        self._with_frame = with_frame
        if self.state is not None:
            for event, cb in self._subscriptions():
                event.disconnect(cb)
        self.state = state
        for event, cb in self._subscriptions():
            event.connect(cb)
        self.notice.clear()
        self._show_listener(state.listener)
        self._show_source(state.source)
        self._show_yaw(state.yaw)
        self.setToolTip(f"Positions are kept inside the {state.region}")
        fixed = state.source_fixed
        for box in self.source:
            box.setReadOnly(fixed is not None)
            box.setButtonSymbols(QtWidgets.QAbstractSpinBox.ButtonSymbols.NoButtons if fixed is not None
                                 else QtWidgets.QAbstractSpinBox.ButtonSymbols.UpDownArrows)
            box.setToolTip(fixed or "")
        self.source_note.setText(SOURCE_FIXED_NOTE if fixed else "")
        self.source_note.setToolTip(fixed or "")
        self.source_note.setVisible(fixed is not None)

    def resizeEvent(self, event) -> None:  # noqa: N802
        """Keep the source note's wrapped lines whole when the window is short of height."""
        super().resizeEvent(event)
        note = self.source_note
        if note.isVisible() and note.width() > 0:
            note.setMinimumHeight(note.heightForWidth(note.width()))

    def _subscriptions(self) -> tuple[tuple[Event[Any], Callable[[Any], None]], ...]:
        ev = self.state.events
        return ((ev.listener, self._show_listener), (ev.source, self._show_source), (ev.yaw, self._show_yaw),
                (ev.clamped, self._show_notice), (ev.wall, self._show_notice))

    # ------------------------------------------------------------------ state -> fields
    @staticmethod
    def _show(fields, xyz) -> None:
        for box, v in zip(fields, xyz):
            with QtCore.QSignalBlocker(box):
                box.setValue(float(v))

    def _update(self, key: str, update: Callable[[], None]) -> None:
        if self._with_frame is None:
            update()
        else:
            self._with_frame(f"pose.{key}", update)

    def _show_listener(self, xyz) -> None:
        xyz = tuple(float(v) for v in xyz)
        self._update("listener", lambda: self._show(self.listener, xyz))

    def _show_source(self, xyz) -> None:
        xyz = tuple(float(v) for v in xyz)
        self._update("source", lambda: self._show(self.source, xyz))

    def _show_yaw(self, yaw: float) -> None:
        yaw = float(yaw)

        def show() -> None:
            with QtCore.QSignalBlocker(self.yaw):
                self.yaw.setValue(yaw)

        self._update("yaw", show)

    def _show_notice(self, message: str) -> None:
        self.notice.setText(message)
        self._notice_timer.start()

    # ------------------------------------------------------------------ fields -> state
    def _listener_typed(self) -> None:
        if self.state is not None:
            self.state.set_listener([b.value() for b in self.listener], keep_height=False)
            self._show_listener(self.state.listener)  # a clamped value shows where it went

    def _source_typed(self) -> None:
        if self.state is not None and self.state.source_movable:  # read-only fields when it is fixed
            self.state.set_source([b.value() for b in self.source])
            self._show_source(self.state.source)

    def _yaw_typed(self) -> None:
        if self.state is not None:
            self.state.set_yaw(self.yaw.value())
            self._show_yaw(self.state.yaw)
