"""Time the propagation map (avgs.propagation_map) of a checkpoint and write a short report.

    .venv/bin/python scripts/bench_propagation_map.py --threads 1 2 --runs 3 \
        --out benchmarks/propagation_map.md

Reports, for each torch thread count, the median over ``--runs`` of the time to the first
map covering the floor at each level of the coarse-to-fine order (every 4th cell a side:
16x16 exact cells, every 2nd: 32x32, every cell: the whole 64x64 map), the model's FLOPs
per cell and the rate achieved, and the machine's load average while it ran.
"""

from __future__ import annotations

import argparse
import datetime as dt
import os
import platform
import statistics
import time
from pathlib import Path

import numpy as np
import torch

from avgs import SceneRenderer
from avgs.propagation_map import propagation_map

DEMO = Path(__file__).resolve().parents[1] / "assets" / "demo" / "scene.ckpt"


def run_once(renderer, size: int, batch: int, chunk: int, yaw: float, z: float) -> list[tuple[int, float]]:
    """[(cells done, seconds since start)] at every yield."""
    t0 = time.perf_counter()
    marks = []
    for m in propagation_map(renderer, yaw=yaw, z=z, size=size, batch=batch, chunk=chunk):
        marks.append((m.done, time.perf_counter() - t0))
    return marks


def flops_per_cell(r) -> float:
    """Multiply-adds x 2 of one cell: B's per-bin layers over the F bins, F's per-point layers over k points
    (the query and context projections, once per pose, and F's last layer, once per mean, are left out)."""
    b = r.model.binauralizer
    per_bin = sum(m.weight.numel() for mlp in (b.mix_mlp, b.diff_mlp) for m in mlp)
    per_bin += b.mix_head.weight.numel() + b.diff_head.weight.numel()
    if b.reverb is not None:
        per_bin += sum(p.numel() for name, p in b.reverb.head.named_parameters() if name.endswith("weight"))
    per_point = 0
    if r.model.field is not None:
        first, *rest = r.model.field.linears
        per_point = 3 * first.out_features + sum(m.weight.numel() for m in rest[:-1])
    return 2.0 * (r.n_freq * per_bin + r.vicinity_size * per_point)


def cpu_name() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.machine()


def measure(r, a, threads: int, z: float) -> dict:
    """The runs at ``threads`` torch threads: {level name: [seconds per run]}, totals, load averages."""
    torch.set_num_threads(threads)
    run_once(r, 8, 64, a.chunk, 0.0, z)  # warm-up
    load_before = os.getloadavg()[0]
    runs = [run_once(r, a.size, a.batch, a.chunk, 30.0 * i, z) for i in range(a.runs)]
    return {"runs": runs, "load": (load_before, os.getloadavg()[0])}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("checkpoint", nargs="?", default=str(DEMO))
    p.add_argument("--threads", type=int, nargs="+", default=[1, 2], help="torch thread counts to measure")
    p.add_argument("--runs", type=int, default=3)
    p.add_argument("--size", type=int, default=64)
    p.add_argument("--batch", type=int, default=256)
    p.add_argument("--chunk", type=int, default=4)
    p.add_argument("--out", type=Path, default=None, help="write the report here (markdown)")
    a = p.parse_args()
    if a.out is not None:
        from avgs import atomic

        atomic.check_output(a.out, what="report")
    r = SceneRenderer.load(a.checkpoint)
    z = float(np.clip(1.6, *r.bounds[:, 2]))
    results = {t: measure(r, a, t, z) for t in a.threads}
    n = a.size * a.size
    levels = [(f"{a.size // s}x{a.size // s} exact cells (every {ordinal} cell a side)", (-(-a.size // s)) ** 2)
              for s, ordinal in ((4, "4th"), (2, "2nd"))] + [(f"all {a.size}x{a.size} cells", n)]
    stamp = dt.datetime.now(dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    threads = " ".join(str(t) for t in a.threads)
    lines = [
        "# Propagation map benchmark",
        "",
        f"Command: `.venv/bin/python scripts/bench_propagation_map.py --threads {threads} --runs {a.runs}"
        f"{' --out ' + str(a.out) if a.out else ''}` ({stamp})  ",
        f"Machine: {cpu_name()}, {os.cpu_count()} cores, torch {torch.__version__}; load average (other jobs "
        "share the cores) "
        + ", ".join(f"{b:.1f} -> {e:.1f} during the {t}-thread runs" for t, (b, e) in
                    ((t, res["load"]) for t, res in results.items())) + "  ",
        f"Scene: `{Path(a.checkpoint).name}`, {len(r.points)} audio points, k = {r.vicinity_size}, "
        f"B width {r.model.cfg.binauralizer_width}, {r.n_freq} bins; map {a.size}x{a.size} at z = {z:.2f}, "
        f"chunks of {a.chunk} cells, yields every {a.batch}",
        "",
        "Time from the start until the map covers the floor at each level of the coarse-to-fine order "
        f"(median of {a.runs} runs, each run's time in brackets):",
        "",
        "| map covering the floor | cells | "
        + " | ".join(f"{t} torch thread{'s' * (t > 1)}" for t in a.threads) + " |",
        "|---|---|" + "---|" * len(a.threads),
    ]
    for name, cells in levels:
        cols = []
        for t in a.threads:
            times = [next(s for done, s in marks if done >= cells) for marks in results[t]["runs"]]
            cols.append(f"{statistics.median(times):.2f} s ({', '.join(f'{s:.2f}' for s in times)})")
        lines.append(f"| {name} | {cells} | " + " | ".join(cols) + " |")
    flops = flops_per_cell(r)
    lines += ["", f"One cell is about {flops / 1e6:.0f} MFLOP of the model (B over {r.n_freq} bins, F over "
              f"k = {r.vicinity_size} points), the whole map {flops * n / 1e9:.0f} GFLOP."]
    for t in a.threads:
        total = statistics.median(marks[-1][1] for marks in results[t]["runs"])
        lines.append(f"- {t} thread{'s' * (t > 1)}: whole map {total:.2f} s, {1000 * total / n:.2f} ms per cell, "
                     f"{flops * n / total / 1e9:.0f} GFLOP/s.")
    text = "\n".join(lines) + "\n"
    print(text)
    if a.out is not None:
        atomic.write_text(a.out, text)


if __name__ == "__main__":
    main()
