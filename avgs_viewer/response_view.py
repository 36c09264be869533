"""The impulse-response panel: the current pose's binaural response and its energy decay.

Drawn with QPainter from a :class:`~avgs_viewer.response.ResponseSummary` (no plotting
library: a repaint costs a few ms of opaque pens and a few hundred points, where a matplotlib
figure costs tens of ms, on the GUI thread that also carries the drags). It repaints only when
it is handed a new response or resized, never while idle: the window's audio path hands it the response
of each pose the audio engine plays, at most every 150 ms while a handle moves (and the
reverberation time, the costliest number, once the move ends).

Left: each ear's response (left ear above, right ear below, on one amplitude scale so their
levels compare), time in ms from emission; right: both ears' energy decay curves
(Schroeder backward integration) in dB with the -60 dB line that defines T60, and the T60
of each ear. A button plays the response itself (the window's "play impulse response").
"""

from __future__ import annotations

import math

import numpy as np
from PySide6 import QtCore, QtGui, QtWidgets

from .response import DECAY_FLOOR_DB, T60_LINE_DB, ResponseSummary, Trace

EAR_COLOURS = (QtGui.QColor(40, 110, 220), QtGui.QColor(215, 60, 40))  # left ear, right ear
EAR_NAMES = ("left ear", "right ear")
DIRECT_COLOUR = QtGui.QColor(20, 160, 60)
"The direct sound's marks: a dashed line at each ear's arrival, and its times and ITD in words."
MIN_PLOT_HEIGHT = 150
DECAY_TITLE = "Energy decay (dB)"
LOADING_TEXT = "No response yet: the scene is loading"
NO_SCENE_TEXT = "No scene: open a checkpoint with File > Open scene"
T60_LABEL = "T60"
"The -60 dB line's label, in the margin right of the decay plot."
FONT_PT = 8


def nice_step(span: float, target: int = 5) -> float:
    """A tick spacing of 1, 2 or 5 times a power of ten giving the nearest to ``target`` ticks over ``span``."""
    if not (span > 0 and math.isfinite(span)):
        return 1.0
    raw = span / max(target, 1)
    power = 10.0 ** math.floor(math.log10(raw))
    return min((m * power for m in (1.0, 2.0, 5.0, 10.0)), key=lambda step: abs(math.log(raw / step)))


def _mix(a: QtGui.QColor, b: QtGui.QColor, t: float) -> QtGui.QColor:
    """``a`` blended over ``b`` with weight ``t``, as an opaque colour (a translucent pen costs
    about 50 times more per line on the raster engine)."""
    return QtGui.QColor(*(round(t * x + (1 - t) * y) for x, y in ((a.red(), b.red()), (a.green(), b.green()),
                                                                  (a.blue(), b.blue()))))


def _fmt(v: float) -> str:
    return f"{v:.0f}" if abs(v) >= 10 or v == int(v) else f"{v:g}"


class ResponsePlot(QtWidgets.QWidget):
    """Both ears' response (left) and energy decay (right), painted from a summary."""

    def __init__(self, parent: QtWidgets.QWidget | None = None):
        super().__init__(parent)
        self.summary: ResponseSummary | None = None
        self.empty_text = LOADING_TEXT
        "What the plot says while it has no response (a scene loading, or none to load)."
        self.trace: Trace | None = None
        "What the waveform lanes show now (decimated to their width in pixels)."
        self.paints = 0
        "How many times the plot was painted (it repaints only when its response or size changes)."
        self._columns = 0
        self.setMinimumHeight(MIN_PLOT_HEIGHT)
        self.setSizePolicy(QtWidgets.QSizePolicy.Policy.Expanding, QtWidgets.QSizePolicy.Policy.Expanding)
        font = self.font()
        font.setPointSize(FONT_PT)
        self.setFont(font)
        self.setToolTip("The predicted binaural impulse response of the current pose: each ear's response, "
                        "and its energy decay (Schroeder backward integration) with the -60 dB line that "
                        "defines the reverberation time T60.")

    def set_summary(self, summary: ResponseSummary | None) -> None:
        """Show ``summary`` (None: nothing yet); repaints once."""
        self.summary = summary
        self.trace = None
        self.update()

    # ------------------------------------------------------------------ layout
    def _areas(self) -> tuple[QtCore.QRectF, QtCore.QRectF]:
        """(waveform area, decay area) in widget pixels, axis labels outside them (the decay's
        right margin holds its T60 line's label)."""
        fm = self.fontMetrics()
        left_pad = fm.horizontalAdvance("-90 dB") + 8
        right_pad = fm.horizontalAdvance(T60_LABEL) + 8
        top, bottom = fm.height() + 4, 2 * fm.height() + 6
        w, h = float(self.width()), float(self.height())
        split = 0.58 * w
        wave = QtCore.QRectF(fm.horizontalAdvance("Right") + 10, top, split - fm.horizontalAdvance("Right") - 22,
                             h - top - bottom)
        decay = QtCore.QRectF(split + left_pad, top, w - split - left_pad - right_pad, h - top - bottom)
        return wave, decay

    def decay_labels(self) -> dict[str, QtCore.QRectF]:
        """Where the decay plot's own labels go (widget pixels): its title and T60 in the row above
        the plot, the T60 line's label in the margin to its right; none inside the plot (the
        curves' area) nor over another."""
        fm = self.fontMetrics()
        _, area = self._areas()
        row_top = area.top() - 1 - fm.height()
        t60 = self.summary.t60_text() if self.summary is not None else ""
        t60_w = min(float(fm.horizontalAdvance(t60)), area.width() * 0.62)
        title_w = min(float(fm.horizontalAdvance(DECAY_TITLE)), area.width() - t60_w - 8)
        y60 = area.top() + area.height() * T60_LINE_DB / DECAY_FLOOR_DB
        return {
            "title": QtCore.QRectF(area.left(), row_top, max(title_w, 0.0), fm.height()),
            "t60": QtCore.QRectF(area.right() - t60_w, row_top, t60_w, fm.height()),
            "line": QtCore.QRectF(area.right() + 4, y60 - fm.height() / 2, fm.horizontalAdvance(T60_LABEL),
                                  fm.height()),
        }

    def trace_for(self, columns: int) -> Trace | None:
        if self.summary is None:
            return None
        if self.trace is None or self._columns != columns:
            self.trace = self.summary.trace(columns)
            self._columns = columns
        return self.trace

    # ------------------------------------------------------------------ painting
    def paintEvent(self, event: QtGui.QPaintEvent) -> None:  # noqa: N802
        self.paints += 1
        p = QtGui.QPainter(self)  # antialiased curves only: axis and grid lines are straight (and 10x cheaper)
        pal = self.palette()
        p.fillRect(self.rect(), pal.color(QtGui.QPalette.ColorRole.Base))
        text = pal.color(QtGui.QPalette.ColorRole.Text)
        if self.summary is None:
            p.setPen(text)
            p.drawText(self.rect(), QtCore.Qt.AlignmentFlag.AlignCenter | QtCore.Qt.TextFlag.TextWordWrap,
                       self.empty_text)
            p.end()
            return
        wave, decay = self._areas()
        if wave.width() < 20 or decay.width() < 20 or wave.height() < 20:
            p.end()
            return
        trace = self.trace_for(max(2, int(wave.width() // 2)))  # a column per 2 pixels: enough, and half the points
        self._paint_waves(p, wave, trace, text)
        self._paint_decay(p, decay, trace, text)
        p.end()

    def _time_axis(self, p: QtGui.QPainter, area: QtCore.QRectF, text: QtGui.QColor) -> None:
        """Ticks and labels in ms under ``area`` (spanning the whole response)."""
        duration = self.summary.duration_ms
        step = nice_step(duration, max(2, int(area.width() // 50)))
        fm = self.fontMetrics()
        grid = _mix(text, self.palette().color(QtGui.QPalette.ColorRole.Base), 0.16)
        t = 0.0
        while t <= duration + 1e-9:
            x = area.left() + area.width() * t / duration
            p.setPen(grid)
            p.drawLine(QtCore.QPointF(x, area.top()), QtCore.QPointF(x, area.bottom()))
            p.setPen(text)
            label = _fmt(t)
            p.drawText(QtCore.QPointF(x - fm.horizontalAdvance(label) / 2, area.bottom() + fm.ascent() + 2), label)
            t += step
        unit = "time (ms)"
        p.drawText(QtCore.QPointF(area.right() - fm.horizontalAdvance(unit), area.bottom() + fm.height() + fm.ascent() + 2),
                   unit)

    def _paint_waves(self, p: QtGui.QPainter, area: QtCore.QRectF, trace: Trace, text: QtGui.QColor) -> None:
        fm = self.fontMetrics()
        peak = max(float(np.max(np.abs(trace.low))), float(np.max(np.abs(trace.high))), 1e-12)
        p.setPen(text)
        p.drawText(QtCore.QPointF(area.left(), area.top() - 4), f"Response (peak {peak:.3g})")
        self._time_axis(p, area, text)
        lane_h = area.height() / 2
        x = area.left() + (np.arange(trace.low.shape[1]) + 0.5) * area.width() / trace.low.shape[1]
        for ear in range(2):
            lane = QtCore.QRectF(area.left(), area.top() + ear * lane_h, area.width(), lane_h)
            mid, half = lane.center().y(), 0.46 * lane_h
            p.setPen(QtGui.QPen(_mix(text, self.palette().color(QtGui.QPalette.ColorRole.Base), 0.27), 1))
            p.drawLine(QtCore.QPointF(lane.left(), mid), QtCore.QPointF(lane.right(), mid))
            hi = mid - half * trace.high[ear] / peak
            lo = mid - half * trace.low[ear] / peak
            hi = np.minimum(hi, mid - 0.5)  # every column at least one pixel tall: a silent stretch shows as a line
            lo = np.maximum(lo, mid + 0.5)
            outline = QtGui.QPolygonF([QtCore.QPointF(a, b) for a, b in zip(x, hi)]
                                      + [QtCore.QPointF(a, b) for a, b in zip(x[::-1], lo[::-1])])
            colour = EAR_COLOURS[ear]
            p.setPen(QtGui.QPen(colour, 1))
            p.setBrush(colour)
            p.setRenderHint(QtGui.QPainter.RenderHint.Antialiasing, True)
            p.drawPolygon(outline)
            p.setRenderHint(QtGui.QPainter.RenderHint.Antialiasing, False)
            p.setBrush(QtCore.Qt.BrushStyle.NoBrush)
            p.setPen(colour)
            name = ("Left", "Right")[ear]
            p.drawText(QtCore.QPointF(area.left() - fm.horizontalAdvance(name) - 6, mid + fm.ascent() / 2 - 1), name)
            arrival = self.summary.direct_s[ear]
            if arrival is not None:  # the direct sound: a dashed line across the ear's lane where it arrives
                xd = area.left() + area.width() * arrival / (self.summary.duration_ms / 1000.0)
                p.setPen(QtGui.QPen(DIRECT_COLOUR, 1, QtCore.Qt.PenStyle.DashLine))
                p.drawLine(QtCore.QPointF(xd, lane.top() + 1), QtCore.QPointF(xd, lane.bottom() - 1))
        direct = self.summary.direct_text()  # inside the top right corner, past the direct sound
        p.setPen(DIRECT_COLOUR)
        p.drawText(QtCore.QPointF(area.right() - fm.horizontalAdvance(direct) - 4, area.top() + fm.ascent() + 3), direct)

    def _paint_decay(self, p: QtGui.QPainter, area: QtCore.QRectF, trace: Trace, text: QtGui.QColor) -> None:
        fm = self.fontMetrics()
        p.setPen(text)
        labels = self.decay_labels()  # above the plot and in its right margin: never under the curves
        for name, label in (("title", DECAY_TITLE), ("t60", self.summary.t60_text())):
            r = labels[name]
            p.drawText(r, QtCore.Qt.AlignmentFlag.AlignLeft | QtCore.Qt.AlignmentFlag.AlignBottom,
                       fm.elidedText(label, QtCore.Qt.TextElideMode.ElideRight, int(r.width()) + 1))
        self._time_axis(p, area, text)
        floor = DECAY_FLOOR_DB

        def y_of(db):
            return area.top() + area.height() * (np.asarray(db, dtype=np.float64) / floor)

        grid = _mix(text, self.palette().color(QtGui.QPalette.ColorRole.Base), 0.16)
        for db in range(0, int(floor) - 1, -20 if area.height() > 90 else -30):
            y = float(y_of(db))
            p.setPen(grid)
            p.drawLine(QtCore.QPointF(area.left(), y), QtCore.QPointF(area.right(), y))
            p.setPen(text)
            label = f"{db}"
            p.drawText(QtCore.QPointF(area.left() - fm.horizontalAdvance(label) - 5, y + fm.ascent() / 2 - 1), label)
        # The -60 dB line: where a curve crosses it, T60 has passed (for a clean exponential decay).
        y60 = float(y_of(T60_LINE_DB))
        p.setPen(QtGui.QPen(text, 1, QtCore.Qt.PenStyle.DashLine))
        p.drawLine(QtCore.QPointF(area.left(), y60), QtCore.QPointF(area.right(), y60))
        p.drawText(labels["line"], QtCore.Qt.AlignmentFlag.AlignLeft | QtCore.Qt.AlignmentFlag.AlignVCenter, T60_LABEL)
        x = area.left() + (np.arange(trace.decay_db.shape[1]) + 0.5) * area.width() / trace.decay_db.shape[1]
        p.setRenderHint(QtGui.QPainter.RenderHint.Antialiasing, True)
        for ear in range(2):
            y = y_of(trace.decay_db[ear])
            p.setPen(QtGui.QPen(EAR_COLOURS[ear], 1.6))
            p.drawPolyline(QtGui.QPolygonF([QtCore.QPointF(a, b) for a, b in zip(x, y)]))
        p.setRenderHint(QtGui.QPainter.RenderHint.Antialiasing, False)
        p.setPen(text)
        p.drawRect(area)


class ResponsePanel(QtWidgets.QWidget):
    """The plot under a title row with the "play response" button; ``play`` is emitted by it."""

    play = QtCore.Signal()

    def __init__(self, key_text: str = "I", parent: QtWidgets.QWidget | None = None):
        super().__init__(parent)
        self.plot = ResponsePlot()
        self.title = QtWidgets.QLabel("<b>Impulse response of this pose</b> "
                                      f"(<span style='color:{EAR_COLOURS[0].name()}'>left ear</span>, "
                                      f"<span style='color:{EAR_COLOURS[1].name()}'>right ear</span>)")
        self.play_button = QtWidgets.QPushButton(f"Play response ({key_text})")
        self.play_button.setToolTip("Play the pose's impulse response once instead of the clip, then the clip again")
        self.play_button.setEnabled(False)
        self.play_button.clicked.connect(lambda _=False: self.play.emit())
        row = QtWidgets.QHBoxLayout()
        row.setContentsMargins(0, 0, 0, 0)
        row.addWidget(self.title)
        row.addStretch(1)
        row.addWidget(self.play_button)
        layout = QtWidgets.QVBoxLayout(self)
        layout.setContentsMargins(6, 4, 6, 4)
        layout.setSpacing(2)
        layout.addLayout(row)
        layout.addWidget(self.plot, 1)
        self._impulse: np.ndarray | None = None
        self._sample_rate = 0
        self._moving = False
        self._stale = False

    @property
    def summary(self) -> ResponseSummary | None:
        """The response shown (or to be shown when the panel is next visible)."""
        if self._stale:
            self._refresh()
        return self.plot.summary

    def show_no_scene(self, text: str = NO_SCENE_TEXT) -> None:
        """Say that there is no scene to show a response of (a checkpoint failed to open), and how to open one."""
        self._impulse, self._stale = None, False
        self.play_button.setEnabled(False)
        self.plot.empty_text = text
        self.plot.set_summary(None)

    def show_response(self, impulse: np.ndarray | None, sample_rate: int, moving: bool = False) -> None:
        """Show ``impulse [2, L]`` (a pose's filter; None: none yet); ``moving``: while a handle moves,
        without the reverberation time. Nothing is computed or drawn for the same array again
        (but the T60 a move left out), nor while the panel is hidden (it catches up when shown)."""
        if impulse is self._impulse and sample_rate == self._sample_rate and (moving or not self._moving):
            return
        self._impulse, self._sample_rate, self._moving = impulse, int(sample_rate), bool(moving)
        self.plot.empty_text = LOADING_TEXT  # a scene is here: its response is on its way
        self.play_button.setEnabled(impulse is not None)
        self._stale = True
        if self.isVisible():
            self._refresh()

    def _refresh(self) -> None:
        self._stale = False
        impulse = self._impulse
        self.plot.set_summary(None if impulse is None else
                              ResponseSummary.of(impulse, self._sample_rate, t60=not self._moving))

    def showEvent(self, event: QtGui.QShowEvent) -> None:  # noqa: N802
        if self._stale:
            self._refresh()
        super().showEvent(event)
