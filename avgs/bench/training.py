"""Training throughput (iterations per second) and peak memory, both stages, CPU and CUDA.

Each measurement runs in a child process (``python -m avgs.bench.training JSON``) so
that its peak resident memory (``ru_maxrss``) is its own; on CUDA the peak is
``torch.cuda.max_memory_allocated``. Stage 1 is timed when :mod:`avgs.gaussians` is
present, on the scene's RGB views at the ``--quick`` preset's resolution.

``init`` picks where the points come from, reading only the frames and poses (never
scene.json), as on a real recording without geometry: ``"random"`` (stage 1's random points
along the training rays; for stage 2, that many audio points) or ``"sfm"`` (points
triangulated from the frames, :mod:`avgs.gaussians.sfm`; its time is reported as
``sfm_seconds``). Stage 2's default ``"box"`` is the bench's fixed-N model (points uniform
in the box around the poses).
"""

from __future__ import annotations

import json
import resource
import subprocess
import sys
import time


def _points_without_geometry(scene_dir: str, n: int, init: str, threads: int) -> tuple:
    """``(points [n, 3], colours [n, 3] or None, extra stats)`` from the frames and poses only."""
    import numpy as np

    from avgs.data.views import load_views
    from avgs.gaussians.trainer import random_init_points

    if init == "sfm":
        from avgs.gaussians.sfm import sfm_points

        try:
            sparse = sfm_points(scene_dir, threads=threads, progress=False)
        except ValueError as exc:  # the row says what failed, without the scene's path and the advice
            raise ValueError(str(exc).split(": ", 1)[-1].split("; ")[0]) from None
        return sparse.points, sparse.colors, {"sfm_seconds": sparse.stats["seconds"], "sfm_points": len(sparse.points)}
    if init != "random":
        raise ValueError(f"init must be 'random' or 'sfm', got {init!r}")
    return random_init_points(load_views(scene_dir, "train"), n, np.random.default_rng(0)), None, {}


def _stage2(scene_dir: str, n_points: int, vicinity: float, iterations: int, device: str, threads: int,
            init: str = "box") -> dict:
    import torch

    from avgs.acoustics.model import AVGSModel
    from avgs.acoustics.points import AudioPoints, alpha_from_colors
    from avgs.bench.speed_error import bench_config, initial_points
    from avgs.data.rwavs import RWAVSScene
    from avgs.train.stage2 import Stage2Trainer

    torch.set_num_threads(threads)
    scene = RWAVSScene(scene_dir)
    extra: dict = {}
    if init == "box":
        points = initial_points(scene, n_points)
    else:
        X, colors, extra = _points_without_geometry(scene_dir, n_points, init, threads)
        alpha = torch.randn(len(X), 52, generator=torch.Generator().manual_seed(0)) * 0.5 if colors is None \
            else alpha_from_colors(torch.as_tensor(colors), "sh+r")
        points = AudioPoints(torch.as_tensor(X, dtype=torch.float32), alpha)
    n_points = points.num_points
    cfg = bench_config(10_000, vicinity, n_points, device)
    cfg.points.enabled = False  # a fixed N, so that the rate is that of N points
    model = AVGSModel(points, cfg.acoustic, cfg.stft)
    trainer = Stage2Trainer(model, scene.dataset("train", cfg.stft), cfg, device)
    for _ in range(3):
        trainer.step()
    if device == "cuda":
        torch.cuda.synchronize()
        torch.cuda.reset_peak_memory_stats()
    t0 = time.perf_counter()
    for _ in range(iterations):
        trainer.step()
    if device == "cuda":
        torch.cuda.synchronize()
    dt = time.perf_counter() - t0
    out = {"stage": 2, "device": device, "init": init, "points": n_points, "k": model.vicinity_k,
           "batch": cfg.acoustic.batch_size, "iterations": iterations, "it_per_s": iterations / dt, **extra}
    if device == "cuda":
        out["peak_mb"] = torch.cuda.max_memory_allocated() / 2**20
    return out


def _stage1(scene_dir: str, iterations: int, device: str, threads: int, init: str = "random") -> dict:
    import torch

    from avgs.data.views import load_views
    from avgs.gaussians.trainer import train_gaussians
    from avgs.train.pipeline import quick_config

    torch.set_num_threads(threads)
    cfg = quick_config().gaussians
    views = load_views(scene_dir, "train")
    pts, colors, extra = _points_without_geometry(scene_dir, cfg.init_points, init, threads)
    cfg.iterations = 3
    train_gaussians(views, cfg, pts, colors, device=device, progress=False)  # warm-up (gsplat JIT on CUDA)
    cfg.iterations = iterations
    if device == "cuda":
        torch.cuda.reset_peak_memory_stats()
    t0 = time.perf_counter()
    g, _ = train_gaussians(views, cfg, pts, colors, device=device, progress=False)
    if device == "cuda":
        torch.cuda.synchronize()
    dt = time.perf_counter() - t0
    out = {"stage": 1, "device": device, "init": init, "gaussians": int(len(g)), "init_points": int(len(pts)),
           "image_downscale": cfg.image_downscale, "iterations": iterations, "it_per_s": iterations / dt, **extra}
    if device == "cuda":
        out["peak_mb"] = torch.cuda.max_memory_allocated() / 2**20
    return out


def _rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # ru_maxrss is in KiB on Linux


def _child(spec: dict) -> dict:
    import torch  # noqa: F401  (imports count towards the base, not the run)

    fn = _stage2 if spec.pop("stage") == 2 else _stage1
    base = _rss_mb()
    out = fn(**spec)
    if out["device"] == "cpu":
        out["peak_mb"] = _rss_mb()
        out["peak_note"] = f"process peak RSS ({base:.0f} MB after importing torch)"
    return out


def measure(spec: dict, timeout: float = 900) -> dict:
    """Run one measurement in a child process; ``{"error": ...}`` when it fails."""
    proc = subprocess.run([sys.executable, "-m", "avgs.bench.training", json.dumps(spec)], capture_output=True,
                          text=True, timeout=timeout)
    lines = [line for line in proc.stdout.splitlines() if line.startswith("{")]
    if proc.returncode != 0 or not lines:
        tail = (proc.stderr.strip().splitlines() or ["no output"])[-1]
        return {**spec, "error": tail[:300]}
    return json.loads(lines[-1])


if __name__ == "__main__":
    print(json.dumps(_child(json.loads(sys.argv[1]))))
