"""Shared fixtures: synthetic scenes from ``avgs synth`` (generated once per run: under
pytest-xdist the first worker to need one builds it, the others copy it: ``built_once.py``).

- ``quick_scene``: an office scene made with ``--quick`` (16 train + 4 val poses, 64x48
  frames), its own data root.
- ``quick_presets``: one ``--quick`` scene of every preset in one data root whose
  position.json already held a foreign entry (``"real_scene"``) before generation.
- ``tail_renderer``: an untrained scene whose reverberant tail is loud and pose-dependent.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from built_once import built_once

FOREIGN_ENTRY = {"real_scene": {"source_position": [0.1, -0.2, 0.3]}}


@pytest.fixture(scope="session")
def quick_scene(tmp_path_factory) -> Path:
    """Path of a quick synthetic office scene (DATA_ROOT/office_quick)."""
    from avgs.synth.writer import SynthConfig, write_scene

    def build(root: Path) -> None:
        write_scene(root, "office_quick", SynthConfig.quick_config("office", seed=0, workers=1), progress=False)

    return built_once(tmp_path_factory, "synth_quick", build) / "office_quick"


@pytest.fixture(scope="session")
def quick_rir_scene(tmp_path_factory) -> Path:
    """Path of a quick impulse-response scene, ``avgs synth --task rir --quick`` (DATA_ROOT/quick_rect); read only."""
    from avgs.cli import main

    def build(root: Path) -> None:
        argv = ["synth", str(root), "--task", "rir", "--quick", "--scene-id", "quick_rect", "--workers", "1",
                "--no-progress"]
        assert main(argv) == 0

    return built_once(tmp_path_factory, "rir_quick", build) / "quick_rect"


@pytest.fixture(scope="session")
def quick_rir_renderer(quick_rir_scene, tmp_path_factory):
    """A ``SceneRenderer`` of the quick impulse-response scene after 40 iterations of the quick config
    (tests/test_rir_direct_sound.py, tests/test_rir_behind_walls.py); read only."""
    from avgs.render.renderer import SceneRenderer
    from avgs.train.impulse_responses import rir_quick_config
    from avgs.train.pipeline import train_scene

    cfg = rir_quick_config()
    cfg.acoustic.iterations = 40
    out = tmp_path_factory.mktemp("direct") / "scene.ckpt"
    train_scene(quick_rir_scene, out, cfg, task="rir", progress=False)
    return SceneRenderer.load(out)


def train_free_field(root: Path, n_train: int, n_val: int, seed: int, iterations: int, prune_every: int,
                     eval_every: int, log_every: int):
    """A free-field scene of ``rwavs_writer`` in ``root`` (the ear facing the source is louder) and a
    binaural-task model trained on it from 600 random points, ``root/scene.ckpt``: (the written
    scene, the final record)."""
    import torch

    from avgs.acoustics.points import AudioPoints
    from avgs.train.pipeline import quick_config, train_scene
    from rwavs_writer import write_scene as write_rwavs

    scene = write_rwavs(root, n_train=n_train, n_val=n_val, seed=seed)
    cfg = quick_config()
    cfg.acoustic.iterations, cfg.acoustic.binauralizer_width = iterations, 64
    cfg.points.densify_every, cfg.points.prune_every = 40, prune_every
    cfg.eval_every = cfg.checkpoint_every = eval_every
    cfg.log_every = log_every
    g = torch.Generator().manual_seed(0)
    points = AudioPoints(torch.rand(600, 3, generator=g) * 2 - 1, torch.randn(600, 52, generator=g))
    return scene, train_scene(scene.scene_dir, root / "scene.ckpt", cfg, progress=False, initial_points=points)


@pytest.fixture(scope="session")
def one_source_ckpt(tmp_path_factory) -> Path:
    """A checkpoint of the binaural task (one source position: ``source_aware`` False): 120
    stage-2 iterations on a free-field scene in the RWAVS layout; a few seconds."""
    def build(root: Path) -> None:
        train_free_field(root, n_train=32, n_val=4, seed=1, iterations=120, prune_every=100, eval_every=120,
                         log_every=60)

    return built_once(tmp_path_factory, "one_source_scene", build) / "scene.ckpt"


@pytest.fixture(scope="session")
def free_field_model(tmp_path_factory):
    """A free-field scene (48 training poses) and a model trained on it for 200 stage-2 iterations,
    evaluated every 50: (the written scene, the checkpoint, the final record). Read only."""
    import dataclasses
    import pickle

    def build(root: Path) -> None:
        written = train_free_field(root, n_train=48, n_val=8, seed=0, iterations=200, prune_every=120, eval_every=50,
                                   log_every=10)
        (root / "written.pkl").write_bytes(pickle.dumps(written))

    root = built_once(tmp_path_factory, "free_field_model", build)
    scene, final = pickle.loads((root / "written.pkl").read_bytes())
    scene = dataclasses.replace(scene, data_root=root, scene_dir=root / scene.scene_dir.relative_to(scene.data_root))
    return scene, root / "scene.ckpt", final


@pytest.fixture(scope="session")
def quick_presets(tmp_path_factory) -> dict[str, Path]:
    """{preset: scene folder} of quick scenes of every preset in one data root."""
    from avgs.synth.presets import PRESETS
    from avgs.synth.writer import SynthConfig, write_scene

    def build(root: Path) -> None:
        (root / "position.json").write_text(json.dumps(FOREIGN_ENTRY))
        for preset in PRESETS:
            write_scene(root, f"{preset}_q", SynthConfig.quick_config(preset, seed=3, workers=1), progress=False)

    root = built_once(tmp_path_factory, "synth_presets", build)
    return {preset: root / f"{preset}_q" for preset in PRESETS}


def _tail_checkpoint() -> dict:
    """A checkpoint whose tail is loud and pose-dependent (random head weights, RT60 0.2-0.8 s)."""
    import numpy as np
    import torch

    from avgs.io.checkpoint import untrained_checkpoint
    from avgs.data.frame import SceneFrame

    room = np.array([[0.0, 0.0, 0.0], [6.0, 4.0, 3.0]])
    pts = np.random.default_rng(0).uniform(room[0], room[1], size=(600, 3))
    ckpt = untrained_checkpoint(pts, np.array([4.5, 2.5, 1.2]), frame=SceneFrame(room.mean(0), 1 / 3), seed=3)
    state = ckpt["binauralizer"]
    g = torch.Generator().manual_seed(5)
    state["reverb.head.weight"] = torch.randn(state["reverb.head.weight"].shape, generator=g) * 0.3
    state["reverb.head.bias"] = torch.full((2,), -0.5)
    state["reverb.log_rt60"] = torch.log(torch.linspace(0.2, 0.8, 257))
    return ckpt


@pytest.fixture(scope="session")
def tail_checkpoint():
    """Makes the checkpoint of ``tail_renderer`` anew at each call (for renderers of one's own)."""
    return _tail_checkpoint


@pytest.fixture(scope="session")
def tail_renderer():
    """A renderer whose tail is loud and pose-dependent (random head weights, RT60 0.2-0.8 s)."""
    from avgs.render.renderer import SceneRenderer

    return SceneRenderer(_tail_checkpoint())


@pytest.fixture(scope="module")
def x():
    """A connection to the X server that sends real pointer and key events (tests of the window)."""
    import os

    from avgs_viewer.xinput import XInput

    if not os.environ.get("DISPLAY"):
        pytest.skip("needs an X display (pytest-xvfb or xvfb-run)")
    with XInput() as conn:
        yield conn
