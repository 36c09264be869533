"""The impulse-response task's onset and direct-sound ITD errors, split by what the truth's first arrival is.

A response whose true onset is more than 1 ms after distance / c has no direct sound in the
simulator (pyroomacoustics: no diffraction, no transmission): its first arrival is a reflection
that passes a door. Prints, per split, the median onset error (ms), direct-sound ITD error (us) and
early ILD error (dB) of a checkpoint for the responses in sight of the source and for those behind a wall.

    .venv/bin/python scripts/rir_onset_split.py data/rir/two_rooms runs/two_rooms.ckpt
"""

from __future__ import annotations

import sys
import warnings

import numpy as np

from avgs.data.rir import RIRScene
from avgs.evaluation import spatial
from avgs.evaluation.impulse_response import load_method, predict
from avgs.train.impulse_responses import speed_of_sound

def main(argv: list[str]) -> int:
    if len(argv) != 2:
        print(__doc__)
        return 2
    warnings.simplefilter("ignore")
    scene = RIRScene(argv[0])
    fs = scene.sample_rate
    speed = speed_of_sound(scene)
    method = load_method("ckpt:" + argv[1])
    method = method.for_scene(scene) if hasattr(method, "for_scene") else method
    train = scene.responses("train")
    for split in ("val", "heldout"):
        query = scene.responses(split)
        pred = predict(method, train, query)
        distance = np.linalg.norm(scene.frame.to_world(query.source) - scene.frame.to_world(query.receiver), axis=1)
        true_on = np.array([spatial.onset(g) for g in query.rir]) / fs
        pred_on = np.array([spatial.onset(p) for p in pred]) / fs
        onset_ms = np.abs(true_on - pred_on) * 1e3
        itd_us = np.abs([spatial.response_itd(g, fs) - spatial.response_itd(p, fs) for g, p in zip(query.rir, pred)]) * 1e6
        ild_db = np.abs([spatial.early_ild(g, fs) - spatial.early_ild(p, fs) for g, p in zip(query.rir, pred)])
        behind = ~spatial.in_sight(true_on, distance, speed)
        for label, rows in (("in sight", ~behind), ("behind a wall", behind)):
            if rows.any():
                print(f"{split:8s} {label:14s} {int(rows.sum()):4d} responses: onset {np.median(onset_ms[rows]):.2f} ms, "
                      f"ITD {np.median(itd_us[rows]):.0f} us, ILD {np.median(ild_db[rows]):.2f} dB")
        print(f"{split:8s} {'all':14s} {len(query):4d} responses: onset {np.median(onset_ms):.2f} ms, ITD {np.median(itd_us):.0f} us, "
              f"ILD {np.median(ild_db):.2f} dB")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
