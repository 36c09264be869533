"""A larger impulse-response scene for memory benchmarks (benchmarks/memory.md), made from a real one
in seconds instead of a simulation: every training and val pair is repeated ``--copies`` times at
receivers moved by a few centimetres (the same responses, linked), held-out pairs as they are.

    .venv/bin/python scripts/rir_memory_scene.py SRC_SCENE DEST_ROOT NAME --copies 4

The copy keeps the RWAVS part (frames, poses, scene.json without its ``rir`` section, which would
contradict the new index) and position.json; it is for measuring memory, not accuracy.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
from pathlib import Path

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("src", type=Path)
    ap.add_argument("dest_root", type=Path)
    ap.add_argument("name")
    ap.add_argument("--copies", type=int, default=4)
    a = ap.parse_args()
    from avgs.data.rir import rir_file_name

    dest = a.dest_root / a.name
    shutil.copytree(a.src, dest, ignore=shutil.ignore_patterns("rir"))
    positions = json.loads((a.src.parent / "position.json").read_text())
    (a.dest_root / "position.json").write_text(json.dumps({a.name: positions[a.src.name]}))
    meta = json.loads((dest / "scene.json").read_text())
    meta.pop("rir", None)
    (dest / "scene.json").write_text(json.dumps(meta))
    index = json.loads((a.src / "rir" / "index.json").read_text())
    receivers = np.asarray(index["receivers"])
    rng = np.random.default_rng(0)
    (dest / "rir").mkdir()
    new_receivers, splits = [], {"train": [], "val": [], "heldout": []}
    for split in ("train", "val"):
        for s, r in index["splits"][split]:
            for _ in range(a.copies):
                new_receivers.append((receivers[r] + rng.uniform(-0.01, 0.01, 3)).tolist())
                k = len(new_receivers) - 1
                splits[split].append([s, k])
                for y in index["orientations_deg"]:
                    os.link(a.src / "rir" / rir_file_name(s, r, y), dest / "rir" / rir_file_name(s, k, y))
    for s, r in index["splits"]["heldout"]:
        new_receivers.append(receivers[r].tolist())
        k = len(new_receivers) - 1
        splits["heldout"].append([s, k])
        for y in index["orientations_deg"]:
            os.link(a.src / "rir" / rir_file_name(s, r, y), dest / "rir" / rir_file_name(s, k, y))
    index.update(receivers=new_receivers, splits=splits)
    (dest / "rir" / "index.json").write_text(json.dumps(index))
    n = sum(len(v) for v in splits.values()) * len(index["orientations_deg"])
    print(f"wrote {dest}: {n} responses ({', '.join(f'{len(v)} {k}' for k, v in splits.items())} pairs)")


if __name__ == "__main__":
    main()
