"""Baselines, the evaluation protocol and ``avgs eval`` on scenes in the RWAVS layout."""

from __future__ import annotations

import json

import numpy as np
import pytest

from avgs import dsp
from avgs.evaluation import binaural as evaluate, metrics
from avgs.evaluation.baselines import BASELINES, mono_energy, mono_mono, oracle_mask, stereo_energy
from avgs.cli import main
from avgs.data.rwavs import RWAVSScene
from rwavs_writer import write_scene


@pytest.fixture(scope="module")
def data_root(tmp_path_factory):
    root = tmp_path_factory.mktemp("eval")
    write_scene(root, "office_1", n_train=8, n_val=6, seed=1)
    write_scene(root, "office_2", n_train=8, n_val=6, seed=2)
    write_scene(root, "garden-1", n_train=8, n_val=6, seed=3, metadata={"environment": "outdoor"})
    write_scene(root, "7", n_train=8, n_val=6, seed=4)
    return root


@pytest.fixture(scope="module")
def scene(data_root):
    return RWAVSScene(data_root / "office_1")


def energy(x, axis=None):
    return np.mean(np.asarray(x, dtype=np.float64) ** 2, axis=axis)


def test_baselines_scale_the_source_to_the_target_energy(scene):
    for clip in scene.val:
        mm, me, se = mono_mono(clip, scene), mono_energy(clip, scene), stereo_energy(clip, scene)
        for out in (mm, me, se):
            assert out.shape == clip.binaural.shape and out.dtype == np.float32
        np.testing.assert_array_equal(mm, np.stack([clip.mono, clip.mono]))
        np.testing.assert_array_equal(me[0], me[1])
        assert energy(me) == pytest.approx(energy(clip.binaural), rel=1e-5)
        np.testing.assert_allclose(energy(se, axis=-1), energy(clip.binaural, axis=-1), rtol=1e-5)
        # every output is the source times a gain
        for out in (me, se):
            for ch in out:
                gain = np.dot(ch, clip.mono) / np.dot(clip.mono, clip.mono)
                np.testing.assert_allclose(ch, gain * clip.mono, atol=1e-6)


def test_oracle_mask_recovers_a_known_filter_and_bounds_the_flat_gains(scene):
    """A target that is the source through fixed per-ear filters is matched exactly; on the
    real clips the best per-frequency gains are never worse than Stereo-Energy's flat ones."""
    from scipy.signal import lfilter

    clip = scene.val[0]
    left = 0.5 * clip.mono
    right = lfilter([0.3, 0.2], [1.0], clip.mono)  # a gentle low-pass: a gain per frequency (to STFT resolution)
    filtered = type(clip)(clip.time, clip.frame_path, clip.c2w, clip.listener, clip.yaw, clip.mono,
                          np.stack([left, right]).astype(np.float32))
    out, mags = oracle_mask(filtered, scene)
    assert out.shape == filtered.binaural.shape and out.dtype == np.float32
    np.testing.assert_allclose(out[0], left, atol=1e-5)
    assert metrics.mag(out, filtered.binaural) < 1e-3 * metrics.mag(mono_mono(filtered), filtered.binaural)
    # the left ear is the source times 0.5: its masked magnitudes are exact
    assert mags.shape == (2, 257, 173)
    np.testing.assert_allclose(mags[0], 0.5 * dsp.magnitude(clip.mono).numpy(), rtol=1e-4, atol=1e-6)  # float32 STFT
    for c in scene.val:
        out, mags = oracle_mask(c, scene)
        se = stereo_energy(c, scene)
        assert metrics.mag(out, c.binaural) <= metrics.mag(se, c.binaural) + 1e-9
        # least squares per bin: the masked magnitudes themselves beat any flat gain
        assert metrics.mag_spectrogram(mags, c.binaural) <= metrics.mag(se, c.binaural) + 1e-9


def test_a_silent_source_gives_silence(scene):
    clip = scene.val[0]
    silent = type(clip)(clip.time, clip.frame_path, clip.c2w, clip.listener, clip.yaw, np.zeros_like(clip.mono), clip.binaural)
    for method in BASELINES.values():
        out, mags = evaluate.predict(method, silent, scene)
        assert np.all(out == 0.0) and np.all(np.isfinite(out))
        assert np.all(mags == 0.0)


def test_baselines_keep_the_papers_order(data_root):
    report = evaluate.evaluate(BASELINES, evaluate.find_scenes(data_root), progress=False)
    overall = {name: report["methods"][name]["overall"] for name in BASELINES}
    assert overall["mono-mono"]["MAG"] > 3 * overall["mono-energy"]["MAG"]
    assert overall["stereo-energy"]["MAG"] <= overall["mono-energy"]["MAG"]
    assert overall["mono-mono"]["ENV"] > overall["mono-energy"]["ENV"] >= overall["stereo-energy"]["ENV"]


def test_scene_score_is_the_mean_over_val_clips(scene):
    score = evaluate.score_scene(mono_energy, scene, progress=False)
    mags = [metrics.mag(mono_energy(c, scene), c.binaural) for c in scene.val]
    envs = [metrics.env(mono_energy(c, scene), c.binaural) for c in scene.val]
    assert score["MAG"] == pytest.approx(np.mean(mags)) and score["ENV"] == pytest.approx(np.mean(envs))


def test_any_callable_is_a_method(scene):
    oracle = lambda clip, scene: clip.binaural  # noqa: E731
    exact = evaluate.score_scene(oracle, scene, progress=False)
    assert {k: exact[k] for k in evaluate.MEAN_METRICS} == {"MAG": 0.0, "ENV": 0.0, "ILD": 0.0, "MAGp": 0.0}
    assert exact["ITD"] == 0.0 and exact["LAT"] in (100.0, None)  # None: no clip with a true |ITD| >= 150 us
    swapped = lambda clip, scene: clip.binaural[::-1]  # noqa: E731  left and right exchanged
    swapped_score = evaluate.score_scene(swapped, scene, progress=False)
    assert swapped_score["MAG"] > 0
    # exchanging the ears negates every clip's ILD: the error is twice its size
    ilds = [abs(2 * float(metrics.ild(c.binaural))) for c in scene.val]
    assert swapped_score["ILD"] == pytest.approx(np.mean(ilds), rel=1e-6)
    short = lambda clip, scene: clip.binaural[:, :-1]  # noqa: E731
    with pytest.raises(ValueError, match=r"short returned \(2, 22049\) .* expected \(2, 22050\)"):
        evaluate.score_scene(short, scene, name="short", progress=False)


def test_magp_scores_a_methods_own_magnitudes(scene):
    """A method that returns a Prediction is scored on its magnitudes in MAGp, on its waveform in MAG."""
    def louder(clip, scene):  # the true waveform, but magnitudes 10 % too loud
        return evaluate.Prediction(clip.binaural, 1.1 * dsp.magnitude(clip.binaural).numpy())

    score = evaluate.score_scene(louder, scene, progress=False)
    assert score["MAG"] == 0.0 and score["ILD"] == 0.0
    expected = np.mean([2 * np.mean((0.1 * dsp.magnitude(c.binaural).numpy()) ** 2) for c in scene.val])
    assert score["MAGp"] == pytest.approx(expected, rel=1e-5) and expected > 0
    # a waveform alone is scored on its own STFT: MAGp equals MAG
    se = evaluate.score_scene(stereo_energy, scene, progress=False)
    assert se["MAGp"] == pytest.approx(se["MAG"], rel=1e-5)
    bad = lambda clip, scene: evaluate.Prediction(clip.binaural, np.zeros((2, 257, 10)))  # noqa: E731
    with pytest.raises(ValueError, match=r"bad returned magnitudes \(2, 257, 10\) .* expected \(2, 257, 173\)"):
        evaluate.score_scene(bad, scene, name="bad", progress=False)


def test_environment_rule(data_root):
    envs = {p.name: evaluate.environment_of(RWAVSScene(p)) for p in evaluate.find_scenes(data_root)}
    # scene.json's "environment", else the prefix before '_' or '-', else the name
    assert envs == {"7": "7", "garden-1": "outdoor", "office_1": "office", "office_2": "office"}


def test_overall_is_the_mean_of_environment_means():
    scenes = {"a_1": {"MAG": 1.0, "ENV": 0.1}, "a_2": {"MAG": 3.0, "ENV": 0.3}, "b": {"MAG": 8.0, "ENV": 0.8}}
    out = evaluate.aggregate(scenes, {"a_1": "a", "a_2": "a", "b": "b"})
    assert out["environments"] == {"a": {"MAG": 2.0, "ENV": pytest.approx(0.2)}, "b": {"MAG": 8.0, "ENV": 0.8}}
    assert out["overall"] == {"MAG": 5.0, "ENV": pytest.approx(0.5)}  # not the scene mean 4.0


def test_cli_prints_tables_and_writes_json(data_root, tmp_path, capsys):
    out = tmp_path / "results" / "scores.json"
    argv = ["eval", str(data_root), "--method", "mono-mono", "--method", "stereo-energy", "--json", str(out), "--no-progress"]
    assert main(argv) == 2 and "folder" in capsys.readouterr().err  # refused before any scoring: no folder
    out.parent.mkdir()
    assert main(argv) == 0
    printed = capsys.readouterr().out
    for label in ("scene office_1", "scene garden-1", "env   office", "env   outdoor", "overall", "mono-mono", "stereo-energy"):
        assert label in printed
    report = json.loads(out.read_text())
    assert set(report["methods"]) == {"mono-mono", "stereo-energy"}
    for name, result in report["methods"].items():
        assert set(result["scenes"]) == {"7", "garden-1", "office_1", "office_2"}
        for score in result["scenes"].values():
            assert list(score) == ["MAG", "ENV", "ILD", "MAGp", "ITD", "LAT"]
            assert all(np.isfinite(v) for k, v in score.items() if k != "LAT")
            assert score["LAT"] is None or 0.0 <= score["LAT"] <= 100.0
        office = np.mean([result["scenes"][s]["MAG"] for s in ("office_1", "office_2")])
        assert result["environments"]["office"]["MAG"] == pytest.approx(office)
        expected = np.mean([office, result["scenes"]["garden-1"]["MAG"], result["scenes"]["7"]["MAG"]])
        assert result["overall"]["MAG"] == pytest.approx(expected)
    assert [p.name for p in out.parent.iterdir()] == ["scores.json"]  # no temporary file left behind


def test_cli_scene_selection_defaults_and_errors(data_root, tmp_path, capsys):
    out = tmp_path / "one.json"
    assert main(["eval", str(data_root), "--scene", "office_2", "--json", str(out), "--no-progress"]) == 0
    report = json.loads(out.read_text())
    assert set(report["methods"]) == set(BASELINES)  # default: the three baselines
    assert set(report["methods"]["mono-energy"]["scenes"]) == {"office_2"}
    capsys.readouterr()
    assert main(["eval", str(data_root), "--method", "nearest"]) == 2
    assert "unknown method 'nearest'" in capsys.readouterr().err
    assert main(["eval", str(data_root), "--scene", "office_9"]) == 2
    assert "office_9: no RWAVS scene there" in capsys.readouterr().err
    assert main(["eval", str(data_root), "--method", f"ckpt:{tmp_path / 'none.ckpt'}"]) == 2
    assert "none.ckpt" in capsys.readouterr().err
    assert main(["eval", str(tmp_path / "nowhere")]) == 2
    assert "data root missing" in capsys.readouterr().err


def test_a_folder_of_checkpoints_is_one_method_each_scoring_its_own_scene(data_root, tmp_path):
    from avgs.io.checkpoint import save_checkpoint, untrained_checkpoint

    folder = tmp_path / "runs"
    for name in ("office_1", "garden-1"):
        scene = RWAVSScene(data_root / name)
        pts = scene.frame.to_world(np.random.default_rng(0).uniform(-1, 1, (200, 3)))
        save_checkpoint(untrained_checkpoint(pts, scene.frame.to_world(scene.source), frame=scene.frame, name=name),
                        folder / f"{name}.ckpt")
    out = tmp_path / "scores.json"
    assert main(["eval", str(data_root), "--method", "stereo-energy", "--method", f"ckpt:{folder}",
                 "--json", str(out), "--no-progress"]) == 0
    scores = json.loads(out.read_text())["methods"][f"ckpt:{folder}"]
    assert set(scores["scenes"]) == {"office_1", "garden-1"}  # the scenes it has checkpoints for
    assert all(np.isfinite(v["MAG"]) for v in scores["scenes"].values())
    (folder / "copy.ckpt").write_bytes((folder / "office_1.ckpt").read_bytes())
    with pytest.raises(ValueError, match="two checkpoints for scene 'office_1'"):
        evaluate.load_method(f"ckpt:{folder}")
