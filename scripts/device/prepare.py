"""Pack what a run on a lent GPU machine needs into ``.gpu/`` (git-ignored), under the
device tool's 64 MiB limit: 16-bit FLAC copies of scenes (kept under their RWAVS
``.wav`` names; libsndfile reads a file by its header), optionally their key frames,
and the wheels that machine's Python 3.12 lacks (it reaches no package index).

    .venv/bin/python scripts/device/prepare.py data/rawhrtf/office_0 data/rawhrtf/house_0 [--frames]

Then name the folders in the device call's ``carry`` (see ``h100.sh``).
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
from pathlib import Path

import soundfile as sf

WHEELS = {
    "whl": ["soundfile", "tqdm", "cffi", "pycparser"],
    "whl2": ["gsplat", "rich", "markdown-it-py", "mdurl", "pygments", "pytest", "pluggy", "iniconfig"],
}


def pack_scene(scene: Path, dest: Path, frames: bool) -> None:
    dest.mkdir(parents=True, exist_ok=True)
    for f in scene.iterdir():
        if f.suffix == ".json":
            shutil.copy(f, dest / f.name)
        elif f.suffix == ".wav":
            audio, rate = sf.read(str(f), dtype="float32", always_2d=True)
            tmp = dest / (f.name + ".part")
            sf.write(str(tmp), audio, rate, subtype="PCM_16", format="FLAC")
            tmp.replace(dest / f.name)
        elif f.name == "frames" and frames:
            shutil.copytree(f, dest / "frames", dirs_exist_ok=True)
    position = scene.parent / "position.json"
    if position.is_file():
        shutil.copy(position, dest.parent / "position.json")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scenes", nargs="*", type=Path, help="DATA_ROOT/SCENE_ID folders to pack")
    parser.add_argument("--frames", action="store_true", help="also copy the key frames (stage 1 needs them)")
    parser.add_argument("--out", type=Path, default=Path(".gpu"))
    args = parser.parse_args()
    for scene in args.scenes:
        if not (scene / "transforms.json").is_file():
            parser.error(f"{scene}: not an RWAVS scene (no transforms.json)")
        pack_scene(scene, args.out / "data" / scene.parent.name / scene.name, args.frames)
    for folder, names in WHEELS.items():
        subprocess.run([sys.executable, "-m", "pip", "download", "-q", "--no-deps", "--only-binary=:all:",
                        "--python-version", "3.12", "--platform", "manylinux2014_x86_64",
                        "--platform", "manylinux_2_28_x86_64", "--implementation", "cp",
                        "-d", str(args.out / folder), *names], check=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
