"""Scenes whose files contradict each other are refused with one line naming the file and the
value, or loaded with a one-line warning where a real recording could look like that
(issue 32, item 3; avgs/data/consistency.py, avgs/data/recordings.py, avgs/data/pose_files.py).

Each case mutates a real small scene: ``quick_scene`` (``avgs synth --quick``) or one of
tests/rwavs_writer.py (no scene.json, as real RWAVS scenes are). The last tests load every
clean scene our generators write and assert that not one warning is raised.
"""

from __future__ import annotations

import json
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf

from avgs.cli import main
from avgs.data.recordings import MAX_ACOUSTIC_LAG_S
from avgs.data.rwavs import RWAVSScene
from avgs.data.views import load_views
from rwavs_writer import write_scene

SR = 22050


@pytest.fixture(scope="module")
def plain(tmp_path_factory) -> Path:
    """A scene as real RWAVS ones are (no scene.json, no transforms.json), 16.5 s of audio."""
    return write_scene(tmp_path_factory.mktemp("plain"), "office_1", n_train=12, n_val=4, seed=2).scene_dir


def copy_of(scene_dir: Path, tmp_path: Path) -> Path:
    """A private copy of the scene's data root (position.json included); its scene folder."""
    shutil.copytree(scene_dir.parent, tmp_path / "data")
    return tmp_path / "data" / scene_dir.name


def edit(path: Path, change) -> None:
    meta = json.loads(path.read_text())
    change(meta)
    path.write_text(json.dumps(meta))


def poses(meta: dict) -> list[np.ndarray]:
    return [np.array(e["camera_to_world"]).reshape(4, 4) for e in meta["camera_path"]]


def set_poses(meta: dict, mats) -> None:
    for e, m in zip(meta["camera_path"], mats):
        e["camera_to_world"] = [float(v) for v in np.asarray(m).reshape(-1)]


def quiet(load):
    """``load()`` under warnings-as-errors: the clean scenes must not warn at all."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        return load()


def cli_lines(capsys, scene: Path) -> tuple[int, list[str]]:
    """The exit status and stderr lines of ``avgs eval`` of the scene's data root, scoring a
    baseline on it (it opens the scene with the audio loader)."""
    capsys.readouterr()
    rc = main(["eval", str(scene.parent), "--scene", scene.name, "--method", "mono-mono", "--no-progress"])
    return rc, [line for line in capsys.readouterr().err.splitlines() if line.strip()]


# -- the index files -------------------------------------------------------------------


def test_a_scaled_entry_naming_a_frame_the_unscaled_file_does_not_pose_is_refused(quick_scene, tmp_path):
    scene = copy_of(quick_scene, tmp_path)
    edit(scene / "transforms_scale_train.json", lambda m: m["camera_path"][0].update(file_path="frames/00000.png"))
    expected = r"transforms_scale_train.json: camera_path\[0\].camera_to_world poses frame 0, which transforms_train.json does not pose"
    with pytest.raises(ValueError, match=expected):
        RWAVSScene(scene)
    with pytest.raises(ValueError, match=expected):
        load_views(scene, "val")  # the view loader reads every split's files, not only the one asked for


def test_a_frame_named_but_never_written_warns_when_only_the_scaled_files_exist(quick_scene, tmp_path):
    scene = copy_of(quick_scene, tmp_path)
    for split in ("train", "val"):
        (scene / f"transforms_{split}.json").unlink()
    edit(scene / "transforms_scale_train.json", lambda m: m["camera_path"][0].update(file_path="frames/00000.png"))
    with pytest.warns(UserWarning, match=r"camera_path\[0\].file_path names 00000.png, which does not exist, while 19 of the 20 key frames named do \(1 missing\)"):
        RWAVSScene(scene)
    with pytest.raises(FileNotFoundError, match="00000.png: missing"):
        load_views(scene, "train")
    shutil.rmtree(scene / "frames")  # no key frame at all: audio-only data, loaded silently
    assert len(quiet(lambda: RWAVSScene(scene)).train) == 16


def test_unscaled_splits_with_nothing_to_normalise_them_warn(plain, tmp_path, capsys):
    scene = copy_of(plain, tmp_path)
    for split in ("train", "val"):
        (scene / f"transforms_scale_{split}.json").unlink()
    with pytest.warns(UserWarning, match=r"poses read from transforms_train.json, transforms_val.json with no transforms_scale_\*.json .* used unnormalised \(\|coordinate\| up to 5"):
        loaded = RWAVSScene(scene)
    assert loaded.frame.scale == 1.0
    with pytest.warns(UserWarning, match="used unnormalised"):
        load_views(scene, "train")
    rc, lines = cli_lines(capsys, scene)
    assert rc == 0 and len([x for x in lines if "warning:" in x]) == 1, lines


def test_an_identity_normalisation_for_unscaled_poses_is_refused_by_the_source(quick_scene, tmp_path):
    scene = copy_of(quick_scene, tmp_path)
    for split in ("train", "val"):
        (scene / f"transforms_scale_{split}.json").unlink()
    edit(scene / "scene.json", lambda m: m.update(to_normalised={"center": [0.0, 0.0, 0.0], "scale": 1.0}))
    with pytest.raises(ValueError, match=r"scene.json: source.position \(through to_normalised\) is .* normalised units from position.json"):
        with pytest.warns(UserWarning, match="puts the listener at"):
            RWAVSScene(scene)
    with pytest.warns(UserWarning, match=r"transforms_train.json: camera_path\[\d+\].camera_to_world \(frame \d+\) puts the listener at"):
        load_views(scene, "train")  # the view loader reads no source: the poses' reach is what shows


# -- the recordings --------------------------------------------------------------------


@pytest.mark.parametrize("name, channel, expected", [
    ("binaural_syn_re.wav", None, "binaural_syn_re.wav: every sample is silent"),
    ("source_syn_re.wav", None, "source_syn_re.wav: every sample is silent"),
    ("binaural_syn_re.wav", 1, r"binaural_syn_re.wav: channel 1 \(right\) is silent"),
])
def test_an_all_zero_recording_is_refused(quick_scene, tmp_path, capsys, name, channel, expected):
    scene = copy_of(quick_scene, tmp_path)
    audio, sr = sf.read(scene / name, dtype="float32", always_2d=True)
    audio[:, slice(None) if channel is None else channel] = 0.0
    sf.write(scene / name, audio, sr, subtype="FLOAT")
    with pytest.raises(ValueError, match=expected):
        RWAVSScene(scene)
    assert len(RWAVSScene(scene, audio=False).train) == 0  # a task that reads no WAV is not concerned
    rc, lines = cli_lines(capsys, scene)
    assert rc == 2 and len(lines) == 1 and "error:" in lines[0] and name in lines[0], lines


def delayed(path: Path, seconds: float) -> None:
    """The WAV at ``path`` starts ``seconds`` later (zeros in front), its length kept."""
    audio, sr = sf.read(path, dtype="float32", always_2d=True)  # [T, C]
    shift = int(round(seconds * sr))
    sf.write(path, np.concatenate([np.zeros((shift, audio.shape[1]), np.float32), audio[:-shift]]), sr, subtype="FLOAT")


@pytest.mark.parametrize("which", ["quick", "plain"])
@pytest.mark.parametrize("name, other", [("binaural_syn_re.wav", "source_syn_re.wav"), ("source_syn_re.wav", "binaural_syn_re.wav")])
def test_a_recording_delayed_by_half_a_second_warns(quick_scene, plain, tmp_path, capsys, which, name, other):
    scene = copy_of(quick_scene if which == "quick" else plain, tmp_path)
    delayed(scene / name, 0.5)
    with pytest.warns(UserWarning, match=rf"{name}: lags {other} by 0\.(4[6-9]|5[0-4]) s .* expected at most {MAX_ACOUSTIC_LAG_S:g} s") as seen:
        RWAVSScene(scene)
    assert len([w for w in seen if "lags" in str(w.message)]) == 1
    rc, lines = cli_lines(capsys, scene)
    assert rc == 0 and len([x for x in lines if "warning:" in x and "lags" in x]) == 1, lines


def test_a_delay_within_what_sound_takes_to_cross_a_room_is_no_warning(quick_scene, tmp_path):
    scene = copy_of(quick_scene, tmp_path)
    delayed(scene / "binaural_syn_re.wav", 0.1)  # 34 m of travel: a large hall, not a shifted file
    quiet(lambda: RWAVSScene(scene))


# -- the view loader -------------------------------------------------------------------


def test_views_refuse_scaled_poses_translated_away_from_the_unscaled_ones(plain, tmp_path):
    scene = copy_of(plain, tmp_path)
    path = scene / "transforms_scale_train.json"
    edit(path, lambda m: set_poses(m, [_moved(p, 3.0) if i == 0 else p for i, p in enumerate(poses(m))]))
    with pytest.raises(ValueError, match=r"transforms_scale_train.json: camera_path\[0\].camera_to_world \(frame 1\) disagrees with transforms_train.json"):
        load_views(scene, "train")
    edit(path, lambda m: set_poses(m, [_moved(p, 40.0) if i == 0 else p for i, p in enumerate(poses(m))]))
    with pytest.raises(ValueError, match=r"office_1: cannot relate transforms_\*.json to transforms_scale_\*.json: the scaled positions are not a positively scaled copy"):
        load_views(scene, "val")


def _moved(c2w: np.ndarray, dx: float) -> np.ndarray:
    out = c2w.copy()
    out[0, 3] += dx
    return out


def test_views_warn_of_poses_far_outside_the_normalised_frame(plain, tmp_path):
    scene = copy_of(plain, tmp_path)
    for split in ("train", "val"):
        (scene / f"transforms_{split}.json").unlink()
        edit(scene / f"transforms_scale_{split}.json", lambda m: set_poses(m, [_moved(p, 40.0) for p in poses(m)]))
    with pytest.warns(UserWarning, match=r"transforms_scale_(train|val).json: camera_path\[\d+\].camera_to_world \(frame \d+\) puts the listener at \[40.*\(\d+ pose\(s\) beyond 1.5\); expected normalised poses within \[-1, 1\]\^3"):
        load_views(scene, "train")
    with pytest.warns(UserWarning, match="puts the listener at"):
        RWAVSScene(scene)


def test_views_refuse_a_validation_frame_that_is_also_a_training_frame(quick_scene, tmp_path):
    scene = copy_of(quick_scene, tmp_path)
    for kind in ("transforms_scale", "transforms"):
        first = json.loads((scene / f"{kind}_train.json").read_text())["camera_path"][3]
        edit(scene / f"{kind}_val.json", lambda m: m["camera_path"].append(first))
    for split in ("train", "val"):
        with pytest.raises(ValueError, match=r"transforms_scale_val.json: frame 4 is also a train frame \(transforms_scale_train.json\)"):
            load_views(scene, split)


def test_views_refuse_scaled_splits_that_are_no_copy_of_the_unscaled_ones(plain, tmp_path):
    scene = copy_of(plain, tmp_path)
    edit(scene / "transforms_scale_train.json", lambda m: set_poses(m, poses(m)[1:] + poses(m)[:1]))  # each pose moved one frame on
    with pytest.raises(ValueError, match=r"transforms_scale_train.json: camera_path\[\d+\].camera_to_world \(frame \d+\) disagrees with transforms_train.json"):
        load_views(scene, "train")


def _intrinsics(scene: Path, **scaled) -> None:
    edit(scene / "transforms.json", lambda m: m.update({k: m[k] * f for k, f in scaled.items()}))


def test_views_refuse_a_focal_length_ten_times_the_other(quick_scene, tmp_path, capsys):
    scene = copy_of(quick_scene, tmp_path)
    _intrinsics(scene, fl_x=10.0)
    with pytest.raises(ValueError, match=r"transforms.json: fl_x \d+(\.\d+)? and fl_y \d+(\.\d+)? \(in pixels of the 64x48 frames\) make pixels 10 times as wide as high"):
        load_views(scene, "train")


def test_views_warn_of_pixels_not_square_or_a_focal_length_off_the_stated_fov(quick_scene, tmp_path):
    scene = copy_of(quick_scene, tmp_path)
    _intrinsics(scene, fl_x=1.5)
    with pytest.warns(UserWarning, match=r"transforms.json: fl_x .* make pixels 1.5 times as wide as high; expected square pixels"):
        load_views(scene, "train")
    _intrinsics(scene, fl_x=10.0 / 1.5, fl_y=10.0)  # both ten times: square, but not the camera the poses' fov states
    with pytest.warns(UserWarning, match=r"transforms.json: fl_y .* gives a vertical field of view of 8.01 degrees, but transforms_scale_train.json frame 1's fov says 70"):
        load_views(scene, "train")


def test_views_refuse_a_principal_point_outside_the_frame(quick_scene, tmp_path):
    scene = copy_of(quick_scene, tmp_path)
    _intrinsics(scene, cx=10.0)
    with pytest.raises(ValueError, match=r"transforms.json: principal point cx 320, cy 24 .* lies outside the frame"):
        load_views(scene, "val")


# -- clean scenes: not one warning -------------------------------------------------------


def test_every_clean_scene_our_generator_writes_loads_without_a_warning(quick_presets, quick_scene):
    for scene in [quick_scene, *quick_presets.values()]:
        loaded = quiet(lambda: RWAVSScene(scene))
        assert len(loaded.train) > 0 and len(loaded.val) > 0
        for split in ("train", "val"):
            quiet(lambda: load_views(scene, split))


@pytest.mark.parametrize("seed", range(4))
def test_every_clean_scene_the_test_writer_writes_loads_without_a_warning(tmp_path, seed):
    variants = [
        dict(n_train=5, n_val=2),
        dict(n_train=30, n_val=8, first_frame=3, tail_s=0.9),
        dict(n_train=12, n_val=4, unscaled_as_frames=True),
        dict(n_train=12, n_val=4, unscaled=False),
        dict(n_train=9, n_val=3, poseless_frames=(4,), unlisted_frames=(6,)),
    ]
    for i, kw in enumerate(variants):
        scene = write_scene(tmp_path / f"v{i}", f"scene_{i}", seed=seed, **kw).scene_dir
        quiet(lambda: RWAVSScene(scene))
        for split in ("train", "val"):
            quiet(lambda: load_views(scene, split))


DEMO_SCENE = Path(__file__).resolve().parents[1] / "data" / "rir" / "two_rooms"


@pytest.mark.skipif(not DEMO_SCENE.is_dir(), reason="the bundled demo's scene is made by scripts/make_demo.sh")
def test_the_bundled_demo_scene_loads_without_a_warning():
    loaded = quiet(lambda: RWAVSScene(DEMO_SCENE))
    assert len(loaded.train) == 80 and len(loaded.val) == 20
    quiet(lambda: load_views(DEMO_SCENE, "val", downscale=4))
