"""The impulse-response reader under fuzzing, as the binaural one is (tests/test_data_validation.py).

A real ``--quick`` scene (``quick_rir_scene``) is copied and damaged by one to three random
mutations of ``rir/index.json``, ``scene.json``, the transforms files and the response WAVs
(their headers, lengths, sample formats, samples, files removed, added, replaced by folders or
link loops). :class:`RIRScene` must then either refuse the scene with one of its own errors
(ValueError / FileNotFoundError, one line, naming a file of the scene) or load exactly the scene
that was written: the same positions (within the reader's pose tolerance), pairs, orientations,
frame, length and samples. Another exception is an *unhandled* case; a load that differs from
what was written is a *silent* load of a broken scene. Both must stay at 0.
"""

from __future__ import annotations

import json
import os
import shutil
import struct
import tempfile
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.io import wavfile

from avgs.cli import main
from avgs.data.rir import SPLITS, RIRScene, rir_file_name
from avgs.data.rwavs import POSE_TOLERANCE
from test_data_validation import mutate_json

OURS = (ValueError, FileNotFoundError)
JSON_FILES = ("rir/index.json", "rir/index.json", "scene.json", "scene.json", "transforms_scale_train.json", "transforms_train.json")
FIGURES: Counter = Counter()
EXAMPLES = int(os.environ.get("AVGS_RIR_FUZZ_EXAMPLES", "150"))
"Fuzzed scenes per run (about 10 s per 150 on one core); the environment variable runs more."


@pytest.fixture(scope="module")
def reference(quick_rir_scene):
    """(scene folder, the scene as loaded, every split's responses) of the unbroken scene."""
    scene = RIRScene(quick_rir_scene)
    return quick_rir_scene, scene, {k: scene.responses(k) for k in SPLITS}


@pytest.fixture(scope="module", autouse=True)
def figures():
    yield
    if FIGURES:
        print(f"\nRIR fuzz: {FIGURES['tried']} scenes tried, {FIGURES['refused']} refused by our errors, "
              f"{FIGURES['loaded']} loaded unchanged, {FIGURES['unhandled']} unhandled, {FIGURES['silent']} silent")


def copy_scene(scene_dir: Path, dest: Path) -> Path:
    """What RIRScene reads of ``scene_dir`` (rir/, scene.json, the transforms files), copied under ``dest``."""
    out = dest / scene_dir.name
    shutil.copytree(scene_dir / "rir", out / "rir")
    for p in scene_dir.glob("*.json"):
        shutil.copy(p, out / p.name)
    return out


def response_files(scene_dir: Path) -> list[str]:
    return sorted(p.name for p in (scene_dir / "rir").glob("s*.wav"))


def mutate_wav(path: Path, data) -> None:
    """One random damage of a response WAV."""
    try:
        audio, rate = sf.read(str(path), dtype="float32", always_2d=True)  # [L, 2]
    except Exception:  # broken already
        audio, rate = None, None
    how = data.draw(st.sampled_from(["rate", "truncate", "subtype", "longer", "shorter", "channels", "nan", "loud", "bytes"]))
    raw = bytearray(path.read_bytes())
    if how == "rate":
        raw[24:28] = struct.pack("<I", data.draw(st.sampled_from([0, 1, 16000, 44100, 2**32 - 1]) | st.integers(0, 2**32 - 1)))
        path.write_bytes(bytes(raw))
    elif how == "truncate":
        path.write_bytes(bytes(raw[: data.draw(st.integers(0, len(raw) - 1))]))
    elif how == "bytes":
        at = data.draw(st.integers(0, min(35, len(raw) - 1)))  # the RIFF header and fmt chunk, not the samples
        raw[at] = data.draw(st.integers(0, 255))
        path.write_bytes(bytes(raw))
    elif audio is None:
        return
    elif how == "subtype":
        sf.write(str(path), audio, rate, subtype=data.draw(st.sampled_from(["PCM_16", "PCM_24", "PCM_32", "DOUBLE"])))
    elif how in ("longer", "shorter"):
        n = data.draw(st.sampled_from([1, 64, 128, 256]))
        out = np.concatenate([audio, np.zeros((n, audio.shape[1]), np.float32)]) if how == "longer" else audio[:-n]
        wavfile.write(path, rate, np.ascontiguousarray(out))
    elif how == "channels":
        wavfile.write(path, rate, np.ascontiguousarray(np.repeat(audio[:, :1], data.draw(st.sampled_from([1, 3])), axis=1)))
    else:  # a sample NaN / Inf or far beyond full scale
        out = audio.copy()
        out[data.draw(st.integers(0, len(out) - 1)), data.draw(st.integers(0, out.shape[1] - 1))] = (
            data.draw(st.sampled_from([np.nan, np.inf, -np.inf])) if how == "nan" else 1e5)
        wavfile.write(path, rate, out)


def mutate_scene(scene_dir: Path, data) -> None:
    """One random mutation of the scene on disk."""
    kind = data.draw(st.sampled_from(["json", "json", "json", "json", "wav", "wav", "remove", "folder", "loop", "extra"]))
    if kind == "json":
        path = scene_dir / data.draw(st.sampled_from(JSON_FILES))
        if not path.is_file() or path.is_symlink():
            return
        try:
            obj = json.loads(path.read_bytes())
        except (ValueError, RecursionError):
            return
        if path.name == "scene.json" and isinstance(obj, dict) and isinstance(obj.get("rir"), dict) and data.draw(st.booleans()):
            obj["rir"] = mutate_json(obj["rir"], data)  # aim at the section the reader cross-checks
        else:
            obj = mutate_json(obj, data)
        path.write_text(json.dumps(obj))
        return
    names = response_files(scene_dir)
    if not names:
        return
    path = scene_dir / "rir" / data.draw(st.sampled_from(names))
    if not path.is_file() or path.is_symlink():
        return
    if kind == "wav":
        mutate_wav(path, data)
    elif kind == "remove":
        os.remove(path)
    elif kind == "folder":
        os.remove(path)
        path.mkdir()
    elif kind == "loop":
        os.remove(path)
        os.symlink(path.name, path)
    else:  # a response of a pair or orientation the index does not list
        s, r, y = data.draw(st.sampled_from([(0, 0, 45), (2, 3, 315), (999, 9999, 0)]))  # never a listed name
        extra = scene_dir / "rir" / rir_file_name(s, r, y)
        if not extra.exists():
            shutil.copy(path, extra)


def same_scene(scene: RIRScene, ref: RIRScene, responses: dict) -> list[str]:
    """What differs between a loaded scene and the reference (empty when nothing does)."""
    tol = POSE_TOLERANCE * max(1.0, float(np.max(np.abs(ref.sources))), float(np.max(np.abs(ref.receivers))))
    diff = []
    if scene.length != ref.length or scene.sample_rate != ref.sample_rate:
        diff.append("length or rate")
    if not np.array_equal(scene.orientations, ref.orientations):
        diff.append("orientations")
    for k in SPLITS:
        if not np.array_equal(scene.pairs[k], ref.pairs[k]):
            diff.append(f"pairs {k}")
    for name in ("sources", "receivers"):
        a, b = getattr(scene, name), getattr(ref, name)
        if a.shape != b.shape or np.abs(a - b).max() > tol or np.abs(scene.frame.to_world(a) - ref.frame.to_world(b)).max() > tol / ref.frame.scale:
            diff.append(name)
    if diff:
        return diff
    for k in SPLITS:
        got = scene.responses(k).rir
        if not (np.isfinite(got).all() and np.array_equal(got, responses[k].rir)):
            diff.append(f"responses {k}")
    return diff


def check(scene_dir: Path, ref: RIRScene, responses: dict) -> None:
    FIGURES["tried"] += 1
    try:
        scene = RIRScene(scene_dir)
        diff = same_scene(scene, ref, responses)
    except OURS as exc:
        FIGURES["refused"] += 1
        assert "\n" not in str(exc), f"a message of more than one line: {exc!r}"
        assert str(scene_dir) in str(exc), f"the message names no file of the scene: {exc}"
        return
    except Exception as exc:  # noqa: BLE001 (what the fuzz looks for)
        FIGURES["unhandled"] += 1
        raise AssertionError(f"unhandled {type(exc).__name__}: {exc}") from exc
    if diff:
        FIGURES["silent"] += 1
        raise AssertionError(f"a broken scene loaded silently: {', '.join(diff)} differ from what was written")
    FIGURES["loaded"] += 1


@settings(max_examples=EXAMPLES, deadline=None, database=None, derandomize=True,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large, HealthCheck.function_scoped_fixture])
@given(data=st.data())
def fuzz(reference, data):
    """One to three mutations of a copy of the scene, then :func:`check` (EXAMPLES times)."""
    scene_dir, ref, responses = reference
    with tempfile.TemporaryDirectory() as tmp:
        copy = copy_scene(scene_dir, Path(tmp))
        for _ in range(data.draw(st.integers(1, 3))):
            mutate_scene(copy, data)
        check(copy, ref, responses)


def test_fuzzed_rir_scenes_load_unchanged_or_are_refused_by_our_errors(reference):
    """Each fuzzed scene refused in one line or loaded unchanged; and the run's figures: most are
    refused, some load unchanged (harmless mutations). One test, so that a worker of pytest-xdist
    never checks the figures of a fuzz run on another."""
    FIGURES.clear()
    fuzz(reference)
    assert FIGURES["tried"] >= EXAMPLES
    assert FIGURES["unhandled"] == FIGURES["silent"] == 0
    assert FIGURES["refused"] > 0.5 * FIGURES["tried"] and FIGURES["loaded"] > 0


def test_the_cli_refuses_a_broken_rir_scene_in_one_line(quick_rir_scene, tmp_path, capsys):
    scene_dir = copy_scene(quick_rir_scene, tmp_path / "data")
    shutil.copytree(quick_rir_scene / "frames", scene_dir / "frames")
    shutil.copy(quick_rir_scene.parent / "position.json", scene_dir.parent / "position.json")
    victim = scene_dir / "rir" / response_files(scene_dir)[3]
    audio, rate = sf.read(str(victim), dtype="float32")
    sf.write(str(victim), audio, rate, subtype="PCM_16")
    out = tmp_path / "out.ckpt"
    assert main(["train", str(scene_dir), "--task", "rir", "--quick", "--iterations", "2", "--out", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and err.startswith("avgs train: error:") and str(victim) in err and "32-bit float" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["data"]  # nothing written
