"""How far the rendered direct sound's ITD is from the one placed, and both from the truth, for the
responses in sight of the source (true onset within 1 ms of distance / c): median |difference| in us.

    .venv/bin/python scripts/rir_itd_check.py data/rir/two_rooms runs/two_rooms_law.ckpt

"placed" is the checkpoint's law of the direction (``itd_law``; else Woodworth's sphere with its
``itd_scale``); "rendered" the GCC-PHAT ITD of the first 5 ms of the predicted response
(:func:`avgs.evaluation.spatial.response_itd`), as ``avgs eval`` scores it.
"""

from __future__ import annotations

import sys
import warnings

import numpy as np
import torch

from avgs.acoustics.interaural import interaural_delay, itd_law
from avgs.data.frame import signed_direction
from avgs.data.rir import RIRScene
from avgs.evaluation import spatial
from avgs.evaluation.impulse_response import load_method, predict
from avgs.io.checkpoint import load_checkpoint
from avgs.train.impulse_responses import speed_of_sound


def main(argv: list[str]) -> int:
    if len(argv) != 2:
        print(__doc__)
        return 2
    warnings.simplefilter("ignore")
    scene = RIRScene(argv[0])
    fs, speed = scene.sample_rate, speed_of_sound(scene)
    b = load_checkpoint(argv[1])["binauralizer"]
    method = load_method("ckpt:" + argv[1])
    method = method.for_scene(scene) if hasattr(method, "for_scene") else method
    train = scene.responses("train")
    for split in ("val", "heldout"):
        q = scene.responses(split)
        pred = predict(method, train, q)
        theta = signed_direction(torch.as_tensor(np.asarray(q.receiver), dtype=torch.float64),
                                 torch.as_tensor(np.radians(np.asarray(q.yaw, dtype=np.float64))),
                                 torch.as_tensor(np.asarray(q.source), dtype=torch.float64))
        placed = (itd_law(theta, b["itd_law"].double()) if b.get("itd_law") is not None
                  else interaural_delay(theta, float(b["itd_scale"]))).numpy()  # tau, > 0: the right ear later
        true = -np.array([spatial.response_itd(g, fs) for g in q.rir])
        rendered = -np.array([spatial.response_itd(p, fs) for p in pred])
        distance = np.linalg.norm(scene.frame.to_world(q.source) - scene.frame.to_world(q.receiver), axis=1)
        sight = spatial.in_sight(np.array([spatial.onset(g) for g in q.rir]) / fs, distance, speed)

        def us(a):
            return np.median(np.abs(a[sight])) * 1e6

        print(f"{split:8s} {int(sight.sum())} in sight: rendered - placed {us(rendered - placed):.0f} us, "
              f"truth - placed {us(true - placed):.0f} us, truth - rendered {us(true - rendered):.0f} us")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
