"""Median time (ms) of a pose's render, filter and masks on the bundled demo and a one-source checkpoint,
for comparing two checkouts side by side (run alternately: the host's load moves timings).

    git worktree add /tmp/old OLD_COMMIT
    for i in 1 2 3 4 5; do
      OMP_NUM_THREADS=1 .venv/bin/python scripts/pose_timing.py ONE_SOURCE.ckpt --checkout /tmp/old >> old.jsonl
      OMP_NUM_THREADS=1 .venv/bin/python scripts/pose_timing.py ONE_SOURCE.ckpt >> new.jsonl
    done

``--checkout DIR`` imports avgs from DIR only (with PYTHONPATH=DIR, a module that DIR lacks would
still come from this venv's editable install, silently); ``--threads N`` (default 1). Prints one JSON line: the avgs
it imported and, per checkpoint and call, the median over 3 x 40 poses.
"""

from __future__ import annotations

import json
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import torch

DEMO = Path(__file__).resolve().parents[1] / "assets" / "demo" / "scene.ckpt"


def _import_from(checkout: str | None):
    """avgs from ``checkout`` (a source tree) when given, ahead of the editable install's finder."""
    if checkout:
        sys.meta_path[:] = [f for f in sys.meta_path if "editable" not in type(f).__module__.lower()
                            and "editable" not in repr(f).lower()]
        sys.path.insert(0, str(Path(checkout).resolve()))
    import avgs

    if checkout and not Path(avgs.__file__).resolve().is_relative_to(Path(checkout).resolve()):
        sys.exit(f"imported {avgs.__file__}, not the checkout {checkout}")
    return avgs


def main(one_source: str, checkout: str | None = None, threads: int = 1) -> None:
    avgs = _import_from(checkout)
    torch.set_num_threads(threads)
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
    import argparse

    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("one_source", help="a one-source (binaural-task) checkpoint")
    parser.add_argument("--checkout", help="import avgs from this source tree")
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args()
    main(args.one_source, args.checkout, args.threads)
