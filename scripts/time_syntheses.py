"""Time the default synthesis, the filter alone and 8 phase iterations side by side on the demo.

Usage: ``OMP_NUM_THREADS=2 .venv/bin/python scripts/time_syntheses.py [THREADS]`` (default 2).
Each of 60 poses (``avgs.bench.latency.random_poses``) is rendered with the three syntheses
in turn (a 1 s test signal); medians over the last 55. ``avgs bench`` times every synthesis
too; this is the quick check.
"""

import sys
import time

import numpy as np
import torch

from avgs.bench.latency import random_poses, test_signal
from avgs.config import SynthesisConfig
from avgs.inference import SceneRenderer

torch.set_num_threads(int(sys.argv[1]) if len(sys.argv) > 1 else 2)
renderer = SceneRenderer.load("assets/demo/scene.ckpt")
poses = random_poses(renderer, 64)
signal = test_signal(1.0, renderer.sample_rate)
syntheses = {
    "default": SynthesisConfig(),
    "filter": SynthesisConfig(method="filter"),
    "source phase + 8 iterations": SynthesisConfig(phase="source", phase_iterations=8),
}
times = {name: [] for name in syntheses}
for i in range(60):
    listener, yaw = poses[i % len(poses)]
    for name, synthesis in syntheses.items():
        start = time.perf_counter()
        renderer.render(listener, yaw, signal, synthesis=synthesis)
        times[name].append(time.perf_counter() - start)
for name, t in times.items():
    print(f"{name}: median {1e3 * np.median(t[5:]):.2f} ms per pose")
