"""Memory grows with the batch or the block, not with the scene or the clip (issue 32, item 5).

- Training of the impulse-response task reads a batch of responses at a time: its targets equal
  those of the whole split, and the Python-visible memory (tracemalloc: numpy arrays, the
  responses read) of its set-up, steps and evaluation on a scene of 4N responses stays within
  a factor of that on N responses. Before, the whole split was read (and transformed) at once.
- :func:`avgs.render.chunked.render_to_file` writes a render block by block: equal to the
  whole render to float rounding, and its tracemalloc peak for a 4x longer clip stays within a
  factor of the shorter one's (the one-shot render holds the whole output).

Figures and commands: benchmarks/memory.md.
"""

from __future__ import annotations

import json
import tracemalloc
import warnings
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf
import torch
from scipy.io import wavfile

from avgs.acoustics.points import AudioPoints
from avgs.config import STFT, SynthesisConfig
from avgs.data.rir import RIRScene, rir_file_name
from avgs.render.chunked import render_to_file
from avgs.render.renderer import SceneRenderer
from avgs.train.impulse_responses import (
    RIRTrainer, floored_log_magnitude, mean_log_magnitude, peak_magnitude, rir_data, rir_quick_config)

SR = STFT.sample_rate
DEMO = Path(__file__).resolve().parents[1] / "assets" / "demo" / "scene.ckpt"
LENGTH = 128 * 258  # 1.5 s, the longest response a scene may hold


def write_rir_scene(root: Path, receivers: int, seed: int = 0) -> Path:
    """A valid impulse-response scene without its RWAVS part: source 0 heard by ``receivers``
    receivers (3 of 4 train, the rest val), source 1 held out at 2 of them; 4 orientations of
    decaying noise, 1.5 s each."""
    rng = np.random.default_rng(seed)
    scene = root / f"grid_{receivers}"
    (scene / "rir").mkdir(parents=True)
    n_train = receivers * 3 // 4
    splits = {"train": [[0, r] for r in range(n_train)], "val": [[0, r] for r in range(n_train, receivers)],
              "heldout": [[1, 0], [1, 1]]}
    index = {"format": "avgs-rir/1", "sample_rate": SR, "orientations_deg": [0, 90, 180, 270],
             "sources": [[0.1, 0.2, 0.0], [-0.5, 0.3, 0.0]],
             "receivers": rng.uniform(-0.9, 0.9, (receivers, 3)).round(4).tolist(), "splits": splits}
    (scene / "rir" / "index.json").write_text(json.dumps(index))
    decay = np.exp(-np.arange(LENGTH) / (0.1 * SR)).astype(np.float32)
    for s, r in (p for k in splits.values() for p in k):
        for y in index["orientations_deg"]:
            h = (rng.standard_normal((LENGTH, 2)).astype(np.float32) * decay[:, None] * 0.1)
            wavfile.write(scene / "rir" / rir_file_name(s, r, y), SR, h)
    return scene


@pytest.fixture(scope="module")
def scenes(tmp_path_factory):
    root = tmp_path_factory.mktemp("grids")
    return {n: write_rir_scene(root, n) for n in (8, 32)}  # 24 and 96 training responses


def train_briefly(scene_dir: Path) -> dict:
    """What ImpulseResponseTraining does with a scene: the floor, the mean target, a trainer, 3 steps, val."""
    torch.manual_seed(0)
    scene = RIRScene(scene_dir)
    cfg = rir_quick_config()
    cfg.rir.width, cfg.acoustic.batch_size = 32, 4
    cfg.rir.length, cfg.rir.frames = scene.length, 1 + scene.length // STFT.hop_length
    log_floor = float(np.log(peak_magnitude(scene, "train", STFT))) - 8.0
    train = rir_data(scene, "train", log_floor, STFT, cfg.rir.smooth_bins)
    from avgs.acoustics.rir_model import RIRModel

    points = AudioPoints(torch.rand(200, 3) * 2 - 1, torch.randn(200, 52))
    model = RIRModel.build(points, cfg, STFT)
    with torch.no_grad():
        model.binauralizer.log_floor.fill_(log_floor)
        model.binauralizer.mean.copy_(mean_log_magnitude(train))
    trainer = RIRTrainer(model, train, cfg)
    for _ in range(3):
        trainer.step()
    return trainer.evaluate(rir_data(scene, "val", log_floor, STFT, cfg.rir.smooth_bins))


def test_batch_targets_equal_the_whole_splits(scenes):
    scene = RIRScene(scenes[8])
    data = rir_data(scene, "train", -9.0, STFT, 9)
    whole = floored_log_magnitude(scene.responses("train").rir, -9.0, STFT, 9)  # [M, 2, F, N]
    idx = np.array([3, 0, 17, 3, 23])
    assert torch.equal(data.log_mag(idx), whole[idx])
    torch.testing.assert_close(mean_log_magnitude(data), whole.double().mean(0).float(), rtol=0, atol=1e-6)
    assert peak_magnitude(scene, "train", STFT) == pytest.approx(float(torch.stft(
        torch.from_numpy(scene.responses("train").rir.reshape(-1, LENGTH)), 512, 128, window=torch.hann_window(512),
        return_complex=True).abs().max()), rel=1e-6)


def traced_peak(fn) -> int:
    tracemalloc.start()
    try:
        fn()
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def test_training_memory_does_not_grow_with_the_scene(scenes):
    train_briefly(scenes[8])  # warm up: imports, caches
    small = traced_peak(lambda: train_briefly(scenes[8]))
    large = traced_peak(lambda: train_briefly(scenes[32]))
    whole_split = 96 * 2 * LENGTH * 4  # the larger scene's 96 training responses in float32: 25 MB
    assert large < 1.5 * small + 2e6, (small, large)  # measured 18.0 MB and 18.0 MB: a chunk of 32 responses
    assert large < whole_split, (large, whole_split)  # the split read at once (before: 25 + 8 MB of val)


@pytest.fixture(scope="module")
def renderers(one_source_ckpt):
    return {"rir": SceneRenderer.load(DEMO), "binaural": SceneRenderer.load(one_source_ckpt)}


def noise(n: int, seed: int = 0) -> np.ndarray:
    return (np.random.default_rng(seed).standard_normal(n) * 0.2).astype(np.float32)


@pytest.mark.parametrize("task", ["rir", "binaural"])
@pytest.mark.parametrize("method", ["spectrogram", "filter"])
def test_a_render_written_in_blocks_equals_the_whole_render(renderers, task, method, tmp_path):
    r = renderers[task]
    r.synthesis = SynthesisConfig(method=method)
    x = noise(20 * SR, seed=3)
    lo, hi = r.bounds
    listener, yaw = lo + 0.4 * (hi - lo), 70.0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        whole = r.render(listener, yaw, x)
        result, n = render_to_file(r, tmp_path / "out.wav", listener, yaw, x, block=5000)
    y = sf.read(str(tmp_path / "out.wav"), dtype="float32", always_2d=True)[0].T  # [2, T]
    assert n == len(x) and y.shape == whole.binaural.shape
    top = float(np.abs(whole.binaural).max())
    # float rounding; the mid phase's through its 12 phase iterations (tests/test_stability.py)
    tol = 1e-4 if (task, method) == ("binaural", "spectrogram") else 1e-6
    assert np.abs(y - whole.binaural).max() <= tol * top
    assert result.theta == pytest.approx(whole.theta) and result.binaural is None
    assert [p.name for p in tmp_path.iterdir()] == ["out.wav"]  # nothing else left


def test_a_render_to_a_fixed_point_format_is_scaled_to_full_scale(renderers, tmp_path):
    r = renderers["rir"]
    r.synthesis = SynthesisConfig(method="filter")
    x = noise(3 * SR, seed=1) * 20  # peaks far beyond full scale
    lo, hi = r.bounds
    listener = lo + 0.4 * (hi - lo)
    whole = r.render(listener, 10.0, x).binaural
    with pytest.warns(UserWarning, match=r"scaled down by that much to fit PCM_24"):
        render_to_file(r, tmp_path / "out.flac", listener, 10.0, x, format="FLAC", subtype="PCM_24", block=4096)
    y = sf.read(str(tmp_path / "out.flac"), dtype="float32", always_2d=True)[0].T
    assert np.abs(y).max() <= 1.0
    np.testing.assert_allclose(y, whole / np.abs(whole).max(), atol=2e-6)  # 24-bit rounding


RSS_PROBE = """
import sys, warnings
import numpy as np, psutil, torch
torch.set_num_threads(1)
from avgs.config import SynthesisConfig
from avgs.render.chunked import render_to_file
from avgs.render.renderer import SceneRenderer
ckpt, seconds, out = sys.argv[1], float(sys.argv[2]), sys.argv[3]
r = SceneRenderer.load(ckpt, synthesis=SynthesisConfig(method=sys.argv[4]))
lo, hi = r.bounds
n = int(seconds * r.sample_rate)
x = np.empty(n, np.float32)  # filled in pieces: no float64 temporary as large as the clip
rng = np.random.default_rng(0)
for i in range(0, n, 1 << 16):
    x[i : i + (1 << 16)] = rng.standard_normal(min(1 << 16, n - i)) * 0.2
with warnings.catch_warnings():
    warnings.simplefilter("ignore")
    render_to_file(r, out + ".warm.wav", lo + 0.4 * (hi - lo), 30.0, x[: 1 << 17])  # first-use allocations
    before = psutil.Process().memory_info().rss
    with open("/proc/self/clear_refs", "w") as f:
        f.write("5")  # resets the peak RSS (VmHWM) to the current RSS
    render_to_file(r, out, lo + 0.4 * (hi - lo), 30.0, x)
hwm = next(int(line.split()[1]) for line in open("/proc/self/status") if line.startswith("VmHWM:"))  # kB
print(hwm * 1024 - before)
"""


def render_growth(ckpt, seconds: float, method: str, tmp_path) -> int:
    """Bytes the peak RSS of a fresh process rose by while ``render_to_file`` wrote ``seconds`` of noise."""
    import subprocess
    import sys

    env = {**__import__("os").environ, "OMP_NUM_THREADS": "1"}
    out = subprocess.run([sys.executable, "-c", RSS_PROBE, str(ckpt), str(seconds), str(tmp_path / "p.wav"), method],
                         capture_output=True, text=True, env=env, check=True)
    return int(out.stdout.strip().splitlines()[-1])


@pytest.mark.parametrize("task, method, seconds", [("rir", "filter", 15),
                                                   pytest.param("binaural", "spectrogram", 30, marks=pytest.mark.slow)])
@pytest.mark.skipif(not Path("/proc/self/clear_refs").exists(), reason="needs Linux's resettable peak RSS")
def test_render_memory_does_not_grow_with_the_clip(one_source_ckpt, task, method, seconds, tmp_path):
    """Peak RSS over the process's level before the render (the clip already in memory), for a
    clip of ``seconds`` and one 4x longer: the growth stays far below the whole render's output
    (8 bytes a sample; the one-shot path also makes a scaled copy of the input), RSS, not timings.
    The mid phase's blocks (about 12 s) fill by 30 s: a shorter clip would not be the same steady state."""
    ckpt = DEMO if task == "rir" else one_source_ckpt
    short, long = render_growth(ckpt, seconds, method, tmp_path), render_growth(ckpt, 4 * seconds, method, tmp_path)
    output_growth = 8 * 3 * seconds * SR  # [2, T] float32 of the 3 x seconds more: 8 MB for 15 s
    # measured (MB, 30 s / 120 s): RIR filter 1.9 / 0.1, binaural mid 24.2 / 23.4; render() + write_audio 17.4 / 43.0
    # (the one-shot path's growth: 12.8 MB for 45 s more, thrice the bound at 15 s; the mid phase's at 15 / 60 s:
    # 15.4 / 24.7 MB, its blocks not yet full at 15 s)
    assert long - short < output_growth / 2, (short, long)


def test_avgs_render_of_a_long_clip_goes_in_blocks_and_equals_the_whole_render(renderers, tmp_path, monkeypatch):
    """`avgs render` renders inputs longer than WHOLE_SECONDS block by block: the same file as the
    whole render (float rounding), the same line printed."""
    import avgs.commands.render as render_command
    from avgs.cli import main as cli_main

    r = renderers["binaural"]
    x = noise(2 * SR, seed=3)
    wav = tmp_path / "in.wav"
    sf.write(wav, x, SR, subtype="FLOAT")
    lo, hi = r.bounds
    listener = lo + 0.4 * (hi - lo)
    argv = ["render", str(r.path), "--listener", *map(str, listener), "--yaw", "20", "--input", str(wav)]
    assert cli_main([*argv, "--output", str(tmp_path / "whole.wav")]) == 0
    import avgs.render.chunked as chunked

    calls = []
    monkeypatch.setattr(chunked, "render_to_file", lambda *a, **k: calls.append(1) or render_to_file(*a, **k))
    monkeypatch.setattr(render_command, "WHOLE_SECONDS", 0.5)  # this 2 s clip now goes in blocks
    assert cli_main([*argv, "--output", str(tmp_path / "blocks.wav")]) == 0
    assert calls == [1]
    whole = sf.read(str(tmp_path / "whole.wav"), dtype="float32")[0]
    blocks = sf.read(str(tmp_path / "blocks.wav"), dtype="float32")[0]
    assert whole.shape == blocks.shape == (2 * SR, 2)
    np.testing.assert_allclose(blocks, whole, atol=1e-4 * float(np.abs(whole).max()))
