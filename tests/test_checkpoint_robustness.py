"""Malformed checkpoints: every one gives one line naming the file and the problem and exit
status 2 from the command line (``avgs info``, ``render``, ``prune``, ``eval --method ckpt:X``,
``train --resume``), never a traceback and never PyTorch's advice about ``weights_only``.

A table of corruptions of a valid checkpoint (with a training state) goes through the real
CLI; byte-level damage (truncation, bit flips, other files) too; a hypothesis property test
mutates the checkpoint dict at random and requires :func:`avgs.io.checkpoint.load_checkpoint`
to either refuse it with ValueError or give a checkpoint the renderer turns into finite audio.
"""

from __future__ import annotations

import copy
import io
import math
import os
import pickle
import random
import zipfile
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf
import torch
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st
from rwavs_writer import write_scene

from avgs.acoustics.points import AudioPoints
from avgs.io.checkpoint import (
    FORMAT_VERSION,
    checkpoint_digest,
    load_checkpoint,
    save_checkpoint,
    untrained_checkpoint,
)
from avgs.cli import main as cli_main
from avgs.render.renderer import SceneRenderer
from avgs.train.pipeline import quick_config, train_scene

ITERATIONS = 3


def tiny_config(iterations: int = ITERATIONS):
    cfg = quick_config()
    cfg.acoustic.iterations = iterations
    cfg.acoustic.binauralizer_width, cfg.acoustic.field_width, cfg.acoustic.context_dim = 32, 16, 16
    cfg.points.densify_every = 2
    cfg.checkpoint_every, cfg.eval_every, cfg.log_every = 1, 100, 1
    return cfg


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    """(scene folder, its data root, a valid trained checkpoint dict with a training state, a mono WAV)."""
    root = tmp_path_factory.mktemp("robust")
    scene = write_scene(root, n_train=6, n_val=2, seed=0)
    g = torch.Generator().manual_seed(0)
    points = AudioPoints(torch.rand(80, 3, generator=g) * 2 - 1, torch.randn(80, 52, generator=g))
    out = root / "valid.ckpt"
    train_scene(scene.scene_dir, out, tiny_config(), progress=False, initial_points=points)
    wav = root / "mono.wav"
    sf.write(wav, np.random.default_rng(0).standard_normal(3000).astype(np.float32) * 0.1, 22050, subtype="FLOAT")
    return scene.scene_dir, root, load_checkpoint(out), wav


def commands(world, path: Path, tmp_path: Path, which=("info", "render", "prune", "eval", "resume")) -> dict:
    scene_dir, root, _, wav = world
    argv = {
        "info": ["info", str(path)],
        "render": ["render", str(path), "--listener", "2", "2", "1.6", "--yaw", "30", "--input", str(wav),
                   "--output", str(tmp_path / "out.wav"), "--phase-iterations", "0"],
        "prune": ["prune", str(path), "--out", str(tmp_path / "pruned.ckpt")],
        "eval": ["eval", str(root), "--method", f"ckpt:{path}", "--no-progress"],
        "resume": ["train", str(scene_dir), "--out", str(path), "--resume", "--quick", "--iterations",
                   str(ITERATIONS + 1), "--no-progress"],
    }
    return {name: argv[name] for name in which}


def assert_refused(capsys, argv: list[str], path: Path) -> str:
    """``avgs ARGV`` exits 2 with one line on stderr that names ``path``; returns that line."""
    rc = cli_main(argv)
    captured = capsys.readouterr()
    err = captured.err
    lines = [line for line in err.splitlines() if line.strip()]
    assert rc == 2, f"{argv[0]}: rc {rc}, stderr {err!r}, stdout {captured.out[-300:]!r}"
    assert len(lines) == 1, f"{argv[0]}: {err!r}"
    assert "Traceback" not in err and "weights_only" not in err, err
    assert str(path) in lines[0], f"{argv[0]}: {lines[0]!r} does not name {path}"
    return lines[0]


def test_the_valid_checkpoint_passes_every_command(world, tmp_path, capsys):
    path = save_checkpoint(world[2], tmp_path / "ok.ckpt")
    for name, argv in commands(world, path, tmp_path).items():
        assert cli_main(argv) == 0, f"{name}: {capsys.readouterr().err}"
    capsys.readouterr()


# -- the table ---------------------------------------------------------------------------


def _set(*keys_and_value):
    *keys, value = keys_and_value

    def edit(c):
        node = c
        for k in keys[:-1]:
            node = node[k]
        node[keys[-1]] = value(node[keys[-1]]) if callable(value) else value

    return edit


def _delete(*keys):
    def edit(c):
        node = c
        for k in keys[:-1]:
            node = node[k]
        del node[keys[-1]]

    return edit


def _nan_at(index=0, value=math.nan):
    def fill(t):
        t = t.clone()
        t.view(-1)[index] = value
        return t

    return fill


def _optimizer_entry(c) -> dict:
    return next(iter(c["train_state"]["optimizer"]["state"].values()))


def _wrong_exp_avg(c):
    entry = _optimizer_entry(c)
    entry["exp_avg"] = torch.zeros(*entry["exp_avg"].shape[:-1], entry["exp_avg"].shape[-1] + 1)


def _drop_last_group(c):
    opt = c["train_state"]["optimizer"]
    for pid in opt["param_groups"].pop()["params"]:
        opt["state"].pop(pid, None)


def _stage1_like(c):
    c.clear()
    c.update({"format": "avgs-stage1", "version": 1, "gaussians": {"means": torch.zeros(3, 3)}})


# name -> (edit of the checkpoint dict, a regex the message must match, commands it affects)
ALL = ("info", "render", "prune", "eval", "resume")
CASES = {
    "binauralizer size mismatch": (_set("binauralizer", "mix_mlp.0.weight", torch.zeros(32, 33)), r"mix_mlp\.0\.weight.*shape", ALL),
    "field size mismatch": (_set("field", "mlp.0.weight", torch.zeros(16, 10)), r"field\.mlp\.0\.weight.*shape", ALL),
    "alpha dims do not fit F": (_set("audio_points", "alpha", lambda a: torch.zeros(a.shape[0], a.shape[1] + 2)), r"field\.mlp\.0\.weight", ALL),
    "binauralizer key missing": (_delete("binauralizer", "diff_head.bias"), r"binauralizer.*lacks diff_head\.bias", ALL),
    "binauralizer extra key": (_set("binauralizer", "extra.weight", torch.zeros(2)), r"unexpected extra\.weight", ALL),
    "weight is a string": (_set("binauralizer", "mix_head.bias", "0.5"), r"mix_head\.bias must be a tensor", ALL),
    "integer weights": (_set("binauralizer", "mix_head.bias", torch.ones(1, dtype=torch.int64)), r"mix_head\.bias.*floating", ALL),
    "NaN weight": (_set("binauralizer", "diff_head.bias", _nan_at()), r"binauralizer\.diff_head\.bias holds NaN or Inf", ALL),
    "Inf weight": (_set("field", "mlp.2.weight", _nan_at(5, math.inf)), r"field\.mlp\.2\.weight holds NaN or Inf", ALL),
    "NaN rt60": (_set("binauralizer", "reverb.log_rt60", _nan_at(3)), r"reverb\.log_rt60 holds NaN", ALL),
    "Inf audio point": (_set("audio_points", "X", _nan_at(0, math.inf)), r"audio_points\.X holds NaN or Inf", ALL),
    "NaN alpha": (_set("audio_points", "alpha", _nan_at(7)), r"audio_points\.alpha holds NaN or Inf", ALL),
    "X [N, 2]": (_set("audio_points", "X", lambda x: x[:, :2].clone()), r"audio_points\.X must be a tensor \[\*, 3\]", ALL),
    "X 1-D": (_set("audio_points", "X", lambda x: x.reshape(-1).clone()), r"audio_points\.X", ALL),
    "no audio points": (_set("audio_points", "X", torch.zeros(0, 3)), r"at least one point", ALL),
    "alpha rows differ": (_set("audio_points", "alpha", lambda a: a[:-1].clone()), r"audio_points\.alpha must be a tensor", ALL),
    "audio_points a list": (_set("audio_points", [1, 2]), r"'audio_points' must be a dict", ALL),
    "X missing": (_delete("audio_points", "X"), r"'X' is missing", ALL),
    "sample rate 0": (_set("stft", "sample_rate", 0), r"stft\.sample_rate", ALL),
    "sample rate negative": (_set("stft", "sample_rate", -22050), r"stft\.sample_rate", ALL),
    "sample rate a float": (_set("stft", "sample_rate", 22050.5), r"stft\.sample_rate must be a positive integer", ALL),
    "n_fft 0": (_set("stft", "n_fft", 0), r"stft\.n_fft", ALL),
    "hop above n_fft": (_set("stft", "hop_length", 1024), r"stft\.hop_length", ALL),
    "window above n_fft": (_set("stft", "win_length", 4096), r"stft\.win_length", ALL),
    "hop 0": (_set("stft", "hop_length", 0), r"stft\.hop_length", ALL),
    "stft a string": (_set("stft", "22050"), r"'stft' must be a dict", ALL),
    "config stft sample rate 0": (_set("config", "stft", "sample_rate", 0), r"config\.stft\.sample_rate", ALL),
    "future format version": (_set("format_version", FORMAT_VERSION + 1), r"newer avgs", ALL),
    "format version 0": (_set("format_version", 0), r"format version 0", ALL),
    "format version a string": (_set("format_version", "1"), r"format_version", ALL),
    "no format version": (_delete("format_version"), r"not an AV-GS checkpoint.*format_version", ALL),
    "config missing": (_delete("config"), r"missing config", ALL),
    "binauralizer missing": (_delete("binauralizer"), r"missing binauralizer", ALL),
    "empty dict": (lambda c: c.clear(), r"format_version", ALL),
    "stage-1 file": (_stage1_like, r"not an AV-GS checkpoint", ALL),
    "config a list": (_set("config", [1, 2]), r"bad 'config'", ALL),
    "config a string": (_set("config", "TrainConfig()"), r"bad 'config'", ALL),
    "config section a string": (_set("config", "acoustic", "wide"), r"bad 'config'", ALL),
    "config width a string": (_set("config", "acoustic", "field_width", "64"), r"acoustic\.field_width", ALL),
    "config width absurd": (_set("config", "acoustic", "binauralizer_width", 10**9), r"binauralizer_width must be at most", ALL),
    "config width other": (_set("config", "acoustic", "binauralizer_width", 64), r"query_proj\.weight has shape \(32, 39\).*builds \(64, 39\)", ALL),
    "config layers absurd": (_set("config", "acoustic", "field_layers", 10**7), r"field_layers must be at most", ALL),
    "config rate beyond float": (_set("config", "acoustic", "lr", 10**400), r"acoustic\.lr .*expected a finite number", ALL),
    "config percentile 0": (_set("config", "acoustic", "vicinity_percentile", 0.0), r"vicinity percentile", ALL),
    "config densify_every 0": (_set("config", "points", "densify_every", 0), r"densify_every", ALL),
    "config activation unknown": (_set("config", "acoustic", "mixture_activation", "tanh"), r"mixture_activation", ALL),
    "config tail toggled": (_set("config", "acoustic", "reverb_tail", False), r"unexpected reverb", ALL),
    "frame scale 0": (_set("frame", "scale", 0.0), r"bad 'frame'", ALL),
    "frame center 2 numbers": (_set("frame", "center", [0.0, 1.0]), r"bad 'frame'", ALL),
    "frame a tensor": (_set("frame", torch.zeros(3)), r"bad 'frame'", ALL),
    "source 2 numbers": (_set("source", torch.zeros(2)), r"source must be a tensor \[3\], got shape \(2,\)", ALL),
    "source [3, 1]": (_set("source", lambda s: s.reshape(3, 1).clone()), r"source must be a tensor \[3\], got shape \(3, 1\)", ALL),
    "source [1, 3]": (_set("source", lambda s: s.reshape(1, 3).clone()), r"source must be a tensor \[3\], got shape \(1, 3\)", ALL),
    "frame center [3, 1]": (_set("frame", "center", torch.zeros(3, 1)), r"frame\.center must be a tensor \[3\], got shape \(3, 1\)", ALL),
    "frame center nested": (_set("frame", "center", [[0.0], [1.0], [2.0]]), r"frame\.center must be 3 numbers", ALL),
    "scene identity malformed": (_set("scene", "identity", "md5:00"), r"scene\.identity must be 'sha256:'", ALL),
    "source NaN": (_set("source", _nan_at(1)), r"source holds NaN", ALL),
    "source a list": (_set("source", [1.0, 2.0, 3.0]), r"source must be a tensor", ALL),
    "bounds [3, 3]": (_set("scene", "bounds", torch.zeros(3, 3)), r"scene\.bounds must be a tensor \[2, 3\]", ALL),
    "bounds NaN": (_set("scene", "bounds", _nan_at(2)), r"scene\.bounds holds NaN", ALL),
    "bounds upside down": (_set("scene", "bounds", lambda b: b.flip(0).clone()), r"min corner, max corner", ALL),
    "bounds missing": (_delete("scene", "bounds"), r"'scene' must hold 'bounds'", ALL),
    "scene a string": (_set("scene", "office"), r"'scene' must be a dict", ALL),
    "outline [K, 3, 3]": (_set("scene", "outline", torch.zeros(4, 3, 3)), r"scene\.outline", ALL),
    "scene name a tensor": (_set("scene", "name", torch.zeros(1)), r"scene\.name must be a string", ALL),
    "history a dict": (_set("history", {"a": 1}), r"'history' must be a list", ALL),
    "history with a tensor": (_set("history", lambda h: h + [{"loss": torch.zeros(2)}]), r"history\[\d+\]\.loss", ALL),
    "gaussians without means": (_set("gaussians", {"sh": torch.zeros(2, 16, 3)}), r"'gaussians' must hold at least 'means'", ALL),
    "gaussians means [M, 2]": (_set("gaussians", {"means": torch.zeros(5, 2)}), r"gaussians\.means", ALL),
    "gaussians sh rows differ": (_set("gaussians", {"means": torch.zeros(5, 3), "sh": torch.zeros(4, 16, 3)}), r"gaussians\.sh", ALL),
    "vicinity_k 0": (_set("vicinity_k", 0), r"vicinity_k", ALL),
    "vicinity_k a string": (_set("vicinity_k", "15"), r"vicinity_k", ALL),
    "metrics with a tensor": (_set("metrics", {"val_mag": torch.zeros(3)}), r"'metrics'", ALL),
    "metrics a list": (_set("metrics", [0.1]), r"'metrics' must be a dict", ALL),
    "iteration missing": (_delete("train_state", "iteration"), r"train_state lacks 'iteration'", ALL),
    "iteration negative": (_set("train_state", "iteration", -1), r"train_state\.iteration must be an integer >= 0", ALL),
    "iteration a float": (_set("train_state", "iteration", 2.5), r"train_state\.iteration", ALL),
    "iteration a bool": (_set("train_state", "iteration", True), r"train_state\.iteration", ALL),
    "iteration a tensor": (_set("train_state", "iteration", torch.tensor(2)), r"train_state\.iteration", ALL),
    "train_state a list": (_set("train_state", [1]), r"'train_state' must be a dict", ALL),
    "optimizer missing": (_delete("train_state", "optimizer"), r"train_state lacks 'optimizer'", ALL),
    "optimizer groups missing": (_delete("train_state", "optimizer", "param_groups"), r"optimizer must hold", ALL),
    "optimizer moment NaN": (lambda c: _optimizer_entry(c).update(exp_avg=_nan_at()(_optimizer_entry(c)["exp_avg"])), r"exp_avg holds NaN", ALL),
    "optimizer step negative": (lambda c: _optimizer_entry(c).update(step=torch.tensor(-3.0)), r"step must be a number >= 0", ALL),
    "generator state short": (_set("train_state", "generator", torch.zeros(10, dtype=torch.uint8)), r"train_state\.generator", ALL),
    "torch rng float": (_set("train_state", "torch_rng", lambda t: t.float()), r"train_state\.torch_rng", ALL),
    "grad_sum of another N": (_set("train_state", "manager", "grad_sum", torch.zeros(3)), r"train_state\.manager\.grad_sum", ALL),
    "count alone": (_set("train_state", "manager", "grad_sum", None), r"both 'grad_sum' and 'count'", ALL),
    "numpy rng malformed": (_set("train_state", "numpy_rng", {"keys": torch.zeros(3)}), r"numpy_rng", ALL),
    "python rng malformed": (_set("train_state", "python_rng", "state"), r"python_rng", ALL),
    # Only resuming reads the optimizer state against the model's parameters.
    "optimizer moment of the wrong shape": (_wrong_exp_avg, r"cannot resume.*exp_avg.*shape", ("resume",)),
    "optimizer state of no group": (_set("train_state", "optimizer", "param_groups", lambda g: g[:-1]), r"belongs to no parameter group", ALL),
    "optimizer group missing": (_drop_last_group, r"cannot resume.*parameter groups", ("resume",)),
    "no train state": (_delete("train_state"), r"no training state", ("resume",)),
}


@pytest.mark.parametrize("case", list(CASES))
def test_malformed_checkpoint_is_one_line_and_exit_2(world, tmp_path, capsys, case):
    edit, pattern, affected = CASES[case]
    import re

    ckpt = copy.deepcopy(world[2])
    edit(ckpt)
    path = save_checkpoint(ckpt, tmp_path / "bad.ckpt")
    for name, argv in commands(world, path, tmp_path, affected).items():
        line = assert_refused(capsys, argv, path)
        assert re.search(pattern, line), f"{name}: {line!r} does not match {pattern!r}"
    if affected == ALL:  # the same without a checksum (a file written by an older avgs, or by hand)
        raw = tmp_path / "raw.ckpt"
        torch.save(ckpt, raw)
        with pytest.raises(ValueError, match=re.escape(str(raw))):
            load_checkpoint(raw)
    assert not (tmp_path / "out.wav").exists() and not (tmp_path / "pruned.ckpt").exists()


# -- bytes -------------------------------------------------------------------------------


def _torch_bytes(obj) -> bytes:
    buf = io.BytesIO()
    torch.save(obj, buf)
    return buf.getvalue()


def _zip_bytes() -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as z:
        z.writestr("archive/data.pkl", b"not a pickle")
    return buf.getvalue()


FILES = {
    "empty": lambda valid: b"",
    "text": lambda valid: b"definitely not a checkpoint\n",
    "json": lambda valid: b'{"format_version": 1}',
    "plain pickle of a set": lambda valid: pickle.dumps({1, 2, 3}),
    "torch.save of a list": lambda valid: _torch_bytes([1, 2, 3]),
    "torch.save of a tensor": lambda valid: _torch_bytes(torch.zeros(3)),
    "torch.save of a numpy array": lambda valid: _torch_bytes({"format_version": 1, "x": np.zeros(3)}),
    "another zip": lambda valid: _zip_bytes(),
    "truncated to 1 byte": lambda valid: valid[:1],
    "truncated to 100 bytes": lambda valid: valid[:100],
    "truncated to half": lambda valid: valid[: len(valid) // 2],
    "last byte missing": lambda valid: valid[:-1],
    "end of central directory missing": lambda valid: valid[:-22],
    "checksum mismatch": lambda valid: _torch_bytes(_tampered(valid)),
    "checksum not a string": lambda valid: _torch_bytes({**torch.load(io.BytesIO(valid), weights_only=True), "checksum": 5}),
}


def _tampered(valid: bytes) -> dict:
    """The checkpoint with one weight changed but the checksum it was written with."""
    ckpt = torch.load(io.BytesIO(valid), weights_only=True)
    ckpt["binauralizer"]["mix_head.bias"] = ckpt["binauralizer"]["mix_head.bias"] + 1e-3
    return ckpt


@pytest.fixture(scope="module")
def valid_bytes(world, tmp_path_factory):
    return save_checkpoint(world[2], tmp_path_factory.mktemp("bytes") / "v.ckpt").read_bytes()


@pytest.mark.parametrize("kind", list(FILES))
def test_files_that_are_not_checkpoints(world, valid_bytes, tmp_path, capsys, kind):
    path = tmp_path / "file.ckpt"
    path.write_bytes(FILES[kind](valid_bytes))
    for name, argv in commands(world, path, tmp_path, ("info", "render", "prune", "eval", "resume")).items():
        line = assert_refused(capsys, argv, path)
        assert ("not an AV-GS checkpoint" in line or "damaged checkpoint" in line), f"{name}: {line!r}"


def test_torch_advice_is_not_passed_on(valid_bytes, tmp_path):
    path = tmp_path / "numpy.ckpt"
    path.write_bytes(FILES["torch.save of a numpy array"](valid_bytes))
    with pytest.raises(ValueError) as info:
        load_checkpoint(path)
    message = str(info.value)
    assert message.startswith(f"{path}: not an AV-GS checkpoint (cannot be read as a torch.save file: ")
    assert "\n" not in message and "weights_only" not in message and "trust" not in message
    assert "tensors and plain values" in message


@pytest.mark.parametrize("seed", range(4))
def test_random_truncations_and_bit_flips(world, valid_bytes, tmp_path, capsys, seed):
    """Any truncation is refused; a flipped bit is refused unless it hit bytes that hold none of the
    checkpoint's contents (zip bookkeeping torch.load ignores), in which case the file loads as written."""
    rng = random.Random(seed)
    original = checkpoint_digest(torch.load(io.BytesIO(valid_bytes), weights_only=True))
    path = tmp_path / "damaged.ckpt"
    refused = 0
    for trial in range(12):
        data = bytearray(valid_bytes)
        if trial % 3 == 0:
            data = data[: rng.randrange(len(data))]
        else:
            pos = rng.randrange(len(data))
            data[pos] ^= 1 << rng.randrange(8)
        path.write_bytes(bytes(data))
        for which in ("info", "render"):
            argv = commands(world, path, tmp_path, (which,))[which]
            rc = cli_main(argv)
            captured = capsys.readouterr()
            if rc == 0:
                assert trial % 3 != 0, "a truncated file was accepted"
                # read as load_checkpoint reads it: onto the CPU, so a storage's location record (which a flip
                # can garble, and plain torch.load then fails to parse) is not read
                ckpt = torch.load(path, weights_only=True, map_location="cpu")
                assert checkpoint_digest(ckpt) == original  # nothing the model reads was changed
                continue
            refused += 1
            lines = [line for line in captured.err.splitlines() if line.strip()]
            assert rc == 2 and len(lines) == 1 and str(path) in lines[0], captured.err
            assert "Traceback" not in captured.err and "weights_only" not in captured.err
    assert refused >= 12  # most damage is noticed (the truncations always)


# -- files that cannot be read -------------------------------------------------------------


def test_folders_missing_and_unreadable_files(world, valid_bytes, tmp_path, capsys):
    folder = tmp_path / "folder.ckpt"
    folder.mkdir()
    missing = tmp_path / "missing.ckpt"
    for path in (folder, missing):
        for argv in commands(world, path, tmp_path, ("info", "render", "prune")).values():
            assert_refused(capsys, argv, path)
    if os.geteuid() != 0:  # root reads anything
        locked = tmp_path / "locked.ckpt"
        locked.write_bytes(valid_bytes)
        locked.chmod(0)
        try:
            line = assert_refused(capsys, ["info", str(locked)], locked)
            assert "ermission" in line
        finally:
            locked.chmod(0o644)


def test_older_checkpoints_without_checksum_or_resume_statistics_still_load(world, tmp_path, capsys):
    """Files written before the checksum and the full training state: read, rendered and resumed."""
    ckpt = copy.deepcopy(world[2])
    for key in ("manager", "numpy_rng", "python_rng", "schedule"):
        ckpt["train_state"].pop(key)
    path = tmp_path / "old.ckpt"
    torch.save(ckpt, path)  # no checksum
    assert "checksum" not in load_checkpoint(path)
    for name, argv in commands(world, path, tmp_path, ("info", "render", "resume")).items():
        assert cli_main(argv) == 0, f"{name}: {capsys.readouterr().err}"
    capsys.readouterr()


def test_a_loaded_and_edited_checkpoint_saves_with_a_fresh_checksum(world, tmp_path):
    path = save_checkpoint(world[2], tmp_path / "a.ckpt")
    ckpt = load_checkpoint(path)
    assert "checksum" not in ckpt
    ckpt["scene"]["name"] = "renamed"
    save_checkpoint(ckpt, path)
    assert load_checkpoint(path)["scene"]["name"] == "renamed"
    assert torch.load(path, weights_only=True)["checksum"].startswith("sha256:")


# -- property: any mutation of the dict is refused or renders ------------------------------------------


@pytest.fixture(scope="module")
def small_ckpt(world):
    """A small untrained checkpoint (fast to render) with the trained one's training state."""
    rng = np.random.default_rng(1)
    ckpt = untrained_checkpoint(rng.uniform([0, 0, 0], [6, 4, 3], size=(40, 3)), [4.5, 2.5, 1.2], config=tiny_config())
    state = copy.deepcopy(world[2]["train_state"])
    state["manager"] = {"grad_sum": torch.rand(40), "count": torch.ones(40)}
    ckpt["train_state"] = state
    ckpt["metrics"] = {"val_mag": 0.5}
    ckpt["history"] = [{"stage": "stage2", "iteration": 1, "loss": 0.5}]
    return ckpt


def _leaves(node, prefix=()):
    """Paths to every entry of nested dicts and lists."""
    items = node.items() if isinstance(node, dict) else enumerate(node) if isinstance(node, list) else ()
    for key, value in items:
        yield prefix + (key,)
        if isinstance(value, (dict, list)) and len(prefix) < 6:
            yield from _leaves(value, prefix + (key,))


OTHER_VALUES = [None, 0, -1, 2.5, math.nan, "x", True, [], {}, [1.0, 2.0, 3.0], torch.tensor(1.0),
                torch.zeros(0), torch.ones(3, dtype=torch.int64)]


def _mutate(value, op: str, draw):
    if op == "other type":
        return copy.deepcopy(draw(st.sampled_from(OTHER_VALUES)))
    if not isinstance(value, torch.Tensor):  # a copy: a later mutation must not change OTHER_VALUES itself
        return copy.deepcopy(draw(st.sampled_from(OTHER_VALUES)))
    if op in ("nan", "inf"):
        if not value.is_floating_point() or value.numel() == 0:
            return torch.full((2,), math.nan)
        t = value.clone()
        t.view(-1)[draw(st.integers(0, t.numel() - 1))] = math.nan if op == "nan" else -math.inf
        return t
    if op == "wrong shape":
        shape = list(value.shape) or [1]
        axis = draw(st.integers(0, len(shape) - 1))
        shape[axis] = max(0, shape[axis] + draw(st.sampled_from([-1, 1, 2])))
        if draw(st.booleans()):
            shape = shape + [2]
        return torch.zeros(shape, dtype=value.dtype if value.is_floating_point() else torch.float32)
    if op == "dtype":
        return value.to(draw(st.sampled_from([torch.float64, torch.int32, torch.uint8, torch.bool])))
    return value


@settings(max_examples=100, deadline=None, database=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(st.data())
def test_any_mutation_is_refused_or_renders_finite_audio(small_ckpt, tmp_path_factory, data):
    ckpt = copy.deepcopy(small_ckpt)
    for _ in range(data.draw(st.integers(1, 3), label="mutations")):
        paths = list(_leaves(ckpt))
        if not paths:
            break
        path = data.draw(st.sampled_from(paths), label="path")
        parent = ckpt
        for key in path[:-1]:
            parent = parent[key]
        op = data.draw(st.sampled_from(["delete", "nan", "inf", "wrong shape", "other type", "dtype"]), label="op")
        if op == "delete":
            del parent[path[-1]]
        else:
            parent[path[-1]] = _mutate(parent[path[-1]], op, data.draw)
    file = tmp_path_factory.mktemp("mutated") / "m.ckpt"
    save_checkpoint(ckpt, file)
    try:
        loaded = load_checkpoint(file)
    except ValueError as exc:
        assert str(exc).startswith(f"{file}: ") and "\n" not in str(exc)
        event("refused")
        return
    event("loaded")
    r = SceneRenderer(loaded, path=file)
    centre = r.bounds.mean(axis=0)
    out = r.render(centre, 20.0, np.random.default_rng(0).standard_normal(1500).astype(np.float32))
    assert out.binaural.shape == (2, 1500) and np.all(np.isfinite(out.binaural))


def test_a_large_iteration_count_is_accepted(world, tmp_path, capsys):
    """Only negative or non-integer counters are malformed; a long run's count is not."""
    ckpt = copy.deepcopy(world[2])
    ckpt["train_state"]["iteration"] = 10**9
    path = save_checkpoint(ckpt, tmp_path / "long.ckpt")
    assert cli_main(["info", str(path)]) == 0
    assert "at iteration 1000000000" in capsys.readouterr().out
