"""Exact resume: ``avgs train --resume`` from any saved checkpoint ends bit-identical to a run
that was never interrupted (CPU, fixed seed).

The quick scene trains stage 2 alone (``--init sfm``, no G), with densification every 4
iterations and a checkpoint every 3, so checkpoints fall just before densification steps
(3 before 4, 15 before 16) and in the middle of the gradient statistics a densification
step reads. The fast test resumes, in this process, from checkpoints an uninterrupted run
wrote on its way; the other kills ``avgs train`` subprocesses with SIGKILL (watching the
JSON-lines log) and resumes them with ``--resume`` (about 40 s).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch

from avgs.io.checkpoint import load_checkpoint
from avgs.train import pipeline
from avgs.train.logging import log_paths
from avgs.train.pipeline import quick_config, train_scene

ITERATIONS = 24
DENSIFY_EVERY = 4
CHECKPOINT_EVERY = 3
DENSIFY_UNTIL = 0.75  # densify at 4, 8, 12, 16 (of 24)
FLAGS = [
    "--quick", "--init", "sfm", "--no-gaussians", "--stage1-init-points", "400", "--seed", "0",
    "--iterations", str(ITERATIONS), "--points-densify-every", str(DENSIFY_EVERY),
    "--points-densify-until-fraction", str(DENSIFY_UNTIL), "--points-prune-every", "10",
    "--checkpoint-every", str(CHECKPOINT_EVERY), "--log-every", "1", "--eval-every", "1000", "--no-progress",
]


def config():
    """The configuration FLAGS give (for the in-process runs)."""
    cfg = quick_config()
    cfg.init, cfg.store_gaussians, cfg.seed = "sfm", False, 0
    cfg.gaussians.init_points = 400
    cfg.acoustic.iterations = ITERATIONS
    cfg.points.densify_every, cfg.points.densify_until_fraction, cfg.points.prune_every = DENSIFY_EVERY, DENSIFY_UNTIL, 10
    cfg.checkpoint_every, cfg.log_every, cfg.eval_every = CHECKPOINT_EVERY, 1, 1000
    return cfg


def assert_same_model(a: dict, b: dict) -> None:
    """Audio points, alpha, F and B and the optimizer's moments: bit-identical."""
    assert torch.equal(a["audio_points"]["X"], b["audio_points"]["X"])
    assert torch.equal(a["audio_points"]["alpha"], b["audio_points"]["alpha"])
    for net in ("field", "binauralizer"):
        assert a[net].keys() == b[net].keys()
        for key in a[net]:
            assert torch.equal(a[net][key], b[net][key]), f"{net}.{key}"
    sa, sb = a["train_state"], b["train_state"]
    assert sa["iteration"] == sb["iteration"] == ITERATIONS
    for pid, entry in sa["optimizer"]["state"].items():
        for key, value in entry.items():
            assert torch.equal(value, sb["optimizer"]["state"][pid][key]), f"optimizer {pid} {key}"
    for key in ("grad_sum", "count"):
        x, y = sa["manager"][key], sb["manager"][key]
        assert (x is None and y is None) or torch.equal(x, y)


def no_temporaries(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.startswith("."))


@pytest.fixture(scope="module")
def uninterrupted(quick_scene, tmp_path_factory):
    """An uninterrupted in-process run; returns (final checkpoint, {iteration: bytes of each saved checkpoint})."""
    out = tmp_path_factory.mktemp("full") / "full.ckpt"
    saved: dict[int, bytes] = {}
    save = pipeline.save_checkpoint

    def keep_every_save(ckpt, path):
        written = save(ckpt, path)
        saved[ckpt["train_state"]["iteration"]] = Path(path).read_bytes()
        return written

    pipeline.save_checkpoint = keep_every_save
    try:
        train_scene(quick_scene, out, config(), progress=False)
    finally:
        pipeline.save_checkpoint = save
    return load_checkpoint(out), saved


def test_the_run_densifies_between_its_checkpoints(uninterrupted):
    full, saved = uninterrupted
    assert sorted(saved) == list(range(CHECKPOINT_EVERY, ITERATIONS + 1, CHECKPOINT_EVERY))
    added = {r["iteration"]: r["added"] for r in full["history"] if r.get("stage") == "stage2" and r.get("added")}
    assert {4, 16} <= set(added), added  # points were spawned right after the checkpoints at 3 and 15
    assert full["train_state"]["manager"]["grad_sum"] is not None


@pytest.mark.parametrize("start", [3, 9, 15])
def test_resume_from_a_saved_checkpoint_is_bit_identical(quick_scene, uninterrupted, tmp_path, start):
    """3 and 15: just before a densification step (the statistics of 1-3 and 13-15 decide what
    spawns at 4 and 16); 9: in the middle of the statistics for 12."""
    full, saved = uninterrupted
    out = tmp_path / "resumed.ckpt"
    out.write_bytes(saved[start])
    assert load_checkpoint(out)["train_state"]["iteration"] == start
    train_scene(quick_scene, out, config(), resume=True, progress=False)
    resumed = load_checkpoint(out)
    assert_same_model(resumed, full)
    assert [r["iteration"] for r in resumed["history"] if r.get("stage") == "resume"] == [start]
    assert no_temporaries(tmp_path) == []


def test_train_state_is_plain_and_complete(uninterrupted):
    """Everything the trainer restores is in the file, readable with weights_only=True."""
    _, saved = uninterrupted
    state = load_checkpoint_bytes(saved[3])["train_state"]
    assert {"iteration", "optimizer", "schedule", "generator", "manager_generator", "manager", "torch_rng",
            "numpy_rng", "python_rng"} <= set(state)
    assert state["schedule"]["total"] == ITERATIONS and len(state["schedule"]["base_lrs"]) == 4
    n = state["manager"]["grad_sum"].shape[0]
    assert state["manager"]["count"].shape == (n,) and float(state["manager"]["count"].max()) > 0


def load_checkpoint_bytes(data: bytes) -> dict:
    import io

    return torch.load(io.BytesIO(data), weights_only=True)


# -- killed subprocesses -------------------------------------------------------------------


def _train(scene: Path, out: Path, resume: bool = False) -> subprocess.Popen:
    env = {**os.environ, "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    args = [sys.executable, "-m", "avgs.cli", "train", str(scene), "--out", str(out), *FLAGS]
    return subprocess.Popen(args + (["--resume"] if resume else []), env=env, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE)


def _logged_iteration(log: Path) -> int:
    """The last stage-2 iteration in the JSON-lines log (0 before any)."""
    try:
        lines = log.read_text().splitlines()
    except OSError:
        return 0
    its = [0]
    for line in lines:
        try:
            record = json.loads(line)
        except ValueError:  # a line being written
            continue
        if record.get("stage") == "stage2":
            its.append(int(record["iteration"]))
    return max(its)


def _kill_at(proc: subprocess.Popen, log: Path, iteration: int, timeout: float = 240.0) -> None:
    """SIGKILL ``proc`` once its log shows ``iteration`` (the checkpoints before it are complete:
    an iteration's record is written after the previous iteration's save)."""
    deadline = time.monotonic() + timeout
    while _logged_iteration(log) < iteration:
        if proc.poll() is not None:
            raise AssertionError(f"training ended (rc {proc.returncode}) before iteration {iteration}: "
                                 f"{proc.stderr.read().decode()[-2000:]}")
        if time.monotonic() > deadline:
            proc.kill()
            raise AssertionError(f"no iteration {iteration} in {log} after {timeout} s")
        time.sleep(0.005)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    proc.stderr.close()


def _finish(proc: subprocess.Popen) -> None:
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 0, err.decode()[-2000:]


@pytest.mark.slow  # ~30 s: three training subprocesses; the in-process resumes above are the fast path
def test_killed_runs_resume_bit_identically(quick_scene, tmp_path):
    """An uninterrupted ``avgs train`` subprocess, and one killed twice (just after the checkpoint
    before the densification at 4, and again after the one before 16) and resumed with --resume
    each time: the same points, alpha and F/B weights, bit for bit."""
    ref_out = tmp_path / "ref" / "scene.ckpt"
    ref_out.parent.mkdir()
    _finish(_train(quick_scene, ref_out))
    ref = load_checkpoint(ref_out)

    out = tmp_path / "killed" / "scene.ckpt"
    out.parent.mkdir()
    log, _ = log_paths(out)
    resumed_from = []
    for i, kill_at in enumerate((DENSIFY_EVERY, 4 * DENSIFY_EVERY)):
        _kill_at(_train(quick_scene, out, resume=i > 0), log, kill_at)
        resumed_from.append(load_checkpoint(out)["train_state"]["iteration"])
    _finish(_train(quick_scene, out, resume=True))
    assert resumed_from[0] >= CHECKPOINT_EVERY and resumed_from[0] < resumed_from[1] < ITERATIONS, resumed_from
    final = load_checkpoint(out)
    assert_same_model(final, ref)
    assert [r["iteration"] for r in final["history"] if r.get("stage") == "resume"] == resumed_from
    assert no_temporaries(out.parent) == []  # a save cut short leaves nothing behind once training went on


def test_resume_refuses_a_checkpoint_without_the_tasks_training_state(one_source_ckpt, tmp_path):
    from avgs.io.checkpoint import save_checkpoint, untrained_checkpoint
    from avgs.config import TrainConfig
    from avgs.tasks import IMPULSE_RESPONSE
    from avgs.train.pipeline import resume_from

    bare = tmp_path / "bare.ckpt"
    save_checkpoint(untrained_checkpoint(torch.rand(50, 3) * 2 - 1, torch.zeros(3), seed=0), bare)
    with pytest.raises(ValueError, match="bare.ckpt: holds no training state of the binaural task to resume from"):
        resume_from(bare, TrainConfig(), tmp_path / "log.jsonl")
    with pytest.raises(ValueError, match="holds no training state of the rir task to resume from"):
        resume_from(one_source_ckpt, TrainConfig(), tmp_path / "log.jsonl", task=IMPULSE_RESPONSE)  # a binaural-task run
    resumed, cfg, log, points, _ = resume_from(one_source_ckpt, TrainConfig(), tmp_path / "log.jsonl")
    assert cfg.acoustic.iterations == TrainConfig().acoustic.iterations and points.num_points == len(resumed["audio_points"]["X"])
