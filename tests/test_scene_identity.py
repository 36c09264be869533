"""A checkpoint carries its training scene's identity (:mod:`avgs.data.identity`); ``avgs eval``
and ``avgs train --resume`` refuse another scene of the same name, and an older checkpoint
without the field is matched by name with one warning."""

from __future__ import annotations

import json
import shutil

import pytest
import torch
from rwavs_writer import write_scene

from avgs.acoustics.points import AudioPoints
from avgs.cli import main as cli_main
from avgs.data.identity import identity_parts, scene_identity
from avgs.io.checkpoint import load_checkpoint, save_checkpoint
from avgs.train.pipeline import quick_config, train_scene

ITERATIONS = 3


def tiny_config():
    cfg = quick_config()
    cfg.acoustic.iterations = ITERATIONS
    cfg.acoustic.binauralizer_width, cfg.acoustic.field_width, cfg.acoustic.context_dim = 32, 16, 16
    cfg.checkpoint_every, cfg.eval_every, cfg.log_every = 1, 100, 1
    return cfg


@pytest.fixture(scope="module")
def scenes(tmp_path_factory):
    """(scene A, scene B: the same name and clip length, other poses and source; a checkpoint trained on A)."""
    a = write_scene(tmp_path_factory.mktemp("root_a"), "office_1", n_train=6, n_val=2, seed=0).scene_dir
    b = write_scene(tmp_path_factory.mktemp("root_b"), "office_1", n_train=6, n_val=2, seed=1).scene_dir
    g = torch.Generator().manual_seed(0)
    points = AudioPoints(torch.rand(80, 3, generator=g) * 2 - 1, torch.randn(80, 52, generator=g))
    out = tmp_path_factory.mktemp("ckpt") / "scene.ckpt"
    train_scene(a, out, tiny_config(), progress=False, initial_points=points)
    return a, b, out


def run(argv, capsys) -> tuple[int, list[str], str]:
    code = cli_main([str(x) for x in argv])
    captured = capsys.readouterr()
    return code, [ln for ln in captured.err.splitlines() if ln.strip()], captured.out


def test_the_checkpoint_carries_its_scenes_identity(scenes):
    a, b, ckpt = scenes
    identity = load_checkpoint(ckpt)["scene"]["identity"]
    assert identity == scene_identity(a) and identity != scene_identity(b)
    assert set(identity_parts(a)) == {"position.json[office_1]", "transforms_train.json", "transforms_val.json",
                                      "transforms_scale_train.json", "transforms_scale_val.json"}


def test_eval_scores_its_own_scene_and_refuses_another_of_the_same_name(scenes, capsys):
    a, b, ckpt = scenes
    code, err, out = run(["eval", a.parent, "--method", f"ckpt:{ckpt}", "--no-progress", "--phase-iterations", "0"], capsys)
    assert code == 0 and err == [] and "office_1" in out
    code, err, out = run(["eval", b.parent, "--method", f"ckpt:{ckpt}", "--no-progress"], capsys)
    assert code == 2 and len(err) == 1 and out == ""
    assert err[0].startswith(f"avgs eval: error: {ckpt}: trained on another scene than {b.resolve()}")
    assert scene_identity(a)[:19] in err[0] and scene_identity(b)[:19] in err[0]


def test_a_folder_of_checkpoints_refuses_too(scenes, tmp_path, capsys):
    a, b, ckpt = scenes
    shutil.copy(ckpt, tmp_path / "office_1.ckpt")
    code, err, _ = run(["eval", b.parent, "--method", f"ckpt:{tmp_path}", "--no-progress"], capsys)
    assert code == 2 and len(err) == 1 and "trained on another scene" in err[0]


def test_an_older_checkpoint_without_identity_warns_once_and_goes_on(scenes, tmp_path, capsys):
    a, b, ckpt = scenes
    old = load_checkpoint(ckpt)
    del old["scene"]["identity"]
    path = save_checkpoint(old, tmp_path / "old.ckpt")
    code, err, out = run(["eval", b.parent, "--method", f"ckpt:{path}", "--no-progress", "--phase-iterations", "0"], capsys)
    assert code == 0 and "office_1" in out
    assert len(err) == 1 and err[0].startswith(f"avgs eval: warning: {path}: carries no scene identity"), err


def test_resume_refuses_another_scene(scenes, tmp_path, capsys):
    a, b, ckpt = scenes
    own = shutil.copy(ckpt, tmp_path / "scene.ckpt")
    before = own.read_bytes()
    resume = ["--out", own, "--resume", "--quick", "--iterations", ITERATIONS + 1, "--no-progress"]
    code, err, _ = run(["train", b, *resume], capsys)
    assert code == 2 and len(err) == 1 and "trained on another scene" in err[0] and str(b) in err[0]
    assert own.read_bytes() == before
    assert run(["train", a, *resume], capsys)[0] == 0
    assert load_checkpoint(own)["train_state"]["iteration"] == ITERATIONS + 1


def copy_scene(scene, tmp_path):
    root = tmp_path / "copy"
    shutil.copytree(scene.parent, root)
    return root / scene.name


def edit_json(path, edit):
    data = json.loads(path.read_text())
    edit(data)
    path.write_text(json.dumps(data))


def test_what_changes_a_scenes_identity(scenes, tmp_path):
    a = copy_scene(scenes[0], tmp_path)
    original = scene_identity(a)
    # Reformatted JSON, another scene's source, the audio and frames: the same scene.
    edit_json(a / "transforms_train.json", lambda d: None)
    edit_json(a.parent / "position.json", lambda d: d.update(other_scene={"source_position": [0.1, 0.2, 0.3]}))
    (a / "binaural_syn_re.wav").write_bytes(b"")
    assert scene_identity(a) == original
    # Its source, a pose, the set of poses, the normalisation: another scene.
    changed = []
    edit_json(a.parent / "position.json", lambda d: d["office_1"]["source_position"].__setitem__(0, 0.4321))
    changed.append(scene_identity(a))
    edit_json(a / "transforms_scale_val.json", lambda d: d["camera_path"][0]["camera_to_world"].__setitem__(3, 0.123))
    changed.append(scene_identity(a))
    edit_json(a / "transforms_train.json", lambda d: d["camera_path"].pop())
    changed.append(scene_identity(a))
    (a / "scene.json").write_text(json.dumps({"to_normalised": {"center": [1, 2, 3], "scale": 0.5}}))
    changed.append(scene_identity(a))
    assert len({original, *changed}) == 5


def test_an_impulse_response_index_is_part_of_it(scenes, tmp_path):
    a = copy_scene(scenes[0], tmp_path)
    (a / "rir").mkdir()
    index = {"format": "avgs-rir/1", "sample_rate": 22050, "orientations_deg": [0, 90], "sources": [[0, 0, 0]],
             "receivers": [[0.5, 0, 0]], "splits": {"train": [[0, 0]], "val": [], "heldout": []}}
    (a / "rir" / "index.json").write_text(json.dumps(index))
    with_index = scene_identity(a)
    index["receivers"][0][1] = 0.25
    (a / "rir" / "index.json").write_text(json.dumps(index, indent=1))
    assert len({scene_identity(scenes[0]), with_index, scene_identity(a)}) == 3


def test_an_unreadable_index_file_is_one_line_naming_it(scenes, tmp_path):
    a = copy_scene(scenes[0], tmp_path)
    (a / "transforms_val.json").write_text("{not json")
    with pytest.raises(ValueError, match=str(a / "transforms_val.json")):
        scene_identity(a)
