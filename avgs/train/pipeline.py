"""Both stages end to end: scene folder in, ``scene.ckpt`` (+ log + curves) out.

Stage 1 warms up the 3D-GS scene G on the RGB key frames (:mod:`avgs.gaussians`);
G_a is initialised from it (``init="gs"``) or straight from the scene's geometry points
(``init="sfm"``, scenes with a scene.json only). Stage 2 (:mod:`avgs.train.stage2`)
trains G_a, F and B on the audio clips, saving the checkpoint atomically every
``checkpoint_every`` iterations; ``resume=True`` continues from the last one.
"""

from __future__ import annotations

import copy
import time
from pathlib import Path

import numpy as np
import torch

from avgs.acoustics.model import AVGSModel
from avgs.acoustics.points import AudioPoints, alpha_from_colors, alpha_from_gaussians, parse_alpha_spec
from avgs.checkpoint import build_checkpoint, config_of, load_checkpoint, outline_from_metadata, save_checkpoint
from avgs.config import TrainConfig
from avgs.train.logging import JsonLinesLog, log_paths, plot_curves
from avgs.train.stage2 import Stage2Trainer


def quick_config(cfg: TrainConfig | None = None) -> TrainConfig:
    """The ``--quick`` preset: a tiny run for tests and smoke checks (small images, few iterations)."""
    cfg = copy.deepcopy(cfg or TrainConfig())
    g, a, p = cfg.gaussians, cfg.acoustic, cfg.points
    g.iterations, g.init_points, g.image_downscale = 30, 1500, 4
    g.densify_from, g.densify_every, g.sh_degree_interval = 10, 10, 10
    g.max_gaussians = 4000
    a.iterations, a.batch_size = 300, 4
    p.densify_every, p.prune_every, p.max_points = 50, 150, 4000
    cfg.checkpoint_every, cfg.eval_every, cfg.log_every = 100, 150, 10
    return cfg


def _audio_points_from_stage1(scene, cfg: TrainConfig, log, progress: bool):
    """(AudioPoints, gaussians dict or None): stage 1 as ``cfg.init`` and ``cfg.store_gaussians`` ask."""
    rng = np.random.default_rng(cfg.seed)
    spec = cfg.acoustic.alpha_init
    parse_alpha_spec(spec)
    geometry = None
    if scene.metadata is not None and scene.metadata.get("surfaces"):
        from avgs.data.synth.geometry import surface_points

        geometry = surface_points(scene.metadata, cfg.gaussians.init_points, rng)  # ([n,3] normalised, [n,3])
    elif cfg.init == "sfm":
        raise ValueError(
            f"{scene.root}: --init sfm needs the scene's geometry points (scene.json 'surfaces'), which this "
            "scene does not have (real RWAVS scenes); use --init gs"
        )

    gaussians = None
    if cfg.init == "gs" or cfg.store_gaussians:
        from avgs.data.views import load_views
        from avgs.gaussians.trainer import random_init_points, train_gaussians

        views = load_views(scene.root, "train")
        if geometry is not None:
            init_points, init_colors = geometry
        else:
            init_points, init_colors = random_init_points(views, cfg.gaussians.init_points, rng), None

        def log_fn(record: dict) -> None:
            log.write({"stage": "stage1", **record})

        gaussians, _ = train_gaussians(
            views,
            cfg.gaussians,
            init_points,
            init_colors,
            device=cfg.device,
            seed=cfg.seed,
            progress=progress,
            log_fn=log_fn,
        )
    if cfg.init == "gs":
        X = gaussians.means.detach().float().cpu()  # [N, 3]
        alpha = alpha_from_gaussians(gaussians, spec).cpu()  # [N, D]
    else:
        X = torch.as_tensor(np.asarray(geometry[0]), dtype=torch.float32)
        alpha = alpha_from_colors(torch.as_tensor(np.asarray(geometry[1])), spec)
    if len(X) > cfg.points.max_points:  # keep G_a within the cap from the start
        keep = torch.randperm(len(X), generator=torch.Generator().manual_seed(cfg.seed))[: cfg.points.max_points]
        X, alpha = X[keep], alpha[keep]
    stored = gaussians.to_dict() if (gaussians is not None and cfg.store_gaussians) else None
    return AudioPoints(X, alpha), stored


def _bounds_world(scene, X: torch.Tensor, gaussians: dict | None) -> np.ndarray:
    """Box [2, 3] (world) around the audio points, G, the listener poses and the source."""
    parts = [X.detach().cpu().numpy().reshape(-1, 3), scene.source[None]]
    parts += [np.stack([c.listener for c in clips]) for clips in (scene.train, scene.val) if clips]
    if gaussians is not None and "means" in gaussians:
        parts.append(gaussians["means"].detach().cpu().numpy().reshape(-1, 3))
    pts = scene.frame.to_world(np.concatenate(parts).astype(np.float64))
    return np.stack([pts.min(0), pts.max(0)])


def train_scene(
    scene_dir: str | Path,
    out: str | Path,
    cfg: TrainConfig | None = None,
    *,
    resume: bool = False,
    progress: bool = True,
    initial_points: AudioPoints | None = None,
) -> dict:
    """Train AV-GS on one scene and write ``out``; returns the final log record (with val MAG/ENV).

    ``initial_points`` (normalised frame) skips stage 1: G_a starts from them and no G is
    stored (for experiments on given geometry, and for tests that exercise stage 2 alone).

    With ``resume`` and an existing ``out``, the model, optimizer and random state come from
    it and training continues from its iteration up to ``cfg.acoustic.iterations``.
    """
    from tqdm.auto import tqdm

    from avgs.data.rwavs import RWAVSScene

    cfg = copy.deepcopy(cfg or TrainConfig())
    out = Path(out)
    log_path, png_path = log_paths(out)
    scene = RWAVSScene(scene_dir, cfg.stft)
    if not scene.train:
        raise ValueError(f"{scene.root}: no training clips")
    torch.manual_seed(cfg.seed)

    resumed = None
    if resume and out.is_file():
        resumed = load_checkpoint(out)
        if "train_state" not in resumed:
            raise ValueError(f"{out}: holds no training state to resume from")
        stored = config_of(resumed)
        stored.acoustic.iterations = cfg.acoustic.iterations
        stored.checkpoint_every, stored.eval_every, stored.log_every = cfg.checkpoint_every, cfg.eval_every, cfg.log_every
        stored.device = cfg.device
        cfg = stored
        log = JsonLinesLog(log_path, resumed["history"])
        pts = resumed["audio_points"]
        points = AudioPoints(pts["X"], pts["alpha"])
        gaussians = resumed.get("gaussians")
    else:
        log = JsonLinesLog(log_path)
        t0 = time.perf_counter()
        if initial_points is not None:
            points, gaussians = initial_points, None
        else:
            points, gaussians = _audio_points_from_stage1(scene, cfg, log, progress)
        log.write({"stage": "stage1", "event": "done", "seconds": time.perf_counter() - t0, "points": points.num_points})

    torch.manual_seed(cfg.seed)
    model = AVGSModel(points, cfg.acoustic, cfg.stft.n_freq)
    if resumed is not None:
        if model.field is not None:
            model.field.load_state_dict(resumed["field"])
        model.binauralizer.load_state_dict(resumed["binauralizer"])
    trainer = Stage2Trainer(model, scene.dataset("train", cfg.stft), cfg, cfg.device)
    if resumed is not None:
        trainer.load_state_dict(resumed["train_state"])
    val = scene.dataset("val", cfg.stft) if scene.val else None
    outline = outline_from_metadata(scene.metadata)

    def save(metrics: dict | None = None) -> None:
        ckpt = build_checkpoint(
            model,
            scene.frame,
            scene.source,
            cfg,
            history=log.records,
            gaussians=gaussians,
            name=scene.name,
            bounds_world=_bounds_world(scene, model.points.X, gaussians),
            outline_world=outline,
            stft=cfg.stft,
            extra={"train_state": trainer.state_dict(), "metrics": dict(metrics or {})},
        )
        save_checkpoint(ckpt, out)

    total = cfg.acoustic.iterations
    final: dict = {}
    bar = tqdm(total=total, initial=trainer.iteration, desc="stage 2 (audio)", disable=not progress, dynamic_ncols=True)
    t0 = time.perf_counter()
    while trainer.iteration < total:
        rec = trainer.step()
        it = trainer.iteration
        bar.update(1)
        record = {"stage": "stage2", "iteration": it, **rec}
        if val is not None and (it % cfg.eval_every == 0 or it == total):
            record.update(trainer.evaluate(val))
            bar.set_postfix(loss=f"{rec['loss']:.4f}", mag=f"{record['val_mag']:.3f}", points=rec["points"])
        if it % cfg.log_every == 0 or it == total or rec["added"] or rec["removed"] or "val_mag" in record:
            log.write({**record, "seconds": time.perf_counter() - t0})
        if it == total:
            final = {k: record[k] for k in ("iteration", "loss", "points", "val_mag", "val_env") if k in record}
        elif it % cfg.checkpoint_every == 0:
            save()
    bar.close()
    if not final:  # resumed at or past the end: evaluate what there is
        final = {"iteration": trainer.iteration, "points": model.points.num_points}
        if val is not None:
            final.update(trainer.evaluate(val))
    log.write({"stage": "final", **final})
    save(final)
    plot_curves(log.records, png_path)
    return final
