"""Each synthesis of a pose's masks, scored and timed side by side: the table of docs/results.md#synthesis.

Usage::

    OMP_NUM_THREADS=2 .venv/bin/python scripts/synthesis_table.py \\
        --scene data/presets/office_0=runs/presets/office_0.ckpt --scene ... [--out table.md] [--threads 2]

For every scene (``DATA_ROOT/SCENE=CHECKPOINT``, a binaural-task checkpoint) and synthesis
(:data:`SYNTHESES`): MAG and ENV over the scene's val clips (:func:`avgs.evaluation.binaural.score_scene`,
as ``avgs eval`` scores them), and the time of one pose (``SceneRenderer.render`` of its 1 s
clip, masks included), the syntheses taking turns clip by clip so that they share the
machine's load. Prints a markdown table per scene and the mean over scenes, with the
command and the machine.
"""

from __future__ import annotations

import argparse
import math
import platform
import sys
import time
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import torch

from avgs.evaluation import metrics
from avgs.config import MID_PHASE_ITERATIONS, SynthesisConfig
from avgs.data.rwavs import RWAVSScene
from avgs.render.renderer import SceneRenderer

SYNTHESES = {
    "the pose's filter (`--synthesis filter`)": SynthesisConfig(method="filter"),
    "filter's phase": SynthesisConfig(phase="filter"),
    "filter's phase + 8 iterations per ear": SynthesisConfig(phase="filter", phase_iterations=8),
    "source's phase + 8 iterations per ear": SynthesisConfig(phase="source", phase_iterations=8),
    "mid phase, 8 iterations": SynthesisConfig(phase_iterations=8),
    f"**mid phase, {MID_PHASE_ITERATIONS} iterations (default)**": SynthesisConfig(),
    "mid phase, 12 iterations": SynthesisConfig(phase_iterations=12),
    "mid phase, 16 iterations": SynthesisConfig(phase_iterations=16),
}


def score(scene: RWAVSScene, renderer: SceneRenderer, repeats: int) -> dict[str, dict[str, float]]:
    clips = scene.clips("val")
    out = {name: {"MAG": [], "ENV": [], "ms": []} for name in SYNTHESES}
    for i, clip in enumerate(clips):
        listener = tuple(float(v) for v in scene.frame.to_world(clip.listener))
        yaw = math.degrees(clip.yaw)
        for name, synthesis in SYNTHESES.items():
            times = []
            for _ in range(repeats if i >= 2 else 1):  # the first two clips warm up
                start = time.perf_counter()
                y = renderer.render(listener, yaw, clip.mono, synthesis=synthesis).binaural
                times.append(time.perf_counter() - start)
            if i >= 2:
                out[name]["ms"].append(1e3 * float(np.median(times)))
            out[name]["MAG"].append(metrics.mag(y, clip.binaural))
            out[name]["ENV"].append(metrics.env(y, clip.binaural))
    return {name: {"MAG": float(np.mean(v["MAG"])), "ENV": float(np.mean(v["ENV"])), "ms": float(np.median(v["ms"]))}
            for name, v in out.items()}


def table(rows: dict[str, dict[str, float]], reference: str) -> list[str]:
    lines = ["| synthesis | MAG | ENV | ms per pose (median) | time vs filter's phase |", "|---|---|---|---|---|"]
    for name, r in rows.items():
        lines.append(f"| {name} | {r['MAG']:.4f} | {r['ENV']:.4f} | {r['ms']:.2f} | {r['ms'] / rows[reference]['ms']:.2f}x |")
    return lines


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", action="append", required=True, metavar="DATA_ROOT/SCENE=CKPT")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=3, help="Timed renders per clip and synthesis (median).")
    parser.add_argument("--out", help="Also write the tables to this markdown file.")
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    reference = "filter's phase"
    lines = [f"Command: `OMP_NUM_THREADS={args.threads} python {' '.join(sys.argv)}`  ",
             f"Date: {datetime.now(timezone.utc):%Y-%m-%d %H:%M} UTC; {platform.processor() or platform.machine()}, "
             f"torch {torch.__version__}, {args.threads} threads", ""]
    per_scene = {}
    for spec in args.scene:
        scene_dir, _, ckpt = spec.partition("=")
        if not ckpt:
            parser.error(f"--scene {spec!r}: expected DATA_ROOT/SCENE=CHECKPOINT")
        scene, renderer = RWAVSScene(scene_dir), SceneRenderer.load(ckpt)
        rows = score(scene, renderer, args.repeats)
        per_scene[scene.name] = rows
        lines += [f"### {scene.name} ({len(scene.clips('val'))} val clips, `{ckpt}`)", ""] + table(rows, reference) + [""]
        print("\n".join(lines[-(len(rows) + 5):]), flush=True)
    mean = {name: {k: float(np.mean([per_scene[s][name][k] for s in per_scene])) for k in ("MAG", "ENV", "ms")}
            for name in SYNTHESES}
    lines += [f"### Mean over the {len(per_scene)} scenes", ""] + table(mean, reference) + [""]
    text = "\n".join(lines)
    print(text)
    if args.out:
        Path(args.out).write_text(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
