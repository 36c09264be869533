"""Stage 1: warm up the 3D-GS scene G on the RGB key frames (paper §3.4: 3k iterations).

Per iteration one random training view is rendered and ``L = (1 - l) L1 + l (1 - SSIM)``
(l = 0.2) is minimised with Adam at the learning rates of 3D-GS (positions scaled by the
scene extent and decayed 100x exponentially over the run); the SH degree grows by one every
``sh_degree_interval`` iterations; clone / split / prune / opacity reset follow
:class:`avgs.gaussians.densify.DensifyStrategy`. With a fixed seed, CPU runs are
reproducible (one ``torch.Generator`` drives view choice and split sampling).
"""

from __future__ import annotations

import math
import time
import warnings
from typing import Callable

import numpy as np
import torch

from avgs.config import GaussianConfig
from avgs.data.views import Views, load_views
from avgs.gaussians.cameras import viewmat_from_c2w
from avgs.gaussians.densify import DensifyStrategy
from avgs.gaussians.model import GaussianModel
from avgs.gaussians.rasterize import rasterize, resolve_backend
from avgs.gaussians.ssim import ssim

INIT_DEPTH = (0.05, 2.0)
"Depth range of random initial points along training rays, times max(scene extent, 1)."
TRAIN_PSNR_VIEWS = 8
"Training views (evenly spaced) on which the final training PSNR is measured."


def random_init_points(views: Views, n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` points ``[n, 3]`` (normalised frame) for a scene without geometry: each on the
    ray of a random pixel of a random training view, at a depth uniform in
    :data:`INIT_DEPTH` x max(scene extent, 1), so every point starts inside some view."""
    if n < 1:
        raise ValueError(f"random_init_points: n must be >= 1, got {n}")
    c2w = views.c2w.detach().cpu().double().numpy()  # [V, 4, 4]
    K = views.K.detach().cpu().double().numpy()  # [V, 3, 3]
    v = rng.integers(0, len(views), n)
    u = rng.uniform(0, views.width, n)
    w = rng.uniform(0, views.height, n)
    s = max(views.scene_extent(), 1.0)
    depth = rng.uniform(INIT_DEPTH[0] * s, INIT_DEPTH[1] * s, n)
    d_cam = np.stack([(u - K[v, 0, 2]) / K[v, 0, 0], -(w - K[v, 1, 2]) / K[v, 1, 1], -np.ones(n)], -1)  # [n, 3] OpenGL
    d_world = np.einsum("nij,nj->ni", c2w[v, :3, :3], d_cam)
    return (c2w[v, :3, 3] + depth[:, None] * d_world).astype(np.float64)


def psnr(pred: torch.Tensor, target: torch.Tensor) -> float:
    """PSNR (dB) of images in [0, 1] (``pred`` clamped); 100 for an exact match."""
    mse = float(((pred.detach().clamp(0, 1) - target) ** 2).mean())
    return 100.0 if mse <= 1e-10 else -10.0 * math.log10(mse)


def _render(model: GaussianModel, viewmat, K, width, height, sh_degree, backend, background=None):
    return rasterize(
        model.means, model.quats, model.scales, model.opacities, model.sh,
        viewmat, K, width, height, sh_degree=sh_degree, backend=backend, background=background,
    )  # fmt: skip


@torch.no_grad()
def render_view(
    gaussians: GaussianModel,
    c2w,
    K,
    width: int,
    height: int,
    sh_degree: int | None = None,
    backend: str = "auto",
    background=None,
) -> torch.Tensor:
    """G seen from any pose: ``c2w [4, 4]`` OpenGL camera-to-world (normalised frame), ``K [3, 3]``
    pixels -> ``rgb [H, W, 3]`` in [0, 1] on the model's device."""
    dev = gaussians.means.device
    c2w = torch.as_tensor(np.asarray(c2w, dtype=np.float32) if not isinstance(c2w, torch.Tensor) else c2w).float().to(dev)
    K = torch.as_tensor(np.asarray(K, dtype=np.float32) if not isinstance(K, torch.Tensor) else K).float().to(dev)
    degree = gaussians.sh_degree if sh_degree is None else sh_degree
    rgb, _, _ = _render(gaussians, viewmat_from_c2w(c2w), K, width, height, degree, resolve_backend(backend, dev), background)
    return rgb.clamp(0.0, 1.0)


@torch.no_grad()
def evaluate_psnr(gaussians: GaussianModel, views: Views, sh_degree: int | None = None, backend: str = "auto") -> float:
    """Mean PSNR (dB) of G's renders against ``views`` (at the views' resolution)."""
    if len(views) == 0:
        raise ValueError("evaluate_psnr: no views")
    views = views.to(gaussians.means.device)
    scores = [
        psnr(render_view(gaussians, views.c2w[i], views.K[i], views.width, views.height, sh_degree, backend), views.images[i])
        for i in range(len(views))
    ]
    return float(np.mean(scores))


def _val_views(views: Views, val_views: Views | None) -> Views | None:
    if val_views is not None:
        return val_views
    if views.root is None or views.split != "train":
        return None
    try:
        return load_views(views.root, "val")
    except FileNotFoundError:
        return None  # a scene without a val split
    except ValueError as exc:
        warnings.warn(f"stage 1: no held-out PSNR, the val views do not load: {exc}", UserWarning, stacklevel=3)
        return None


def make_optimizer(model: GaussianModel, cfg: GaussianConfig, scene_scale: float) -> torch.optim.Adam:
    """Adam with one group per parameter (named), 3D-GS learning rates, eps 1e-15."""
    lrs = {
        "means": cfg.lr_means * scene_scale,
        "quats": cfg.lr_quat,
        "log_scales": cfg.lr_scale,
        "opacity_logits": cfg.lr_opacity,
        "sh0": cfg.lr_sh0,
        "shN": cfg.lr_shN,
    }
    groups = [{"params": [model.params[k]], "lr": lr, "name": k} for k, lr in lrs.items()]
    return torch.optim.Adam(groups, eps=1e-15)


def train_gaussians(
    views: Views,
    cfg: GaussianConfig,
    init_points,
    init_colors=None,
    *,
    device: str | torch.device = "cpu",
    seed: int = 0,
    progress: bool = True,
    log_fn: Callable[[dict], None] | None = None,
    val_views: Views | None = None,
) -> tuple[GaussianModel, dict]:
    """Fit G to ``views`` (downscaled by ``cfg.image_downscale``) from ``init_points [n, 3]``
    (normalised) with colours ``init_colors [n, 3]`` in [0, 1] or None (grey).

    ``val_views`` default: the scene's val split when ``views`` came from a scene folder.
    ``log_fn`` receives JSON-able records (``iteration, loss, psnr, num_gaussians, ...``).
    Returns the model (on ``device``) and stats: ``iterations, seconds, ms_per_iteration,
    num_gaussians, train_psnr, val_psnr`` (None without val views), ``backend``, image
    size, ``scene_extent`` and totals of ``cloned, split, pruned``.
    """
    from tqdm.auto import tqdm

    t_start = time.perf_counter()
    dev = torch.device(device)
    gen = torch.Generator().manual_seed(int(seed))
    train = views.downscaled(cfg.image_downscale).to(dev)
    val = _val_views(views, val_views)
    val = val.downscaled(cfg.image_downscale).to(dev) if val is not None else None
    backend = resolve_backend(cfg.backend, dev)

    pts = np.asarray(init_points, dtype=np.float64).reshape(-1, 3)
    cols = None if init_colors is None else np.asarray(init_colors, dtype=np.float32).reshape(-1, 3)
    if cols is not None and len(cols) != len(pts):
        raise ValueError(f"train_gaussians: {len(cols)} initial colours for {len(pts)} points")
    if len(pts) > cfg.max_gaussians:
        keep = torch.randperm(len(pts), generator=gen)[: cfg.max_gaussians].sort().values.numpy()
        pts, cols = pts[keep], (None if cols is None else cols[keep])
    model = GaussianModel.from_points(pts, cols, sh_degree=cfg.sh_degree).to(dev)

    extent = train.scene_extent()
    optimizer = make_optimizer(model, cfg, extent)
    strategy = DensifyStrategy.from_config(cfg, extent)
    state = strategy.initialize_state()
    viewmats = viewmat_from_c2w(train.c2w)  # [V, 4, 4]
    W, H, total = train.width, train.height, int(cfg.iterations)
    totals = {"cloned": 0, "split": 0, "pruned": 0}
    lam = cfg.ssim_weight

    means_group = next(g for g in optimizer.param_groups if g["name"] == "means")
    bar = tqdm(total=total, desc="stage 1 (3D-GS)", disable=not progress, dynamic_ncols=True)
    t_loop = time.perf_counter()
    for step in range(total):
        means_group["lr"] = cfg.lr_means * extent * 0.01 ** (step / total)
        i = int(torch.randint(len(train), (1,), generator=gen))
        sh_degree = min(step // max(1, cfg.sh_degree_interval), cfg.sh_degree)
        rgb, _, aux = _render(model, viewmats[i], train.K[i], W, H, sh_degree, backend)
        gt = train.images[i]
        l1 = (rgb - gt).abs().mean()
        loss = (1.0 - lam) * l1 + lam * (1.0 - ssim(rgb, gt))
        strategy.step_pre_backward(aux)
        loss.backward()
        optimizer.step()
        optimizer.zero_grad(set_to_none=True)
        changes = strategy.step_post_backward(model, optimizer, state, step, aux, gen)
        for k in totals:
            totals[k] += changes.get(k, 0)
        it = step + 1
        if it == 1 or it % max(1, cfg.log_every) == 0 or it == total or changes:
            rec = {
                "iteration": it,
                "loss": loss.item(),
                "psnr": psnr(rgb, gt),
                "num_gaussians": len(model),
                "sh_degree": sh_degree,
                "seconds": time.perf_counter() - t_start,
            }
            rec.update({k: v for k, v in changes.items() if v})
            if log_fn is not None:
                log_fn(rec)
            bar.set_postfix(loss=f"{rec['loss']:.4f}", psnr=f"{rec['psnr']:.2f}", n=len(model))
        bar.update(1)
    bar.close()
    loop_seconds = time.perf_counter() - t_loop

    model.requires_grad_(False)
    picks = np.unique(np.linspace(0, len(train) - 1, min(TRAIN_PSNR_VIEWS, len(train))).round().astype(int))
    stats = {
        "iterations": total,
        "seconds": time.perf_counter() - t_start,
        "ms_per_iteration": 1000.0 * loop_seconds / max(1, total),
        "num_gaussians": len(model),
        "train_psnr": evaluate_psnr(model, train.subset(picks), backend=backend),
        "val_psnr": evaluate_psnr(model, val, backend=backend) if val is not None and len(val) else None,
        "backend": backend,
        "width": W,
        "height": H,
        "scene_extent": extent,
        **totals,
    }
    model.requires_grad_(True)
    stats["seconds"] = time.perf_counter() - t_start
    if log_fn is not None:
        keys = ("train_psnr", "val_psnr", "num_gaussians", "ms_per_iteration", "seconds")
        log_fn({"iteration": total, "event": "eval", **{k: stats[k] for k in keys}})
    return model, stats
