"""The RWAVS reader against scenes written by an independent minimal writer (tests/rwavs_writer.py)."""

from __future__ import annotations

import json
import math
import os
import pickle
import shutil
import warnings

import numpy as np
import pytest
import soundfile as sf
import torch

from avgs import dsp
from avgs.data.frame import SceneFrame, c2w_from_yaw, facing_from_c2w, signed_direction, yaw_from_c2w
from avgs.data.rwavs import RWAVSScene
from rwavs_writer import SR, opengl_c2w, write_scene


def direction_to_source(listener, yaw: float, source) -> float:
    """:func:`avgs.data.frame.signed_direction` of one pose, in float64."""
    as64 = lambda v: torch.as_tensor(np.asarray(v, dtype=np.float64))  # noqa: E731
    return float(signed_direction(as64(listener)[None], as64([yaw]), as64(source))[0])


def wrap(angle: float) -> float:
    return math.atan2(math.sin(angle), math.cos(angle))


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    return write_scene(tmp_path_factory.mktemp("rwavs"), "office_1", n_train=12, n_val=4, seed=3)


@pytest.fixture(scope="module")
def scene(written):
    return RWAVSScene(written.scene_dir)


# -- the frame and the pose convention ------------------------------------------------


def test_scene_frame_fit_recovers_a_uniform_scale_and_shift():
    rng = np.random.default_rng(0)
    world = rng.uniform(-5, 20, size=(30, 3))
    truth = SceneFrame(np.array([7.0, -2.0, 1.5]), 0.125)
    frame, rms = SceneFrame.fit(world, truth.to_normalised(world))
    np.testing.assert_allclose(frame.center, truth.center, atol=1e-9)
    assert frame.scale == pytest.approx(truth.scale, rel=1e-12)
    assert rms < 1e-12
    np.testing.assert_allclose(frame.to_world(frame.to_normalised(world)), world, atol=1e-9)


def test_scene_frame_fit_reports_a_rotation_it_cannot_hold():
    rng = np.random.default_rng(1)
    world = rng.uniform(-1, 1, size=(20, 3))
    rotated = world @ np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]).T
    _, rms = SceneFrame.fit(world, rotated)
    assert rms > 0.1


def test_scene_frame_dict_round_trip_and_validation():
    frame = SceneFrame(np.array([1.0, 2.0, 3.0]), 0.5)
    back = SceneFrame.from_dict(json.loads(json.dumps(frame.to_dict())))
    np.testing.assert_array_equal(back.center, frame.center)
    assert back.scale == frame.scale
    from_tensors = SceneFrame.from_dict({"center": torch.tensor([1.0, 2.0, 3.0]), "scale": torch.tensor(0.5)})
    np.testing.assert_allclose(from_tensors.center, frame.center)
    with pytest.raises(ValueError, match="scale"):
        SceneFrame(np.zeros(3), 0.0)
    with pytest.raises(ValueError, match="center"):
        SceneFrame(np.array([0.0, np.nan, 0.0]), 1.0)
    with pytest.raises(ValueError, match="'center' and 'scale'"):
        SceneFrame.from_dict({"scale": 1.0})


def test_yaw_90_faces_plus_y_and_a_source_on_the_left_has_positive_theta():
    for c2w in (c2w_from_yaw([0.0, 0.0, 1.6], math.pi / 2), opengl_c2w([0.0, 0.0, 1.6], math.pi / 2)):
        np.testing.assert_allclose(facing_from_c2w(c2w), [0.0, 1.0, 0.0], atol=1e-12)
        assert yaw_from_c2w(c2w) == pytest.approx(math.pi / 2)
    listener, yaw = np.array([0.0, 0.0, 1.6]), math.pi / 2  # facing +y: left is -x
    assert direction_to_source(listener, yaw, [-2.0, 0.0, 1.0]) == pytest.approx(math.pi / 2)
    assert direction_to_source(listener, yaw, [3.0, 0.0, 1.0]) == pytest.approx(-math.pi / 2)
    assert direction_to_source(listener, yaw, [0.0, 5.0, 0.0]) == pytest.approx(0.0)
    assert abs(direction_to_source(listener, yaw, [0.0, -5.0, 0.0])) == pytest.approx(math.pi)
    assert direction_to_source(listener, yaw, [-1.0, 1.0, 0.0]) == pytest.approx(math.pi / 4)


def test_our_c2w_and_the_writers_agree():
    rng = np.random.default_rng(2)
    for _ in range(10):
        pos, yaw = rng.uniform(-3, 3, 3), rng.uniform(-math.pi, math.pi)
        np.testing.assert_allclose(c2w_from_yaw(pos, yaw), opengl_c2w(pos, yaw), atol=1e-12)


# -- reading a scene -------------------------------------------------------------------


def test_reads_poses_source_and_frame(written, scene):
    assert scene.name == "office_1" and scene.root == written.scene_dir.resolve()
    assert scene.sample_rate == SR and scene.metadata is None
    assert (len(scene.train), len(scene.val)) == (12, 4)
    np.testing.assert_allclose(scene.frame.center, written.center, atol=1e-9)
    assert scene.frame.scale == pytest.approx(written.scale)
    np.testing.assert_allclose(scene.source, written.source, atol=1e-9)
    for clips, poses in ((scene.train, written.train), (scene.val, written.val)):
        assert [c.time for c in clips] == [float(p.frame) for p in poses]
        for clip, pose in zip(clips, poses):
            np.testing.assert_allclose(clip.listener, written.normalised(pose.position), atol=1e-9)
            np.testing.assert_allclose(scene.frame.to_world(clip.listener), pose.position, atol=1e-9)
            np.testing.assert_allclose(clip.c2w[:3, 3], clip.listener)
            assert wrap(clip.yaw - pose.yaw) == pytest.approx(0.0, abs=1e-9)
            assert clip.frame_path == written.scene_dir.resolve() / "frames" / f"{pose.frame:05d}.png"
            assert clip.frame_path.is_file()


def test_clip_is_the_second_centred_on_the_frame_time(written, scene):
    for clip in scene.train + scene.val:
        start = int(round((clip.time - 0.5) * SR))
        assert clip.mono.dtype == np.float32 and clip.binaural.dtype == np.float32
        assert clip.mono.shape == (SR,) and clip.binaural.shape == (2, SR)
        np.testing.assert_array_equal(clip.mono, written.mono[start : start + SR])
        np.testing.assert_array_equal(clip.binaural, written.binaural[:, start : start + SR])


def test_clips_at_the_ends_are_zero_padded(tmp_path):
    # Frame 0 has only its second half recorded; the last frame only 0.2 s after it.
    w = write_scene(tmp_path, "pad", n_train=5, n_val=1, first_frame=0, tail_s=0.2)
    scene = RWAVSScene(w.scene_dir)
    clips = {c.time: c for c in scene.train + scene.val}
    first, last = clips[0.0], clips[5.0]
    half = SR // 2
    np.testing.assert_array_equal(first.mono[:half], 0.0)
    np.testing.assert_array_equal(first.mono[half:], w.mono[: SR - half])
    np.testing.assert_array_equal(first.binaural[:, half:], w.binaural[:, : SR - half])
    recorded = len(w.mono) - int(round(4.5 * SR))
    assert recorded == int(round(0.7 * SR))
    np.testing.assert_array_equal(last.mono[:recorded], w.mono[-recorded:])
    np.testing.assert_array_equal(last.mono[recorded:], 0.0)
    np.testing.assert_array_equal(last.binaural[:, recorded:], 0.0)


def test_frames_without_a_pose_are_skipped(tmp_path):
    w = write_scene(tmp_path, "gaps", n_train=9, n_val=3, poseless_frames=(2,), unlisted_frames=(5, 7))
    scene = RWAVSScene(w.scene_dir)
    times = sorted(c.time for c in scene.train + scene.val)
    assert times == [float(k) for k in range(1, 13) if k not in (2, 5, 7)]


def test_the_louder_ear_is_the_one_facing_the_source(tmp_path):
    # Source at (4.5, 2.5); listeners around it facing +y, so x < 4.5 puts it on the right.
    poses = [(x, y, math.pi / 2) for x in (1.5, 3.0, 6.0, 5.8) for y in (1.0, 3.0)]
    w = write_scene(tmp_path, "ears", n_train=6, n_val=2, poses=poses)
    scene = RWAVSScene(w.scene_dir)
    sides = set()
    for clip in scene.train + scene.val:
        theta = direction_to_source(clip.listener, clip.yaw, scene.source)
        left, right = np.mean(clip.binaural[0] ** 2), np.mean(clip.binaural[1] ** 2)
        assert np.sign(theta) == np.sign(left - right), (clip.time, theta, left, right)
        sides.add(bool(theta > 0))
    assert sides == {True, False}


def test_scene_json_frame_is_used_and_unscaled_poses_are_normalised(tmp_path):
    w0 = write_scene(tmp_path / "a", "office_9", scaled=False)
    meta = {"environment": "office", "to_normalised": {"center": [3.0, 2.0, 1.5], "scale": 1 / 3}}
    # Unscaled poses only: without scene.json the frame is the identity (with a warning) ...
    with pytest.warns(UserWarning, match="used unnormalised"):
        plain = RWAVSScene(w0.scene_dir)
    assert plain.frame.scale == 1.0 and np.all(plain.frame.center == 0)
    np.testing.assert_allclose(plain.train[0].listener, w0.train[0].position)
    # ... with it, poses come out normalised by its map.
    w = write_scene(tmp_path / "b", "office_9", scaled=False, metadata=meta)
    scene = RWAVSScene(w.scene_dir)
    assert scene.metadata == meta
    np.testing.assert_allclose(scene.frame.center, [3.0, 2.0, 1.5])
    for clip, pose in zip(scene.train, w.train):
        np.testing.assert_allclose(clip.listener, (pose.position - [3.0, 2.0, 1.5]) / 3, atol=1e-9)


def test_unscaled_poses_in_nerfstudio_frames_format(tmp_path):
    w = write_scene(tmp_path, "ns", unscaled_as_frames=True, poseless_frames=(4,))
    scene = RWAVSScene(w.scene_dir)
    np.testing.assert_allclose(scene.frame.center, w.center, atol=1e-9)
    assert scene.frame.scale == pytest.approx(w.scale)
    assert 4.0 not in [c.time for c in scene.train + scene.val]
    os.remove(w.scene_dir / "transforms_scale_train.json")  # train poses now come from the frames file
    scene = RWAVSScene(w.scene_dir)
    for clip, pose in zip(scene.train, [p for p in w.train if p.frame != 4]):
        np.testing.assert_allclose(clip.listener, w.normalised(pose.position), atol=1e-9)


def test_scaled_poses_only_give_an_identity_frame(tmp_path):
    w = write_scene(tmp_path, "s", unscaled=False)
    scene = RWAVSScene(w.scene_dir)
    assert scene.frame.scale == 1.0
    np.testing.assert_allclose(scene.train[0].listener, w.normalised(w.train[0].position), atol=1e-9)


def test_rotated_scaled_poses_warn_that_world_is_approximate(tmp_path):
    w = write_scene(tmp_path, "rot")
    path = w.scene_dir / "transforms_scale_train.json"
    meta = json.loads(path.read_text())
    for e in meta["camera_path"]:
        m = np.array(e["camera_to_world"]).reshape(4, 4)
        m[:3, 3] = m[[1, 0, 2], 3] * [-1, 1, 1]
        e["camera_to_world"] = m.reshape(-1).tolist()
    path.write_text(json.dumps(meta))
    with pytest.warns(UserWarning, match="not a uniformly scaled"):
        RWAVSScene(w.scene_dir)


def tree(root):
    return sorted((str(p.relative_to(root)), p.stat().st_size, p.stat().st_mtime_ns) for p in root.rglob("*"))


def test_reads_only_never_writes_and_never_unpickles(tmp_path):
    w = write_scene(tmp_path, "ro", n_train=4, n_val=2)
    marker = tmp_path / "unpickled"

    class Trap:
        def __reduce__(self):
            return (open, (str(marker), "w"))

    (w.scene_dir / "feats_train.pkl").write_bytes(pickle.dumps(Trap()))
    before = tree(tmp_path)
    scene = RWAVSScene(w.scene_dir)
    scene.dataset("train")
    assert not marker.exists()
    assert tree(tmp_path) == before


# -- bad input: the error names the file and what was expected ----------------------------


@pytest.fixture
def fresh(tmp_path, written):
    """A private copy of the module's scene to break."""
    root = tmp_path / "data"
    shutil.copytree(written.data_root, root)
    return root / written.name


def test_missing_audio_is_named(fresh):
    os.remove(fresh / "binaural_syn_re.wav")
    with pytest.raises(FileNotFoundError, match="binaural_syn_re.wav.*2-channel 22050 Hz"):
        RWAVSScene(fresh)


def test_wrong_sample_rate_is_named(fresh):
    audio, _ = sf.read(fresh / "source_syn_re.wav")
    sf.write(fresh / "source_syn_re.wav", audio, 16000)
    with pytest.raises(ValueError, match=r"source_syn_re.wav: sample rate 16000 Hz, expected 22050 Hz"):
        RWAVSScene(fresh)


def test_wrong_channel_count_is_named(fresh):
    audio, _ = sf.read(fresh / "binaural_syn_re.wav")
    sf.write(fresh / "binaural_syn_re.wav", audio[:, 0], SR)
    with pytest.raises(ValueError, match=r"binaural_syn_re.wav: 1 channel\(s\), expected 2"):
        RWAVSScene(fresh)


def test_nan_in_a_pose_is_named(fresh):
    path = fresh / "transforms_scale_val.json"
    meta = json.loads(path.read_text())
    meta["camera_path"][1]["camera_to_world"][3] = float("nan")
    path.write_text(json.dumps(meta))
    with pytest.raises(ValueError, match=r"transforms_scale_val.json: camera_path\[1\].*NaN"):
        RWAVSScene(fresh)


def test_audio_shorter_than_the_last_frame_is_named(fresh):
    audio, _ = sf.read(fresh / "source_syn_re.wav")
    sf.write(fresh / "source_syn_re.wav", audio[: 10 * SR], SR)
    with pytest.raises(ValueError, match=r"source_syn_re.wav: 10.00 s .* last posed frame \(t = 16 s\)"):
        RWAVSScene(fresh)


def test_missing_transforms_position_and_bad_names_are_named(fresh):
    table = json.loads((fresh.parent / "position.json").read_text())
    (fresh.parent / "position.json").write_text(json.dumps({"other": table[fresh.name]}))
    with pytest.raises(ValueError, match="position.json: no entry for scene 'office_1'"):
        RWAVSScene(fresh)
    os.remove(fresh.parent / "position.json")
    with pytest.raises(FileNotFoundError, match="position.json: missing"):
        RWAVSScene(fresh)
    path = fresh / "transforms_scale_train.json"
    meta = json.loads(path.read_text())
    meta["camera_path"][0]["file_path"] = "frames/cover.png"
    path.write_text(json.dumps(meta))
    with pytest.raises(ValueError, match="transforms_scale_train.json.*'frames/cover.png' is not a numbered frame"):
        RWAVSScene(fresh)
    os.remove(path)
    os.remove(fresh / "transforms_train.json")
    with pytest.raises(FileNotFoundError, match="transforms_scale_train.json: missing"):
        RWAVSScene(fresh)


# -- the tensor view ------------------------------------------------------------------


def test_dataset_holds_the_clips_and_their_stfts(scene):
    ds = scene.dataset("val")
    assert len(ds) == len(scene.val)
    n = dsp.n_frames(SR)
    one = ds[1]
    assert one["mono_stft"].shape == (257, n) and one["mono_stft"].is_complex()
    assert one["binaural_mag"].shape == (2, 257, n) and one["mono_mag"].shape == (257, n)
    clip = scene.val[1]
    torch.testing.assert_close(one["binaural_mag"], dsp.magnitude(torch.from_numpy(clip.binaural)))
    torch.testing.assert_close(one["mono_mag"], dsp.magnitude(torch.from_numpy(clip.mono)))
    torch.testing.assert_close(one["listener"], torch.tensor(clip.listener, dtype=torch.float32))
    assert one["theta"].item() == pytest.approx(direction_to_source(clip.listener, clip.yaw, scene.source), abs=1e-6)
    batch = ds.batch([3, 0])
    assert batch["binaural_mag"].shape == (2, 2, 257, n) and batch["source"].shape == (2, 3)
    torch.testing.assert_close(batch["mono"][1], torch.from_numpy(scene.val[0].mono))
    torch.testing.assert_close(batch["yaw"], torch.tensor([scene.val[3].yaw, scene.val[0].yaw], dtype=torch.float32))
    loader = torch.utils.data.DataLoader(ds, batch_size=2)
    first = next(iter(loader))
    assert first["binaural_mag"].shape == (2, 2, 257, n)


def test_loading_warns_nothing(written):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        RWAVSScene(written.scene_dir)


def _load_script(path: str):
    """A module from ``scripts/<path>`` (the scripts are not a package)."""
    import importlib.util
    from pathlib import Path

    file = Path(__file__).resolve().parents[1] / "scripts" / path
    spec = importlib.util.spec_from_file_location(file.stem, file)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_a_scene_packed_for_the_gpu_machine_reads_as_the_original(tmp_path):
    """scripts/device/prepare.py keeps the RWAVS names with 16-bit FLAC inside: the reader
    takes it by its header, and the clips match the original to 16-bit rounding."""
    prepare = _load_script("device/prepare.py")
    w = write_scene(tmp_path / "data", "office_1", n_train=5, n_val=2, seed=4)
    packed = tmp_path / "gpu" / "data" / "office_1"
    prepare.pack_scene(w.scene_dir, packed, frames=False)
    assert sf.info(str(packed / "binaural_syn_re.wav")).format == "FLAC"
    assert (packed.parent / "position.json").is_file() and not (packed / "frames").exists()
    original, copy = RWAVSScene(w.scene_dir).dataset("train"), RWAVSScene(packed).dataset("train")
    assert torch.equal(original.listener, copy.listener)
    assert torch.allclose(original.binaural, copy.binaural, atol=2.0 / 2**15)
    assert torch.allclose(original.mono, copy.mono, atol=2.0 / 2**15)


def test_a_subset_scene_keeps_the_frame_the_val_poses_and_some_train_poses(tmp_path):
    subset = _load_script("subset_scene.py")
    w = write_scene(tmp_path / "data", "office_1", n_train=9, n_val=3, seed=5)
    out = subset.subset_scene(w.scene_dir, tmp_path / "sparse", poses=4, seed=1)
    full, part = RWAVSScene(w.scene_dir), RWAVSScene(out)
    assert len(part.train) == 4 and len(part.val) == len(full.val) == 3
    a, b = part.frame.to_dict(), full.frame.to_dict()
    assert a.keys() == b.keys() and all(np.allclose(a[k], b[k], rtol=0, atol=1e-9) for k in a)  # same frame
    full_xy = {tuple(np.round(c.listener, 6)) for c in full.train}
    assert {tuple(np.round(c.listener, 6)) for c in part.train} <= full_xy
    assert torch.equal(part.dataset("val").binaural, full.dataset("val").binaural)
    with pytest.raises(ValueError, match="--poses must be in 1..9"):
        subset.subset_scene(w.scene_dir, tmp_path / "bad", poses=10)
