"""Where the 3D view's overlays go: one layout for the axes marker, the listener's-view inset,
the map's colour bar, the colour legend and the pose caption, in the window and in pictures.

:func:`layout` takes the picture's size in pixels and what is shown, and returns for each
overlay a rectangle in normalised viewport coordinates (0..1, y up, as VTK's viewports) such
that no two intersect and all lie inside the picture. Fixed parts go first: the axes marker
in the lower left, the inset in the lower right, the colour bar in the right column above
the inset. The legend and the caption then take the first corner slot that covers neither
another overlay nor a handle (``avoid``: circles in pixels); where none is free they shrink
(to :data:`MIN_SCALE` of their size) and, failing that, are left out. Every change is said
in ``Layout.notes``. :class:`OverlayBoard` keeps what a plotter shows and places it all again
on any change (a resize, the map switched on, a legend for a picture). No Qt, no VTK.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Iterable, Sequence

import numpy as np

Box = tuple[float, float, float, float]  # (x0, y0, x1, y1)
NAMES = ("axes", "inset", "colour_bar", "legend", "caption")
CORNERS = ("upper right", "upper left", "lower right", "lower left")
SCALES = (1.0, 0.85, 0.7, 0.55)
MIN_SCALE = SCALES[-1]
"The smallest a legend or caption is drawn (of the size it asked for) before it is left out."


@dataclass(frozen=True)
class Shown:
    """What the picture shows: ``legend`` and ``caption`` as the (width, height) in pixels they
    ask for, ``inset_aspect`` the inset image's height / width; None: not shown."""

    axes: bool = False
    inset_aspect: float | None = None
    colour_bar: bool = False
    legend: tuple[float, float] | None = None
    caption: tuple[float, float] | None = None


@dataclass
class Layout:
    """Rectangles (normalised, ``(x0, y0, x1, y1)``) of the overlays placed, their pixel
    rectangles, the scale each was drawn at (legend, caption, inset: a size below 1 means
    shrunk), the corner the legend and caption went to, and notes on what was shrunk or left out."""

    width: int
    height: int
    rects: dict[str, Box] = field(default_factory=dict)
    pixels: dict[str, Box] = field(default_factory=dict)
    scales: dict[str, float] = field(default_factory=dict)
    corners: dict[str, str] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)


def pad_px(height: float) -> float:
    """The gap between an overlay and the picture's edge or another overlay."""
    return max(3.0, 0.012 * height)


def text_px(height: float) -> float:
    """A line of overlay text (the inset's title), pixels."""
    return float(np.clip(0.045 * height, 12.0, 22.0))


def axes_px(width: float, height: float) -> float:
    """The axes marker's side, pixels."""
    return float(np.clip(0.14 * min(width, height), 40.0, 140.0))


def intersects(a: Box, b: Box) -> bool:
    """True when boxes ``a`` and ``b`` share area (touching edges do not count)."""
    return min(a[2], b[2]) > max(a[0], b[0]) and min(a[3], b[3]) > max(a[1], b[1])


def _circle_cost(box: Box, circles: Iterable[tuple[Sequence[float], float]]) -> float:
    cost = 0.0
    for c, r in circles:
        dx = max(box[0] - c[0], 0.0, c[0] - box[2])
        dy = max(box[1] - c[1], 0.0, c[1] - box[3])
        if dx * dx + dy * dy < r * r:
            cost += 1.0
    return cost


def _slot(w: float, h: float, pad: float, size: tuple[float, float], placed: list[Box],
          circles, corners: Sequence[str]) -> tuple[str, Box, float] | None:
    """The first corner position for a box of ``size`` inside the picture covering no box of
    ``placed`` and, if it can, no circle; (corner, box, handles covered) or None."""
    bw, bh = size
    best = None
    for corner in corners:
        top, right = corner.startswith("upper"), corner.endswith("right")
        xs = [w - pad - bw if right else pad]
        xs += [o[0] - pad - bw if right else o[2] + pad for o in placed]
        ys = [h - pad - bh if top else pad]
        ys += [o[1] - pad - bh if top else o[3] + pad for o in placed]
        # nearest the corner first
        xs = sorted(set(xs), reverse=right)
        ys = sorted(set(ys), reverse=top)
        for y0 in ys:
            for x0 in xs:
                box = (x0, y0, x0 + bw, y0 + bh)
                if x0 < -1e-9 or y0 < -1e-9 or box[2] > w + 1e-9 or box[3] > h + 1e-9:
                    continue
                if any(intersects(box, o) for o in placed):
                    continue
                cost = _circle_cost(box, circles)
                if cost == 0:
                    return corner, box, 0.0
                if best is None or cost < best[2]:
                    best = (corner, box, cost)
    return best


def layout(width: int, height: int, shown: Shown, avoid: Iterable[tuple[Sequence[float], float]] = ()) -> Layout:
    """Non-overlapping rectangles for the overlays in ``shown`` on a ``width`` x ``height`` picture
    (pixels), each inside it; ``avoid``: ((x, y), radius) circles in pixels (the handles) that the
    legend and caption keep off where they can. See the module's docstring."""
    w, h = float(width), float(height)
    out = Layout(int(width), int(height))
    pad = pad_px(h)
    circles = list(avoid)
    placed: list[Box] = []

    def put(name: str, box: Box) -> None:
        placed.append(box)
        out.pixels[name] = box
        out.rects[name] = (box[0] / w, box[1] / h, box[2] / w, box[3] / h)

    if shown.axes:
        s = axes_px(w, h)
        put("axes", (0.0, 0.0, s, s))
    column_top = pad  # where the right column (inset, then colour bar) is filled up to
    if shown.inset_aspect is not None:
        aspect = float(shown.inset_aspect)
        title = text_px(h)
        iw = float(np.clip(0.25 * w, 64.0, 400.0))
        room = 0.5 * h - pad - title  # the inset takes at most the lower half of the right column
        if iw * aspect > room:
            iw = room / aspect
        iw = min(iw, 0.45 * w)
        if iw < 48.0:
            out.notes.append(f"listener's view inset left out: no room in a {width} x {height} picture")
        else:
            box = (w - pad - iw, pad, w - pad, pad + iw * aspect + title)
            put("inset", box)
            out.scales["inset"] = iw / float(np.clip(0.25 * w, 64.0, 400.0))
            column_top = box[3] + pad
    if shown.colour_bar:
        bw = float(np.clip(0.1 * w, 64.0, 110.0))
        bar_h = min(0.55 * h, h - pad - column_top)
        if bar_h >= max(80.0, 0.25 * h) and bw <= 0.4 * w:
            put("colour_bar", (w - pad - bw, h - pad - bar_h, w - pad, h - pad))
        else:  # beside the inset, over the bottom of the picture
            x1 = (out.pixels["inset"][0] if "inset" in out.pixels else w) - pad
            bar_h = min(0.55 * h, h - 2 * pad)
            box = (x1 - bw, pad, x1, pad + bar_h)
            if bar_h >= 80.0 and box[0] >= pad and not any(intersects(box, o) for o in placed):
                put("colour_bar", box)
            else:
                out.notes.append(f"colour bar left out: no room in a {width} x {height} picture")
    for name, corners in (("legend", CORNERS), ("caption", CORNERS[1:] + CORNERS[:1])):
        size = getattr(shown, name)
        if size is None:
            continue
        found = None
        for scale in SCALES:
            sized = (min(size[0] * scale, w - 2 * pad), min(size[1] * scale, h - 2 * pad))
            slot = _slot(w, h, pad, sized, placed, circles, corners)
            if slot is not None and (found is None or slot[2] < found[3]):
                found = (scale, slot[0], slot[1], slot[2])
            if found is not None and found[3] == 0:
                break
        if found is None:
            out.notes.append(f"{name} left out: no room in a {width} x {height} picture")
            continue
        scale, corner, box, _ = found
        scale = min(scale, (box[2] - box[0]) / size[0], (box[3] - box[1]) / size[1])
        put(name, box)
        out.scales[name], out.corners[name] = scale, corner
        if scale < 1.0 - 1e-9:
            out.notes.append(f"{name} shrunk to {scale:.0%} to fit a {width} x {height} picture")
    return out


@dataclass
class _Part:
    ask: Callable[[], object]  # what ``Shown`` takes for it (True, an aspect, a size), or None: not shown
    place: Callable[[Box | None, float, Layout], None]  # its rectangle (None: left out), its scale


class OverlayBoard:
    """The overlays a plotter shows, placed by :func:`layout` whenever one is added, removed or
    the picture changes size. ``size()``: the picture's (width, height) in pixels; ``avoid()``:
    the circles to keep off (the handles). One board per plotter (:meth:`of`)."""

    def __init__(self, size: Callable[[], tuple[int, int]]):
        self.size = size
        self.avoid: Callable[[], Iterable] = lambda: ()
        self._parts: dict[str, _Part] = {}
        self.last: Layout | None = None

    @classmethod
    def of(cls, plotter) -> "OverlayBoard":
        board = getattr(plotter, "_avgs_overlays", None)
        if board is None:
            def size() -> tuple[int, int]:
                w, h = plotter.render_window.GetSize()
                return max(int(w), 1), max(int(h), 1)

            board = cls(size)
            plotter._avgs_overlays = board
        return board

    def put(self, name: str, ask: Callable[[], object], place: Callable[[Box | None, float, Layout], None],
            relayout: bool = True) -> Layout | None:
        """Show overlay ``name`` (one of :data:`NAMES`); everything is placed again."""
        if name not in NAMES:
            raise ValueError(f"overlay must be one of {', '.join(NAMES)}, got {name!r}")
        self._parts[name] = _Part(ask, place)
        return self.relayout() if relayout else None

    def remove(self, name: str, relayout: bool = True) -> None:
        if self._parts.pop(name, None) is not None and relayout:
            self.relayout()

    def __contains__(self, name: str) -> bool:
        return name in self._parts

    def shown(self) -> Shown:
        kw = {}
        for name, part in self._parts.items():
            value = part.ask()
            key = "inset_aspect" if name == "inset" else name
            kw[key] = bool(value) if name in ("axes", "colour_bar") else value
        return Shown(**kw)

    def relayout(self) -> Layout:
        """Place every overlay for the picture's size now; returns the layout (also ``last``)."""
        w, h = self.size()
        needs = "legend" in self._parts or "caption" in self._parts  # only they keep off the handles
        result = layout(w, h, self.shown(), self.avoid() if needs else ())
        self.last = result
        for name, part in list(self._parts.items()):
            part.place(result.rects.get(name), result.scales.get(name, 1.0), result)
        return result
