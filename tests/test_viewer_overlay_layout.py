"""The overlays' one layout (avgs_viewer.overlay_layout): for many picture sizes and every
combination of overlays, no two rectangles intersect and all lie inside the picture."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from avgs_viewer.overlay_layout import NAMES, OverlayBoard, Shown, intersects, layout

SIZES = [(320, 240), (400, 300), (480, 640), (640, 360), (800, 600), (1024, 768), (1366, 768),
         (1920, 1080), (2560, 1440), (3840, 2160), (240, 320), (2000, 400), (200, 900)]


def legend_size(h):  # what SceneView asks for: 8 rows of 2.8 % of the height
    row = float(np.clip(0.028 * h, 11.0, 26.0))
    return row * (1.8 + 0.55 * 24), row * 8.6


def caption_size(h):
    font = float(np.clip(0.02 * h, 10.0, 18.0))
    return 0.62 * font * 40 + font, 1.25 * font * 2 + 0.6 * font


def all_shown(w, h):
    for axes, inset, bar, legend, caption in itertools.product([False, True], repeat=5):
        yield Shown(axes=axes, inset_aspect=0.75 if inset else None, colour_bar=bar,
                    legend=legend_size(h) if legend else None, caption=caption_size(h) if caption else None)


@pytest.mark.parametrize("size", SIZES)
def test_no_two_overlays_intersect_and_all_lie_inside(size):
    w, h = size
    rng = np.random.default_rng(0)
    for shown in all_shown(w, h):
        handles = [((rng.uniform(0, w), rng.uniform(0, h)), 20.0) for _ in range(2)]
        out = layout(w, h, shown, avoid=handles)
        boxes = list(out.rects.items())
        for name, (x0, y0, x1, y1) in boxes:
            assert 0 <= x0 < x1 <= 1 and 0 <= y0 < y1 <= 1, (size, shown, name)
        for (a, ra), (b, rb) in itertools.combinations(boxes, 2):
            assert not intersects(ra, rb), (size, shown, a, b, ra, rb)
        asked = {n for n in NAMES if getattr(shown, "inset_aspect" if n == "inset" else n) not in (None, False)}
        # What is asked for is placed, or a note says it was left out; a shrunk one says so too.
        for name in asked - set(out.rects):
            assert any(note.startswith(name.replace("_", " ").replace("inset", "listener's view inset"))
                       for note in out.notes), (size, name, out.notes)
        for name, scale in out.scales.items():
            if name in ("legend", "caption") and scale < 0.999:
                assert any(note.startswith(f"{name} shrunk") for note in out.notes)


def test_everything_fits_at_usual_sizes_and_the_small_picture_drops_with_a_note():
    full = lambda w, h: Shown(axes=True, inset_aspect=0.75, colour_bar=True,  # noqa: E731
                              legend=legend_size(h), caption=caption_size(h))
    for w, h in [(1024, 768), (1920, 1080), (800, 600)]:
        out = layout(w, h, full(w, h))
        assert set(out.rects) == set(NAMES) and not out.notes, (w, h, out.notes)
    small = layout(400, 300, full(400, 300))
    assert {"axes", "inset", "colour_bar"} <= set(small.rects)
    assert all(name in small.rects or any(name in n for n in small.notes) for name in ("legend", "caption"))


def test_legend_keeps_off_a_handle_when_a_corner_is_free():
    w, h = 1024, 768
    first = layout(w, h, Shown(legend=legend_size(h)))
    assert first.corners["legend"] == "upper right"
    x0, y0, x1, y1 = first.pixels["legend"]
    moved = layout(w, h, Shown(legend=legend_size(h)), avoid=[(((x0 + x1) / 2, (y0 + y1) / 2), 15.0)])
    assert moved.corners["legend"] != "upper right"


def test_board_places_again_on_every_change():
    size = [1024, 768]
    board = OverlayBoard(lambda: tuple(size))
    placed = {}
    board.put("colour_bar", lambda: True, lambda r, s, _: placed.__setitem__("colour_bar", r))
    board.put("inset", lambda: 0.75, lambda r, s, _: placed.__setitem__("inset", r))
    assert placed["colour_bar"][1] >= placed["inset"][3]  # the bar above the inset
    size[:] = [400, 300]
    board.relayout()
    assert not intersects(placed["colour_bar"], placed["inset"])
    board.remove("inset")
    assert "inset" not in board and placed["colour_bar"][1] < 0.5
    with pytest.raises(ValueError, match="overlay must be one of"):
        board.put("title", lambda: True, lambda *a: None)
