"""No output a user names can destroy an input, replace a non-file or end in a traceback
(:func:`avgs.io.atomic.check_output`, :func:`avgs.io.atomic.atomic_path`)."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest
import soundfile as sf

from avgs.io.atomic import TEMP_MARK, OutputError, atomic_path, check_output, write_text
from avgs.io.checkpoint import save_checkpoint, untrained_checkpoint
from avgs.cli import main as cli_main


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """A checkpoint and a mono WAV in one folder."""
    d = tmp_path_factory.mktemp("outputs")
    rng = np.random.default_rng(0)
    ckpt = save_checkpoint(untrained_checkpoint(rng.uniform(0, 4, (300, 3)), [2.0, 2.0, 1.0]), d / "scene.ckpt")
    wav = d / "mono.wav"
    sf.write(wav, (0.1 * rng.standard_normal(4000)).astype(np.float32), 22050)
    return d, ckpt, wav


def snapshot(folder) -> dict:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if p.is_file()}


def render(ckpt, wav, output) -> list[str]:
    return ["render", str(ckpt), "--listener", "1", "1", "1", "--yaw", "0", "--input", str(wav), "--output", str(output)]


def run_cli(argv, capsys) -> tuple[int, str]:
    code = cli_main(argv)
    return code, capsys.readouterr().err


@pytest.mark.parametrize("target", ["checkpoint", "input", "link-to-input", "folder", "folder/", "missing-folder", "fifo"])
def test_render_refuses_outputs_it_must_not_write(files, tmp_path, target, capsys):
    d, ckpt, wav = files
    before = snapshot(d)
    output = {
        "checkpoint": ckpt, "input": wav, "folder": tmp_path, "folder/": f"{tmp_path}{os.sep}",
        "missing-folder": tmp_path / "nowhere" / "out.wav",
    }.get(target)
    if target == "link-to-input":
        output = tmp_path / "link.wav"
        output.symlink_to(wav)
    if target == "fifo":
        output = tmp_path / "pipe.wav"
        os.mkfifo(output)
    code, err = run_cli(render(ckpt, wav, output), capsys)
    assert code == 2 and err.count("\n") == 1 and "Traceback" not in err and str(output).rstrip(os.sep) in err
    assert snapshot(d) == before  # nothing changed, nothing left behind
    if target == "fifo":
        assert not os.path.isfile(output)  # still a FIFO


def test_render_writes_a_new_file_and_replaces_its_own_earlier_output(files, tmp_path, capsys):
    d, ckpt, wav = files
    out = tmp_path / "out.wav"
    assert run_cli(render(ckpt, wav, out), capsys)[0] == 0
    first, rate = sf.read(out, dtype="float32")  # the samples: a float WAV's PEAK chunk holds the time of writing
    assert run_cli(render(ckpt, wav, out), capsys)[0] == 0
    again, rate_again = sf.read(out, dtype="float32")
    assert rate_again == rate and np.array_equal(again, first)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.wav"]


def test_eval_json_and_prune_out_never_replace_a_checkpoint(files, tmp_path, capsys):
    d, ckpt, _ = files
    before = ckpt.read_bytes()
    assert run_cli(["prune", str(ckpt), "--out", str(ckpt)], capsys)[0] == 2
    assert run_cli(["eval", str(tmp_path), "--method", f"ckpt:{ckpt}", "--json", str(ckpt)], capsys)[0] == 2
    assert ckpt.read_bytes() == before


def test_train_refuses_to_write_into_its_own_scene(quick_scene, capsys):
    before = snapshot(quick_scene)
    for name in ("binaural_syn_re.wav", "transforms_train.json", "frames"):
        code, err = run_cli(["train", str(quick_scene), "--quick", "--out", str(quick_scene / name)], capsys)
        assert code == 2 and "Traceback" not in err, err
    assert snapshot(quick_scene) == before


def test_a_killed_save_leaves_a_temporary_file_that_the_next_save_removes(tmp_path):
    target = tmp_path / "scene.json"
    code = (f"import os, signal\nfrom avgs.io.atomic import atomic_path\n"
            f"with atomic_path({str(target)!r}) as tmp:\n    tmp.write_text('half')\n    os.kill(os.getpid(), signal.SIGKILL)\n")
    subprocess.run([sys.executable, "-c", code], check=False)
    left = [p for p in tmp_path.iterdir() if TEMP_MARK in p.name]
    assert len(left) == 1 and not target.exists()
    write_text(target, "whole")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene.json"] and target.read_text() == "whole"


def test_a_live_writers_temporary_file_is_left_alone(tmp_path):
    target = tmp_path / "a.txt"
    with atomic_path(target) as mine:
        mine.write_text("x")
        write_text(target, "other writer")  # same process: its temporary file is alive
        assert mine.exists()
    assert target.read_text() == "x"


def test_check_output_rules(tmp_path):
    inputs = [tmp_path / "scene"]
    (tmp_path / "scene").mkdir()
    (tmp_path / "scene" / "audio.wav").write_bytes(b"data")
    assert check_output(tmp_path / "scene" / "new.ckpt", inputs) == (tmp_path / "scene" / "new.ckpt").resolve()
    with pytest.raises(OutputError, match="inside the input folder"):
        check_output(tmp_path / "scene" / "audio.wav", inputs)
    (tmp_path / "exists.txt").write_text("x")
    with pytest.raises(OutputError, match="exists already"):
        check_output(tmp_path / "exists.txt", exist_ok=False)
    loop = tmp_path / "loop"
    loop.symlink_to(loop)
    with pytest.raises(OutputError):
        check_output(loop)


def test_an_unwritable_destination_is_one_clear_error(files, tmp_path, capsys):
    if os.geteuid() == 0:
        pytest.skip("root writes into read-only folders")
    d, ckpt, wav = files
    ro = tmp_path / "ro"
    ro.mkdir(mode=0o500)
    code, err = run_cli(render(ckpt, wav, ro / "out.wav"), capsys)
    assert code == 2 and "cannot write" in err and "Traceback" not in err


def test_a_full_disk_is_one_clear_error_and_leaves_nothing(files, tmp_path, capsys, monkeypatch):
    """ENOSPC while writing (simulated: root can write anywhere, and no test fills a disk)."""
    import errno

    import avgs.io.atomic

    d, ckpt, wav = files

    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(avgs.io.atomic.os, "replace", full)
    code, err = run_cli(render(ckpt, wav, tmp_path / "out.wav"), capsys)
    assert code == 2 and "cannot write" in err and "No space left" in err and "Traceback" not in err
    assert list(tmp_path.iterdir()) == []  # the temporary file is gone too


def test_warnings_are_one_line_and_threads_are_set(files, tmp_path, capsys, monkeypatch):
    import torch

    from avgs.threads import choose_threads, free_cores

    d, ckpt, wav = files
    argv = ["--threads", "1", *render(ckpt, wav, tmp_path / "o.wav")]
    argv[argv.index("--listener") + 1] = "200"  # far outside the scene
    code, err = run_cli(argv, capsys)
    assert code == 0 and torch.get_num_threads() == 1
    assert err.count("\n") == 1 and err.startswith("avgs render: warning: listener (200, 1, 1) is outside the scene")
    assert run_cli(["--threads", "0", "info", str(ckpt)], capsys)[0] == 2
    monkeypatch.setenv("OMP_NUM_THREADS", "3")
    assert choose_threads(None) == 3 and choose_threads(2) == 2
    monkeypatch.delenv("OMP_NUM_THREADS")
    assert 1 <= choose_threads(None) == free_cores() <= (os.cpu_count() or 1)


@pytest.mark.parametrize("name, fmt", [("out.mp3", "MP3"), ("out.flac", "FLAC"), ("out.ogg", "OGG"), ("OUT.WAV", "WAV")])
def test_render_writes_the_format_its_extension_names(files, tmp_path, capsys, name, fmt):
    d, ckpt, wav = files
    out = tmp_path / name
    code, err = run_cli(render(ckpt, wav, out), capsys)
    assert code == 0, err
    info = sf.info(out)
    assert info.format == fmt and info.channels == 2 and info.samplerate == 22050
    audio, _ = sf.read(out, dtype="float32")
    assert np.max(np.abs(audio)) > 1e-3  # sound, not silence
    if fmt != "WAV":  # formats without float samples: nothing beyond full scale, the level change said
        assert np.max(np.abs(audio)) <= 1.0 + 1e-3
        assert err == "" or (err.count("\n") == 1 and "scaled down" in err)
    assert sorted(p.name for p in tmp_path.iterdir()) == [name]


@pytest.mark.parametrize("name", ["out.m4a", "out.aac", "out", "out.wav.txt"])
def test_render_refuses_an_extension_it_cannot_write(files, tmp_path, capsys, name):
    d, ckpt, wav = files
    code, err = run_cli(render(ckpt, wav, tmp_path / name), capsys)
    assert code == 2 and err.count("\n") == 1 and str(tmp_path / name) in err and ".wav, .flac, .ogg, .mp3" in err
    assert list(tmp_path.iterdir()) == []


def test_version_prints_the_package_version():
    from importlib.metadata import version

    done = subprocess.run([sys.executable, "-m", "avgs.cli", "--version"], capture_output=True, text=True)
    assert done.returncode == 0 and done.stdout.strip() == f"avgs {version('avgs')}"


def test_info_says_the_iteration_of_a_finished_run(files, tmp_path, capsys):
    """A finished run saved without its training state (the bundled demo) is at its final iteration,
    not at 0; an untrained checkpoint names no iteration."""
    from avgs.io.checkpoint import load_checkpoint

    d, ckpt, _ = files
    assert run_cli(["info", str(ckpt)], capsys)[0] == 0
    assert "at iteration" not in capsys.readouterr().out
    finished = load_checkpoint(ckpt)
    finished["metrics"] = {"iteration": 500, "loss": 0.5}
    path = save_checkpoint(finished, tmp_path / "finished.ckpt")
    assert cli_main(["info", str(path)]) == 0
    out = capsys.readouterr().out
    assert "at iteration 500" in out and "at iteration 0" not in out and "final iteration 500" in out
