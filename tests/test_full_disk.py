"""A write that fails (a full disk, a file size limit) is one line naming the file, exit status 2,
and leaves nothing behind: no temporary, no half file, no log of a run that saved nothing.

The real CLI runs in a subprocess whose file size limit (``RLIMIT_FSIZE``, SIGXFSZ ignored) makes
writes past it fail with EFBIG, the way a full disk makes them fail with ENOSPC; and, where this
process may mount one, onto a small tmpfs that really fills up.
"""

from __future__ import annotations

import os
import pickle
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf
import torch

from avgs.io.checkpoint import save_checkpoint, untrained_checkpoint

REPO = Path(__file__).resolve().parents[1]
LIMITED = textwrap.dedent("""
    import resource, signal, sys
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    limit = int(sys.argv[1])
    if limit >= 0:
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
    from avgs.cli import main
    sys.exit(main(sys.argv[2:]))
""")


def avgs(argv: list, limit: int = -1, timeout: float = 300) -> tuple[int, str]:
    """``avgs ARGV`` in a subprocess, files limited to ``limit`` bytes (-1: no limit); (status, stderr)."""
    env = dict(os.environ, OMP_NUM_THREADS="1", PYTHONDONTWRITEBYTECODE="1")
    proc = subprocess.run([sys.executable, "-c", LIMITED, str(limit), *map(str, argv)], cwd=REPO, env=env,
                          capture_output=True, text=True, timeout=timeout)
    return proc.returncode, proc.stderr


def assert_one_line(status: int, err: str, command: str, path: Path) -> str:
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert status == 2, err
    assert len(lines) == 1 and "Traceback" not in err, err
    line = lines[0]
    assert line.startswith(f"avgs {command}: error: cannot write {path}"), line
    return line


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    """(a checkpoint, a 20 s mono WAV) in a folder of their own."""
    d = tmp_path_factory.mktemp("full_disk_inputs")
    rng = np.random.default_rng(0)
    ckpt = save_checkpoint(untrained_checkpoint(rng.uniform(0, 4, (300, 3)), [2.0, 2.0, 1.0]), d / "scene.ckpt")
    wav = d / "long.wav"
    sf.write(wav, (0.1 * rng.standard_normal(20 * 22050)).astype(np.float32), 22050, subtype="FLOAT")
    return ckpt, wav


def render_argv(ckpt, wav, output) -> list:
    return ["render", ckpt, "--listener", "1", "1", "1", "--yaw", "0", "--input", wav, "--output", output,
            "--synthesis", "filter"]


@pytest.mark.parametrize("name", ["out.wav", pytest.param("out.flac", marks=pytest.mark.slow),
                                  pytest.param("out.mp3", marks=pytest.mark.slow)])  # the same guard: one in the default suite
def test_render_past_the_file_size_limit(inputs, tmp_path, name):
    ckpt, wav = inputs
    out = tmp_path / name
    line = assert_one_line(*avgs(render_argv(ckpt, wav, out), limit=100_000), "render", out)
    assert "File too large" in line
    assert list(tmp_path.iterdir()) == []  # no temporary, no half file


def test_render_replaces_nothing_when_the_write_fails(inputs, tmp_path):
    """An earlier output stays as it was (the temporary is what failed, and it is gone)."""
    ckpt, wav = inputs
    out = tmp_path / "out.wav"
    out.write_bytes(b"an earlier render")
    assert_one_line(*avgs(render_argv(ckpt, wav, out), limit=100_000), "render", out)
    assert out.read_bytes() == b"an earlier render" and sorted(tmp_path.iterdir()) == [out]


def test_prune_and_eval_outputs_past_the_limit(inputs, tmp_path, quick_scene):
    ckpt, _ = inputs
    pruned = tmp_path / "pruned.ckpt"  # torch.save's zip writer: the OS error, not "unexpected pos"
    line = assert_one_line(*avgs(["prune", ckpt, "--out", pruned], limit=20_000), "prune", pruned)
    assert "File too large" in line and "enforce fail" not in line
    report = tmp_path / "scores.json"
    assert_one_line(*avgs(["eval", quick_scene.parent, "--methods", "mono-mono", "--json", report, "--no-progress"],
                          limit=0), "eval", report)
    assert list(tmp_path.iterdir()) == []


def test_train_whose_checkpoint_cannot_be_written_leaves_no_log(quick_scene, tmp_path):
    from avgs.cli import main

    out = tmp_path / "scene.ckpt"
    base = ["train", quick_scene, "--out", out, "--quick", "--iterations", "4", "--no-progress"]
    assert main([str(a) for a in base + ["--stage1-only"]]) == 0  # G first, here, unlimited: the run below reuses it
    stage1 = sorted(tmp_path.iterdir())
    line = assert_one_line(*avgs(base, limit=200_000), "train", out)
    assert "File too large" in line and "enforce fail" not in line
    assert sorted(tmp_path.iterdir()) == stage1  # no checkpoint, no temporary, no log, no curves


@pytest.mark.slow  # the checkpoint variant stays in the default suite
def test_train_whose_log_cannot_be_written(quick_scene, tmp_path):
    out = tmp_path / "scene.ckpt"
    log = tmp_path / "scene.ckpt.log.jsonl"
    assert_one_line(*avgs(["train", quick_scene, "--out", out, "--quick", "--iterations", "4", "--no-progress"],
                          limit=300), "train", log)
    assert list(tmp_path.iterdir()) == []


# -- a real full file system --------------------------------------------------------------------


@pytest.fixture
def small_disk(tmp_path):
    """A 1 MiB tmpfs at ``tmp_path / "disk"``, unmounted afterwards (skipped where mounting is not permitted)."""
    disk = tmp_path / "disk"
    disk.mkdir()
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=1m", "tmpfs", str(disk)], capture_output=True, text=True)
    if mounted.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here ({mounted.stderr.strip() or mounted.returncode})")
    try:
        yield disk
    finally:
        subprocess.run(["umount", str(disk)], check=False)


def test_render_onto_a_full_file_system(inputs, small_disk):
    ckpt, wav = inputs
    out = small_disk / "out.wav"  # 20 s of 2 x float32 at 22050 Hz: 3.5 MB onto 1 MiB
    line = assert_one_line(*avgs(render_argv(ckpt, wav, out)), "render", out)
    assert "No space left on device" in line
    assert list(small_disk.iterdir()) == []


def test_train_onto_a_full_file_system(quick_scene, small_disk):
    out = small_disk / "scene.ckpt"
    status, err = avgs(["train", quick_scene, "--out", out, "--quick", "--iterations", "4", "--no-progress"])
    line = assert_one_line(status, err, "train", out)  # G's stage-1 file fits in 1 MiB; G_a, F, B and G do not
    assert "No space left on device" in line
    from avgs.train.stage1 import load_stage1, stage1_path

    assert list(small_disk.iterdir()) == [stage1_path(out)]  # no checkpoint, temporary or log
    assert load_stage1(stage1_path(out))["scene"] == quick_scene.name  # whole: the next run reuses it


# -- refused before any work: nothing written ---------------------------------------------------


class _Trap:
    def __reduce__(self):
        return (print, ("this ran",))


@pytest.mark.parametrize("kind", ["foreign scene", "code", "not a torch file"])
def test_a_refused_stage1_file_leaves_no_log(quick_scene, tmp_path, capsys, kind):
    """In this process (no file size limit needed): ``avgs.cli.main``'s status and stderr."""
    from avgs.cli import main

    given = tmp_path / "given" / "g.stage1.pt"
    given.parent.mkdir()
    if kind == "foreign scene":
        torch.save({"format": "avgs-stage1", "version": 1, "scene": "another_scene", "key": {},
                    "gaussians": {"means": torch.zeros(2, 3), "sh": torch.zeros(2, 16, 3)}}, given)
    elif kind == "code":
        torch.save({"format": "avgs-stage1", "version": 1, "trap": _Trap()}, given)
    else:
        given.write_bytes(pickle.dumps({"format": "avgs-stage1"}))
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    status = main([str(a) for a in ["train", quick_scene, "--out", out_dir / "scene.ckpt", "--quick", "--stage1",
                                    given, "--no-progress"]])
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert status == 2 and len(lines) == 1 and str(given) in lines[0], err
    assert "weights_only" not in err and "will likely succeed" not in err and "this ran" not in err
    if kind == "foreign scene":
        assert "another_scene" in lines[0]
    assert list(out_dir.iterdir()) == []


def test_stage1_loader_gives_no_torch_advice(tmp_path):
    from avgs.train.stage1 import load_stage1

    path = tmp_path / "code.stage1.pt"
    torch.save({"format": "avgs-stage1", "version": 1, "trap": _Trap()}, path)
    with pytest.raises(ValueError) as info:
        load_stage1(path)
    message = str(info.value)
    assert message.startswith(f"{path}: not a stage-1 file") and "\n" not in message
    assert "weights_only" not in message and "objects other than tensors" in message

