"""The loaders refuse invalid scenes with our own errors, naming the file and the field.

``RWAVSScene`` (with its clips and datasets) and ``load_views`` either load a scene with
all-finite arrays or raise ValueError / FileNotFoundError whose message names the file at
fault (and the field, where there is one): never another exception (OverflowError,
TypeError, IsADirectoryError, RecursionError, UnicodeDecodeError, PIL's errors, ...) and
never a silent load of an invalid scene. Part (a): one explicit case per failure kind;
part (b): a property-based fuzz of a small valid scene (hypothesis).
"""

from __future__ import annotations

import json
import math
import os
import shutil
import struct
import tempfile
import warnings
import zlib
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from avgs.data import files, rwavs
from avgs.data.rwavs import SPLITS, RWAVSScene
from avgs.data.views import load_views
from rwavs_writer import SR, WrittenScene, write_scene

OURS = (ValueError, FileNotFoundError)


def scene_json(w: WrittenScene) -> dict:
    """A scene.json in the generator's form (the parts the loader cross-checks) for ``w``."""
    return {
        "environment": "office",
        "to_normalised": {"center": [float(v) for v in w.center], "scale": float(w.scale)},
        "source": {"position": [float(v) for v in w.source_world], "normalised": [float(v) for v in w.source]},
        "poses": [
            {"frame": p.frame, "position": [round(float(v), 6) for v in p.position], "yaw_deg": round(math.degrees(p.yaw), 6)}
            for p in sorted(w.train + w.val, key=lambda p: p.frame)
        ],
        "rt60": {"broadband_s": 0.4},
    }


F_60 = 2.0 / math.tan(math.radians(30.0))  # the focal length (pixels) of the writer's 60 degree vertical fov, 4 pixels high
INTRINSICS = {"camera_model": "OPENCV", "fl_x": F_60, "fl_y": F_60, "cx": 3.0, "cy": 2.0, "w": 6, "h": 4, "frames": []}


@pytest.fixture(scope="module")
def plain(tmp_path_factory) -> WrittenScene:
    """A small valid scene as real RWAVS ones are: no scene.json, both kinds of transforms file."""
    return write_scene(tmp_path_factory.mktemp("plain"), "office_1", n_train=5, n_val=2, seed=11)


@pytest.fixture(scope="module")
def full(tmp_path_factory) -> WrittenScene:
    """A smaller valid scene with everything the loaders read: scene.json and transforms.json too."""
    w = write_scene(tmp_path_factory.mktemp("full"), "room_1", n_train=3, n_val=1, seed=5)
    (w.scene_dir / "scene.json").write_text(json.dumps(scene_json(w), indent=1))
    (w.scene_dir / "transforms.json").write_text(json.dumps(INTRINSICS))
    return w


def copy_scene(w: WrittenScene, dest: Path) -> Path:
    """A private copy of ``w``'s data root under ``dest``; returns the copy's scene folder."""
    root = dest / f"data_{w.name}"
    shutil.copytree(w.data_root, root)
    return root / w.name


@pytest.fixture
def scene(tmp_path, plain) -> Path:
    return copy_scene(plain, tmp_path)


@pytest.fixture
def scene_meta(tmp_path, full) -> Path:
    return copy_scene(full, tmp_path)


def edit(path: Path, change) -> None:
    """Parse ``path`` as JSON, let ``change(obj)`` edit it in place, write it back."""
    obj = json.loads(path.read_text())
    change(obj)
    path.write_text(json.dumps(obj))


def c2w_of(path: Path, i: int) -> list:
    return json.loads(path.read_text())["camera_path"][i]["camera_to_world"]


def set_c2w(path: Path, i: int, values) -> None:
    def change(meta):
        meta["camera_path"][i]["camera_to_world"] = values

    edit(path, change)


def refused(load, where: Path, *fragments: str, kind=ValueError) -> str:
    """``load(where)`` raises exactly ``kind`` (not a subclass such as UnicodeDecodeError)
    whose message holds every fragment; returns the message."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        with pytest.raises(OURS) as info:
            load(where)
    message = str(info.value)
    assert type(info.value) is kind, f"{type(info.value).__name__}: {message}"
    for fragment in fragments:
        assert fragment in message, f"{fragment!r} not in {message!r}"
    return message


def load_all(scene_dir: Path) -> RWAVSScene:
    """The scene, its clips and both datasets."""
    scene = RWAVSScene(scene_dir)
    for split in SPLITS:
        if scene.clips(split):
            scene.dataset(split)
    return scene


# -- (a) each failure kind, by name ------------------------------------------------------------


def test_the_valid_scenes_load_and_float_rounded_poses_still_do(scene, scene_meta):
    a = load_all(scene)
    assert (len(a.train), len(a.val)) == (5, 2)
    b = load_all(scene_meta)
    assert b.metadata is not None and (len(b.train), len(b.val)) == (3, 1)
    assert len(load_views(scene_meta, "train")) == 3
    # Poses rounded to 6 decimals (as real, float-rounded RWAVS files are) are still rigid and consistent.
    for path in scene.glob("transforms*.json"):
        edit(path, lambda m: [e.update(camera_to_world=[round(v, 6) for v in e["camera_to_world"]]) for e in m["camera_path"]])
    rounded = load_all(scene)
    np.testing.assert_allclose(rounded.train[0].listener, a.train[0].listener, atol=1e-5)


def test_huge_json_integers_are_refused_by_field(scene):
    path = scene / "transforms_scale_train.json"
    set_c2w(path, 0, [10**400] + c2w_of(path, 0)[1:])
    refused(RWAVSScene, scene, "transforms_scale_train.json", "camera_path[0].camera_to_world[0]", "too large")
    table = json.loads((scene.parent / "position.json").read_text())
    table["office_1"]["source_position"][1] = -(10**400)
    (scene.parent / "position.json").write_text(json.dumps(table))
    os.remove(path)
    refused(RWAVSScene, scene, "position.json", "source_position[1]")


def test_a_list_where_a_number_belongs_in_the_normalisation(scene_meta):
    edit(scene_meta / "scene.json", lambda m: m["to_normalised"].update(scale=[0.5]))
    refused(RWAVSScene, scene_meta, "scene.json", "to_normalised", "'scale' must be a number, got a list")
    # load_views reads the map only without the scaled poses
    os.remove(scene_meta / "transforms_scale_train.json")
    refused(lambda d: load_views(d, "train"), scene_meta, "scene.json", "'scale'")


def test_booleans_and_strings_are_not_numbers(scene, scene_meta):
    path = scene / "transforms_scale_val.json"
    m = c2w_of(path, 1)
    set_c2w(path, 1, m[:15] + [True])  # True == 1.0 == the right value: refused as a boolean nonetheless
    refused(RWAVSScene, scene, "transforms_scale_val.json", "camera_path[1].camera_to_world[15]", "boolean")
    set_c2w(path, 1, m[:15] + ["1"])
    refused(RWAVSScene, scene, "transforms_scale_val.json", "camera_path[1].camera_to_world[15]", "string")
    set_c2w(path, 1, m)
    table = json.loads((scene.parent / "position.json").read_text())
    table["office_1"]["source_position"][2] = False
    (scene.parent / "position.json").write_text(json.dumps(table))
    refused(RWAVSScene, scene, "position.json", "source_position[2]", "boolean")
    # views: a fov given as a string, an intrinsic given as a boolean
    edit(scene_meta / "transforms_scale_train.json", lambda m: m["camera_path"][0].update(fov="60"))
    refused(lambda d: load_views(d, "train"), scene_meta, "transforms_scale_train.json", "camera_path[0].fov", "string")
    os.remove(scene_meta / "transforms_scale_train.json")
    edit(scene_meta / "transforms.json", lambda m: m.update(fl_y=True))
    refused(lambda d: load_views(d, "train"), scene_meta, "transforms.json", "fl_y", "boolean")


def test_poses_that_are_not_rigid_are_refused(scene):
    path = scene / "transforms_scale_train.json"
    good = np.array(c2w_of(path, 3)).reshape(4, 4)
    stretched = good.copy()
    stretched[:3, 0] *= 1.1
    set_c2w(path, 3, stretched.reshape(-1).tolist())
    refused(RWAVSScene, scene, "transforms_scale_train.json", "camera_path[3].camera_to_world is not a rigid transform", "not orthonormal")
    set_c2w(path, 3, [0.0] * 16)
    refused(RWAVSScene, scene, "camera_path[3].camera_to_world is not a rigid transform")
    mirrored = good.copy()
    mirrored[:3, 0] *= -1
    set_c2w(path, 3, mirrored.reshape(-1).tolist())
    refused(RWAVSScene, scene, "camera_path[3].camera_to_world is not a rigid transform", "reflection")
    set_c2w(path, 3, good.reshape(-1).tolist())
    unscaled = scene / "transforms_train.json"
    set_c2w(unscaled, 0, np.vstack([np.array(c2w_of(unscaled, 0)).reshape(4, 4)[:3], [0.5, 0, 0, 1]]).reshape(-1).tolist())
    refused(RWAVSScene, scene, "transforms_train.json", "camera_path[0].camera_to_world", "bottom row")


def test_views_refuse_a_non_rigid_pose(scene):
    path = scene / "transforms_scale_train.json"
    set_c2w(path, 2, [0.0] * 16)
    refused(lambda d: load_views(d, "train"), scene, "transforms_scale_train.json", "camera_path[2].camera_to_world is not a rigid transform")


def test_coordinates_beyond_the_limit_are_refused(scene):
    path = scene / "transforms_scale_train.json"
    m = c2w_of(path, 0)
    m[3] = 1e300  # a float32 listener would be inf
    set_c2w(path, 0, m)
    refused(RWAVSScene, scene, "transforms_scale_train.json", "camera_path[0].camera_to_world", "beyond")


def test_nan_or_infinity_anywhere_is_refused(scene_meta):
    edit(scene_meta / "scene.json", lambda m: m["rt60"].update(broadband_s=float("nan")))  # a field the loader never uses
    refused(RWAVSScene, scene_meta, "scene.json", "rt60.broadband_s is NaN")
    edit(scene_meta / "scene.json", lambda m: m["rt60"].update(broadband_s=0.4))
    text = (scene_meta / "transforms_val.json").read_text().replace('"fov": 60.0', '"fov": 1e999', 1)
    (scene_meta / "transforms_val.json").write_text(text)  # overflows to Infinity as it is parsed
    refused(RWAVSScene, scene_meta, "transforms_val.json", "camera_path[0].fov is Infinity")


def test_a_frame_listed_twice_in_a_split_is_refused(scene):
    path = scene / "transforms_scale_train.json"

    def twice(meta):
        again = json.loads(json.dumps(meta["camera_path"][1]))
        again["camera_to_world"][3] += 0.25  # one frame, two poses
        meta["camera_path"].append(again)

    edit(path, twice)
    refused(RWAVSScene, scene, "transforms_scale_train.json", "camera_path[5].file_path", "again", "camera_path[1]")
    refused(lambda d: load_views(d, "train"), scene, "transforms_scale_train.json", "camera_path[5]")
    edit(path, lambda m: m["camera_path"].pop())
    # the same frame under another spelling of its path
    edit(path, lambda m: m["camera_path"].append({**m["camera_path"][1], "file_path": "./frames/" + m["camera_path"][1]["file_path"][7:]}))
    refused(RWAVSScene, scene, "transforms_scale_train.json", "again")


def test_a_key_given_twice_is_refused(scene):
    path = scene / "transforms_scale_val.json"
    text = path.read_text()
    path.write_text(text.replace('"camera_to_world":', '"camera_to_world": [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1], "camera_to_world":', 1))
    refused(RWAVSScene, scene, "transforms_scale_val.json", "'camera_to_world' appears twice")


@pytest.mark.parametrize("bad", ["../00001.png", "frames/../../00001.png", "/tmp/frames/00001.png", "..\\..\\00001.png", "C:/frames/00001.png"])
def test_file_paths_must_stay_inside_the_scene(scene, bad):
    path = scene / "transforms_scale_train.json"
    edit(path, lambda m: m["camera_path"][0].update(file_path=bad))
    refused(RWAVSScene, scene, "transforms_scale_train.json", "camera_path[0]", "leaves the scene folder")
    refused(lambda d: load_views(d, "train"), scene, "transforms_scale_train.json", "leaves the scene folder")


def test_frame_names_must_be_plain_numbers(scene):
    edit(scene / "transforms_scale_train.json", lambda m: m["camera_path"][0].update(file_path="frames/0_001.png"))
    refused(RWAVSScene, scene, "transforms_scale_train.json", "camera_path[0] file_path 'frames/0_001.png' is not a numbered frame")
    edit(scene / "transforms_scale_train.json", lambda m: m["camera_path"][0].update(file_path=1))
    refused(RWAVSScene, scene, "camera_path[0] file_path must be a string")


def test_a_file_path_the_os_refuses_is_no_crash(scene):
    # A path component longer than the OS allows (ENAMETOOLONG): the clip's key frame is then
    # looked up as frames/<its name>, as for any file_path not found as given.
    edit(scene / "transforms_scale_train.json", lambda m: m["camera_path"][0].update(file_path="x/" + "a" * 300 + "/00001.png"))
    loaded = RWAVSScene(scene)
    assert loaded.train[0].frame_path == scene.resolve() / "frames" / "00001.png"
    assert len(load_views(scene, "train")) == 5


def test_train_and_val_must_be_disjoint(scene):
    val = json.loads((scene / "transforms_scale_val.json").read_text())["camera_path"][0]
    val_plain = json.loads((scene / "transforms_val.json").read_text())["camera_path"][0]
    edit(scene / "transforms_scale_train.json", lambda m: m["camera_path"].append(val))
    edit(scene / "transforms_train.json", lambda m: m["camera_path"].append(val_plain))
    frame = int(val["file_path"][7:12])
    refused(RWAVSScene, scene, "transforms_scale_val.json", f"frame {frame} is also a train frame", "disjoint")


def test_scaled_and_unscaled_poses_must_agree(scene):
    path = scene / "transforms_train.json"
    m = c2w_of(path, 2)
    m[7] += 0.3  # 30 cm: no uniform scale + translation (or rotation) explains it
    set_c2w(path, 2, m)
    refused(RWAVSScene, scene, "transforms_scale_train.json", "camera_path[2].camera_to_world", "transforms_train.json", "disagrees")
    m[7] -= 0.3
    turned = np.array(m).reshape(4, 4)
    turned[:3, :3] = turned[:3, :3] @ np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])  # same place, other way
    set_c2w(path, 2, turned.reshape(-1).tolist())
    refused(RWAVSScene, scene, "transforms_scale_train.json", "camera_path[2].camera_to_world", "rotation by")


def test_poses_must_agree_with_scene_json(scene_meta):
    # With scene.json's map, the unscaled poses must map onto the scaled ones through it.
    path = scene_meta / "transforms_val.json"
    m = c2w_of(path, 0)
    m[3] += 0.05
    set_c2w(path, 0, m)
    refused(RWAVSScene, scene_meta, "transforms_scale_val.json", "camera_path[0].camera_to_world", "scene.json's to_normalised")
    m[3] -= 0.05
    set_c2w(path, 0, m)
    load_all(scene_meta)
    # ... and scene.json's own record of the poses and the source must agree with the files.
    edit(scene_meta / "scene.json", lambda s: s["poses"][1].update(yaw_deg=s["poses"][1]["yaw_deg"] + 10.0))
    refused(RWAVSScene, scene_meta, "scene.json", "poses[1] (frame 2)", "yaw by 10")
    edit(scene_meta / "scene.json", lambda s: s["poses"][1].update(yaw_deg=s["poses"][1]["yaw_deg"] - 10.0))
    edit(scene_meta / "scene.json", lambda s: s["source"].update(normalised=[0.0, 0.0, 0.0]))
    refused(RWAVSScene, scene_meta, "scene.json", "source.normalised", "position.json")


def test_position_json_must_agree_with_scene_json(scene_meta):
    table = json.loads((scene_meta.parent / "position.json").read_text())
    table["room_1"]["source_position"][0] += 0.2
    (scene_meta.parent / "position.json").write_text(json.dumps(table))
    refused(RWAVSScene, scene_meta, "scene.json", "position.json", "source_position")


def test_non_utf8_json_is_named(scene_meta):
    for name in ("transforms_scale_train.json", "scene.json"):
        path = scene_meta / name
        original = path.read_bytes()
        path.write_bytes(original.replace(b'"office"', '"b\u00fcro"'.encode("latin-1")) if name == "scene.json" else b"\xff\xfe" + original)
        refused(RWAVSScene, scene_meta, name, "not UTF-8")
        path.write_bytes(original)
    (scene_meta / "transforms.json").write_bytes('{"fl_x": "\u00e9"}'.encode("latin-1"))
    os.remove(scene_meta / "transforms_scale_train.json")
    refused(lambda d: load_views(d, "train"), scene_meta, "transforms.json", "not UTF-8")


def test_deeply_nested_json_is_refused(scene):
    path = scene / "transforms_scale_train.json"
    path.write_text('{"camera_path": ' + "[" * 100_000 + "]" * 100_000 + "}")
    refused(RWAVSScene, scene, "transforms_scale_train.json", "nested too deeply")
    path.write_text('{"camera_path": [{"file_path": "frames/00001.png", "x": ' + "[" * 200 + "]" * 200 + "}]}")
    refused(RWAVSScene, scene, "transforms_scale_train.json", "camera_path[0].x", "nests deeper than")


def test_json_larger_than_the_limit_is_refused(scene):
    path = scene / "transforms_scale_val.json"
    path.write_text(path.read_text() + " " * (files.MAX_JSON_BYTES + 1))
    refused(RWAVSScene, scene, "transforms_scale_val.json", "more than the")


@pytest.mark.parametrize("name", ["transforms_scale_train.json", "scene.json", "../position.json", "binaural_syn_re.wav"])
def test_a_folder_where_a_file_belongs_is_refused(scene_meta, name):
    path = scene_meta / name
    os.remove(path)
    path.mkdir()
    refused(RWAVSScene, scene_meta, path.name, "is a folder")


def test_a_key_frame_that_is_a_folder_is_refused(scene):
    path = scene / "frames" / "00002.png"
    os.remove(path)
    path.mkdir()
    refused(lambda d: load_views(d, "train"), scene, "00002.png", "is a folder")


@pytest.mark.parametrize("name", ["transforms_scale_val.json", "../position.json", "source_syn_re.wav"])
def test_symlink_loops_are_refused(scene, name):
    path = scene / name
    os.remove(path)
    os.symlink(path.name, path)  # a link to itself
    refused(RWAVSScene, scene, path.name, "cannot be opened")


def test_a_scene_folder_in_a_symlink_loop_is_refused(tmp_path):
    loop = tmp_path / "loop"
    os.symlink("loop", loop)
    refused(RWAVSScene, loop, "loop", "cannot resolve")


def write_png_header(path: Path, width: int, height: int) -> None:
    """A PNG whose header declares ``width`` x ``height`` (with valid checksums) and holds one row of data."""

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"\x00" * 64)) + chunk(b"IEND", b""))


def test_decompression_bombs_and_oversized_images_are_refused_before_decoding(scene):
    path = scene / "frames" / "00002.png"
    write_png_header(path, 100_000, 100_000)  # PIL's own decompression-bomb guard fires
    refused(lambda d: load_views(d, "train"), scene, "00002.png", "too large")
    write_png_header(path, 9000, 9000)  # 81 Mpx: under PIL's limit, over ours; refused from the header
    refused(lambda d: load_views(d, "train"), scene, "00002.png", "declares 9000x9000")


def test_wav_sample_rates_outside_the_sane_range_are_refused(scene):
    path = scene / "source_syn_re.wav"
    data = bytearray(path.read_bytes())
    assert data[:4] == b"RIFF" and data[12:16] == b"fmt " and struct.unpack("<I", data[24:28])[0] == SR
    data[24:28] = struct.pack("<I", 1)  # a 1 Hz WAV
    path.write_bytes(bytes(data))
    refused(RWAVSScene, scene, "source_syn_re.wav", "sample rate 1 Hz is outside 8000..192000 Hz")


def test_audio_longer_than_the_cap_is_refused(scene, monkeypatch):
    monkeypatch.setattr(rwavs, "MAX_AUDIO_SECONDS", 5.0)  # the scene holds 7.5 s
    refused(RWAVSScene, scene, "binaural_syn_re.wav", "more than the 5 s")


def test_audio_far_beyond_full_scale_is_refused(scene):
    audio, _ = sf.read(scene / "binaural_syn_re.wav", dtype="float32")
    audio[100, 1] = 1e30
    sf.write(scene / "binaural_syn_re.wav", audio, SR, subtype="FLOAT")
    refused(RWAVSScene, scene, "binaural_syn_re.wav", "magnitude 1e+30")


def test_intrinsics_that_overflow_float32_are_refused(scene_meta):
    edit(scene_meta / "transforms.json", lambda m: m.update(fl_x=1e39))
    refused(lambda d: load_views(d, "train"), scene_meta, "transforms.json", "not finite")


# -- (b) the fuzz: any mutation loads cleanly or is refused by our errors -------------------------

JSON_FILES = (
    "transforms_scale_train.json",
    "transforms_scale_val.json",
    "transforms_train.json",
    "transforms_val.json",
    "scene.json",
    "transforms.json",
    "../position.json",
)
OTHER_FILES = ("source_syn_re.wav", "binaural_syn_re.wav", "frames/00001.png", "frames/00003.png")


def nested(depth: int):
    out: list = [0.5]
    for _ in range(depth):
        out = [out]
    return out


scalars = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(-(2**70), 2**70),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=12),
    st.sampled_from([10**400, -(10**400), 1e308, -1e308, 5e-324, 0, 1, -1, 22050, "1.0", "NaN", "../00001.png", "frames/00002.png"]),
)
json_values = st.one_of(
    scalars,
    st.lists(scalars, max_size=17),
    st.dictionaries(st.sampled_from(["center", "scale", "file_path", "camera_to_world", "fov", "x"]), scalars, max_size=3),
    st.integers(1, 120).map(nested),
)
file_paths = st.sampled_from(
    ["../00001.png", "../../data/00002.png", "/etc/00001.png", "frames", "frames/", ".", "", "frames/00003.png",
     "frames/00002.png", "./frames/00001.png", "frames\\00002.png", "frames/+1.png", "C:\\00001.png", "frames/99999.png",
     "frames/" + "a" * 300 + "/00001.png", "1" + "0" * 400]
)


def json_nodes(obj, path=()):
    """Every (path, value) in a parsed JSON tree, the root included."""
    yield path, obj
    if isinstance(obj, dict):
        for k, v in obj.items():
            yield from json_nodes(v, path + (k,))
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            yield from json_nodes(v, path + (i,))


def get(obj, path):
    for key in path:
        obj = obj[key]
    return obj


def mutate_json(obj, data):
    """One random structural mutation of a parsed JSON tree; returns the new tree."""
    nodes = list(json_nodes(obj))
    kind = data.draw(st.sampled_from(["replace", "replace", "delete", "duplicate", "perturb", "file_path"]))
    if kind == "replace":
        path, _ = data.draw(st.sampled_from(nodes))
        value = data.draw(json_values)
        if not path:
            return value
        get(obj, path[:-1])[path[-1]] = value
    elif kind == "delete":
        paths = [p for p, _ in nodes if p]
        if paths:
            path = data.draw(st.sampled_from(paths))
            del get(obj, path[:-1])[path[-1]]
    elif kind == "duplicate":
        lists = [(p, v) for p, v in nodes if isinstance(v, list) and v]
        if lists:
            _, v = data.draw(st.sampled_from(lists))
            v.insert(data.draw(st.integers(0, len(v))), json.loads(json.dumps(v[data.draw(st.integers(0, len(v) - 1))])))
    elif kind == "perturb":
        numbers = [p for p, v in nodes if isinstance(v, (int, float)) and not isinstance(v, bool) and p and abs(v) < 1e6]
        if numbers:
            path = data.draw(st.sampled_from(numbers))
            factor = data.draw(st.sampled_from([1e-9, 1e-4, 1e-2, 0.3, -1.0, 1e5]))
            get(obj, path[:-1])[path[-1]] = get(obj, path) * (1 + factor) + factor
    elif kind == "file_path":
        entries = [v for _, v in nodes if isinstance(v, dict) and "file_path" in v]
        if entries:
            data.draw(st.sampled_from(entries))["file_path"] = data.draw(file_paths)
    return obj


def mutate_files(scene_dir: Path, data) -> None:
    """One random mutation of the scene on disk."""
    kind = data.draw(st.sampled_from(["json", "json", "json", "json", "bytes", "folder", "loop", "remove", "wav_rate", "png", "move_entry"]))
    if kind in ("json", "bytes", "folder", "loop", "remove"):
        path = scene_dir / data.draw(st.sampled_from(JSON_FILES + (OTHER_FILES if kind in ("folder", "loop", "remove") else ())))
        if not path.is_file() or path.is_symlink():  # an earlier mutation removed or replaced it
            return
        if kind == "json":
            try:
                obj = json.loads(path.read_bytes())
            except (ValueError, RecursionError):  # an earlier mutation broke it already
                return
            path.write_text(json.dumps(mutate_json(obj, data)))
        elif kind == "bytes":
            raw = bytearray(path.read_bytes())
            at = data.draw(st.integers(0, max(len(raw) - 1, 0)))
            how = data.draw(st.sampled_from(["latin1", "truncate", "deep"]))
            if how == "latin1":
                raw[at:at] = b"\xe9\xff"
            elif how == "truncate":
                del raw[at:]
            else:
                raw = bytearray(b'{"camera_path": ' + b"[" * 5000 + b"]" * 5000 + b"}")
            path.write_bytes(bytes(raw))
        elif kind == "folder":
            os.remove(path)
            path.mkdir()
        elif kind == "loop":
            os.remove(path)
            os.symlink(path.name, path)
        else:
            os.remove(path)
    elif kind == "wav_rate":
        path = scene_dir / data.draw(st.sampled_from(OTHER_FILES[:2]))
        if not path.is_file() or path.is_symlink():  # an earlier mutation removed or replaced it
            return
        raw = bytearray(path.read_bytes())
        raw[24:28] = struct.pack("<I", data.draw(st.sampled_from([0, 1, 7999, 16000, 192001, 2**32 - 1]) | st.integers(0, 2**32 - 1)))
        path.write_bytes(bytes(raw))
    elif kind == "png":
        path = scene_dir / "frames" / f"{data.draw(st.integers(1, 4)):05d}.png"
        w, h = data.draw(st.sampled_from([(100_000, 100_000), (20_000, 1), (0, 0), (6, 4), (9000, 9000)]))
        if path.is_file() and not path.is_symlink():
            write_png_header(path, w, h)
    else:  # move_entry: an entry of one split into the other's file
        a, b = data.draw(st.permutations(["transforms_scale_train.json", "transforms_scale_val.json"]))
        try:
            src, dst = json.loads((scene_dir / a).read_bytes()), json.loads((scene_dir / b).read_bytes())
            dst["camera_path"].append(src["camera_path"][0])
        except (OSError, ValueError, RecursionError, LookupError, TypeError, AttributeError):  # broken already
            return
        (scene_dir / b).write_text(json.dumps(dst))


def assert_ours(exc: BaseException, data_root: Path) -> None:
    assert type(exc) in OURS, f"{type(exc).__name__}: {exc}"
    assert str(data_root) in str(exc) or "loop" in str(exc), f"the message names no file: {exc}"


def all_finite(*arrays) -> bool:
    return all(bool(torch.isfinite(torch.as_tensor(np.asarray(a) if not isinstance(a, torch.Tensor) else a)).all()) for a in arrays)


def check_loading(scene_dir: Path, data_root: Path) -> None:
    """Loading either succeeds with all-finite arrays or raises one of our errors naming a file."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        try:
            scene = RWAVSScene(scene_dir)
        except OURS as exc:
            assert_ours(exc, data_root)
        else:
            assert all_finite(scene.source, scene.frame.center, [scene.frame.scale])
            for split in SPLITS:
                clips = scene.clips(split)
                for c in clips:
                    assert all_finite(c.c2w, c.listener, [c.yaw, c.time], c.mono, c.binaural)
                if clips:
                    ds = scene.dataset(split)
                    assert all_finite(ds.listener, ds.yaw, ds.theta, ds.mono, ds.binaural, ds.mono_stft, ds.binaural_mag)
        for split in SPLITS:
            try:
                views = load_views(scene_dir, split)
            except OURS as exc:
                assert_ours(exc, data_root)
            else:
                assert all_finite(views.images, views.c2w, views.K)


@settings(max_examples=100, deadline=None, database=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(data=st.data())
def test_fuzzed_scenes_load_cleanly_or_are_refused_by_our_errors(full, data):
    with tempfile.TemporaryDirectory() as tmp:
        scene_dir = copy_scene(full, Path(tmp))
        for _ in range(data.draw(st.integers(1, 3))):
            mutate_files(scene_dir, data)
        check_loading(scene_dir, scene_dir.parent)
