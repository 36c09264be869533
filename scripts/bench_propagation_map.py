"""Time the propagation map (avgs.render.propagation_map) of a checkpoint, measure the fast map's error
against the exact one, and write a short report.

    .venv/bin/python scripts/bench_propagation_map.py --threads 1 2 --workers 1 2 --runs 3 \
        --out benchmarks/propagation_map.md

For each torch thread count (``--threads``: torch's intra-op threads) and each number of map
worker threads (``--workers``: ``propagation_map(workers=...)``), the median over ``--runs``
runs (yaws 0, 30, 60 ...) of the time to the first map covering the floor at each level of
the coarse-to-fine order, and the whole map. Then the exact map of the same poses (one
thread, one worker, also timed) and the fast map's error against it (max, 99th percentile
and median over all cells of all runs), the model's FLOPs per cell both ways, and the
machine's load average (``os.getloadavg``, what ``uptime`` prints) while it ran.
"""

from __future__ import annotations

import argparse
import datetime as dt
import os
import statistics
import time
from pathlib import Path

import numpy as np
import torch

from avgs import SceneRenderer
from avgs.bench.machine import cpu_name
from avgs.render.cells import FastMap, bin_subset, early_frames, frame_nodes
from avgs.render.propagation_map import compute_map, propagation_map

DEMO = Path(__file__).resolve().parents[1] / "assets" / "demo" / "scene.ckpt"


def run_once(renderer, size: int, batch: int, chunk: int | None, yaw: float, z: float, workers: int,
             exact: bool = False):
    """([(cells done, seconds since start)] at every yield, the last map)."""
    t0 = time.perf_counter()
    marks, last = [], None
    for last in propagation_map(renderer, yaw=yaw, z=z, size=size, batch=batch, chunk=chunk, workers=workers,
                                exact=exact):
        marks.append((last.done, time.perf_counter() - t0))
    return marks, last


def _weights(layers) -> int:
    return sum(m.weight.numel() for m in layers)


def flops_per_cell(r, fast: FastMap | None) -> tuple[float, str]:
    """(multiply-adds x 2 of one cell, what it counts). ``fast`` None: the exact map. F: its
    per-point layers over the k points (the last layer, once per mean, left out)."""
    per_point = 0
    if r.model.field is not None:
        first, *rest = r.model.field.linears
        per_point = 3 * first.out_features + _weights(rest[:-1])
    field = r.vicinity_size * per_point
    b = r.model.binauralizer
    n_bins = b.n_freq if fast is None else len(bin_subset(b.n_freq, fast.bin_stride)[0])
    if r.source_aware:  # a model of responses: frames too
        W = b.width
        n_frames = b.n_frames if fast is None else len(frame_nodes(b.n_frames, early_frames(r), fast.tail_frames))
        pose = _weights([b.pose_proj, *b.pose_mlp]) + (b.context_proj.weight.numel() if b.context_proj else 0)
        per_frame = len(b.time_mlp) * W * W + 2 * n_bins * W  # the time MLP (its frame part) and the head
        interpolate = 0 if fast is None else 2 * n_bins * n_frames * b.n_frames
        what = f"the RIR network over {n_frames} frames x {n_bins} bins, F over k = {r.vicinity_size} points"
        return 2.0 * (pose + n_frames * per_frame + interpolate + field), what
    per_bin = _weights(b.mix_mlp) + _weights(b.diff_mlp) + b.mix_head.weight.numel() + b.diff_head.weight.numel()
    if b.reverb is not None:
        per_bin += sum(p.numel() for name, p in b.reverb.head.named_parameters() if name.endswith("weight"))
    return 2.0 * (n_bins * per_bin + field), f"B over {n_bins} bins, F over k = {r.vicinity_size} points"


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("checkpoint", nargs="?", default=str(DEMO))
    p.add_argument("--threads", type=int, nargs="+", default=[1, 2], help="torch intra-op thread counts")
    p.add_argument("--workers", type=int, nargs="+", default=[1, 2], help="map worker thread counts")
    p.add_argument("--runs", type=int, default=3)
    p.add_argument("--size", type=int, default=64)
    p.add_argument("--batch", type=int, default=256)
    p.add_argument("--chunk", type=int, default=None, help="cells per model call (default: the map's)")
    p.add_argument("--out", type=Path, default=None, help="write the report here (markdown)")
    a = p.parse_args()
    if a.out is not None:
        from avgs.io import atomic

        atomic.check_output(a.out, what="report")
    r = SceneRenderer.load(a.checkpoint)
    z = float(np.clip(1.6, *r.bounds[:, 2]))
    yaws = [30.0 * i for i in range(a.runs)]
    load_start = os.getloadavg()
    torch.set_num_threads(1)
    run_once(r, 8, 64, a.chunk, 0.0, z, 1)  # warm-up
    results = {}
    for t in a.threads:
        torch.set_num_threads(t)
        for w in a.workers:
            before = os.getloadavg()[0]
            runs = [run_once(r, a.size, a.batch, a.chunk, yaw, z, w) for yaw in yaws]
            results[t, w] = {"runs": [marks for marks, _ in runs], "maps": [m for _, m in runs],
                             "load": (before, os.getloadavg()[0])}
    torch.set_num_threads(1)
    exact_times, exact_maps = [], []
    before = os.getloadavg()[0]
    for yaw in yaws:
        t0 = time.perf_counter()
        exact_maps.append(compute_map(r, yaw=yaw, z=z, size=a.size, exact=True))
        exact_times.append(time.perf_counter() - t0)
    exact_load = (before, os.getloadavg()[0])
    load_end = os.getloadavg()

    n = a.size * a.size
    levels = [(f"{a.size // s}x{a.size // s} cells (every {ordinal} cell a side)", (-(-a.size // s)) ** 2)
              for s, ordinal in ((4, "4th"), (2, "2nd"))] + [(f"all {a.size}x{a.size} cells", n)]
    stamp = dt.datetime.now(dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    cmd = (f"`.venv/bin/python scripts/bench_propagation_map.py --threads {' '.join(map(str, a.threads))} "
           f"--workers {' '.join(map(str, a.workers))} --runs {a.runs}{' --out ' + str(a.out) if a.out else ''}`")
    fast = FastMap()
    b = r.model.binauralizer
    what = f"{len(bin_subset(b.n_freq, fast.bin_stride)[0])} of {b.n_freq} bins"
    if r.source_aware:  # a model of responses: frames too
        what += f", {len(frame_nodes(b.n_frames, early_frames(r), fast.tail_frames))} of {b.n_frames} frames " \
                f"({early_frames(r)} early, {fast.tail_frames} later)"
    configs = list(results)
    lines = [
        "# Propagation map benchmark",
        "",
        f"Command: {cmd} ({stamp})  ",
        f"Machine: {cpu_name()}, {os.cpu_count()} cores, torch {torch.__version__}; 1-minute load average "
        f"{load_start[0]:.1f} at the start, {load_end[0]:.1f} at the end (other jobs share the cores)  ",
        f"Scene: `{Path(a.checkpoint).name}` (task {r.task}), {len(r.points)} audio points, k = {r.vicinity_size}; "
        f"map {a.size}x{a.size} at z = {z:.2f}, yields every {a.batch} cells; the fast map ({what})",
        "",
        "Fast map: time from the start until the map covers the floor at each level of the coarse-to-fine "
        f"order (median of {a.runs} runs, each run's time in brackets):",
        "",
        "| map covering the floor | cells | "
        + " | ".join(f"{t} torch thread{'s' * (t > 1)}, {w} worker{'s' * (w > 1)}" for t, w in configs) + " |",
        "|---|---|" + "---|" * len(configs),
    ]
    for name, cells in levels:
        cols = []
        for key in configs:
            times = [next(s for done, s in marks if done >= cells) for marks in results[key]["runs"]]
            cols.append(f"{statistics.median(times):.2f} s ({', '.join(f'{s:.2f}' for s in times)})")
        lines.append(f"| {name} | {cells} | " + " | ".join(cols) + " |")
    lines += ["", "Load average (1 minute) before -> after each column: "
              + ", ".join(f"{t}/{w}: {b0:.1f} -> {b1:.1f}" for (t, w), res in results.items()
                          for b0, b1 in [res["load"]]) + "."]
    exact_total = statistics.median(exact_times)
    lines += ["", f"Exact map (`exact=True`), 1 torch thread, 1 worker: {exact_total:.2f} s "
              f"({', '.join(f'{s:.2f}' for s in exact_times)}), load {exact_load[0]:.1f} -> {exact_load[1]:.1f}."]
    lines += ["", f"Fast map against the exact map, all {a.runs * n} cells of the {a.runs} runs (dB):", "",
              "| | max | 99th percentile | median |", "|---|---|---|---|"]
    fast_maps = results[configs[0]]["maps"]
    for kind in ("level", "ild"):
        err = np.concatenate([np.abs(f.values(kind) - e.values(kind)).ravel() for f, e in zip(fast_maps, exact_maps)])
        lines.append(f"| {'level' if kind == 'level' else 'ILD'} | {err.max():.3f} | {np.quantile(err, 0.99):.3f} | "
                     f"{np.median(err):.3f} |")
    span = max(float(e.level.max() - e.level.min()) for e in exact_maps)
    lines += ["", f"(The level spans {span:.1f} dB over the floor.) Workers compute the same cells in the same chunks: "
              "their maps are identical to one worker's."]
    fl_fast, what_fast = flops_per_cell(r, fast)
    fl_exact, what_exact = flops_per_cell(r, None)
    lines += ["", f"FLOPs per cell: exact {fl_exact / 1e6:.0f} MFLOP ({what_exact}), the map "
              f"{fl_exact * n / 1e9:.0f} GFLOP; fast {fl_fast / 1e6:.1f} MFLOP ({what_fast}), the map "
              f"{fl_fast * n / 1e9:.0f} GFLOP."]
    for key in configs:
        total = statistics.median(marks[-1][1] for marks in results[key]["runs"])
        lines.append(f"- fast, {key[0]} torch thread{'s' * (key[0] > 1)}, {key[1]} worker{'s' * (key[1] > 1)}: "
                     f"{total:.2f} s, {1000 * total / n:.3f} ms per cell, {fl_fast * n / total / 1e9:.0f} GFLOP/s.")
    lines.append(f"- exact, 1 thread: {exact_total:.2f} s, {1000 * exact_total / n:.2f} ms per cell, "
                 f"{fl_exact * n / exact_total / 1e9:.0f} GFLOP/s.")
    text = "\n".join(lines) + "\n"
    print(text)
    if a.out is not None:
        atomic.write_text(a.out, text)


if __name__ == "__main__":
    main()
