"""Fly-through videos: a listener path of keyframes (JSON) rendered to an MP4 (H.264 + AAC by
PyAV) whose picture and binaural track follow the path; read back with PyAV. On the bundled
demo (a checkpoint of --task rir, with G)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from avgs.export.flypath import Keyframe, check_keyframes, pose_at, read_path, write_path

av = pytest.importorskip("av")
DEMO = Path(__file__).resolve().parents[1] / "assets" / "demo" / "scene.ckpt"
# A listener facing +x walks past the demo's source at (3, 3, 1.5): it starts with the source
# 2 m to its left and ends with it 1.2 m to its right.
PATH = [{"t": 0.0, "listener": [3.0, 1.0, 1.5], "yaw": 0.0, "source": [3.0, 3.0, 1.5]},
        {"t": 2.0, "listener": [3.0, 4.2, 1.5], "yaw": 0.0}]


@pytest.fixture(scope="module")
def demo():
    if not DEMO.is_file():
        pytest.skip("the bundled demo scene is missing (scripts/make_demo.sh)")
    from avgs import SceneRenderer
    from avgs.config import SynthesisConfig

    return SceneRenderer.load(DEMO, synthesis=SynthesisConfig(method="filter"))


def noise(sample_rate: int) -> np.ndarray:
    return (0.1 * np.random.default_rng(0).standard_normal(sample_rate)).astype(np.float32)


def read_back(path: Path):
    """(video frames [n, H, W, 3], their times, audio [2, T], audio rate) decoded by PyAV."""
    with av.open(str(path)) as c:
        assert c.streams.video[0].codec_context.name in ("h264", "mpeg4")
        assert c.streams.audio[0].codec_context.name == "aac"
        frames = [(f.to_ndarray(format="rgb24"), float(f.time)) for f in c.decode(video=0)]
    with av.open(str(path)) as c:
        rate = c.streams.audio[0].rate
        audio = np.concatenate([f.to_ndarray() for f in c.decode(audio=0)], axis=1)  # [2, T] fltp
    return np.stack([f for f, _ in frames]), np.array([t for _, t in frames]), audio, rate


def itd_us(seg: np.ndarray, rate: int, reach: int = 40) -> float:
    """Lag of the right ear behind the left (us) by phase-transform cross-correlation: > 0 when the left leads."""
    n = 2 * seg.shape[1]
    x = np.fft.rfft(seg[0], n) * np.conj(np.fft.rfft(seg[1], n))
    cc = np.fft.irfft(x / (np.abs(x) + 1e-12))
    lags = np.r_[cc[-reach:], cc[: reach + 1]]  # lags -reach .. reach
    return -(int(np.argmax(lags)) - reach) / rate * 1e6


def check_video(path: Path, fps: float, size: tuple[int, int], seconds: float, rate: int):
    frames, times, audio, audio_rate = read_back(path)
    w, h = size
    assert frames.shape == (round(seconds * fps), h, w, 3)
    assert times[-1] + 1 / fps == pytest.approx(seconds, abs=1e-6)  # the video lasts the path
    assert audio_rate == rate and audio.shape[0] == 2  # stereo at the scene's rate
    assert abs(audio.shape[1] / rate - seconds) < 1 / fps  # within a frame (AAC pads its last frame)
    half = rate // 2
    first, last = audio[:, :half], audio[:, -half:]
    e0, e1 = (np.sum(first**2, axis=1), np.sum(last**2, axis=1))
    assert e0[0] > e0[1] and e1[1] > e1[0]  # left ear louder at the start, right ear at the end
    assert itd_us(first, rate) > 300 and itd_us(last, rate) < -300  # the left ear leads, then the right
    return frames


def test_keyframes_are_checked_and_interpolated(tmp_path):
    frames = check_keyframes([{"t": 0, "listener": [0, 0, 1], "yaw": 350, "source": [1, 1, 1]},
                              {"t": 1, "listener": [2, 0, 1], "yaw": 10},
                              {"t": 3, "listener": [2, 4, 1], "yaw": 10, "source": [3, 1, 1]}])
    mid = pose_at(frames, 0.5)
    np.testing.assert_allclose(mid.listener, [1, 0, 1])
    assert mid.yaw == pytest.approx(0.0, abs=1e-9) or mid.yaw == pytest.approx(360.0)  # the shorter way round
    np.testing.assert_allclose(mid.source, [1, 1, 1])  # carried from the first keyframe
    np.testing.assert_allclose(pose_at(frames, 2.0).source, [2, 1, 1])
    np.testing.assert_allclose(pose_at(frames, 9.0).listener, [2, 4, 1])  # held after the end
    out = write_path(tmp_path / "p.json", frames)
    assert read_path(out) == frames
    assert isinstance(frames[0], Keyframe)


@pytest.mark.parametrize("content, message", [
    ("[1, 2", "not JSON"),
    ('[{"t": 0, "listener": [0, 0, 0], "yaw": 0}]', "at least 2 keyframes"),
    ('[{"t": 0.5, "listener": [0, 0, 0], "yaw": 0}, {"t": 1, "listener": [0, 0, 0], "yaw": 0}]', "start at 0"),
    ('[{"t": 0, "listener": [0, 0, 0], "yaw": 0}, {"t": 0, "listener": [0, 0, 0], "yaw": 0}]', "increase strictly"),
    ('[{"t": 0, "listener": [0, 0], "yaw": 0}, {"t": 1, "listener": [0, 0, 0], "yaw": 0}]', "keyframe 0: listener"),
    ('[{"t": 0, "listener": [0, 0, 0], "yaw": "x"}, {"t": 1, "listener": [0, 0, 0], "yaw": 0}]', "keyframe 0: yaw"),
    ('[{"t": 0, "listener": [0, 0, 0], "yaw": 0, "pitch": 3}, {"t": 1, "listener": [0, 0, 0], "yaw": 0}]', "unknown keys"),
])
def test_a_bad_path_file_is_one_line_naming_it(tmp_path, content, message):
    p = tmp_path / "path.json"
    p.write_text(content)
    with pytest.raises(ValueError) as err:
        read_path(p)
    assert str(p) in str(err.value) and message in str(err.value) and "\n" not in str(err.value)


def test_a_path_renders_an_mp4_that_follows_it(demo, tmp_path):
    from avgs.export.flythrough import FlythroughConfig, listener_frames, render_flythrough
    from avgs.render.listener_view import ListenerView

    view = ListenerView.load(DEMO)
    out = tmp_path / "fly.mp4"
    steps = []
    result = render_flythrough(demo, PATH, noise(demo.sample_rate), out, listener_frames(view, 96, 64),
                               FlythroughConfig(fps=10, width=96, height=64), lambda d, t: steps.append((d, t)))
    assert result.frames == 20 and result.samples == 2 * demo.sample_rate and 0 < result.gain <= 1
    assert steps[-1][0] == steps[-1][1] and [d for d, _ in steps] == sorted(d for d, _ in steps)
    frames = check_video(out, 10, (96, 64), 2.0, demo.sample_rate)
    assert np.abs(frames[0].astype(int) - frames[-1]).mean() > 5  # the listener's view changed along the path


def test_a_cancelled_export_leaves_nothing(demo, tmp_path):
    from avgs.export.flythrough import Cancelled, FlythroughConfig, render_flythrough

    def cancel(done, total):
        if done > total // 2:
            raise Cancelled()

    with pytest.raises(Cancelled):
        render_flythrough(demo, PATH, noise(demo.sample_rate), tmp_path / "x.mp4",
                          lambda pose, heard: np.zeros((32, 32, 3), np.uint8), FlythroughConfig(fps=5, width=32, height=32),
                          cancel)
    assert list(tmp_path.iterdir()) == []


def test_the_viewer_renders_its_3d_view_along_a_path(demo, tmp_path, capsys):
    """``avgs-viewer --flythrough``: the explorer's SceneView off screen (its own process); and bad
    input is one line (``avgs_viewer.app.main`` here: it is refused before any window or GL)."""
    path = tmp_path / "path.json"
    path.write_text(json.dumps(PATH))
    out = tmp_path / "view.mp4"
    clip = tmp_path / "noise.wav"
    import soundfile as sf

    sf.write(str(clip), noise(demo.sample_rate), demo.sample_rate, subtype="FLOAT")
    run = [sys.executable, "-m", "avgs_viewer.app", str(DEMO), "--flythrough", str(path), "--video", str(out),
           "--fps", "10", "--size", "128", "96", "--clip", str(clip)]
    done = subprocess.run(run, capture_output=True, text=True, timeout=300, env={**__import__("os").environ,
                                                                                "OMP_NUM_THREADS": "1"})
    assert done.returncode == 0, done.stderr[-2000:]
    frames = check_video(out, 10, (128, 96), 2.0, demo.sample_rate)
    assert np.abs(frames[0].astype(int) - frames[-1]).mean() > 0.5  # the listener's handle moved
    from avgs_viewer.app import main as viewer_main

    status = viewer_main([str(DEMO), "--flythrough", str(path), "--video", str(tmp_path / "odd.mp4"),
                          "--size", "130", "97"])
    err = capsys.readouterr().err
    assert status == 2 and "even whole number" in err and err.count("\n") == 1
    assert not (tmp_path / "odd.mp4").exists()


def test_avgs_export_video_draws_g_from_the_listeners_head(demo, tmp_path, capsys):
    from avgs.cli import main

    path = tmp_path / "path.json"
    path.write_text(json.dumps(PATH))
    out = tmp_path / "cli.mp4"
    assert main(["export", str(DEMO), "--video", str(out), "--path", str(path), "--fps", "5", "--size", "64", "48"]) == 0
    assert f"wrote {out} (10 frames" in capsys.readouterr().out
    check_video(out, 5, (64, 48), 2.0, demo.sample_rate)
    assert main(["export", str(DEMO), "--video", str(tmp_path / "no.mp4")]) == 2
    assert "--video needs --path" in capsys.readouterr().err
