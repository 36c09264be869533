"""How many responses of a generated scene pyroomacoustics' phantom direct sound touched.

pyroomacoustics 0.10.1, in a room made of polygons, renders the source itself at distance / c through
every wall between where no image source up to the room's order reaches the listener
(:func:`avgs.synth.simulate.compute_rir`, which `avgs synth` now uses, gives it zero amplitude). This
counts, per split, the (source, listener) pairs of a scene written by `avgs synth` for which the image
sources find no path: the responses that held a phantom direct sound when written before that fix.

    python scripts/phantom_direct.py data/rir/three_rooms data/presets/house_0 ...
    python scripts/phantom_direct.py --preset house --poses 125 [--seed 0]   # without writing the scene

Works on both layouts: impulse responses (`--task rir`: every split's pairs) and binaural scenes (the
scene's source to each pose); with ``--preset``, on the poses `avgs synth --preset P --poses N --seed S`
writes (its source to each, train and val). Prints one line per scene and split.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from avgs.synth.simulate import SimSettings, build_room, load_settings, load_spec, unreached_sources


def unreached(spec, settings: SimSettings, listener: np.ndarray, sources: np.ndarray) -> np.ndarray:
    """``[S]`` bool: no image source of ``sources [S, 3]`` up to the room's order reaches ``listener [3]``."""
    room = build_room(spec, settings)
    for s in sources:
        room.add_source(s)
    room.add_microphone(listener)
    room.image_source_model()
    return np.array(unreached_sources(room))


def pairs(scene: Path) -> dict[str, list[tuple[np.ndarray, np.ndarray]]]:
    """World (listener, source) pairs per split of a scene written by `avgs synth`."""
    meta = json.loads((scene / "scene.json").read_text())
    if (scene / "rir" / "index.json").exists():
        from avgs.data.rir import SPLITS, RIRScene

        frame = meta["to_normalised"]
        centre, scale = np.asarray(frame["center"], dtype=np.float64), float(frame["scale"])
        rir = RIRScene(scene)
        out = {}
        for split in SPLITS:
            r = rir.responses(split)
            lis = np.asarray(r.receiver, dtype=np.float64) / scale + centre
            src = np.asarray(r.source, dtype=np.float64) / scale + centre
            out[split] = list(zip(lis, src))
        return out
    source = np.asarray(meta["source"]["position"], dtype=np.float64)
    frames = meta.get("frames", {})
    out: dict[str, list] = {}
    for pose in meta["poses"]:
        split = next((k for k, (lo, hi) in frames.items() if lo <= pose["frame"] <= hi), "all")
        out.setdefault(split, []).append((np.asarray(pose["position"], dtype=np.float64), source))
    return out


def preset_pairs(preset: str, poses: int, seed: int):
    """The spec, settings and (listener, source) pairs per split of `avgs synth --preset P --poses N --seed S`."""
    from avgs.synth.poses import sample_poses
    from avgs.synth.presets import make_spec
    from avgs.synth.writer import SynthConfig

    cfg = SynthConfig(preset=preset, poses=poses, seed=seed)
    spec = make_spec(preset, seed)
    rng = np.random.default_rng([seed, 1])  # as avgs.synth.writer.write_scene draws them
    n_train, n_val = cfg.split_sizes()
    train = sample_poses(spec, n_train, rng)
    val = sample_poses(spec, n_val, rng, avoid=train)
    source = np.asarray(spec.source, dtype=np.float64)
    settings = SimSettings.from_dict({**cfg.sim.to_dict(), "seed": seed})
    return spec, settings, {k: [(np.asarray(p.position, dtype=np.float64), source) for p in v]
                            for k, v in (("train", train), ("val", val))}


def count(name: str, spec, settings: SimSettings, splits: dict) -> None:
    if spec.is_shoebox:
        print(f"{name}: a shoebox room (pyroomacoustics' own path: always a direct sound), nothing to count")
        return
    for split, items in splits.items():
        by_listener: dict[tuple, list] = {}
        for lis, src in items:
            by_listener.setdefault(tuple(np.round(lis, 6)), []).append(src)
        hit = total = 0
        for lis, sources in by_listener.items():
            unique = np.unique(np.round(np.asarray(sources), 6), axis=0)
            flags = dict(zip(map(tuple, unique), unreached(spec, settings, np.asarray(lis), unique)))
            hit += sum(flags[tuple(np.round(s, 6))] for s in sources)
            total += len(sources)
        print(f"{name} {split}: {hit} of {total} responses with no image-source path (a phantom direct sound before the fix)")


def main(argv: list[str]) -> None:
    if argv and argv[0] == "--preset":
        import argparse

        ap = argparse.ArgumentParser(prog="phantom_direct.py")
        ap.add_argument("--preset", required=True)
        ap.add_argument("--poses", type=int, default=100)
        ap.add_argument("--seed", type=int, default=0)
        a = ap.parse_args(argv)
        count(f"{a.preset} (seed {a.seed}, {a.poses} poses)", *preset_pairs(a.preset, a.poses, a.seed))
        return
    for path in map(Path, argv):
        count(str(path), load_spec(path), load_settings(path), pairs(path))


if __name__ == "__main__":
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    main(sys.argv[1:])
