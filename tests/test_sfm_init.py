"""``--init sfm`` on a scene without geometry: SfM points triangulated from the frames with
their known poses (:mod:`avgs.gaussians.sfm`), checked against the generated scene's true
surfaces, and a stripped scene (frames, poses and audio only) trained end to end."""

from __future__ import annotations

import importlib.util
import json
import tempfile
from pathlib import Path

import numpy as np
import pytest

from avgs.config import TrainConfig

ROOT = Path(__file__).resolve().parents[1]


def _strip_geometry():
    spec = importlib.util.spec_from_file_location("strip_geometry", ROOT / "scripts" / "strip_geometry.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.strip_geometry


@pytest.fixture(scope="module")
def scenes(tmp_path_factory) -> tuple[Path, Path]:
    """(generated office scene with 256x192 frames, its copy without scene.json)."""
    from avgs.synth.writer import SynthConfig, write_scene

    cfg = SynthConfig.quick_config("office", seed=0, poses=24, workers=1)
    cfg.width, cfg.height = 256, 192  # SIFT needs more than the quick preset's 64x48 frames
    scene = write_scene(tmp_path_factory.mktemp("sfm_full"), "office_sfm", cfg, progress=False).scene_dir
    stripped = _strip_geometry()(scene, tmp_path_factory.mktemp("sfm_stripped"))
    return scene, stripped


def _listing(folder: Path) -> list[str]:
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*"))


def test_stripped_copy_has_no_geometry_and_keeps_the_source(scenes):
    from avgs.data.rwavs import RWAVSScene, read_scene_metadata

    scene, stripped = scenes
    assert (scene / "scene.json").is_file() and not (stripped / "scene.json").exists()
    assert read_scene_metadata(stripped) is None
    np.testing.assert_allclose(RWAVSScene(stripped).source, RWAVSScene(scene).source)


def test_triangulated_points_lie_on_the_true_surfaces(scenes):
    from scipy.spatial import cKDTree

    from avgs.data.rwavs import read_scene_metadata
    from avgs.data.scene_geometry import surface_points
    from avgs.gaussians.sfm import MIN_POINTS, sfm_points

    scene, stripped = scenes
    before = _listing(stripped)
    leftovers = set(Path(tempfile.gettempdir()).glob("avgs-sfm-*"))
    sparse = sfm_points(stripped, progress=False, threads=1)
    assert _listing(stripped) == before, "SfM wrote into the scene folder"
    assert set(Path(tempfile.gettempdir()).glob("avgs-sfm-*")) == leftovers, "SfM left its temporary folder behind"

    meta = read_scene_metadata(scene)
    truth, truth_colors = surface_points(meta, 300_000, np.random.default_rng(0))  # normalised, ~1 cm apart
    dist, nearest = cKDTree(truth).query(sparse.points)
    metres = dist / meta["to_normalised"]["scale"]
    assert len(sparse.points) >= MIN_POINTS and sparse.stats["points"] == len(sparse.points)
    assert np.median(metres) < 0.05, f"median distance to the true surfaces {np.median(metres):.3f} m"
    assert np.mean(metres < 0.2) > 0.95, f"only {np.mean(metres < 0.2):.1%} of the points within 20 cm of a surface"
    assert sparse.colors.shape == sparse.points.shape and 0 <= sparse.colors.min() and sparse.colors.max() <= 1
    # frames are drawn in the material colours (shaded, +-7 % tile jitter)
    assert np.median(np.abs(sparse.colors - truth_colors[nearest]).max(1)) < 0.2


def test_too_few_points_is_an_error_naming_the_scene(scenes):
    from avgs.data.views import load_views
    from avgs.gaussians.sfm import triangulate_views

    views = load_views(scenes[1], "train").subset([0, 1, 2]).downscaled(4)
    with pytest.raises(ValueError, match="tiny_scene: only .* SfM points"):
        triangulate_views(views, name="tiny_scene", progress=False, threads=1)


def test_pairs_follow_the_poses():
    from avgs.gaussians.sfm import image_pairs

    def pose(x: float, yaw_deg: float) -> np.ndarray:
        yaw = np.radians(yaw_deg)
        facing = np.array([np.cos(yaw), np.sin(yaw), 0.0])
        z = -facing  # OpenGL: the camera looks along -Z
        y = np.array([0.0, 0.0, 1.0])
        c2w = np.eye(4)
        c2w[:3, :3] = np.stack([np.cross(y, z), y, z], axis=1)
        c2w[:3, 3] = [x, 0.0, 0.0]
        return c2w

    c2w = np.stack([pose(0.0, 0), pose(0.1, 10), pose(0.2, 0), pose(0.0, 180), pose(5.0, 0)])
    pairs = image_pairs(c2w, per_view=2)
    assert all(i < j for i, j in pairs)
    assert (0, 1) in pairs and (0, 2) in pairs
    assert not any(3 in p for p in pairs), "a view looking the other way was paired"
    assert all(sum(i in p for p in pairs) <= 4 for i in range(5))


def test_init_source_and_stage1_key():
    from avgs.train.stage1 import stage1_init_source, stage1_key

    sfm, gs = TrainConfig(init="sfm"), TrainConfig(init="gs")
    surfaces = {"surfaces": [{"corners": []}]}
    assert stage1_init_source(surfaces, sfm) == stage1_init_source(surfaces, gs) == "scene.json"
    assert stage1_init_source(None, sfm) == stage1_init_source({"preset": "x"}, sfm) == "sfm"
    assert stage1_init_source(None, gs) == "random"
    assert stage1_key(gs, "scene.json") == stage1_key(gs, "random") == stage1_key(gs)  # older stage-1 files stay valid
    assert stage1_key(gs, "sfm") == {**stage1_key(gs), "init_points_from": "sfm"}


def test_stripped_scene_trains_end_to_end_with_sfm_init(scenes, tmp_path):
    from avgs.io.checkpoint import load_checkpoint
    from avgs.cli import main

    stripped = scenes[1]
    before = _listing(stripped)
    out = tmp_path / "sfm.ckpt"
    rc = main(["train", str(stripped), "--out", str(out), "--quick", "--init", "sfm", "--iterations", "40",
               "--eval-every", "40", "--stage1-iterations", "10", "--no-progress"])
    assert rc == 0 and out.is_file()
    assert _listing(stripped) == before, "training wrote into the scene folder"
    records = [json.loads(line) for line in (tmp_path / "sfm.ckpt.log.jsonl").read_text().splitlines()]
    sources = [r for r in records if r.get("event") == "init_source"]
    assert sources and sources[0]["source"] == "sfm"
    sfm = next(r for r in records if r.get("event") == "sfm_points")
    trained = next(r for r in records if r.get("event") == "trained")
    assert trained["init_source"] == "sfm" and trained["init_points"] == sfm["kept"] >= 100
    ckpt = load_checkpoint(out)
    assert ckpt["gaussians"] is not None
    assert np.isfinite(ckpt["metrics"]["val_mag"])


def test_cpu_budget_shrinks_only_full_size_frames_on_the_cpu(scenes):
    from avgs.train.stage1 import cpu_stage1_budget

    stripped = scenes[1]
    cfg = TrainConfig()  # the paper's full-size frames; 256x192 here
    assert cpu_stage1_budget(stripped, cfg) == {"image_downscale": 2, "max_gaussians": cfg.gaussians.cpu_max_gaussians}
    cfg.gaussians.max_gaussians = 5000
    assert cpu_stage1_budget(stripped, cfg)["max_gaussians"] == 5000
    cfg.gaussians.image_downscale = 3  # a size given: kept
    assert cpu_stage1_budget(stripped, cfg) is None
    cuda = TrainConfig(device="cuda")
    assert cpu_stage1_budget(stripped, cuda) is None
    off = TrainConfig()
    off.gaussians.cpu_max_pixels = 0  # --stage1-cpu-max-pixels 0: the frames as they are
    assert cpu_stage1_budget(stripped, off) is None
