"""avgs export --ir / --sofa: a pose's binaural response as a WAV and a grid of responses as a
SOFA file (SingleRoomSRIR) that sofar verifies and reads back equal, on the bundled demo
(a checkpoint of --task rir) and on a one-source checkpoint."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf

from avgs.cli import main
from avgs.export.grid import GridSpec, ResponseGrid, compute_grid, listener_grid
from avgs.export.sofa import read_grid, write_grid

sofar = pytest.importorskip("sofar")
DEMO = Path(__file__).resolve().parents[1] / "assets" / "demo" / "scene.ckpt"


@pytest.fixture(scope="module")
def demo():
    if not DEMO.is_file():
        pytest.skip("the bundled demo scene is missing (scripts/make_demo.sh)")
    from avgs import SceneRenderer

    return SceneRenderer.load(DEMO)


def test_the_ir_wav_is_the_poses_filter(demo, tmp_path, capsys):
    out = tmp_path / "ir.wav"
    assert main(["export", str(DEMO), "--ir", str(out), "--listener", "6", "2", "1.5", "--yaw", "90",
                 "--source", "2", "3", "1.5"]) == 0
    info = sf.info(str(out))
    assert (info.channels, info.samplerate, info.subtype) == (2, demo.sample_rate, "FLOAT")
    data, _ = sf.read(str(out), dtype="float32", always_2d=True)  # [L, 2]
    expected = demo.binaural_filter((6, 2, 1.5), 90.0, source=(2, 3, 1.5)).impulse  # [2, L]
    np.testing.assert_array_equal(data.T, expected)
    # the source is behind-left of a listener facing +y at larger x: the left ear's direct sound comes first
    onset = [int(np.argmax(np.abs(ch) > 0.2 * np.abs(ch).max())) for ch in data.T]
    assert onset[0] < onset[1]


def test_a_sofa_grid_verifies_and_reads_back_equal(demo, tmp_path, capsys):
    out = tmp_path / "grid.sofa"
    assert main(["export", str(DEMO), "--sofa", str(out), "--spacing", "2.5", "--yaws", "0", "90", "200.5",
                 "--height", "1.2", "--sources", "3", "3", "1.5", "6", "1", "1.2"]) == 0
    assert "2 source(s) x" in capsys.readouterr().out
    sofa = sofar.read_sofa(str(out), verbose=False)
    sofa.verify(issue_handling="raise")  # sofar's own convention check
    assert sofa.GLOBAL_SOFAConventions == "SingleRoomSRIR"
    grid = read_grid(out)
    listeners = listener_grid(demo.bounds, 2.5, 1.2)
    S, P, Y = grid.shape
    assert (S, P, Y) == (2, len(listeners), 3)
    assert np.asarray(sofa.Data_IR).shape == (S * P * Y, 2, grid.ir.shape[-1])
    np.testing.assert_allclose(grid.listeners, listeners, atol=1e-12)
    np.testing.assert_allclose(grid.yaws, [0.0, 90.0, 200.5], atol=1e-9)
    np.testing.assert_allclose(grid.sources, [[3, 3, 1.5], [6, 1, 1.2]], atol=1e-12)
    assert grid.sample_rate == demo.sample_rate
    # every response is the renderer's for that pose
    for s, p, y in ((0, 0, 0), (1, P - 1, 2), (0, P // 2, 1)):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # a headroom note; predict_responses has no limit, compare where none applies
            expected = demo.predict_responses(demo.frame.to_normalised(grid.sources[s][None]),
                                              demo.frame.to_normalised(grid.listeners[p][None]), [grid.yaws[y]])[0]
        np.testing.assert_allclose(grid.ir[s, p, y], expected, rtol=0, atol=1e-5 * np.abs(expected).max())  # batch rounding
    filt = demo.binaural_filter(grid.listeners[0], grid.yaws[0], source=grid.sources[0]).impulse
    np.testing.assert_allclose(grid.ir[0, 0, 0], filt, atol=1e-6)


def test_a_grid_of_any_values_round_trips(tmp_path):
    rng = np.random.default_rng(3)
    grid = ResponseGrid(rng.uniform(-3, 3, (1, 3)), rng.uniform(-3, 3, (4, 3)), np.array([10.0, 359.5, 123.25]),
                        rng.standard_normal((1, 4, 3, 2, 50)).astype(np.float32), 48000,
                        np.array([[-4.0, -4, 0], [4, 4, 3]]))
    back = read_grid(write_grid(tmp_path / "g.sofa", grid))
    np.testing.assert_array_equal(back.ir, grid.ir)
    np.testing.assert_allclose(back.yaws, grid.yaws, atol=1e-9)
    np.testing.assert_allclose(back.listeners, grid.listeners, atol=0)
    np.testing.assert_allclose(back.bounds, grid.bounds, atol=0)
    assert back.sample_rate == 48000


def test_a_one_source_checkpoint_gives_its_filters_pose_by_pose(one_source_ckpt, tmp_path):
    from avgs import SceneRenderer

    r = SceneRenderer.load(one_source_ckpt)
    assert not r.source_aware
    steps = []
    grid = compute_grid(r, GridSpec(spacing=0.8, yaws=(0.0, 180.0)), lambda d, t: steps.append((d, t)))
    assert grid.shape[0] == 1 and steps[-1][0] == steps[-1][1] == grid.shape[1] * 2
    np.testing.assert_allclose(grid.sources[0], r.source)
    p = grid.shape[1] - 1
    np.testing.assert_array_equal(grid.ir[0, p, 1], r.binaural_filter(grid.listeners[p], 180.0).impulse)
    back = read_grid(write_grid(tmp_path / "one.sofa", grid))
    np.testing.assert_array_equal(back.ir, grid.ir)
    with pytest.raises(ValueError, match="one source position"):
        compute_grid(r, GridSpec(spacing=0.8, sources=((0, 0, 0), (0.1, 0, 0))))


@pytest.mark.parametrize("argv, message", [
    (["--sofa", "{tmp}/g.txt"], "must be written to a .sofa file"),
    (["--sofa", "{tmp}/g.sofa", "--sources", "1", "2"], "three numbers (x y z) per source"),
    (["--sofa", "{tmp}/g.sofa", "--spacing", "0"], "spacing must be a positive number"),
    (["--ir", "{tmp}/ir.wav"], "--ir needs the pose"),
    (["--ir", "{tmp}/ir.flac", "--listener", "1", "1", "1", "--yaw", "0"], "must be written to a .wav file"),
])
def test_bad_input_is_one_line_and_nothing_is_written(demo, tmp_path, capsys, argv, message):
    argv = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    assert main(["export", str(DEMO), *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("avgs export: error:") and message in err and "\n" not in err
    assert list(tmp_path.iterdir()) == []
