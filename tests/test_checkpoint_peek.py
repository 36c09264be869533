"""A checkpoint's plain values without torch (avgs.io.checkpoint_peek), as the sweep's workers read them."""

from __future__ import annotations

import io
import os
import pickle
import subprocess
import sys
import zipfile

import numpy as np
import pytest
import torch

from avgs.io.checkpoint import save_checkpoint, untrained_checkpoint
from avgs.io.checkpoint_peek import OMITTED, peek_checkpoint
from avgs.sweep.state import checkpoint_progress


def _without_tensors(value):
    """``value`` (what torch.load gives) with each tensor replaced as the peek replaces it."""
    if isinstance(value, torch.Tensor):
        return OMITTED
    if isinstance(value, dict):
        return {k: _without_tensors(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return type(value)(_without_tensors(v) for v in value)
    return value


@pytest.fixture()
def trained_ckpt(tmp_path):
    """A real checkpoint as ``avgs train`` writes one: weights, points, config, history, train state."""
    pts = np.random.default_rng(0).uniform([0, 0, 0], [6, 4, 3], size=(50, 3))
    ckpt = untrained_checkpoint(pts, [4.5, 2.5, 1.2])
    ckpt["history"] = [{"stage": "stage2", "iteration": i, "loss": 1.0 / i} for i in (10, 20, 30)]
    ckpt["train_state"] = {"iteration": 30, "optimizer": {"state": {0: {"exp_avg": torch.ones(3)}}, "param_groups": []}}
    return save_checkpoint(ckpt, tmp_path / "scene.ckpt")


def test_the_peek_gives_every_plain_value_torch_load_gives(trained_ckpt):
    peeked = peek_checkpoint(trained_ckpt)
    loaded = torch.load(trained_ckpt, map_location="cpu", weights_only=True)
    assert peeked == _without_tensors(loaded)
    assert peeked["config"] == loaded["config"] and peeked["history"][-1] == {"stage": "stage2", "iteration": 30, "loss": 1 / 30}
    assert peeked["audio_points"]["X"] is OMITTED
    assert checkpoint_progress(trained_ckpt) == (30, False)
    ckpt = torch.load(trained_ckpt, map_location="cpu", weights_only=True)
    ckpt["history"].append({"stage": "final", "iteration": 30})
    assert checkpoint_progress(save_checkpoint(ckpt, trained_ckpt)) == (30, True)


def test_the_sweep_reads_a_run_s_progress_without_importing_torch(trained_ckpt):
    code = ("import sys; from avgs.sweep.state import checkpoint_progress; "
            f"print(checkpoint_progress({str(trained_ckpt)!r}), 'torch' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True).stdout
    assert out.split() == ["(30,", "False)", "False"]


def _archive(path, payload: bytes):
    with zipfile.ZipFile(path, "w") as z:
        z.writestr("scene/data.pkl", payload)
    return path


class _Runs:
    def __init__(self, folder):
        self.folder = folder

    def __reduce__(self):
        return (os.mkdir, (self.folder,))


def test_a_file_that_would_run_code_is_refused_and_runs_nothing(tmp_path):
    made = str(tmp_path / "made_by_the_pickle")
    evil = _archive(tmp_path / "evil.ckpt", pickle.dumps({"history": [], "x": _Runs(made)}))
    with pytest.raises(pickle.UnpicklingError, match="posix.mkdir is not a global a checkpoint holds"):
        peek_checkpoint(evil)
    assert checkpoint_progress(evil) == (0, False)
    assert not os.path.exists(made)


def test_damaged_and_foreign_files_are_not_finished(tmp_path, trained_ckpt):
    data = trained_ckpt.read_bytes()
    cut = tmp_path / "cut.ckpt"
    cut.write_bytes(data[: len(data) // 2])
    legacy = tmp_path / "legacy.ckpt"
    buffer = io.BytesIO()
    torch.save({"history": [{"stage": "final"}]}, buffer, _use_new_zipfile_serialization=False)
    legacy.write_bytes(buffer.getvalue())
    empty = _archive(tmp_path / "empty.ckpt", b"")
    for path in (cut, legacy, empty):
        assert checkpoint_progress(path) == (0, False), path
    assert checkpoint_progress(tmp_path / "none.ckpt") is None
