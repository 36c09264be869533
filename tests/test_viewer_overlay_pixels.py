"""The overlays' layout in real pixels: headless screenshots of the demo with the map, legend,
caption and the listener's-view inset (issue 31, item 7). Each overlay's own pixels (the picture
with it minus the picture without it) lie inside its rectangle, and the rectangles are apart, so
no overlay draws over another; at --scale 2 points and lines are twice as wide."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import pyvista as pv
import torch
from PIL import Image

from avgs import SceneRenderer
from avgs.render.listener_view import ListenerView
from avgs_viewer.export import write_screenshot
from avgs_viewer.overlay_layout import intersects
from avgs_viewer.propagation_view import PropagationView, show_inset
from avgs_viewer.scene_view import SceneView
from avgs_viewer.state import ViewerState

DEMO = Path(__file__).resolve().parents[1] / "assets" / "demo" / "scene.ckpt"
pytestmark = pytest.mark.skipif(not DEMO.is_file(), reason="the bundled demo checkpoint is missing")


@pytest.fixture(scope="module")
def renderer():
    torch.set_num_threads(1)
    return SceneRenderer.load(DEMO)


def picture(plotter, path: Path, scale: int = 1) -> np.ndarray:
    plotter.render()  # what was just shown or hidden, drawn
    return np.asarray(Image.open(write_screenshot(plotter, path, scale=scale)))[..., :3].astype(int)


def changed_box(a: np.ndarray, b: np.ndarray):
    """The bounding box (x0, y0, x1, y1 from the bottom, pixels) of where ``a`` and ``b`` differ."""
    rows, cols = np.nonzero(np.abs(a - b).sum(axis=2) > 24)
    if not len(rows):
        return None
    h = a.shape[0]
    return cols.min(), h - 1 - rows.max(), cols.max() + 1, h - rows.min()


@pytest.mark.parametrize("size", [(400, 300), (1024, 768)])
def test_each_overlay_draws_only_inside_its_own_rectangle(renderer, tmp_path, size):
    plotter = pv.Plotter(off_screen=True, window_size=list(size))
    state = ViewerState(renderer.bounds, renderer.source, outline=renderer.outline)
    view = SceneView(plotter, renderer, state)
    floor = PropagationView(plotter, renderer, state, mode="level")
    floor.size = 12
    floor.draw_now()
    show_inset(plotter, ListenerView.load(DEMO).render(state.listener, state.yaw, 192, 144))
    view.show_legend()
    view.show_caption()
    out = view.board.last
    assert set(out.pixels) == {"axes", "inset", "colour_bar", "legend", "caption"}, out.notes
    for a, b in [(a, b) for a in out.pixels for b in out.pixels if a < b]:
        assert not intersects(out.pixels[a], out.pixels[b]), (a, b)
    full = picture(plotter, tmp_path / "full.png")
    props = {"legend": [view._legend_actor], "caption": [view._caption],
             "colour_bar": list(plotter.scalar_bars.values()),
             "inset": [plotter.actors["listener_view_caption"]] + [
                 p for p in plotter.renderer.GetViewProps() if p.GetClassName() == "vtkLogoRepresentation"]}
    for name, parts in props.items():
        for p in parts:
            p.SetVisibility(False)
        without = picture(plotter, tmp_path / f"no_{name}.png")
        for p in parts:
            p.SetVisibility(True)
        box = changed_box(full, without)
        assert box is not None, name  # it was drawn
        x0, y0, x1, y1 = out.pixels[name]
        assert x0 - 2 <= box[0] and y0 - 2 <= box[1] and box[2] <= x1 + 2 and box[3] <= y1 + 2, (name, box, out.pixels[name])
    floor.close()
    view.close()
    plotter.close()


def median_run(img: np.ndarray) -> float:
    """The median length of the vertical runs of ink (not background) over all columns: a line's
    or a point's width in pixels."""
    ink = np.abs(img - np.array([22, 24, 30])).sum(axis=2) > 40  # [H, W]
    padded = np.pad(ink, ((1, 1), (0, 0))).astype(np.int8)
    d = np.diff(padded, axis=0)
    starts, ends = np.nonzero(d.T == 1), np.nonzero(d.T == -1)
    runs = ends[1] - starts[1]
    return float(np.median(runs))


SCALE_PROBE = """
import json, sys
from pathlib import Path
import pyvista as pv, torch
torch.set_num_threads(1)
sys.path.insert(0, sys.argv[2])
from test_viewer_overlay_pixels import DEMO, median_run, picture
from avgs import SceneRenderer
from avgs_viewer.scene_view import SceneView
from avgs_viewer.state import ViewerState
tmp = Path(sys.argv[1])
renderer = SceneRenderer.load(DEMO)
plotter = pv.Plotter(off_screen=True, window_size=[400, 300])
state = ViewerState(renderer.bounds, renderer.source, outline=renderer.outline)
view = SceneView(plotter, renderer, state, axes=False, max_points=300)  # points apart from each other
view.overlay.SetDraw(False)  # the handles' layer off: the outline's lines alone, then the points alone
view._points_actor.SetVisibility(False)
lines = [median_run(picture(plotter, tmp / f"lines{s}.png", s)) for s in (1, 2)]
view._points_actor.SetVisibility(True)
plotter.actors["outline"].SetVisibility(False)
points = [median_run(picture(plotter, tmp / f"points{s}.png", s)) for s in (1, 2)]
print(json.dumps({"lines": lines, "points": points, "width": plotter.actors["outline"].GetProperty().GetLineWidth()}))
view.close()
plotter.close()
"""


def test_scale_2_draws_points_and_lines_twice_as_wide(tmp_path):
    """In a fresh process, as `avgs-viewer --screenshot --scale 2` runs: a process that already holds
    other OpenGL contexts (the other GUI tests' windows) may draw wide lines differently."""
    import json
    import os
    import subprocess
    import sys

    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    run = subprocess.run([sys.executable, "-c", SCALE_PROBE, str(tmp_path), str(Path(__file__).parent)],
                         capture_output=True, text=True, env=env, timeout=300)
    assert run.returncode == 0, run.stderr[-2000:]
    got = json.loads(run.stdout.strip().splitlines()[-1])
    lines, points = got["lines"], got["points"]
    assert 1.6 <= lines[1] / lines[0] <= 2.5, lines  # without scaled marks: ~1
    assert 1.6 <= points[1] / points[0] <= 2.5, points
    assert got["width"] == 2  # restored after the picture
