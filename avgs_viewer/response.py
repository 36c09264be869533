"""What the impulse-response panel draws, computed from a pose's filter: no Qt.

A pose's filter is its binaural impulse response ``[2, L]`` (``RenderResult.impulse``,
channel 0 = left ear). :class:`ResponseSummary` holds it with each ear's energy decay
curve (Schroeder backward integration, :func:`avgs.evaluation.metrics.schroeder_db`), reverberation
time (:func:`avgs.evaluation.metrics.rt60`, the T60 that ``avgs eval`` scores) and direct sound
(each ear's arrival and the ITD, as ``avgs eval``'s spatial cues measure them); :meth:`ResponseSummary.trace`
decimates both to a few hundred columns for drawing (each column the minimum and maximum of
the samples it covers, so no peak is lost however long the response).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from avgs.evaluation import spatial

DECAY_FLOOR_DB = -90.0
"The energy decay curves are drawn down to this level (and held there past the response's end)."
T60_LINE_DB = -60.0
"The level the reverberation time is defined by: the decay curves' plot marks it."


@dataclass(frozen=True)
class Trace:
    """One response decimated to ``C`` columns over its whole length."""

    times_ms: np.ndarray  # [C] float64, each column's centre, ms from the response's start (emission)
    low: np.ndarray       # [2, C] float32, the smallest sample of each column (left, right)
    high: np.ndarray      # [2, C] float32, the largest sample of each column
    decay_db: np.ndarray  # [2, C] float64, each ear's energy decay at the column's first sample, dB re its start


@dataclass(frozen=True)
class ResponseSummary:
    """A pose's binaural impulse response, its energy decay and reverberation time per ear."""

    impulse: np.ndarray  # [2, L] float32, read-only, channel 0 = left ear
    sample_rate: int
    decay_db: np.ndarray  # [2, L] float64: Schroeder curve per ear, dB re its start, floored at DECAY_FLOOR_DB
    t60_s: tuple[float | None, float | None] | None  # (left, right) seconds, None where it cannot be measured;
    #                                                  None: not measured (``t60=False``)
    direct_s: tuple[float | None, float | None] = (None, None)  # (left, right) seconds: each ear's direct sound
    itd_s: float = 0.0  # the direct sound's ITD (s; negative: the left ear leads), avgs.evaluation.spatial

    @classmethod
    def of(cls, impulse: np.ndarray, sample_rate: int, t60: bool = True) -> "ResponseSummary":
        """The summary of ``impulse [2, L]`` at ``sample_rate`` Hz; ``t60=False`` leaves the
        reverberation time out (a few ms less: the explorer measures it once a move ends)."""
        from avgs.evaluation.metrics import rt60, schroeder_db

        h = np.array(impulse, dtype=np.float32)  # a copy: the caller's array may be reused
        if h.ndim != 2 or h.shape[0] != 2 or h.shape[1] == 0:
            raise ValueError(f"an impulse response must be [2, L] with L > 0, got shape {h.shape}")
        if not np.all(np.isfinite(h)):
            raise ValueError("the impulse response has non-finite samples")
        h.setflags(write=False)
        decay = np.full(h.shape, DECAY_FLOOR_DB)  # [2, L]
        for ear in range(2):
            curve = schroeder_db(h[ear])  # [L'] with L' <= L (trailing zeros dropped); None when silent
            if curve is not None:
                decay[ear, :len(curve)] = np.maximum(curve, DECAY_FLOOR_DB)
        times = tuple(rt60(h[ear], fs=sample_rate) for ear in range(2)) if t60 else None
        return cls(impulse=h, sample_rate=int(sample_rate), decay_db=decay, t60_s=times,
                   direct_s=direct_arrivals(h, sample_rate), itd_s=spatial.response_itd(h, sample_rate))

    @property
    def length(self) -> int:
        """L, the response's length in samples."""
        return int(self.impulse.shape[1])

    @property
    def duration_ms(self) -> float:
        return 1000.0 * self.length / self.sample_rate

    @property
    def peak(self) -> float:
        """The largest magnitude of either ear's response."""
        return float(np.max(np.abs(self.impulse)))

    def t60_text(self) -> str:
        """Both ears' reverberation times in words, e.g. ``T60 L 0.56 s, R 0.57 s``."""
        def one(v):
            return "-" if v is None else f"{v:.2f} s"

        if self.t60_s is None:
            return "T60 when the move ends"
        return f"T60 L {one(self.t60_s[0])}, R {one(self.t60_s[1])}"

    def direct_text(self) -> str:
        """When each ear hears the direct sound, and the ITD, in words, e.g. ``direct L 4.9 ms, R 5.2 ms, ITD -301 us``."""
        def one(v):
            return "-" if v is None else f"{1000.0 * v:.1f} ms"

        return f"direct L {one(self.direct_s[0])}, R {one(self.direct_s[1])}, ITD {1e6 * self.itd_s:+.0f} us"

    def trace(self, columns: int) -> Trace:
        """The response and its decay decimated to ``columns`` (at most L) columns."""
        edges = column_edges(self.length, columns)  # [C + 1]
        low, high = min_max_columns(self.impulse, edges)
        centres = 0.5 * (edges[:-1] + edges[1:])
        return Trace(times_ms=1000.0 * centres / self.sample_rate, low=low, high=high,
                     decay_db=self.decay_db[:, edges[:-1]])


def direct_arrivals(h: np.ndarray, sample_rate: int) -> tuple[float | None, float | None]:
    """Each ear's direct sound (s): its first sample reaching the onset level of
    :func:`avgs.evaluation.spatial.onset` (0.1 of the response's peak, both ears); None for an ear
    that never does."""
    level = spatial.ONSET_FRACTION * float(np.max(np.abs(h)))
    if level <= 0:
        return None, None
    out = []
    for ear in range(2):
        above = np.flatnonzero(np.abs(h[ear]) >= level)
        out.append(float(above[0]) / sample_rate if above.size else None)
    return out[0], out[1]


def column_edges(length: int, columns: int) -> np.ndarray:
    """[C + 1] int64 sample boundaries splitting ``length`` samples into C = min(columns, length)
    columns of (nearly) equal width; column c covers samples ``edges[c]`` to ``edges[c + 1] - 1``."""
    if length < 1 or columns < 1:
        raise ValueError(f"need at least one sample and one column, got length {length}, columns {columns}")
    c = min(int(columns), int(length))
    return (np.arange(c + 1, dtype=np.int64) * int(length)) // c  # strictly increasing as length >= c


def min_max_columns(x: np.ndarray, edges: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(min, max) of ``x [..., L]`` over each column ``[edges[c], edges[c + 1])``: ``[..., C]`` each."""
    starts = edges[:-1]
    return np.minimum.reduceat(x, starts, axis=-1), np.maximum.reduceat(x, starts, axis=-1)
