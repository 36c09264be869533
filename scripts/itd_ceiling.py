"""How close to a binaural scene's recorded ITDs can any renderer of the 1 s clip come? No model:
the simulator's own response at each validation pose, applied to that clip's mono signal.

The recordings of ``avgs synth`` (avgs/synth/writer.py) are the whole source convolved with each
pose's response, so a clip also holds the reverberant tails of the sound before it, which the
clip's mono signal does not. A renderer gets only that 1 s of mono. For each validation clip this
script compares the recording's ITD (GCC-PHAT, avgs.evaluation.spatial.itd) with the ITD of

- ``history``: the pose's simulated response applied to the whole source up to the clip's end
  (what the writer did; a check that the response is the recording's: ~0 us);
- ``whole response``: the same response applied to the clip's mono alone (the best any renderer of
  the clip can do);
- ``first T ms``: the response cut T ms after its onset (the direct sound and the early
  reflections only), applied to the clip's mono;
- ``image sources, order k``: the room's image sources up to order k (no ray-traced tail, the
  exact geometry and materials), applied to the clip's mono.

Prints the median |ITD error| (us) and the lateralisation agreement (%, the issue's definition) per
scene (docs/results.md, "Where the sound comes from").

    OMP_NUM_THREADS=1 python scripts/itd_ceiling.py data/presets/office_0 data/presets/apartment_0 [--clips 50]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
from pathlib import Path

import numpy as np
from scipy.signal import fftconvolve

from avgs.data.rwavs import RWAVSScene, clip_window, read_wav
from avgs.evaluation import spatial
from avgs.synth.simulate import binaural_rirs, load_settings, load_spec

CUTS_MS = (2.5, 10.0, 40.0, 80.0)
ORDERS = (1, 2)


def applied(mono: np.ndarray, h: np.ndarray, length: int) -> np.ndarray:
    """``mono [T]`` convolved with each ear of ``h [2, L]``, its last ``length`` samples: ``[2, length]``."""
    return np.stack([fftconvolve(mono, ear)[len(mono) - length : len(mono)] for ear in h.astype(np.float64)])


def scene_rows(scene_dir: Path, clips: int) -> dict[str, list[float]]:
    scene = RWAVSScene(scene_dir)
    meta = json.loads((scene_dir / "scene.json").read_text())
    center, scale = np.asarray(meta["to_normalised"]["center"]), float(meta["to_normalised"]["scale"])
    spec, settings = load_spec(scene_dir), load_settings(scene_dir)
    fs = scene.sample_rate
    source = read_wav(scene_dir / "source_syn_re.wav", 1, fs)[0].astype(np.float64)  # [L]
    itds: dict[str, list[float]] = {"truth": [], "history": [], "whole response": []}
    itds.update({f"first {t:g} ms": [] for t in CUTS_MS})
    itds.update({f"image sources, order {k}": [] for k in ORDERS})
    for clip in scene.val[:clips]:
        listener, yaw = clip.listener / scale + center, math.degrees(clip.yaw)
        h = binaural_rirs(spec, listener, yaw, settings)  # [2, L]
        start, stop = clip_window(clip.time, fs)
        mono = clip.mono.astype(np.float64)
        n = len(mono)
        itds["truth"].append(spatial.itd(clip.binaural, fs))
        lo = max(0, start - h.shape[-1] + 1)
        itds["history"].append(spatial.itd(applied(source[lo:stop], h, stop - start), fs))
        itds["whole response"].append(spatial.itd(applied(mono, h, n), fs))
        onset = spatial.onset(h)
        for t in CUTS_MS:
            cut = h[:, : onset + int(round(t * 1e-3 * fs))]
            itds[f"first {t:g} ms"].append(spatial.itd(applied(mono, cut, n), fs))
        for k in ORDERS:
            images = dataclasses.replace(settings, ray_tracing=False, max_order=k, max_order_polygon=k)
            itds[f"image sources, order {k}"].append(spatial.itd(applied(mono, binaural_rirs(spec, listener, yaw, images), n), fs))
    return itds


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scenes", nargs="+", type=Path)
    ap.add_argument("--clips", type=int, default=50, help="validation clips per scene (the first N)")
    args = ap.parse_args(argv)
    for scene_dir in args.scenes:
        itds = scene_rows(scene_dir, args.clips)
        truth = itds.pop("truth")
        lateral = sum(abs(t) >= spatial.LAT_TRUE_MIN_S for t in truth)
        print(f"\n{scene_dir.name}: {len(truth)} val clips, {lateral} with |ITD| >= 150 us")
        print("| applied to the clip | ITD error (us) | agreement (%) |")
        print("|---|---|---|")
        for name, pred in itds.items():
            err = spatial.median([abs(p - t) * 1e6 for p, t in zip(pred, truth)])
            agree = spatial.lateralisation(truth, pred)
            print(f"| {name} | {err:.0f} | {'-' if agree is None else f'{agree:.0f}'} |")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
