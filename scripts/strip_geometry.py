"""Write a copy of a generated scene stripped to frames, camera poses and audio, as a real
recording comes: without ``scene.json`` (the room geometry, materials and simulator
settings), so that training must find the scene's points from the frames
(``avgs train --init sfm`` triangulates them).

Every file but ``scene.json`` is copied (the source scene is never modified); the new
data root gets a ``position.json`` with this scene's source entry only:

    .venv/bin/python scripts/strip_geometry.py data/demo/demo_house data/stripped
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path

GEOMETRY_FILE = "scene.json"


def strip_geometry(scene: Path, data_root: Path) -> Path:
    """Write ``data_root/<scene name>`` without scene.json; returns its folder."""
    scene = Path(scene).resolve()
    position = scene.parent / "position.json"
    if not position.is_file():
        raise FileNotFoundError(f"{position}: missing; expected the data root of an RWAVS scene")
    entry = json.loads(position.read_text()).get(scene.name)
    if entry is None:
        raise ValueError(f"{position}: has no entry for scene {scene.name!r}")
    out = Path(data_root).resolve() / scene.name
    if out == scene:
        raise ValueError(f"{out}: the stripped copy would replace the scene itself; pick another data root")
    if out.exists():
        raise FileExistsError(f"{out}: already exists")
    shutil.copytree(scene, out, ignore=lambda folder, names: [GEOMETRY_FILE] if Path(folder) == scene else [])
    root_position = out.parent / "position.json"
    table = json.loads(root_position.read_text()) if root_position.is_file() else {}
    table[scene.name] = entry
    root_position.write_text(json.dumps(table, indent=1))
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scene", type=Path, help="DATA_ROOT/SCENE_ID of a generated scene")
    parser.add_argument("data_root", type=Path, help="where the stripped copy goes (DATA_ROOT/SCENE_ID)")
    args = parser.parse_args()
    print(f"wrote {strip_geometry(args.scene, args.data_root)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
