"""The propagation map and the listener-view inset in the 3D view: off-screen, and in the real window."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from avgs import SceneRenderer
from avgs_viewer.propagation_view import ListenerInset, MapMode, PropagationView, bar_title, floor_height
from avgs_viewer.state import ViewerState

DEMO = Path(__file__).resolve().parents[1] / "assets" / "demo" / "scene.ckpt"
pytestmark = pytest.mark.skipif(not DEMO.is_file(), reason="the bundled demo checkpoint is missing")


@pytest.fixture(scope="module")
def renderer():
    torch.set_num_threads(1)
    return SceneRenderer.load(DEMO)


def cell_pixels(img: np.ndarray, projector, pmap, floor_z: float, step: int = 3, overlays=()):
    """[(value flat index, rgb)] of the screenshot at the projected centres of map cells that no
    overlay (``overlays``: pixel boxes x0, y0, x1, y1 from the bottom, as the overlays' layout's) covers."""
    out = []
    h = img.shape[0]
    positions = pmap.grid.positions()
    for flat in range(0, len(positions), step):
        x, y = projector.to_display((positions[flat, 0], positions[flat, 1], floor_z))
        col, row = int(round(x)), int(round(h - 1 - y))
        if any(b[0] - 2 <= x <= b[2] + 2 and b[1] - 2 <= y <= b[3] + 2 for b in overlays):
            continue
        if 0 <= row < h and 0 <= col < img.shape[1]:
            out.append((flat, img[row, col, :3].astype(int)))
    return out


def assert_floor_coloured(before: np.ndarray, after: np.ndarray, projector, pmap, floor_z: float,
                          overlays=()) -> None:
    """The floor's cells (those no overlay covers) changed from the dark background to colours ordered like the level."""
    from scipy.stats import spearmanr

    samples = cell_pixels(after, projector, pmap, floor_z, overlays=overlays)
    old = dict(cell_pixels(before, projector, pmap, floor_z, overlays=overlays))
    assert len(samples) > 30
    changed = [flat for flat, rgb in samples if np.abs(rgb - old[flat]).sum() > 60]
    assert len(changed) > 0.5 * len(samples)  # the quietest cells are near the map's dark end (behind walls)
    values = pmap.level.ravel()
    flats = np.array([f for f, _ in samples])
    bright = np.array([rgb.sum() for _, rgb in samples])
    # inferno: louder is brighter, in order (its brightness is flat near black, where a room behind a wall sits:
    # a rank correlation, not a linear one; the demo's map: 0.65 rank, 0.47 linear)
    assert spearmanr(values[flats], bright)[0] > 0.5


def test_map_drawn_off_screen_with_its_colour_bar(renderer, tmp_path):
    import pyvista as pv

    from avgs_viewer.scene_view import SceneView

    r = renderer
    state = ViewerState(r.bounds, r.source, listener=(6.5, 2.5, 1.6), yaw=90.0, has_rgb=True)
    plotter = pv.Plotter(off_screen=True, window_size=[800, 600])
    try:
        view = SceneView(plotter, r, state)
        view._points_actor.SetVisibility(False)  # the floor in full view
        before = plotter.screenshot(return_img=True)
        maps = PropagationView(plotter, r, state, mode=MapMode.LEVEL, size=16)
        pmap = maps.draw_now()
        assert pmap.complete and bar_title("level") in plotter.scalar_bars
        after = plotter.screenshot(return_img=True)
        assert_floor_coloured(before, after, view.projector(), pmap, floor_height(r))
        Image.fromarray(after).save(tmp_path / "map.png")
        maps.set_mode("ild")  # the same map, the other number: no recomputation
        assert maps.latest is pmap and bar_title("ild") in plotter.scalar_bars
        assert bar_title("level") not in plotter.scalar_bars
        maps.set_mode("off")
        assert not plotter.scalar_bars and "propagation_map" not in plotter.actors
        maps.close()
        view.close()
    finally:
        plotter.close()


def test_newest_request_wins_and_stale_maps_are_dropped(renderer):
    import pyvista as pv

    r = renderer
    state = ViewerState(r.bounds, r.source, listener=(2.0, 1.5, 1.6), yaw=0.0)
    plotter = pv.Plotter(off_screen=True, window_size=[320, 240])
    posted = []  # the "GUI thread": the test runs what the worker posts
    try:
        maps = PropagationView(plotter, r, state, mode="level", size=8, post=posted.append)
        state.set_yaw(90.0)  # while the first map computes
        state.set_listener((3.0, 2.0, 1.6))  # same height: no new map
        assert maps.wait(120)
        for fn in posted:
            fn()
        assert maps.latest.complete and maps.latest.yaw == 90.0 and maps.latest_key[1] == 90.0
        assert maps.worker.newest == 2
        drawn = maps._mesh.cell_data["map"]
        assert np.allclose(drawn, maps.latest.level.ravel())
        maps.close()
    finally:
        plotter.close()


def test_listener_inset_shows_g_from_the_listener(renderer):
    import pyvista as pv

    from avgs.render.listener_view import ListenerView

    r = renderer
    state = ViewerState(r.bounds, r.source, listener=(2.0, 2.0, 1.6), yaw=0.0)
    plotter = pv.Plotter(off_screen=True, window_size=[800, 600])
    try:
        plotter.set_background((0.1, 0.1, 0.1))
        before = plotter.screenshot(return_img=True)
        posted = []  # drawing runs on this thread, as the window's queued signal does it
        inset = ListenerInset(plotter, state, lambda: ListenerView.load(DEMO), post=posted.append)
        assert inset.wait(60) and posted
        while posted:
            posted.pop(0)()
        assert inset.image is not None and inset.image.shape == (144, 192, 3)
        after = plotter.screenshot(return_img=True)
        corner = np.abs(after[-100:, -150:].astype(int) - before[-100:, -150:].astype(int)).sum(-1)
        assert (corner > 60).mean() > 0.8  # the lower right corner now shows the image
        state.set_yaw(180.0)
        assert inset.wait(60) and posted
        while posted:
            posted.pop(0)()
        assert inset.shown_pose[1] == 180.0
        inset.close()
    finally:
        plotter.close()


def test_listener_inset_waits_for_the_sound_and_renders_only_the_newest_pose(renderer):
    """While the audio path is busy the inset's G render does not start; a pose change meanwhile
    drops the old pose; once the sound is idle only the newest pose is rendered."""
    import threading
    import time

    import pyvista as pv

    from avgs.render.listener_view import ListenerView

    view = ListenerView.load(DEMO)
    rendered = []  # the yaws the inset rasterised G for

    class Counting:
        def render(self, listener, yaw, *size, stop=None):
            rendered.append(yaw)
            return view.render(listener, yaw, *size, stop=stop)

    state = ViewerState(renderer.bounds, renderer.source, listener=(2.0, 2.0, 1.6), yaw=0.0)
    busy = threading.Event()
    busy.set()
    plotter = pv.Plotter(off_screen=True, window_size=[400, 300])
    try:
        posted = []
        inset = ListenerInset(plotter, state, Counting, post=posted.append, audio_busy=busy.is_set)
        time.sleep(0.5)
        assert rendered == [] and not inset.wait(0.0)  # held while the sound is made
        state.set_yaw(90.0)  # the user turns: the held pose is dropped
        state.set_yaw(180.0)
        busy.clear()
        assert inset.wait(60)
        while posted:
            posted.pop(0)()
        assert rendered == [180.0] and inset.shown_pose[1] == 180.0
        inset.close()
    finally:
        plotter.close()


def test_listener_inset_abandons_a_render_when_the_pose_changes(renderer):
    """A pose change during the render stops it at the next chunk of tiles (``stopped``); the new
    pose is rendered instead."""
    import threading

    import pyvista as pv

    from avgs.render.listener_view import ListenerView

    view = ListenerView.load(DEMO)
    state = ViewerState(renderer.bounds, renderer.source, listener=(2.0, 2.0, 1.6), yaw=0.0)
    started, moved = threading.Event(), threading.Event()

    class Turning:  # turns the listener from inside the first render's first chunk check
        def render(self, listener, yaw, *size, stop=None):
            def check():
                if not started.is_set():
                    started.set()
                    state.set_yaw(45.0)
                    moved.set()
                return stop()
            return view.render(listener, yaw, *size, stop=check)

    plotter = pv.Plotter(off_screen=True, window_size=[400, 300])
    try:
        posted = []
        inset = ListenerInset(plotter, state, Turning, post=posted.append)
        assert moved.wait(60) and inset.wait(60)
        while posted:
            posted.pop(0)()
        assert inset.stopped == 1 and inset.shown_pose[1] == 45.0
        inset.close()
    finally:
        plotter.close()


# -- the real window under Xvfb ------------------------------------------------------------


@pytest.mark.gui
def test_toggling_the_map_in_the_window_colours_the_floor(qtbot, tmp_path):
    pytest.importorskip("pytestqt")
    from PySide6 import QtWidgets

    from avgs_viewer.window import MainWindow

    w = MainWindow(start_audio=False)
    qtbot.addWidget(w)
    w.resize(1280, 800)  # a floor large enough on screen to sample its cells' colours
    w.show()
    with qtbot.waitSignal(w.scene_loaded, timeout=60_000):
        w.open_scene(DEMO)
    try:
        controls = w.map_controls
        assert controls.box.parent() is not None and controls.mode is MapMode.OFF
        controls.view.size = 16
        w.view._points_actor.SetVisibility(False)  # the floor in full view
        qtbot.waitUntil(lambda: controls.inset is not None and controls.inset.image is not None, timeout=60_000)
        QtWidgets.QApplication.processEvents()
        before = np.asarray(Image.open(w.export_screenshot(tmp_path / "off.png")))

        controls.combo.setCurrentIndex(controls.combo.findData("level"))  # what a click on "Level (dB)" does
        qtbot.waitUntil(lambda: controls.view.latest is not None and controls.view.latest.complete, timeout=120_000)
        QtWidgets.QApplication.processEvents()
        assert controls.note.text().startswith("16 x 16 cells")
        after = np.asarray(Image.open(w.export_screenshot(tmp_path / "level.png")))
        assert_floor_coloured(before, after, w.view.projector(), controls.view.latest, floor_height(w.renderer),
                              overlays=list(w.view.board.last.pixels.values()))
        assert bar_title("level") in w.plotter.scalar_bars

        seq = controls.view.worker.newest
        w.state.set_yaw(w.state.yaw + 45.0)  # a new yaw: a new map
        assert controls.view.worker.newest == seq + 1
        controls.combo.setCurrentIndex(controls.combo.findData("off"))
        assert "propagation_map" not in w.plotter.actors
    finally:
        w.close()


@pytest.mark.gui
def test_qt_poster_runs_on_the_gui_thread(qtbot):
    pytest.importorskip("pytestqt")
    import threading

    from PySide6 import QtWidgets

    from avgs_viewer.propagation_view import qt_poster

    parent = QtWidgets.QWidget()
    qtbot.addWidget(parent)
    post = qt_poster(parent)
    ran = []
    worker = threading.Thread(target=lambda: post(lambda: ran.append(threading.current_thread())))
    worker.start()
    worker.join()
    qtbot.waitUntil(lambda: bool(ran), timeout=5000)
    assert ran == [threading.main_thread()]
