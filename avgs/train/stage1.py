"""Stage 1 of the pipeline: G (3D-GS) warmed up on a scene's RGB key frames, and G_a from it.

Stage 1 reads only the frames, the poses and scene.json (never the audio), so it can run
on its own, e.g. on a GPU machine with gsplat, and hand its result to stage 2 elsewhere.
Its result is kept in a small file next to the checkpoint (``scene.ckpt.stage1.pt``):
a later run of the same scene and stage-1 settings reuses it instead of training G again
(nothing lost when stage 2 is interrupted), and ``avgs train --stage1 FILE`` shares one G
between several stage-2 runs (the ablations).

The file is a ``torch.save`` dict of tensors and plain values (``weights_only`` loadable):
``format``, ``version``, ``scene`` (folder name), ``key`` (the settings it depends on),
``gaussians`` (:meth:`avgs.gaussians.model.GaussianModel.to_dict`), ``stats``, ``history``.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Callable

import numpy as np
import torch

from avgs.atomic import torch_save
from avgs.acoustics.points import AudioPoints, alpha_from_colors, alpha_from_gaussians, parse_alpha_spec
from avgs.config import TrainConfig

STAGE1_FORMAT = "avgs-stage1"
STAGE1_VERSION = 1


def stage1_path(checkpoint: str | Path) -> Path:
    """``<ckpt>.stage1.pt`` next to the checkpoint."""
    ckpt = Path(checkpoint)
    return ckpt.with_name(ckpt.name + ".stage1.pt")


def stage1_key(cfg: TrainConfig) -> dict:
    """The settings G depends on: the 3D-GS config and the seed (plain values)."""
    g = dataclasses.asdict(cfg.gaussians)
    g.pop("backend", None)  # either rasterizer trains the same model
    return {"gaussians": g, "seed": int(cfg.seed)}


def needs_gaussians(cfg: TrainConfig) -> bool:
    """Stage 1 runs when G_a is initialised from G or G is stored for drawing."""
    return cfg.init == "gs" or cfg.store_gaussians


def geometry_points(scene_dir: Path, metadata: dict | None, cfg: TrainConfig) -> tuple[np.ndarray, np.ndarray] | None:
    """Points on the scene's surfaces ``([n, 3] normalised, [n, 3] RGB)`` from scene.json, or None."""
    if metadata is None or not metadata.get("surfaces"):
        if cfg.init == "sfm":
            raise ValueError(
                f"{scene_dir}: --init sfm needs the scene's geometry points (scene.json 'surfaces'), which this "
                "scene does not have (real RWAVS scenes); use --init gs"
            )
        return None
    from avgs.data.synth.geometry import surface_points

    rng = np.random.default_rng(cfg.seed)
    return surface_points(metadata, cfg.gaussians.init_points, rng)


def train_stage1(
    scene_dir: str | Path,
    cfg: TrainConfig,
    *,
    progress: bool = True,
    log_fn: Callable[[dict], None] | None = None,
) -> tuple[dict, dict]:
    """Train G on the scene's frames; returns ``(gaussians dict, stats)`` (stats include val PSNR)."""
    from avgs.data.rwavs import read_scene_metadata
    from avgs.data.views import load_views
    from avgs.gaussians.trainer import random_init_points, train_gaussians

    scene_dir = Path(scene_dir)
    geometry = geometry_points(scene_dir, read_scene_metadata(scene_dir), cfg)
    views = load_views(scene_dir, "train")
    if geometry is not None:
        init_points, init_colors = geometry
    else:
        rng = np.random.default_rng(cfg.seed)
        init_points, init_colors = random_init_points(views, cfg.gaussians.init_points, rng), None
    gaussians, stats = train_gaussians(
        views, cfg.gaussians, init_points, init_colors, device=cfg.device, seed=cfg.seed, progress=progress,
        log_fn=log_fn,
    )
    return gaussians.to_dict(), stats


def save_stage1(path: str | Path, scene_name: str, cfg: TrainConfig, gaussians: dict, stats: dict, history: list[dict]) -> Path:
    """Write the stage-1 file atomically."""
    data = {
        "format": STAGE1_FORMAT,
        "version": STAGE1_VERSION,
        "scene": scene_name,
        "key": stage1_key(cfg),
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
    try:
        data = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # noqa: BLE001 - any unreadable file gets the same clear error
        raise ValueError(f"{path}: not a stage-1 file ({type(exc).__name__}: {exc})") from None
    if not isinstance(data, dict) or data.get("format") != STAGE1_FORMAT:
        raise ValueError(f"{path}: not a stage-1 file (expected format {STAGE1_FORMAT!r})")
    if data.get("version") != STAGE1_VERSION:
        raise ValueError(f"{path}: stage-1 format version {data.get('version')!r}, this avgs reads {STAGE1_VERSION}")
    g = data.get("gaussians")
    if not isinstance(g, dict) or "means" not in g or "sh" not in g:
        raise ValueError(f"{path}: holds no Gaussians (expected means, quats, log_scales, opacity_logits, sh)")
    return data


def reusable(data: dict, scene_name: str, cfg: TrainConfig) -> bool:
    """True when a stage-1 file was made for this scene with these settings."""
    return data.get("scene") == scene_name and data.get("key") == stage1_key(cfg)


def audio_points_from(gaussians: dict | None, geometry, cfg: TrainConfig) -> AudioPoints:
    """G_a: X from G's means and alpha from G's parameters (``init="gs"``), or both from the
    scene's geometry points (``init="sfm"``); capped at ``cfg.points.initial_points`` (else
    ``max_points``) by a seeded random subset."""
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
        X = torch.as_tensor(np.asarray(geometry[0]), dtype=torch.float32)  # [N, 3]
        alpha = alpha_from_colors(torch.as_tensor(np.asarray(geometry[1])), spec)  # [N, D]
    cap = min(cfg.points.max_points, cfg.points.initial_points or cfg.points.max_points)
    if len(X) > cap:
        keep = torch.randperm(len(X), generator=torch.Generator().manual_seed(cfg.seed))[:cap]
        X, alpha = X[keep], alpha[keep]
    return AudioPoints(X, alpha)
