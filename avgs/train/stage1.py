"""Stage 1 of the pipeline: G (3D-GS) warmed up on a scene's RGB key frames, and G_a from it.

G starts from points on the scene's surfaces when scene.json has them (our generated
scenes); on a scene without them (a real recording) from SfM points triangulated from the
frames with their known poses under ``--init sfm`` (:mod:`avgs.gaussians.sfm`, as 3D-GS
and the paper start from SfM points), else from random points along the training rays.
:func:`stage1_init_source` names the choice and every run logs it. On the CPU, a stage 1 at
the paper's full frame size trains within a budget instead (:func:`cpu_stage1_budget`).

Stage 1 reads only the frames, the poses and scene.json (never the audio), so it can run
on its own, e.g. on a GPU machine with gsplat, and hand its result to stage 2 elsewhere.
Its result is kept in a small file next to the checkpoint (``scene.ckpt.stage1.pt``):
a later run of the same scene and stage-1 settings reuses it instead of training G again
(nothing lost when stage 2 is interrupted), and ``avgs train --stage1 FILE`` shares one G
between several stage-2 runs (the ablations).

The file is a ``torch.save`` dict of tensors and plain values (``weights_only`` loadable):
``format``, ``version``, ``scene`` (folder name), ``key`` (the settings it depends on, with
``init_points_from: "sfm"`` when G started from SfM points),
``gaussians`` (:meth:`avgs.gaussians.model.GaussianModel.to_dict`), ``stats``, ``history``.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Callable

import numpy as np
import torch

from avgs.io.atomic import torch_save
from avgs.io.checkpoint import load_weights_only
from avgs.acoustics.points import AudioPoints, alpha_from_colors, alpha_from_gaussians, parse_alpha_spec
from avgs.config import TrainConfig

STAGE1_FORMAT = "avgs-stage1"
STAGE1_VERSION = 1


def stage1_path(checkpoint: str | Path) -> Path:
    """``<ckpt>.stage1.pt`` next to the checkpoint."""
    ckpt = Path(checkpoint)
    return ckpt.with_name(ckpt.name + ".stage1.pt")




def stage1_key(cfg: TrainConfig, init_source: str | None = None) -> dict:
    """The settings G depends on: the 3D-GS config, the seed and, for SfM points, that source
    (plain values; the key of a G from scene.json or random points is what it always was)."""
    g = dataclasses.asdict(cfg.gaussians)
    g.pop("backend", None)  # either rasterizer trains the same model
    key = {"gaussians": g, "seed": int(cfg.seed)}
    if init_source == "sfm":
        key["init_points_from"] = "sfm"
    return key


def needs_gaussians(cfg: TrainConfig) -> bool:
    """Stage 1 runs when G_a is initialised from G or G is stored for drawing."""
    return cfg.init == "gs" or cfg.store_gaussians


def has_surfaces(metadata: dict | None) -> bool:
    """True when scene.json describes the scene's surfaces (our generated scenes)."""
    return isinstance(metadata, dict) and bool(metadata.get("surfaces"))


def stage1_init_source(metadata: dict | None, cfg: TrainConfig) -> str:
    """Where the initial points of G (and, with ``--init sfm``, of G_a) come from:
    ``"scene.json"`` (its surfaces, when it has them), ``"sfm"`` (points triangulated from the
    frames, ``--init sfm`` on a scene without surfaces) or ``"random"`` (along training rays)."""
    if has_surfaces(metadata):
        return "scene.json"
    return "sfm" if cfg.init == "sfm" else "random"


def cpu_stage1_budget(scene_dir: Path, cfg: TrainConfig) -> dict | None:
    """Stage 1's CPU budget, or None where ``cfg`` applies as it is.

    On the CPU, a stage 1 asked for the paper's full-size frames (``image_downscale`` 1) on
    frames larger than ``cfg.gaussians.cpu_max_pixels`` trains on frames shrunk by the smallest
    integer factor that fits, with at most ``cpu_max_gaussians`` Gaussians, so that the 3k
    iterations take minutes instead of hours on two cores (docs/results.md, "Scenes without
    geometry"). Returns the ``{"image_downscale", "max_gaussians"}`` to train with. On CUDA,
    with a downscale other than 1 given, or with ``cpu_max_pixels`` 0, nothing changes.
    """
    g = cfg.gaussians
    if cfg.device != "cpu" or g.image_downscale != 1 or g.backend == "gsplat" or g.cpu_max_pixels <= 0:
        return None
    from avgs.data.views import load_views

    views = load_views(scene_dir, "train")
    factor = 1
    while max(1, views.width // factor) * max(1, views.height // factor) > g.cpu_max_pixels:
        factor += 1
    if factor == 1:
        return None
    return {"image_downscale": factor, "max_gaussians": min(g.max_gaussians, g.cpu_max_gaussians)}


def initial_points(
    scene_dir: Path,
    metadata: dict | None,
    cfg: TrainConfig,
    *,
    progress: bool = True,
    log_fn: Callable[[dict], None] | None = None,
) -> tuple[np.ndarray, np.ndarray] | None:
    """Initial points ``([n, 3] normalised, [n, 3] RGB in [0, 1])`` from the source
    :func:`stage1_init_source` names, at most ``cfg.gaussians.init_points`` of them (a seeded
    subset); None for random points (drawn by the stage-1 trainer from its views).

    SfM points are triangulated from the train frames in a temporary folder (nothing is
    written into the scene); ValueError naming the scene when too few triangulate.
    """
    source = stage1_init_source(metadata, cfg)
    rng = np.random.default_rng(cfg.seed)
    if source == "scene.json":
        from avgs.data.scene_geometry import surface_points

        return surface_points(metadata, cfg.gaussians.init_points, rng)
    if source == "random":
        return None
    from avgs.gaussians.sfm import sfm_points

    sparse = sfm_points(scene_dir, "train", progress=progress)
    points, colors = sparse.points, sparse.colors
    if len(points) > cfg.gaussians.init_points:
        keep = np.sort(rng.choice(len(points), cfg.gaussians.init_points, replace=False))
        points, colors = points[keep], colors[keep]
    if log_fn is not None:
        log_fn({"event": "sfm_points", "kept": int(len(points)), **{f"sfm_{k}": v for k, v in sparse.stats.items()}})
    return points, colors


def train_stage1(
    scene_dir: str | Path,
    cfg: TrainConfig,
    *,
    progress: bool = True,
    log_fn: Callable[[dict], None] | None = None,
    init: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[dict, dict]:
    """Train G on the scene's frames; returns ``(gaussians dict, stats)`` (stats include val PSNR
    and ``init_source``). ``init``: the initial points when the caller has them already
    (:func:`initial_points`), else they are made here."""
    from avgs.data.rwavs import read_scene_metadata
    from avgs.data.views import load_views
    from avgs.gaussians.trainer import random_init_points, train_gaussians

    scene_dir = Path(scene_dir)
    metadata = read_scene_metadata(scene_dir)
    source = stage1_init_source(metadata, cfg)
    if init is None and source != "random":
        init = initial_points(scene_dir, metadata, cfg, progress=progress, log_fn=log_fn)
    views = load_views(scene_dir, "train")
    if init is not None:
        init_points, init_colors = init
    else:
        rng = np.random.default_rng(cfg.seed)
        init_points, init_colors = random_init_points(views, cfg.gaussians.init_points, rng), None
    gaussians, stats = train_gaussians(
        views, cfg.gaussians, init_points, init_colors, device=cfg.device, seed=cfg.seed, progress=progress,
        log_fn=log_fn,
    )
    stats["init_source"] = source
    stats["init_points"] = int(len(init_points))
    return gaussians.to_dict(), stats


def save_stage1(path: str | Path, scene_name: str, cfg: TrainConfig, gaussians: dict, stats: dict, history: list[dict]) -> Path:
    """Write the stage-1 file atomically (its key names the initial points' source from ``stats``)."""
    data = {
        "format": STAGE1_FORMAT,
        "version": STAGE1_VERSION,
        "scene": scene_name,
        "key": stage1_key(cfg, stats.get("init_source")),
        "gaussians": {k: v.detach().float().cpu() for k, v in gaussians.items()},
        "stats": {k: v for k, v in stats.items() if isinstance(v, (int, float, str, bool, type(None)))},
        "history": list(history),
    }
    return torch_save(data, path)


def load_stage1(path: str | Path) -> dict:
    """Read and check a stage-1 file (``torch.load(weights_only=True)``)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: stage-1 file missing (write one with 'avgs train SCENE --out X --stage1-only')")
    data = load_weights_only(path, "a stage-1 file")  # never runs code; no advice to allow it
    if not isinstance(data, dict) or data.get("format") != STAGE1_FORMAT:
        raise ValueError(f"{path}: not a stage-1 file (expected format {STAGE1_FORMAT!r})")
    if data.get("version") != STAGE1_VERSION:
        raise ValueError(f"{path}: stage-1 format version {data.get('version')!r}, this avgs reads {STAGE1_VERSION}")
    g = data.get("gaussians")
    if not isinstance(g, dict) or "means" not in g or "sh" not in g:
        raise ValueError(f"{path}: holds no Gaussians (expected means, quats, log_scales, opacity_logits, sh)")
    return data


def reusable(data: dict, scene_name: str, cfg: TrainConfig, init_source: str | None = None) -> bool:
    """True when a stage-1 file was made for this scene with these settings (and this source
    of initial points, :func:`stage1_init_source`)."""
    return data.get("scene") == scene_name and data.get("key") == stage1_key(cfg, init_source)


def audio_points_from(gaussians: dict | None, geometry, cfg: TrainConfig) -> AudioPoints:
    """G_a: X from G's means and alpha from G's parameters (``init="gs"``), or both from the
    initial points (``init="sfm"``: scene.json's surfaces, else SfM points); capped at
    ``cfg.points.initial_points`` (else ``max_points``) by a seeded random subset."""
    from avgs.gaussians.model import GaussianModel

    spec = cfg.acoustic.alpha_init
    parse_alpha_spec(spec)
    if cfg.init == "gs":
        if gaussians is None:
            raise ValueError("--init gs needs stage 1's Gaussians")
        model = GaussianModel.from_dict(gaussians)
        X = model.means.detach().float().cpu()  # [N, 3]
        alpha = alpha_from_gaussians(model, spec).cpu()  # [N, D]
    else:
        if geometry is None:
            raise ValueError("--init sfm needs the initial points (scene.json surfaces or SfM points)")
        X = torch.as_tensor(np.asarray(geometry[0]), dtype=torch.float32)  # [N, 3]
        alpha = alpha_from_colors(torch.as_tensor(np.asarray(geometry[1])), spec)  # [N, D]
    cap = min(cfg.points.max_points, cfg.points.initial_points or cfg.points.max_points)
    if len(X) > cap:
        keep = torch.randperm(len(X), generator=torch.Generator().manual_seed(cfg.seed))[:cap]
        X, alpha = X[keep], alpha[keep]
    return AudioPoints(X, alpha)
