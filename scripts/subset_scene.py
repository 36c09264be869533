"""Write a copy of an RWAVS scene that keeps a seeded random subset of its training poses.

The audio, frames, validation poses and every other file are linked, not copied; only
``transforms_train.json`` and ``transforms_scale_train.json`` are rewritten, with the same
poses picked from both, so the scene's normalised frame stays the same (to float
rounding: it is fitted from the pose pairs). For studying
how the methods do with fewer recordings:

    .venv/bin/python scripts/subset_scene.py data/presets/house_0 data/sparse50 --poses 50
"""

from __future__ import annotations

import argparse
import json
import os
import random
import shutil
import sys
from pathlib import Path

TRAIN_FILES = ("transforms_train.json", "transforms_scale_train.json")


def subset_scene(scene: Path, data_root: Path, poses: int, seed: int = 0) -> Path:
    """Write ``data_root/<scene name>`` keeping ``poses`` training poses; returns its folder."""
    scene = Path(scene).resolve()
    present = [name for name in TRAIN_FILES if (scene / name).is_file()]
    if not present:
        raise FileNotFoundError(f"{scene}: no {' or '.join(TRAIN_FILES)}; expected an RWAVS scene")
    tables = {name: json.loads((scene / name).read_text()) for name in present}
    counts = {name: len(t["camera_path"]) for name, t in tables.items()}
    if len(set(counts.values())) != 1:
        raise ValueError(f"{scene}: the training transforms disagree on the number of poses: {counts}")
    total = next(iter(counts.values()))
    if not 1 <= poses <= total:
        raise ValueError(f"--poses must be in 1..{total} for {scene}, got {poses}")
    keep = sorted(random.Random(seed).sample(range(total), poses))

    out = Path(data_root) / scene.name
    out.mkdir(parents=True, exist_ok=True)
    for item in scene.iterdir():
        target = out / item.name
        if item.name in TRAIN_FILES or target.exists() or target.is_symlink():
            continue
        os.symlink(item, target)
    for name, table in tables.items():
        table["camera_path"] = [table["camera_path"][i] for i in keep]
        tmp = out / (name + ".part")
        tmp.write_text(json.dumps(table))
        tmp.replace(out / name)
    position = scene.parent / "position.json"
    if position.is_file() and not (Path(data_root) / "position.json").exists():
        shutil.copy(position, Path(data_root) / "position.json")
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scene", type=Path, help="DATA_ROOT/SCENE_ID")
    parser.add_argument("data_root", type=Path, help="where the subset scene goes (a new DATA_ROOT)")
    parser.add_argument("--poses", type=int, required=True, help="training poses to keep")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    try:
        print(subset_scene(args.scene, args.data_root, args.poses, args.seed))
    except (FileNotFoundError, ValueError) as exc:
        print(f"subset_scene: error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
