"""Handles, legends and captions as they appear in pictures, drawn off screen (EGL, no X server)."""

from __future__ import annotations

import os

import numpy as np
import pytest
import torch

os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")  # before pyvista loads VTK
import pyvista as pv  # noqa: E402

from avgs.io.checkpoint import save_checkpoint, untrained_checkpoint  # noqa: E402
from avgs.data.frame import SceneFrame  # noqa: E402
from avgs.render.renderer import SceneRenderer  # noqa: E402
from avgs_viewer import app, colors  # noqa: E402
from avgs_viewer.drag import pixel_radius, ray_plane_z  # noqa: E402
from avgs_viewer.export import annotated, check_picture_size, export_headless  # noqa: E402
from avgs_viewer.scene_view import HALO, SceneView  # noqa: E402
from avgs_viewer.state import ViewerState  # noqa: E402

ROOM = np.array([6.0, 4.0, 3.0])
SOURCE = np.array([4.5, 1.0, 1.2])
LISTENER = np.array([1.5, 3.0, 1.2])


@pytest.fixture(scope="module")
def filled(tmp_path_factory):
    """A checkpoint whose audio points fill the whole room: every handle is buried in points."""
    rng = np.random.default_rng(0)
    pts = rng.uniform(0, ROOM, size=(12000, 3))
    c = [(0, 0), (6, 0), (6, 4), (0, 4)]
    outline = [[[*c[i], 0.0], [*c[(i + 1) % 4], 0.0]] for i in range(4)]
    ckpt = untrained_checkpoint(pts, SOURCE, frame=SceneFrame(ROOM / 2, 1 / 3.0), alpha_dim=8, seed=1,
                                outline_world=np.array(outline, dtype=np.float64))
    ckpt["scene"]["bounds"] = torch.tensor([[0.0, 0.0, 0.0], ROOM.tolist()])
    path = save_checkpoint(ckpt, tmp_path_factory.mktemp("filled") / "filled.ckpt")
    return path, SceneRenderer.load(path)


def shot(plotter) -> np.ndarray:
    return plotter.screenshot(return_img=True)[..., :3].astype(int)


def pixel(img: np.ndarray, display_xy) -> np.ndarray:
    h = img.shape[0]
    return img[int(round(h - 1 - display_xy[1])), int(round(display_xy[0]))]


def ring_pixels(img, centre_xy, radius_px) -> np.ndarray:
    """Pixels on a circle of ``radius_px`` around a display point."""
    angles = np.linspace(0, 2 * np.pi, 48, endpoint=False)
    return np.array([pixel(img, centre_xy + radius_px * np.array([np.cos(a), np.sin(a)])) for a in angles])


def test_handles_show_through_the_points_with_rings_in_every_colour_mode(filled):
    _, renderer = filled
    plotter = pv.Plotter(off_screen=True, window_size=[640, 480])
    state = ViewerState(renderer.bounds, renderer.source, listener=LISTENER, yaw=0.0, outline=renderer.outline)
    view = SceneView(plotter, renderer, state, axes=False)
    for mode in ("vicinity", "alpha"):
        state.set_colour_mode(mode)
        img = shot(plotter)
        proj = view.projector()
        for centre, colour in ((state.listener, colors.LISTENER_COLOUR), (state.source, colors.SOURCE_COLOUR)):
            c = proj.to_display(centre)
            # the sphere's own colour at its centre, though thousands of points lie in front of it
            px = pixel(img, c) / 255
            dominant = int(np.argmax(colour))
            assert np.argmax(px) == dominant or (colour[0] > 0.9 and colour[1] > 0.8 and px[0] > 0.5 and px[1] > 0.5)
            assert np.abs(px - np.asarray(colour)).max() < 0.45, (mode, px, colour)
            # a white ring just outside the sphere, a dark one outside that: visible on any colour
            r = pixel_radius(proj, centre, view.handle_radius)
            white = ring_pixels(img, c, r * (1 + HALO[0][0]) / 2)
            dark = ring_pixels(img, c, r * (HALO[0][0] + HALO[1][0]) / 2)
            assert np.mean(white.min(axis=1) > 200) > 0.8, mode
            assert np.mean(dark.max(axis=1) < 40) > 0.7, mode  # the facing arrow crosses the listener's
    view.close()
    plotter.close()


def legend_box_px(view) -> tuple[float, float, float, float]:
    legend = view.plotter.legend
    w, h = view.plotter.render_window.GetSize()
    (x0, y0), (bw, bh) = legend.GetPosition(), legend.GetPosition2()
    return x0 * w, y0 * h, (x0 + bw) * w, (y0 + bh) * h


@pytest.mark.parametrize("size", [(400, 300), (1024, 768)])
def test_legend_is_sized_to_the_picture_and_moves_off_the_handles(filled, size):
    _, renderer = filled
    plotter = pv.Plotter(off_screen=True, window_size=list(size))
    state = ViewerState(renderer.bounds, renderer.source, listener=LISTENER, outline=renderer.outline)
    view = SceneView(plotter, renderer, state, axes=False)
    view.camera_top()
    plotter.camera.zoom(2.0)  # the room fills the picture
    view.show_legend()
    assert view.legend_corner == "upper right"  # the first choice while no handle is there
    # Move the listener to just under that box: the legend must go elsewhere.
    x0, y0, x1, y1 = legend_box_px(view)
    view.hide_legend()
    spot = ray_plane_z(*view.projector().ray(0.5 * (x0 + x1), 0.5 * (y0 + y1)), 1.2)
    state.set_listener(spot)
    assert np.allclose(state.listener[:2], spot[:2])  # inside the room
    before = shot(plotter)
    view.show_legend()
    after = shot(plotter)
    assert view.legend_corner != "upper right"
    x0, y0, x1, y1 = legend_box_px(view)
    rows = len(view.legend_rows()) + 2
    assert 11 * rows <= y1 - y0 <= max(0.04 * size[1], 12) * (rows + 1)  # a row is ~2.8 % of the height
    assert x1 - x0 < 0.6 * size[0]
    for c, r in view.handle_circles(margin=0):
        assert not (x0 - r < c[0] < x1 + r and y0 - r < c[1] < y1 + r)  # no handle under the box
        if 0 <= c[0] < size[0] - 1 and 0 <= c[1] < size[1] - 1:  # on screen
            assert np.array_equal(pixel(before, c), pixel(after, c))
    assert np.abs(after - before).sum() > 0  # and the legend was drawn
    view.close()
    plotter.close()


def test_caption_names_the_pose_and_goes_where_the_legend_is_not(filled):
    _, renderer = filled
    plotter = pv.Plotter(off_screen=True, window_size=[800, 600])
    state = ViewerState(renderer.bounds, renderer.source, listener=LISTENER, yaw=90.0, outline=renderer.outline)
    view = SceneView(plotter, renderer, state)
    plain = shot(plotter)
    with annotated(view, legend=True, caption=True):
        assert view.caption_text().splitlines() == ["listener (1.50, 3.00, 1.20)  yaw 90\N{DEGREE SIGN}",
                                                    "source   (4.50, 1.00, 1.20)"]
        assert view.caption_corner is not None and view.legend_corner is not None
        cx0, cy0, cx1, cy1 = view._caption_box
        lx0, ly0, lx1, ly1 = legend_box_px(view)
        assert cx1 <= lx0 or lx1 <= cx0 or cy1 <= ly0 or ly1 <= cy0  # side by side, not on top
        axes = 0.16 * np.array([800, 600])
        assert cx0 >= axes[0] or cy0 >= axes[1]  # clear of the axes marker
        for c, r in view.handle_circles(margin=0):
            assert not (cx0 - r < c[0] < cx1 + r and cy0 - r < c[1] < cy1 + r)
        marked = shot(plotter)
    assert view.legend_corner is None and view.caption_corner is None
    assert np.array_equal(shot(plotter), plain)  # both removed after the picture
    assert np.abs(marked - plain).sum() > 0
    view.close()
    plotter.close()


def test_headless_export_with_caption(filled, tmp_path):
    _, renderer = filled
    png = tmp_path / "pose.png"
    export_headless(renderer, listener=LISTENER, yaw=45.0, screenshot=png, clip=np.ones(2048, np.float32),
                    window_size=(320, 240), caption=True)
    img = pv.read(png)
    assert img.dimensions[:2] == (320, 240)


@pytest.mark.parametrize("argv, words", [
    (["--size", "-5", "100"], "--size must be two whole numbers of pixels from 64 to 8192"),
    (["--size", "400", "300", "--scale", "0"], "--scale must be a whole number from 1 to 8, got 0"),
    (["--size", "8000", "300", "--scale", "4"], "32000 x 1200 pixels; at most 16384 a side"),
])
def test_bad_size_or_scale_is_one_clear_error_before_any_work(argv, words, tmp_path, capsys):
    png = tmp_path / "x.png"
    assert app.main([str(tmp_path / "missing.ckpt"), "--screenshot", str(png), *argv]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and words in err and err.startswith("avgs-viewer: error: ")
    assert not png.exists()


def test_check_picture_size():
    assert check_picture_size(1024, 768, 2) == (1024, 768, 2)
    assert check_picture_size(64.0, 8192, 2) == (64, 8192, 2)
    for bad in [(63, 100, 1), (100, 100.5, 1), (100, float("nan"), 1), (100, 100, 1.5)]:
        with pytest.raises(ValueError):
            check_picture_size(*bad)
