"""The real window's exports on the bundled demo: File > Record path records a real drag (XTEST
events) as keyframes JSON, and that path, the pose's impulse response and a response grid are
exported from the window's own actions."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("pytestqt")
av = pytest.importorskip("av")

from avgs.export.flypath import read_path  # noqa: E402
from avgs.export.flythrough import FlythroughConfig  # noqa: E402
from real_events import demo_window, drag_handle, screen_xy  # noqa: E402

pytestmark = pytest.mark.gui


@pytest.fixture
def window(qtbot, x):
    w = demo_window(qtbot)
    yield w
    w.close()


def test_the_file_menu_has_the_exports(window):
    texts = [a.text().replace("&", "") for a in window.menuBar().actions()[0].menu().actions()]
    for entry in ("Export impulse response (WAV)...", "Export response grid (SOFA)...", "Record path",
                  "Save recorded path...", "Export fly-through video..."):
        assert entry in texts
    assert window.record_path_action.isCheckable()


def test_a_recorded_drag_is_saved_as_a_path_and_exported(qtbot, window, x, tmp_path):
    w = window
    source, z = w.state.source, w.state.listener[2]
    start_xyz = np.array([source[0] - 1.2, source[1] - 0.5, z])
    w.state.set_listener(start_xyz)
    w.record_path_action.trigger()  # File > Record path on
    assert w.exports.recorder.recording
    qtbot.wait(200)  # a pause before the drag: time in the path
    target = np.array([source[0] + 1.2, source[1] - 0.5, z])
    drag_handle(qtbot, w, x, "listener", screen_xy(w, w.state.listener), screen_xy(w, target), steps=12)
    qtbot.wait(100)
    w.record_path_action.trigger()  # off
    assert not w.exports.recorder.recording
    saved = w.exports.save_recorded_path(tmp_path / "path.json")
    assert saved is not None and w.error_dialog is None
    frames = read_path(saved)
    assert len(frames) >= 5  # the start, the drag's moves, the end
    t = np.array([k.t for k in frames])
    assert t[0] == 0 and np.all(np.diff(t) > 0) and t[-1] >= 0.3
    np.testing.assert_allclose(frames[0].listener, start_xyz, atol=1e-6)
    assert frames[-1].listener[:2] == pytest.approx(target[:2], abs=0.1)
    xs = np.array([k.listener[0] for k in frames])
    assert np.all(np.diff(xs) >= -1e-6) and len(np.unique(np.round(xs, 3))) >= 4  # along the drag, in order
    assert all(k.source == pytest.approx(tuple(source)) for k in frames)

    # the recorded path as a video of the 3D view, from the window
    out = w.exports.export_flythrough(tmp_path / "fly.mp4", None, FlythroughConfig(fps=10, width=96, height=64))
    assert out is not None and w.error_dialog is None
    with av.open(str(out)) as c:
        video = [f.to_ndarray(format="rgb24") for f in c.decode(video=0)]
    assert len(video) == round(t[-1] * 10) and video[0].shape == (64, 96, 3)

    # the pose's impulse response and a small grid, from the window's actions
    import soundfile as sf

    from avgs.export.grid import GridSpec
    from avgs.export.sofa import read_grid

    ir = w.exports.export_impulse(tmp_path / "ir.wav")
    data, rate = sf.read(str(ir), dtype="float32", always_2d=True)
    pose = w.state.pose
    np.testing.assert_array_equal(data.T, w.renderer.binaural_filter(pose.listener, pose.yaw, pose.source).impulse)
    assert rate == w.renderer.sample_rate
    grid = w.exports.export_grid(tmp_path / "grid.sofa", GridSpec(spacing=3.0, yaws=(0.0, 180.0), height=float(z),
                                                                  sources=(tuple(source),)))
    back = read_grid(grid)
    assert back.shape[0] == 1 and back.shape[2] == 2 and np.allclose(back.listeners[:, 2], z)
    assert w.exports.export_grid(tmp_path / "grid.txt", GridSpec()) is None  # refused, said in a dialog
    assert "sofa" in w.error_dialog.text() and not (tmp_path / "grid.txt").exists()
