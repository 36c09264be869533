"""The scene view and the headless exports, drawn off screen (EGL, no X server needed)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf
import torch

os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")  # before pyvista loads VTK
import pyvista as pv  # noqa: E402

from avgs.io.checkpoint import save_checkpoint, untrained_checkpoint  # noqa: E402
from avgs.data.frame import SceneFrame  # noqa: E402
from avgs.gaussians.sh import SH_C0  # noqa: E402
from avgs.render.renderer import SceneRenderer  # noqa: E402
from avgs_viewer import app, colors  # noqa: E402
from avgs_viewer.bench import orbit_fps  # noqa: E402
from avgs_viewer.drag import DragController  # noqa: E402
from avgs_viewer.export import export_headless  # noqa: E402
from avgs_viewer.scene_view import SceneView  # noqa: E402
from avgs_viewer.state import ColourMode, ViewerState  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
ROOM = np.array([5.0, 4.0, 3.0])
SOURCE = np.array([3.8, 2.9, 1.2])
LISTENER = np.array([1.2, 1.0, 1.2])
WALL_RGB = np.array([[0.9, 0.1, 0.1], [0.1, 0.9, 0.1], [0.1, 0.1, 0.9],
                     [0.9, 0.9, 0.1], [0.1, 0.9, 0.9], [0.9, 0.1, 0.9]])  # per box face


def room_points(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Points on the six faces of a 5 x 4 x 3 m room and each point's face index."""
    rng = np.random.default_rng(seed)
    pts = rng.uniform(0, ROOM, size=(n, 3))
    face = rng.integers(0, 6, n)
    axis = face // 2
    pts[np.arange(n), axis] = np.where(face % 2 == 0, 0.0, ROOM[axis])
    return pts, face


def room_outline() -> np.ndarray:
    c = [(0, 0), (5, 0), (5, 4), (0, 4)]
    segs = [[[*c[i], z], [*c[(i + 1) % 4], z]] for z in (0.0, 3.0) for i in range(4)]
    segs += [[[*p, 0.0], [*p, 3.0]] for p in c]
    return np.array(segs, dtype=np.float64)


@pytest.fixture(scope="module")
def room(tmp_path_factory):
    """A real checkpoint of a box room: G_a on the walls, G coloured per wall, an outline."""
    pts, face = room_points(3000)
    frame = SceneFrame(ROOM / 2, 1 / 2.5)
    sh = torch.zeros(len(pts), 16, 3)
    sh[:, 0] = torch.as_tensor((WALL_RGB[face] - 0.5) / SH_C0, dtype=torch.float32)  # DC term -> wall colour
    gaussians = {"means": torch.as_tensor(frame.to_normalised(pts), dtype=torch.float32), "sh": sh}
    ckpt = untrained_checkpoint(pts, SOURCE, frame=frame, outline_world=room_outline(), gaussians=gaussians,
                                alpha_dim=16, seed=2)
    ckpt["scene"]["bounds"] = torch.tensor([[0.0, 0.0, 0.0], ROOM.tolist()])
    path = save_checkpoint(ckpt, tmp_path_factory.mktemp("room") / "room.ckpt")
    return path, SceneRenderer.load(path), face


@pytest.fixture
def plotter():
    p = pv.Plotter(off_screen=True, window_size=[800, 600])
    yield p
    p.close()


def region(img: np.ndarray, centre: np.ndarray, half: int) -> np.ndarray:
    """Pixels [h, w, 3] of a square around a VTK display point (origin bottom left)."""
    h = img.shape[0]
    x, y = int(round(centre[0])), int(round(h - 1 - centre[1]))
    return img[max(0, y - half): y + half, max(0, x - half): x + half, :3]


def count_colour(pixels: np.ndarray, colour) -> int:
    return int(np.sum(np.all(np.abs(pixels.astype(int) - np.asarray(colour, dtype=int)) <= 3, axis=-1)))


def test_vicinity_colours_surround_each_sphere(room, plotter):
    _, renderer, _ = room
    state = ViewerState(renderer.bounds, renderer.source, listener=LISTENER, yaw=30.0)
    view = SceneView(plotter, renderer, state)
    result = renderer.render(listener=LISTENER, yaw=30.0, mono=np.ones(512, np.float32))
    view.set_vicinity(result.listener_vicinity, result.source_vicinity)
    img = plotter.screenshot(return_img=True)
    proj = view.projector()
    near_listener = region(img, proj.to_display(LISTENER), 90)
    near_source = region(img, proj.to_display(renderer.source), 90)
    lis_c, src_c = colors.VICINITY_COLOURS[colors.LISTENER], colors.VICINITY_COLOURS[colors.SOURCE]
    assert count_colour(near_listener, lis_c) > 50 and count_colour(near_listener, lis_c) > 5 * count_colour(near_listener, src_c)
    assert count_colour(near_source, src_c) > 50 and count_colour(near_source, src_c) > 5 * count_colour(near_source, lis_c)
    # The drawn labels are exactly the renderer's sets.
    full = colors.vicinity_labels(len(renderer.points), result.listener_vicinity, result.source_vicinity)
    assert np.array_equal(view.labels, full[view.drawn])
    # And the spheres are where the state says: blue-ish at the listener, yellow-ish at the source.
    sph = region(img, proj.to_display(LISTENER), 3).reshape(-1, 3).mean(0)
    assert sph[2] > 1.5 * sph[0]
    sph = region(img, proj.to_display(renderer.source), 3).reshape(-1, 3).mean(0)
    assert sph[0] > 2 * sph[2] and sph[1] > 2 * sph[2]
    view.close()


def test_a_slice_below_every_point_draws_none_and_raising_it_draws_them_again(room, plotter):
    _, renderer, _ = room
    bounds = renderer.bounds.copy()
    bounds[0, 2] -= 1.0  # a box reaching below the floor's points
    state = ViewerState(bounds, renderer.source)
    view = SceneView(plotter, renderer, state)
    state.set_slice_height(bounds[0, 2])
    assert not view._points_actor.GetVisibility()
    state.set_slice_height(bounds[1, 2])
    assert view._points_actor.GetVisibility() and view._cloud.n_points == len(renderer.points)
    view.close()


def test_slice_hides_the_ceiling_and_modes_recolour(room, plotter):
    _, renderer, face = room
    state = ViewerState(renderer.bounds, renderer.source, has_rgb=True)
    view = SceneView(plotter, renderer, state)
    ceiling = renderer.points[:, 2] > 2.999
    assert 1.2 < state.slice_height < 3.0
    z = view._cloud.points[:, 2]
    assert z.max() <= state.slice_height and np.sum(ceiling) > 0  # the ceiling is sliced off by default
    assert view._cloud.n_points == int(np.sum(renderer.points[:, 2] <= state.slice_height))
    state.set_slice_height(1.0)
    assert view._cloud.n_points == int(np.sum(renderer.points[:, 2] <= 1.0))
    state.set_slice_height(3.0)
    assert view._cloud.n_points == len(renderer.points)
    state.set_colour_mode(ColourMode.RGB)  # each point takes its wall's colour from G
    expected = np.round(WALL_RGB[face] * 255).astype(np.uint8)
    assert np.abs(view._cloud.point_data["colours"].astype(int) - expected.astype(int)).max() <= 1
    state.set_colour_mode(ColourMode.ALPHA)
    assert np.array_equal(view._cloud.point_data["colours"], view.projection(renderer.alpha))
    assert "PC1" in view.legend_rows()[0][0]
    assert view._points_actor.prop.render_points_as_spheres  # idle: shaded spheres
    state.set_interacting(True)  # a drag or camera move: cheap squares
    assert not view._points_actor.prop.render_points_as_spheres
    state.set_interacting(False)
    assert view._points_actor.prop.render_points_as_spheres
    view.close()


def test_draws_a_capped_deterministic_subset(room, plotter):
    _, renderer, _ = room
    state = ViewerState(renderer.bounds, renderer.source)
    a = SceneView(plotter, renderer, state, max_points=1000)
    b = SceneView(pv.Plotter(off_screen=True), renderer, state, max_points=1000)
    assert len(a.drawn) == 1000 and np.array_equal(a.drawn, b.drawn)
    b.plotter.close()


def test_projector_and_drag_on_the_real_camera(room, plotter):
    _, renderer, _ = room
    state = ViewerState(renderer.bounds, renderer.source, listener=LISTENER)
    view = SceneView(plotter, renderer, state)
    plotter.screenshot(return_img=True)  # a first render sets the camera's aspect
    proj = view.projector()
    p = proj.to_display(LISTENER)
    origin, direction = proj.ray(*p)
    miss = np.linalg.norm(np.cross(LISTENER - origin, direction))  # distance of the point from the ray
    assert miss < 1e-3
    drag = DragController(state, view.projector, view.handle_radius)
    target = np.array([3.0, 1.5, LISTENER[2]])
    q = proj.to_display(target)
    assert drag.press(*p)
    drag.release(*q)
    assert np.allclose(state.listener, target, atol=0.02)
    moved = region(plotter.screenshot(return_img=True), q, 3).reshape(-1, 3).mean(0)
    assert moved[2] > 1.5 * moved[0]  # the blue sphere followed
    fps = orbit_fps(plotter, frames=4)
    assert fps["frames"] == 4 and fps["fps"] > 0
    view.close()


def test_headless_export_writes_png_and_wav(room, tmp_path):
    _, renderer, _ = room
    clip = np.sin(np.arange(11025) * 0.05).astype(np.float32)
    png, wav = tmp_path / "shot.png", tmp_path / "out.wav"
    result = export_headless(renderer, listener=LISTENER, yaw=0.0, screenshot=png, audio=wav, clip=clip,
                             scale=2, transparent=True, window_size=(320, 240))
    img = pv.read(png)
    assert img.dimensions[:2] == (640, 480)
    rgba = img.point_data[img.point_data.keys()[0]]
    assert rgba.shape[1] == 4 and rgba[:, 3].min() == 0 and rgba[:, 3].max() == 255  # transparent background
    audio, sr = sf.read(wav, always_2d=True)
    assert sr == renderer.sample_rate and audio.shape == (11025, 2)
    assert np.allclose(audio.T, result.binaural, atol=1e-6)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.wav", "shot.png"]  # no temp files left


def test_command_line_export_without_a_display(room, tmp_path):
    path, renderer, _ = room
    png, wav = tmp_path / "cli.png", tmp_path / "cli.wav"
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY", "VTK_DEFAULT_OPENGL_WINDOW")}
    env["OMP_NUM_THREADS"] = "1"
    proc = subprocess.run(
        [sys.executable, "-m", "avgs_viewer.app", str(path), "--screenshot", str(png), "--listener", "1", "1", "1.2",
         "--yaw", "45", "--source", "4", "3", "1.2", "--size", "400", "300", "--audio", str(wav)],
        capture_output=True, text=True, env=env, cwd=ROOT, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert pv.read(png).dimensions[:2] == (400, 300)
    audio, sr = sf.read(wav, always_2d=True)
    assert audio.shape[1] == 2 and sr == renderer.sample_rate
    assert "bad X server" not in proc.stderr


def test_command_line_errors_are_one_clean_line(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(app, "DEMO_SCENE", tmp_path / "assets" / "demo" / "scene.ckpt")
    assert app.main(["--screenshot", str(tmp_path / "x.png")]) == 2
    err = capsys.readouterr().err
    assert "demo scene" in err and "does not exist" in err and "Traceback" not in err
    (tmp_path / "bad.ckpt").write_bytes(b"garbage")
    assert app.main([str(tmp_path / "bad.ckpt"), "--audio", str(tmp_path / "x.wav")]) == 2
    assert "not an AV-GS checkpoint" in capsys.readouterr().err
