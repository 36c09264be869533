"""Honest inputs and outputs of the explorer (issue 31, item 8): the one clamp that the window,
the headless export and ``avgs render`` share; a clip's changes said; the whole clip exported;
a bad checkpoint leaving a usable empty window; a source in a wall noted; ``--version``."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import soundfile as sf
import torch

from avgs import SceneRenderer
from avgs.data.floor_plan import keep_inside
from avgs.render.renderer import PositionClamped
from avgs_viewer import app
from avgs_viewer.audio_path import load_clip_noted
from avgs_viewer.state import ViewerState

DEMO = Path(__file__).resolve().parents[1] / "assets" / "demo" / "scene.ckpt"
FAR = (20.0, 2.0, 1.5)  # beyond the demo room's wall at x = 8.72 (its box reaches 8.82)


@pytest.fixture(scope="module")
def renderer():
    torch.set_num_threads(1)
    return SceneRenderer.load(DEMO)


def test_version(capsys):
    with pytest.raises(SystemExit) as done:
        app.main(["--version"])
    assert done.value.code == 0
    out = capsys.readouterr().out.strip()
    assert out.startswith("avgs-viewer ") and out.split()[1][0].isdigit()


def test_window_headless_and_render_clamp_the_same_way(renderer, tmp_path, capsys):
    with pytest.warns(PositionClamped, match=r"using \(([0-9.]+), 2, 1\.5\)") as caught:
        used = renderer.inside(FAR)  # what avgs render does with --listener 20 2 1.5
    assert "8.72" in str(caught[0].message)
    state = ViewerState(renderer.bounds, renderer.source, outline=renderer.outline)
    said = []
    state.events.clamped.connect(said.append)
    state.set_listener(FAR, keep_height=False)  # typed in the window's pose panel
    assert said and "(20.00, 2.00, 1.50) -> (8.72, 2.00, 1.50)" in said[0]
    assert np.array_equal(state.listener, used)
    assert np.array_equal(keep_inside(FAR, state.footprint, renderer.bounds), used)
    assert abs(used[0] - 8.722) < 1e-3  # the room's wall, not the box's 8.82

    wav = tmp_path / "out.wav"
    code = app.main([str(DEMO), "--audio", str(wav), "--listener", *map(str, FAR), "--yaw", "0"])
    err = capsys.readouterr().err
    assert code == 0 and wav.is_file()
    assert err.startswith("avgs-viewer: warning: listener kept inside the room: (20.00, 2.00, 1.50) -> (8.72, 2.00, 1.50)")


def test_a_source_in_a_wall_is_noted(renderer):
    state = ViewerState(renderer.bounds, renderer.source, outline=renderer.outline)
    notes = []
    state.events.wall.connect(notes.append)
    state.set_source((2.0, 2.0, 1.5))  # the middle of the left room
    assert notes == []
    state.set_source((4.716, 2.0, 1.5))  # inside the partition (its faces at x = 4.656 and 4.776)
    assert len(notes) == 1 and notes[0].startswith("the source is in or against a wall (0.06 m")


def clip_file(path: Path, seconds: float, rate: int, channels: int) -> Path:
    t = np.arange(int(seconds * rate)) / rate
    x = 0.1 * np.sin(2 * np.pi * 440 * t)[:, None] * np.ones(channels)
    sf.write(str(path), x.astype(np.float32), rate)
    return path


def test_a_clip_says_what_reading_changed(tmp_path, capsys):
    stereo = clip_file(tmp_path / "long.wav", 31.0, 44100, 2)
    mono, notes = load_clip_noted(stereo, 22050)
    assert len(mono) == 30 * 22050
    assert notes == ["clip long.wav: down-mixed 2 channels to mono", "clip long.wav: cut to its first 30 s of 31.0 s",
                     "clip long.wav: resampled 44100 Hz to 22050 Hz"]
    plain = clip_file(tmp_path / "plain.wav", 1.0, 22050, 1)
    assert load_clip_noted(plain, 22050)[1] == []
    # headless: one warning line each
    code = app.main([str(DEMO), "--audio", str(tmp_path / "o.wav"), "--clip", str(stereo)])
    err = capsys.readouterr().err.splitlines()
    assert code == 0 and [e for e in err if "clip long.wav" in e] == [f"avgs-viewer: warning: {n}" for n in notes]


@pytest.mark.gui
def test_window_says_what_the_clip_lost_and_exports_the_whole_clip(qtbot, tmp_path):
    from real_events import open_window

    clip = clip_file(tmp_path / "c.wav", 2.0, 44100, 2)
    w = open_window(qtbot, DEMO)
    try:
        w.open_clip(clip)
        assert "resampled 44100 Hz to 22050 Hz" in w.audio_path.clip_notice.text()
        assert "down-mixed 2 channels" in w.audio_path.clip_notice.text()
        qtbot.waitUntil(lambda: w.live.heard is not None, timeout=30_000)
        out = w.export_audio(tmp_path / "heard.wav")
        data, rate = sf.read(str(out), always_2d=True)
        assert rate == 22050 and data.shape == (2 * 22050, 2)  # the whole clip, not the 50 ms shorter loop
        assert len(w.live.clip) == 2 * 22050 - int(0.05 * 22050)
        assert np.abs(data).max() > 0
    finally:
        w.close()


@pytest.mark.gui
@pytest.mark.parametrize("content", [b"", b"e", b"not a checkpoint at all", "truncated"])
def test_a_bad_checkpoint_leaves_a_usable_empty_window(qtbot, tmp_path, content):
    from PySide6 import QtWidgets

    from avgs_viewer.response_view import NO_SCENE_TEXT
    from avgs_viewer.window import MainWindow

    bad = tmp_path / "broken.ckpt"
    bad.write_bytes(DEMO.read_bytes()[:200_000] if content == "truncated" else content)
    w = MainWindow(start_audio=False)
    qtbot.addWidget(w)
    w.show()
    w.open_scene(bad)
    qtbot.waitUntil(lambda: w.error_dialog is not None, timeout=30_000)
    text = w.error_dialog.text()
    assert str(bad) in text and "not an AV-GS checkpoint" in text
    assert "pop from empty list" not in text and "IndexError" not in text  # a sentence, not an exception
    assert "File > Open" in w.statusBar().currentMessage()
    assert w.response.plot.empty_text == NO_SCENE_TEXT and not w.progress.isVisible()
    w.error_dialog.close()
    QtWidgets.QApplication.processEvents()
    with qtbot.waitSignal(w.scene_loaded, timeout=60_000):  # the window is usable: File > Open works
        w.open_scene(DEMO)
    assert w.renderer is not None
    w.close()


@pytest.mark.gui
def test_window_fits_a_1366x768_screen(qtbot):
    from avgs_viewer.window import MainWindow

    w = MainWindow(start_audio=False)  # (qtbot: the QApplication, whichever test this process ran first)
    try:
        assert w.minimumSizeHint().height() <= 700 and w.minimumSizeHint().width() <= 1366
        assert w.height() <= 700
    finally:
        w.close()
