"""Level meters with a dB scale, a peak hold and a clip light.

:class:`LevelMeter` draws one ear's RMS level as a bar over a dB scale (:data:`FLOOR_DB` to
0 dB full scale, a tick every :data:`TICK_DB`), and a line at the highest sample peak of the last
:data:`PEAK_HOLD_S` seconds. :class:`ClipLight` lights when a sample reached full scale (the
engine's output is limited at 1.0 there: what a sound card would clip) and stays lit until it is
clicked. Values are kept in tenths of a dB (``value``, ``minimum``), as a ``QProgressBar``'s were.
"""

from __future__ import annotations

import math
import time

from PySide6 import QtGui, QtWidgets

FLOOR_DB = -60.0
TICK_DB = 12.0
PEAK_HOLD_S = 1.5
"How long the peak line holds its highest value before it follows the peaks down."
CLIP_LEVEL = 1.0
"A sample at or above this (|x|, full scale) lights the clip light."


def peak_db(peak: float) -> float:
    """A sample peak (|x|) in dB full scale (the floor for silence)."""
    return 20.0 * math.log10(peak) if peak > 10.0 ** (FLOOR_DB / 20.0) else FLOOR_DB


class LevelMeter(QtWidgets.QWidget):
    """One ear's level bar (RMS, dB) on a dB scale, with a held peak line."""

    def __init__(self, parent: QtWidgets.QWidget | None = None, clock=time.monotonic):
        super().__init__(parent)
        self._min, self._max = int(FLOOR_DB * 10), 0
        self._value = self._min
        self.peak_held: float = FLOOR_DB  # dB: the line's place
        self._peak_at = -math.inf
        self._clock = clock
        self.setMinimumSize(120, 30)
        self.setSizePolicy(QtWidgets.QSizePolicy.Policy.Expanding, QtWidgets.QSizePolicy.Policy.Fixed)

    # -- the QProgressBar-like part (tenths of a dB)
    def setRange(self, lo: int, hi: int) -> None:  # noqa: N802
        self._min, self._max = int(lo), int(hi)
        self.update()

    def minimum(self) -> int:
        return self._min

    def maximum(self) -> int:
        return self._max

    def value(self) -> int:
        return self._value

    def setValue(self, v: int) -> None:  # noqa: N802
        v = max(self._min, min(self._max, int(v)))
        if v != self._value:
            self._value = v
            self.update()

    # -- the peak hold
    def show_peak(self, db: float) -> None:
        """A new sample peak (dB full scale): the line rises at once, and falls to it only after PEAK_HOLD_S."""
        now = self._clock()
        if db >= self.peak_held or now - self._peak_at > PEAK_HOLD_S:
            if abs(db - self.peak_held) >= 0.5 or db >= 0.0:  # repaint on a visible change only
                self.peak_held = max(db, FLOOR_DB)
                self.update()
            if db >= self.peak_held:
                self._peak_at = now

    def _x(self, db: float, width: int) -> int:
        lo, hi = self._min / 10.0, self._max / 10.0
        return int(round((min(max(db, lo), hi) - lo) / (hi - lo) * (width - 1)))

    def paintEvent(self, event) -> None:  # noqa: N802
        p = QtGui.QPainter(self)
        w, h = self.width(), self.height()
        bar_h = h - 9  # the scale's ticks and numbers under the bar
        p.fillRect(0, 0, w, bar_h, QtGui.QColor(40, 40, 40))
        level = self._value / 10.0
        x = self._x(level, w)
        for lo, hi, colour in ((FLOOR_DB, -18.0, (60, 180, 75)), (-18.0, -6.0, (230, 200, 40)), (-6.0, 0.0, (220, 60, 40))):
            a, b = self._x(lo, w), min(self._x(hi, w), x)
            if b > a:
                p.fillRect(a, 0, b - a, bar_h, QtGui.QColor(*colour))
        if self.peak_held > self._min / 10.0:
            px = self._x(self.peak_held, w)
            p.fillRect(max(px - 1, 0), 0, 2, bar_h, QtGui.QColor(255, 255, 255))
        font = p.font()
        font.setPixelSize(8)
        p.setFont(font)
        p.setPen(self.palette().color(QtGui.QPalette.ColorRole.WindowText))
        db = self._max / 10.0
        while db >= self._min / 10.0:
            tx = self._x(db, w)
            p.drawLine(tx, bar_h, tx, bar_h + 2)
            text = f"{db:.0f}"
            tw = p.fontMetrics().horizontalAdvance(text)
            p.drawText(min(max(tx - tw // 2, 0), w - tw), h, text)
            db -= TICK_DB
        p.end()


class ClipLight(QtWidgets.QPushButton):
    """Lit (red) once a sample reached full scale; a click puts it out."""

    def __init__(self, parent: QtWidgets.QWidget | None = None):
        super().__init__("CLIP", parent)
        self.lit = False
        self.setFixedWidth(44)
        self.setToolTip("Lights when the output reached full scale (0 dBFS: a sound card clips); click to reset")
        self.clicked.connect(lambda: self.set_lit(False))
        self.set_lit(False)

    def set_lit(self, lit: bool) -> None:
        if lit == self.lit and self.styleSheet():
            return
        self.lit = bool(lit)
        self.setStyleSheet("QPushButton { background: #e02020; color: white; font-weight: bold }" if self.lit
                           else "QPushButton { background: #303030; color: #808080 }")
