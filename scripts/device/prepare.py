"""Pack what a run on a lent GPU machine needs into ``.gpu/`` (git-ignored), under the
device tool's 64 MiB limit: 16-bit FLAC copies of scenes (kept under their RWAVS
``.wav`` names; libsndfile reads a file by its header), optionally their key frames,
and the wheels that machine's Python 3.12 lacks (it reaches no package index).

    .venv/bin/python scripts/device/prepare.py data/rawhrtf/office_0 data/rawhrtf/house_0 [--frames]

An impulse-response scene (``rir/index.json``) travels with its responses as 24-bit FLAC files
beside their WAV names, all scaled by one gain that keeps the loudest sample under 1 (FLAC holds
integers): every metric of ``avgs eval --task rir`` (T60, C50, EDT, onset, ITD, ILD) and the
training's floor (relative to the loudest bin) are unchanged by a common gain; scene.json's
``rir.peak`` and ``rir.scale`` say what was done. The layout wants 32-bit float WAVs, so on that
machine ``prepare.py --unpack .gpu/data`` writes them back first.

Then name the folders in the device call's ``carry`` (see ``h100.sh``).
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
from pathlib import Path

import json

import numpy as np
import soundfile as sf

WHEELS = {
    "whl": ["soundfile", "cffi", "pycparser", "pyroomacoustics"],
    "whl2": ["gsplat"],  # tqdm, rich, pytest and the rest are in that machine's image (device KINDS.md)
}


def pack_scene(scene: Path, dest: Path, frames: bool) -> None:
    dest.mkdir(parents=True, exist_ok=True)
    responses = (scene / "rir" / "index.json").is_file()  # the impulse-response task reads no clips
    for f in sorted(scene.iterdir(), key=lambda f: f.suffix != ".json"):  # scene.json before rir/
        if f.suffix == ".json":
            shutil.copy(f, dest / f.name)
        elif f.suffix == ".wav" and not responses:
            audio, rate = sf.read(str(f), dtype="float32", always_2d=True)
            tmp = dest / (f.name + ".part")
            sf.write(str(tmp), audio, rate, subtype="PCM_16", format="FLAC")
            tmp.replace(dest / f.name)
        elif f.name == "frames" and frames:
            shutil.copytree(f, dest / "frames", dirs_exist_ok=True)
        elif f.name == "rir" and (f / "index.json").is_file():
            pack_responses(f, dest / "rir", dest / "scene.json")
    position = scene.parent / "position.json"
    if position.is_file():
        shutil.copy(position, dest.parent / "position.json")


def pack_responses(folder: Path, dest: Path, scene_json: Path) -> None:
    """``folder``'s responses as 24-bit FLAC under their names, scaled by one gain (peak <= 0.9)."""
    dest.mkdir(parents=True, exist_ok=True)
    shutil.copy(folder / "index.json", dest / "index.json")
    files = sorted(folder.glob("*.wav"))
    peak = max(float(np.abs(sf.read(str(f), dtype="float32")[0]).max()) for f in files)
    gain = min(1.0, 0.9 / peak) if peak > 0 else 1.0
    for f in files:
        audio, rate = sf.read(str(f), dtype="float32", always_2d=True)
        tmp = dest / (f.name + ".part")
        sf.write(str(tmp), audio * np.float32(gain), rate, subtype="PCM_24", format="FLAC")
        tmp.replace(dest / f.with_suffix(".flac").name)
    meta = json.loads(scene_json.read_text())
    meta["rir"]["peak"] = peak * gain
    meta["rir"]["scale"] = gain
    meta["rir"]["packed"] = f"24-bit FLAC, every response times {gain:.6g} (scale-free metrics unchanged)"
    scene_json.write_text(json.dumps(meta, indent=1))


def unpack(root: Path) -> int:
    """Every packed response under ``root`` (``rir/*.flac``) back to a 32-bit float WAV of its name."""
    count = 0
    for f in sorted(root.rglob("rir/*.flac")):
        audio, rate = sf.read(str(f), dtype="float32", always_2d=True)
        tmp = f.with_suffix(".wav.part")
        sf.write(str(tmp), audio, rate, subtype="FLOAT", format="WAV")
        tmp.replace(f.with_suffix(".wav"))
        f.unlink()
        count += 1
    print(f"unpacked {count} responses under {root}")
    return 0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scenes", nargs="*", type=Path, help="DATA_ROOT/SCENE_ID folders to pack")
    parser.add_argument("--frames", action="store_true", help="also copy the key frames (stage 1 needs them)")
    parser.add_argument("--out", type=Path, default=Path(".gpu"))
    parser.add_argument("--unpack", type=Path, metavar="ROOT",
                        help="on the device: write ROOT's packed responses back as 32-bit float WAVs, and stop")
    args = parser.parse_args()
    if args.unpack is not None:
        return unpack(args.unpack)
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
