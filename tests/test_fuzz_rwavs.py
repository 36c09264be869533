"""A seeded fuzz of the RWAVS loaders over mutations of a scene's index JSONs and WAVs.

Every mutated scene must either load (both loaders: the audio clips and the views of both
splits, all finite) or be refused with our error types (ValueError / FileNotFoundError)
naming a file of the scene: 0 unhandled exceptions. Mutations that make the scene
contradict itself (issue 32, item 3) must not load silently: an error or a warning.
The outcome counts are printed (``pytest -s``) for docs/reliability.md.
"""

from __future__ import annotations

import json
import math
import shutil
import warnings
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf

from avgs.data.rwavs import RWAVSScene
from avgs.data.views import load_views
from rwavs_writer import write_scene

OURS = (ValueError, FileNotFoundError)
CASES = 120
INDEX = ("transforms_scale_train.json", "transforms_scale_val.json", "transforms_train.json", "transforms_val.json")
WAVS = ("binaural_syn_re.wav", "source_syn_re.wav")
F_60 = 2.0 / math.tan(math.radians(30.0))  # the writer's 60 degree vertical fov, 4 pixels high


@pytest.fixture(scope="module")
def base(tmp_path_factory) -> Path:
    """A real-looking scene (no scene.json) with nerfstudio intrinsics: 11 frames, 11.5 s."""
    w = write_scene(tmp_path_factory.mktemp("fuzz_base"), "fuzz_1", n_train=8, n_val=3, seed=21)
    intrinsics = {"camera_model": "OPENCV", "fl_x": F_60, "fl_y": F_60, "cx": 3.0, "cy": 2.0, "w": 6, "h": 4, "frames": []}
    (w.scene_dir / "transforms.json").write_text(json.dumps(intrinsics))
    return w.scene_dir


def _json(path: Path, change) -> bool:
    if not path.is_file():
        return False
    meta = json.loads(path.read_text())
    change(meta)
    path.write_text(json.dumps(meta))
    return True


def _c2w(entry) -> np.ndarray:
    return np.array(entry["camera_to_world"], dtype=np.float64).reshape(4, 4)


def _put(entry, m: np.ndarray) -> None:
    entry["camera_to_world"] = [float(v) for v in m.reshape(-1)]


def _moved(entry, offset) -> None:
    m = _c2w(entry)
    m[:3, 3] += offset
    _put(entry, m)


def _wav(path: Path, change) -> None:
    audio, sr = sf.read(path, dtype="float32", always_2d=True)  # [T, C]
    sf.write(path, change(audio, sr).astype(np.float32), sr, subtype="FLOAT")


def _shift(seconds: float):
    def change(audio, sr):
        k = int(round(seconds * sr))
        return np.concatenate([np.zeros((k, audio.shape[1]), np.float32), audio[:-k]])
    return change


def mutate(scene: Path, rng: np.random.Generator) -> tuple[str, bool]:
    """One random mutation of the scene; (its name, whether it makes the scene contradict itself)."""
    kind = str(rng.choice([
        "file_path_zero", "file_path_other", "translate_one", "translate_all", "swap_poses", "val_dup",
        "drop_entry", "drop_scaled", "drop_unscaled", "source_move", "garbage", "intrinsics",
        "wav_zero", "wav_channel_zero", "wav_delay", "wav_small_delay", "wav_truncate", "wav_gain", "wav_noise",
    ]))
    name = str(rng.choice(INDEX))
    path = scene / name
    if kind == "file_path_zero":  # a scaled entry names frame 0, which the unscaled file does not pose
        _json(scene / "transforms_scale_train.json", lambda m: m["camera_path"][0].update(file_path="frames/00000.png"))
        return kind, True
    if kind == "file_path_other":  # an entry renamed to another (or a missing) frame of its split or beyond
        k = int(rng.integers(0, 40))
        _json(path, lambda m: m["camera_path"][int(rng.integers(len(m["camera_path"])))].update(file_path=f"frames/{k:05d}.png"))
        return kind, False
    if kind == "translate_one":  # one scaled pose moved 3 .. 1e5 normalised units: no copy of its unscaled pose
        d = float(rng.choice([3.0, 40.0, 1e5]))
        _json(scene / "transforms_scale_train.json", lambda m: _moved(m["camera_path"][int(rng.integers(len(m["camera_path"])))], [d, 0, 0]))
        return kind, True
    if kind == "translate_all":  # every pose of one file moved (the other kind of file no longer agrees)
        d = float(rng.choice([0.01, 3.0, 40.0]))
        _json(path, lambda m: [_moved(e, [d, -d, 0]) for e in m["camera_path"]])
        return kind, d >= 3.0
    if kind == "swap_poses":  # the scaled poses shifted one frame on: not a copy of the unscaled ones
        def roll(m):
            mats = [_c2w(e) for e in m["camera_path"]]
            for e, mat in zip(m["camera_path"], mats[1:] + mats[:1]):
                _put(e, mat)
        _json(scene / "transforms_scale_train.json", roll)
        return kind, True
    if kind == "val_dup":  # a validation entry that is a training frame
        first = json.loads((scene / "transforms_scale_train.json").read_text())["camera_path"][0]
        _json(scene / "transforms_scale_val.json", lambda m: m["camera_path"].append(first))
        return kind, True
    if kind == "drop_entry":  # an entry removed from one file only: the two kinds of file pose different frames
        _json(path, lambda m: m["camera_path"].pop(int(rng.integers(len(m["camera_path"])))))
        return kind, True
    if kind == "drop_scaled":  # only unscaled files, nothing to normalise them with
        for split in ("train", "val"):
            (scene / f"transforms_scale_{split}.json").unlink()
        return kind, True
    if kind == "drop_unscaled":  # a scene as some copies are: scaled files only (consistent)
        for split in ("train", "val"):
            (scene / f"transforms_{split}.json").unlink()
        return kind, False
    if kind == "source_move":
        d = float(rng.choice([0.1, 5.0, 1e7]))
        _json(scene.parent / "position.json", lambda m: m[scene.name].update(source_position=[v + d for v in m[scene.name]["source_position"]]))
        return kind, False
    if kind == "garbage":  # a number of an index file replaced by a value of another kind
        value = rng.choice(np.array([None, True, "1.0", [], {}, 1e308, -1, 0, 10**30], dtype=object))
        field = str(rng.choice(["camera_to_world", "file_path", "fov"]))
        _json(path, lambda m: m["camera_path"][int(rng.integers(len(m["camera_path"])))].update({field: value}))
        return kind, False
    if kind == "intrinsics":
        key, factor = str(rng.choice(["fl_x", "fl_y", "cx", "cy", "w"])), float(rng.choice([0.1, 1.05, 1.5, 10.0]))
        _json(scene / "transforms.json", lambda m: m.update({key: m[key] * factor}))
        contradicts = (key in ("fl_x", "fl_y") and factor != 1.05) or (key in ("cx", "cy") and factor == 10.0) or (key == "w" and factor in (0.1, 1.5, 10.0))
        return kind, contradicts
    wav = scene / str(rng.choice(WAVS))
    if kind == "wav_zero":
        _wav(wav, lambda a, sr: np.zeros_like(a))
        return kind, True
    if kind == "wav_channel_zero":
        _wav(scene / WAVS[0], lambda a, sr: a * np.array([[1.0, 0.0]] if rng.random() < 0.5 else [[0.0, 1.0]], np.float32))
        return kind, True
    if kind == "wav_delay":
        _wav(wav, _shift(float(rng.choice([0.5, 0.7]))))
        return kind, True
    if kind == "wav_small_delay":  # within what sound takes to cross a hall: nothing to say
        _wav(wav, _shift(float(rng.choice([0.01, 0.05]))))
        return kind, False
    if kind == "wav_truncate":
        _wav(wav, lambda a, sr: a[: int(rng.integers(0, len(a)))])
        return kind, False
    if kind == "wav_gain":
        _wav(wav, lambda a, sr: a * float(rng.choice([1e-9, 1e-3, 1e4])))
        return kind, False
    _wav(wav, lambda a, sr: rng.standard_normal(a.shape).astype(np.float32) * 0.1)  # wav_noise
    return kind, False


def load(scene: Path) -> tuple[str, list[str]]:
    """``"error"`` / ``"loaded"`` and the warnings raised; unhandled exceptions propagate."""
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        try:
            loaded = RWAVSScene(scene)
            for split in ("train", "val"):
                for c in loaded.clips(split):
                    assert np.all(np.isfinite(c.binaural)) and np.all(np.isfinite(c.listener))
                views = load_views(scene, split)
                assert bool(views.c2w.isfinite().all()) and bool(views.K.isfinite().all())
        except OURS as exc:
            message = str(exc)
            assert "\n" not in message and str(scene.parent) in message, message
            return "error", [str(w.message) for w in seen]
    return "loaded", [str(w.message) for w in seen]


def test_fuzzed_index_files_and_recordings_are_never_unhandled_nor_silent_contradictions(base, tmp_path):
    rng = np.random.default_rng(32)
    outcomes: Counter = Counter()
    silent: list[str] = []
    for case in range(CASES):
        scene = tmp_path / f"c{case}" / base.name
        shutil.copytree(base.parent, scene.parent)
        kinds = [mutate(scene, rng) for _ in range(1 + int(rng.random() < 0.25))]
        outcome, warned = load(scene)  # anything but our errors fails the test here
        outcomes[outcome if outcome == "error" or not warned else "warned"] += 1
        if outcome == "loaded" and not warned and any(contradicts for _, contradicts in kinds):
            silent.append(f"case {case}: {[k for k, _ in kinds]}")
        shutil.rmtree(scene.parent)
    print(f"\nfuzz: {CASES} scenes, {outcomes['error']} refused, {outcomes['warned']} loaded with a warning, "
          f"{outcomes['loaded']} loaded clean, 0 unhandled, {len(silent)} silent contradictions")
    assert not silent, silent
    assert outcomes["error"] and outcomes["warned"] and outcomes["loaded"]  # every outcome is exercised
