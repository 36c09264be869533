"""Median time (ms) of a pose's render, filter and masks on the bundled demo and a one-source checkpoint,
for comparing two checkouts side by side (run alternately, one thread each: the host's load moves timings).

    for i in 1 2 3 4 5; do
      PYTHONPATH=OLD_CHECKOUT OMP_NUM_THREADS=1 .venv/bin/python scripts/pose_timing.py ONE_SOURCE.ckpt >> old.jsonl
      OMP_NUM_THREADS=1 .venv/bin/python scripts/pose_timing.py ONE_SOURCE.ckpt >> new.jsonl
    done

Prints one JSON line: the avgs it imported and, per checkpoint and call, the median over 3 x 40 poses.
"""

from __future__ import annotations

import json
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import torch

import avgs

DEMO = Path(__file__).resolve().parents[1] / "assets" / "demo" / "scene.ckpt"


def main(one_source: str) -> None:
    torch.set_num_threads(1)
    warnings.simplefilter("ignore")
    out = {"avgs": avgs.__file__}
    rng = np.random.default_rng(0)
    mono = rng.standard_normal(22050).astype(np.float32) * 0.3
    for tag, path in (("demo", DEMO), ("binaural", one_source)):
        r = avgs.SceneRenderer.load(path)
        lo, hi = r.bounds
        poses = [(lo + (hi - lo) * rng.uniform(0.1, 0.9, 3), float(rng.uniform(0, 360))) for _ in range(40)]
        calls = {"render": lambda p, y: r.render(p, y, mono), "filter": lambda p, y: r.binaural_filter(p, y),
                 "masks": lambda p, y: r.masks(p, y)}
        for name, fn in calls.items():
            for p, y in poses[:5]:
                fn(p, y)
            times = []
            for _ in range(3):
                for p, y in poses:
                    t0 = time.perf_counter()
                    fn(p, y)
                    times.append(time.perf_counter() - t0)
            out[f"{tag}/{name}"] = float(np.median(times) * 1e3)
    print(json.dumps(out))


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    main(sys.argv[1])
