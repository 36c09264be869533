"""Impulse-response scenes (``avgs synth --task rir``) and their loader (:mod:`avgs.data.rir`).

One ``--quick`` scene is generated per module (3 sources x 4 receivers x 4 orientations,
image sources only) and checked for its layout, its split rules, physics (a response equals
the public ``binaural_rirs`` of its pose moved to time 0 = emission; the direct sound arrives
at distance / c; a near source is louder than a far one) and the loader's refusals.
"""

from __future__ import annotations

import dataclasses
import json
import re
import shutil

import numpy as np
import pytest
import soundfile as sf
from scipy.io import wavfile

from avgs.cli import main
from avgs.data.rir import FORMAT, RIRScene, is_rir_scene, rir_file_name
from avgs.data.rwavs import RWAVSScene
from avgs.synth.grid import GridConfig, make_grid
from avgs.synth.poses import is_walkable
from avgs.synth.presets import RIR_ENVIRONMENTS, RIR_PRESETS, make_spec
from avgs.synth.rir_writer import DEFAULT_GRIDS, RIRConfig, response_length, write_rir_scene
from avgs.synth.simulate import SimSettings, binaural_rirs, load_spec

SR = 22050
SPLITS = ("train", "val", "heldout")


@pytest.fixture(scope="module")
def quick_rir(tmp_path_factory):
    """(scene folder, RIRResult) of a quick rect_small scene."""
    root = tmp_path_factory.mktemp("rir")
    result = write_rir_scene(root, "quick_rect", RIRConfig.quick_config("rect_small", seed=0, workers=1), progress=False)
    return result.scene.scene_dir, result


def _index(scene_dir):
    return json.loads((scene_dir / "rir" / "index.json").read_text())


# -- layout ---------------------------------------------------------------------------------


def test_layout_is_the_documented_one_and_also_an_rwavs_scene(quick_rir):
    scene_dir, result = quick_rir
    index = _index(scene_dir)
    assert set(index) == {"format", "sample_rate", "orientations_deg", "sources", "receivers", "splits"}
    assert index["format"] == FORMAT == "avgs-rir/1" and index["sample_rate"] == SR
    assert index["orientations_deg"] == [0, 90, 180, 270]
    assert (len(index["sources"]), len(index["receivers"])) == (3, 4)
    pairs = [tuple(p) for k in SPLITS for p in index["splits"][k]]
    expected = {rir_file_name(s, r, y) for s, r in pairs for y in index["orientations_deg"]}
    written = {p.name for p in (scene_dir / "rir").iterdir()} - {"index.json"}
    assert written == expected and len(written) == result.responses == 48
    assert all(re.fullmatch(r"s\d{3}_r\d{4}_y\d{3}\.wav", n) for n in written)
    lengths = set()
    for name in sorted(written)[:8]:
        info = sf.info(str(scene_dir / "rir" / name))
        assert (info.samplerate, info.channels, info.subtype) == (SR, 2, "FLOAT")
        lengths.add(info.frames)
    assert lengths == {result.length} and result.length % 128 == 0
    # also an RWAVS scene for source 0: the binaural loader and stage 1 read it unchanged
    rw = RWAVSScene(scene_dir)
    np.testing.assert_allclose(rw.source, index["sources"][0], atol=1e-9)
    assert (len(rw.train), len(rw.val)) == (16, 4) and all(c.frame_path.is_file() for c in rw.train)
    meta = rw.metadata
    assert meta["environment"] == "rectangular" and meta["preset"] == "rect_small"
    assert meta["rir"]["length_samples"] == result.length and meta["rir"]["scale"] == 1.0
    np.testing.assert_allclose(rw.frame.to_normalised(meta["rir"]["sources_world"]), index["sources"], atol=1e-9)


def test_split_rules(quick_rir):
    scene_dir, result = quick_rir
    splits = {k: [tuple(p) for p in v] for k, v in _index(scene_dir)["splits"].items()}
    sets = {k: set(v) for k, v in splits.items()}
    assert all(len(sets[k]) == len(splits[k]) for k in SPLITS)  # no pair twice in a split
    assert not (sets["train"] & sets["val"] or sets["train"] & sets["heldout"] or sets["val"] & sets["heldout"])
    held = {s for s, _ in splits["heldout"]}
    trained = {s for s, _ in splits["train"] + splits["val"]}
    assert held == {1} or held == {2}  # 20 % of 3 sources: one, never source 0
    assert not held & trained and 0 in trained
    assert sets["heldout"] == {(s, r) for s in held for r in range(4)}  # every pair of a held-out source
    assert (len(sets["train"]), len(sets["val"])) == (6, 2)  # 80:20 of the 8 training pairs


def test_default_grids_of_every_preset(tmp_path):
    envs = []
    for preset in RIR_PRESETS:
        spec = make_spec(preset, 0)
        envs.append(spec.environment)
        grid = make_grid(spec, DEFAULT_GRIDS[preset], seed=0)
        walk = dataclasses.replace(spec, source_clearance=0.0)
        assert all(is_walkable(walk, p[:2]) for p in np.concatenate([grid.sources, grid.receivers]))
        assert np.allclose(grid.receivers[:, 2], spec.listener_height) and len(grid.receivers) >= 12
        assert len(grid.sources) >= 3 and len(grid.heldout_sources) >= 1 and 0 not in grid.heldout_sources
        n_train, n_val = len(grid.splits["train"]), len(grid.splits["val"])
        assert n_val == round(0.2 * (n_train + n_val))
        again = make_grid(make_spec(preset, 0), DEFAULT_GRIDS[preset], seed=0)
        assert all(np.array_equal(grid.splits[k], again.splits[k]) for k in SPLITS)
    assert sorted(envs) == sorted(RIR_ENVIRONMENTS * 2)
    other = make_grid(make_spec("u_room", 0), DEFAULT_GRIDS["u_room"], seed=1)
    base = make_grid(make_spec("u_room", 0), DEFAULT_GRIDS["u_room"], seed=0)
    assert not np.array_equal(other.splits["val"], base.splits["val"])  # the split follows the seed


def test_response_length_covers_the_decay_in_whole_hops():
    cfg = RIRConfig()
    n = response_length(0.5, 6.86, cfg, SR)  # 1.2 x 0.5 s + 20 ms
    assert n % 128 == 0 and 0.62 * SR <= n < 0.62 * SR + 128
    capped = response_length(5.0, 1.0, cfg, SR)
    assert capped == 33024 and capped % 128 == 0 and capped <= 1.5 * SR < capped + 128  # capped: whole hops within 1.5 s
    short = dataclasses.replace(cfg, max_seconds=0.25)
    assert response_length(5.0, 1.0, short, SR) == 5504 <= 0.25 * SR  # the --quick cap, never one hop beyond
    assert response_length(0.001, 0.0, cfg, SR) == 2304 >= 0.1 * SR  # the floor, rounded up
    assert response_length(None, 1.0, cfg, SR) == response_length(5.0, 1.0, cfg, SR)


# -- the loader ---------------------------------------------------------------------------


def test_loader_round_trip(quick_rir):
    scene_dir, result = quick_rir
    index = _index(scene_dir)
    scene = RIRScene(scene_dir)
    assert is_rir_scene(scene_dir) and not is_rir_scene(scene_dir / "frames")
    assert (scene.name, scene.sample_rate, scene.length, scene.environment) == ("quick_rect", SR, result.length, "rectangular")
    np.testing.assert_array_equal(scene.orientations, [0, 90, 180, 270])
    np.testing.assert_allclose(scene.sources, index["sources"])
    np.testing.assert_allclose(scene.frame.to_world(scene.receivers), result.grid.receivers, atol=1e-9)
    for split in SPLITS:
        rs = scene.responses(split)
        pairs = index["splits"][split]
        assert len(rs) == 4 * len(pairs) and rs.rir.shape == (len(rs), 2, result.length) and rs.rir.dtype == np.float32
        assert rs.source.shape == rs.receiver.shape == (len(rs), 3) and rs.yaw.dtype == np.float64
        for i in (0, len(rs) - 1):
            s, r, y = int(rs.source_index[i]), int(rs.receiver_index[i]), int(rs.yaw[i])
            assert [s, r] == pairs[i // 4] and y == [0, 90, 180, 270][i % 4]
            _, data = wavfile.read(scene_dir / "rir" / rir_file_name(s, r, y))
            np.testing.assert_array_equal(rs.rir[i], data.T)
            np.testing.assert_allclose(rs.source[i], index["sources"][s])
        assert scene.responses(split) is rs  # cached


# -- physics ----------------------------------------------------------------------------------


def test_a_response_is_the_poses_binaural_rir_from_emission(quick_rir):
    scene_dir, result = quick_rir
    scene = RIRScene(scene_dir)
    meta = scene.metadata["rir"]
    spec, settings = load_spec(scene_dir), SimSettings.from_dict(meta["simulation"])
    rs = scene.responses("val")
    for i in (0, 5):
        s, r, y = int(rs.source_index[i]), int(rs.receiver_index[i]), float(rs.yaw[i])
        one = dataclasses.replace(spec, source=meta["sources_world"][s])
        h = binaural_rirs(one, np.array(meta["receivers_world"][r]), y, settings)  # [2, n], from its own time 0
        expected = np.zeros((2, scene.length), dtype=np.float32)
        part = h[:, meta["removed_delay_samples"] :][:, : scene.length]
        expected[:, : part.shape[-1]] = part
        np.testing.assert_allclose(rs.rir[i], expected, atol=1e-6)


def _world(scene, rs):
    src, rec = scene.frame.to_world(rs.source), scene.frame.to_world(rs.receiver)  # [N, 3]
    distance = np.linalg.norm(src - rec, axis=-1)
    bearing = np.degrees(np.arctan2(src[:, 1] - rec[:, 1], src[:, 0] - rec[:, 0]))
    off_axis = (bearing - rs.yaw + 180.0) % 360.0 - 180.0  # where the source is, from the facing
    return distance, off_axis


def test_direct_sound_arrives_at_distance_over_c(quick_rir):
    scene_dir, _ = quick_rir
    scene = RIRScene(scene_dir)
    c = scene.metadata["rir"]["speed_of_sound"]
    checked = 0
    for split in SPLITS:
        rs = scene.responses(split)
        distance, off_axis = _world(scene, rs)
        arrival = distance / c * SR  # [N] samples after emission
        for h, t, a in zip(rs.rir, arrival, off_axis):
            early = np.sum(h[:, : max(0, int(t) - 16)] ** 2) / np.sum(h**2)
            assert early < 0.01  # nothing before the direct sound (beyond filter and interaural spread)
            if abs(a) <= 30:  # the source roughly ahead: both ears' direct sound peaks together, at t
                both = np.abs(h).sum(0)  # [L]
                lo = int(t) - 12
                window = both[lo : int(t) + 13]
                assert abs(lo + int(np.argmax(window)) - t) <= 3
                assert window.max() >= 0.2 * both.max()  # the direct sound, not a ripple (a reflection may be louder)
                checked += 1
    assert checked >= 4


def test_a_near_source_is_louder_than_a_far_one(quick_rir):
    scene_dir, _ = quick_rir
    scene = RIRScene(scene_dir)
    rs = {k: scene.responses(k) for k in SPLITS}
    rir = np.concatenate([rs[k].rir for k in SPLITS])
    rec = np.concatenate([rs[k].receiver_index for k in SPLITS])
    yaw = np.concatenate([rs[k].yaw for k in SPLITS])
    distance = np.concatenate([_world(scene, rs[k])[0] for k in SPLITS])
    energy = np.sum(rir.astype(np.float64) ** 2, axis=(1, 2))
    compared = 0
    for r in np.unique(rec):
        for y in np.unique(yaw):
            idx = np.flatnonzero((rec == r) & (yaw == y))
            near, far = idx[np.argmin(distance[idx])], idx[np.argmax(distance[idx])]
            if distance[far] - distance[near] >= 1.0:
                assert energy[near] > 1.2 * energy[far]
                compared += 1
    assert compared >= 8


# -- determinism -----------------------------------------------------------------------------


def _small(seed: int, workers: int) -> RIRConfig:
    cfg = RIRConfig.quick_config("l_room", seed=seed, workers=workers, grid=GridConfig(max_sources=2, max_receivers=2))
    cfg.binaural = dataclasses.replace(cfg.binaural, poses=3, width=16, height=12)
    return cfg


def test_same_seed_same_bytes_whatever_the_workers(tmp_path):
    a = write_rir_scene(tmp_path / "a", "s", _small(5, 1), progress=False).scene.scene_dir
    b = write_rir_scene(tmp_path / "b", "s", _small(5, 2), progress=False).scene.scene_dir
    names = sorted(p.name for p in (a / "rir").iterdir())
    assert names == sorted(p.name for p in (b / "rir").iterdir()) and len(names) > 8
    assert all((a / "rir" / n).read_bytes() == (b / "rir" / n).read_bytes() for n in names)
    assert (a / "scene.json").read_bytes() == (b / "scene.json").read_bytes()
    c = write_rir_scene(tmp_path / "c", "s", _small(6, 1), progress=False).scene.scene_dir
    assert (c / "rir" / "index.json").read_bytes() != (a / "rir" / "index.json").read_bytes()


# -- refusals ----------------------------------------------------------------------------------


@pytest.fixture
def scene_copy(quick_rir, tmp_path):
    """A copy of the quick scene (and its position.json) to damage."""
    scene_dir, _ = quick_rir
    shutil.copy(scene_dir.parent / "position.json", tmp_path / "position.json")
    return shutil.copytree(scene_dir, tmp_path / scene_dir.name)


def _edit_index(scene_dir, edit):
    path = scene_dir / "rir" / "index.json"
    index = json.loads(path.read_text())
    edit(index)
    path.write_text(json.dumps(index))
    return path


@pytest.mark.parametrize(
    "edit, message",
    [
        (lambda i: i.update(format="avgs-rir/2"), r"format must be 'avgs-rir/1'"),
        (lambda i: i.update(sample_rate="22050"), r"sample_rate must be an integer"),
        (lambda i: i.update(sample_rate=44100), r"sample_rate 44100 Hz, expected 22050"),
        (lambda i: i.update(orientations_deg=[0, 90, 90, 270]), r"orientations_deg lists an orientation twice"),
        (lambda i: i.update(orientations_deg=[0, 90.5]), r"orientations_deg\[1\] must be an integer"),
        (lambda i: i["sources"].__setitem__(0, [0.1, "x", 0.2]), r"sources\[0\]\[1\] must be a number"),
        (lambda i: i.pop("receivers"), r"'receivers' missing"),
        (lambda i: i["splits"]["val"].append([99, 0]), r"splits\.val\[\d+\]: source index 99 out of range"),
        (lambda i: i["splits"]["train"].append([0, 4]), r"receiver index 4 out of range"),
        (lambda i: i["splits"]["val"].append(i["splits"]["train"][0]), r"is listed again \(already in train\)"),
        (lambda i: i["splits"]["train"].append(i["splits"]["heldout"].pop()), r"heldout: source \d+ also appears in a train or val pair"),
        (lambda i: i["splits"].update(test=[]), r"unknown split"),
        (lambda i: i["splits"].update(train=[]), r"train is empty"),
    ],
)
def test_bad_index_is_refused_naming_the_file_and_field(scene_copy, edit, message):
    path = _edit_index(scene_copy, edit)
    with pytest.raises(ValueError, match=message) as err:
        RIRScene(scene_copy)
    assert str(path) in str(err.value)


def test_repeated_key_and_nan_in_index_are_refused(scene_copy):
    path = scene_copy / "rir" / "index.json"
    text = path.read_text()
    path.write_text(text.replace('"format": "avgs-rir/1"', '"format": "avgs-rir/1", "format": "avgs-rir/1"', 1))
    with pytest.raises(ValueError, match=r"index\.json: key 'format' appears twice"):
        RIRScene(scene_copy)
    index = json.loads(text)
    path.write_text(json.dumps(index).replace(str(index["sources"][0][0]), "NaN", 1))
    with pytest.raises(ValueError, match=r"index\.json: sources\[0\]\[0\] is NaN"):
        RIRScene(scene_copy)


def test_missing_or_damaged_wavs_are_refused_by_name(scene_copy):
    index = _index(scene_copy)
    s, r = index["splits"]["heldout"][0]
    victim = scene_copy / "rir" / rir_file_name(s, r, 180)
    data = sf.read(str(victim), dtype="float32")[0]  # [L, 2]
    victim.unlink()
    with pytest.raises(FileNotFoundError, match=re.escape(f"{victim}: missing")):
        RIRScene(scene_copy)
    wavfile.write(victim, SR, np.concatenate([data, np.zeros((128, 2), np.float32)]))
    with pytest.raises(ValueError, match=re.escape(f"{victim}: {len(data) + 128} samples, expected {len(data)}") + r".* same length"):
        RIRScene(scene_copy)
    wavfile.write(victim, SR, np.ascontiguousarray(data[:, :1]))
    with pytest.raises(ValueError, match=re.escape(f"{victim}: 1 channel(s), expected 2")):
        RIRScene(scene_copy)
    wavfile.write(victim, 44100, data)
    with pytest.raises(ValueError, match=re.escape(f"{victim}: sample rate 44100 Hz, expected 22050")):
        RIRScene(scene_copy)
    bad = data.copy()
    bad[10, 1] = np.nan
    wavfile.write(victim, SR, bad)
    scene = RIRScene(scene_copy)  # headers are fine: the samples are checked when the split is read
    scene.responses("train")
    with pytest.raises(ValueError, match=re.escape(f"{victim}: holds NaN or Inf samples")):
        scene.responses("heldout")


def test_cli_task_and_preset_must_agree(tmp_path, capsys):
    assert main(["synth", str(tmp_path), "--task", "rir", "--preset", "office", "--quick"]) == 2
    err = capsys.readouterr().err
    assert "'office'" in err and "--task binaural" in err and "rect_small" in err
    assert main(["synth", str(tmp_path), "--preset", "office", "--receiver-spacing", "1", "--quick"]) == 2
    assert "--task rir only" in capsys.readouterr().err
    assert not any(tmp_path.iterdir())
    # an impulse-response preset's room also makes an ordinary binaural scene
    argv = ["synth", str(tmp_path), "--preset", "two_rooms", "--quick", "--poses", "2", "--width", "16", "--height", "12", "--workers", "1", "--no-progress"]
    assert main(argv) == 0
    scene = RWAVSScene(tmp_path / "two_rooms_0")
    assert scene.metadata["environment"] == "multi-room" and not is_rir_scene(scene.root)


def test_responses_no_sound_reaches_are_counted_and_said(tmp_path, capsys):
    """--quick has no ray tracing: a receiver two rooms from a source that no image source reaches gets a
    silent response (once a phantom direct sound: avgs.synth.simulate.compute_rir); the CLI says how many,
    and scene.json keeps the count, which equals the all-zero files written."""
    argv = ["synth", str(tmp_path), "--task", "rir", "--preset", "three_rooms", "--quick", "--workers", "1", "--no-progress"]
    assert main(argv) == 0
    out = capsys.readouterr().out
    scene = tmp_path / "three_rooms_0"
    meta = json.loads((scene / "scene.json").read_text())["rir"]
    zero = sum(not np.any(wavfile.read(f)[1]) for f in sorted((scene / "rir").glob("*.wav")))
    assert meta["silent"] == zero > 0
    assert f"note: {zero} of " in out and "hold no sound" in out


def _edit_meta(scene_dir, edit):
    path = scene_dir / "scene.json"
    meta = json.loads(path.read_text())
    edit(meta["rir"])
    path.write_text(json.dumps(meta))
    return path


def test_source_0_is_never_held_out(scene_copy):
    def hold_source_0(i):
        s = i["splits"]
        s["heldout"] += [p for k in ("train", "val") for p in s[k] if p[0] == 0]
        for k in ("train", "val"):
            s[k] = [p for p in s[k] if p[0] != 0]
    path = _edit_index(scene_copy, hold_source_0)
    with pytest.raises(ValueError, match=r"splits\.heldout holds source 0, the RWAVS part's source") as err:
        RIRScene(scene_copy)
    assert str(path) in str(err.value)


@pytest.mark.parametrize(
    "edit, message",
    [
        (lambda r: r.update(length_samples=r["length_samples"] + 128), r"expected \d+ \(as scene\.json's rir\.length_samples\)"),
        (lambda r: r.update(length_samples=r["length_samples"] + 1), r"rir\.length_samples is \d+; expected whole 128-sample hops"),
        (lambda r: r.update(length_samples=33152), r"rir\.length_samples is 33152; .*at most 1\.5 s"),
        (lambda r: r["counts"].update(val=r["counts"]["val"] + 1), r"rir\.counts\.val is \d+; index\.json lists \d+ val pairs"),
        (lambda r: r.update(heldout_sources=[2 if r["heldout_sources"] == [1] else 1]), r"rir\.heldout_sources is \[\d\]; index\.json's held-out pairs have sources \[\d\]"),
        (lambda r: r["receivers_world"][2].__setitem__(0, r["receivers_world"][2][0] + 0.5), r"rir\.receivers_world\[2\] is 0\.2\d+ normalised units from index\.json's"),
        (lambda r: r["sources_world"].pop(), r"rir\.sources_world must list 3 \[x, y, z\]"),
        (lambda r: r.update(counts="all"), r"rir\.counts\.train is null"),
    ],
)
def test_scene_json_must_agree_with_the_index(scene_copy, edit, message):
    path = _edit_meta(scene_copy, edit)
    with pytest.raises(ValueError, match=message) as err:
        RIRScene(scene_copy)
    assert "\n" not in str(err.value) and (str(path) in str(err.value) or str(scene_copy / "rir") in str(err.value))


def test_wavs_must_be_float32_whole_hops_within_the_cap(scene_copy):
    index = _index(scene_copy)
    s, r = index["splits"]["val"][0]
    victim = scene_copy / "rir" / rir_file_name(s, r, 90)
    data = sf.read(str(victim), dtype="float32")[0]  # [L, 2]
    for subtype in ("PCM_16", "DOUBLE"):
        sf.write(str(victim), data, SR, subtype=subtype)
        with pytest.raises(ValueError, match=re.escape(f"{victim}: WAV of {subtype} samples, expected a WAV of 32-bit float")):
            RIRScene(scene_copy)
    sf.write(str(victim), data, SR, format="AIFF", subtype="FLOAT")
    with pytest.raises(ValueError, match=re.escape(f"{victim}: AIFF of FLOAT samples")):
        RIRScene(scene_copy)
    wavfile.write(victim, SR, np.concatenate([data, np.zeros((64, 2), np.float32)]))
    with pytest.raises(ValueError, match=re.escape(f"{victim}: {len(data) + 64} samples; expected whole 128-sample hops")):
        RIRScene(scene_copy)
    wavfile.write(victim, SR, np.zeros((33024 + 128, 2), np.float32))
    with pytest.raises(ValueError, match=re.escape(f"{victim}: 33152 samples; expected whole 128-sample hops, 128 .. 33024 (at most 1.5 s)")):
        RIRScene(scene_copy)
    wavfile.write(victim, SR, data)
    assert RIRScene(scene_copy).length == len(data)  # restored: loads again


def test_rows_read_on_demand_equal_the_whole_split(quick_rir):
    scene = RIRScene(quick_rir[0])
    whole, rows = scene.responses("val"), scene.index("val")
    assert len(rows) == len(whole) == 8
    for k in ("source", "receiver", "yaw", "source_index", "receiver_index"):
        np.testing.assert_array_equal(getattr(rows, k), getattr(whole, k))
    pick = [5, 0, 5, 3]
    np.testing.assert_array_equal(scene.read("val", pick), whole.rir[pick])
    assert scene.read("val", []).shape == (0, 2, scene.length)
