"""Two ways to predict the direct sound's ITD of an impulse response from the training responses
alone, scored on the truth (no model): what docs/results.md reports as tried and left out.

1. Behind a wall (true onset more than 1 ms after distance / c), the first arrival's direction and
   delay taken from the nearest training pairs that are behind a wall too: each training pair's
   four facings give its arrival's world direction (ITD = p cos(yaw) - q sin(yaw), least squares)
   and its delay after distance / c; a query takes those of its nearest pair, and of its three
   nearest weighted by inverse distance (listener and source distances added).
2. In sight, an ITD law of the direction: K sine harmonics of the signed direction fitted by least
   squares to the training responses in sight, against Woodworth's shape with the fitted scale
   (what the model uses).

    .venv/bin/python scripts/first_arrival_trials.py data/rir/two_rooms
"""

from __future__ import annotations

import sys
import warnings

import numpy as np
import torch

from avgs.acoustics.interaural import fit_scale, woodworth_shape
from avgs.data.frame import signed_direction
from avgs.data.rir import RIRScene, RIRSet
from avgs.evaluation import spatial
from avgs.train.impulse_responses import speed_of_sound



def cues(scene: RIRScene, rows: RIRSet, speed: float) -> dict[str, np.ndarray]:
    """Per response: world positions, direction (radians), onset after distance / c (s), ITD (s), behind a wall."""
    fs = scene.sample_rate
    src, rec = scene.frame.to_world(rows.source), scene.frame.to_world(rows.receiver)
    late = np.array([spatial.onset(h) for h in rows.rir]) / fs - np.linalg.norm(src - rec, axis=1) / speed
    theta = signed_direction(torch.as_tensor(rows.receiver, dtype=torch.float64), torch.as_tensor(np.radians(rows.yaw)),
                             torch.as_tensor(rows.source, dtype=torch.float64)).numpy()
    return {"src": src, "rec": rec, "theta": theta, "late": late, "behind": late > spatial.IN_SIGHT_S,
            "itd": np.array([spatial.response_itd(h, fs) for h in rows.rir])}


def facing_basis(yaw_deg: np.ndarray) -> np.ndarray:
    yaw = np.radians(yaw_deg)
    return np.stack([np.cos(yaw), -np.sin(yaw)], axis=-1)  # [M, 2]: ITD = basis @ (p, q)


def main(argv: list[str]) -> int:
    if len(argv) != 1:
        print(__doc__)
        return 2
    warnings.simplefilter("ignore")
    scene = RIRScene(argv[0])
    speed = speed_of_sound(scene)
    train = scene.responses("train")
    t = cues(scene, train, speed)
    pairs: dict[tuple[int, int], list[int]] = {}
    for i, key in enumerate(zip(train.source_index.tolist(), train.receiver_index.tolist())):
        pairs.setdefault(key, []).append(i)
    fitted = []  # (source, receiver, (p, q), delay after distance / c, behind)
    for rows in pairs.values():
        pq, *_ = np.linalg.lstsq(facing_basis(train.yaw[rows]), t["itd"][rows], rcond=None)
        fitted.append((t["src"][rows[0]], t["rec"][rows[0]], pq, float(np.mean(t["late"][rows])), bool(np.mean(t["late"][rows]) > spatial.IN_SIGHT_S)))
    scale = fit_scale(t["theta"], t["itd"])
    print(f"{argv[0]}: {len(fitted)} training pairs, {sum(f[4] for f in fitted)} behind a wall; fitted head {scale * 1e6:.0f} us")
    for split in ("val", "heldout"):
        q = scene.responses(split)
        c = cues(scene, q, speed)
        wood = -woodworth_shape(torch.as_tensor(c["theta"])).numpy() * scale  # in the metric's sign
        b = np.where(c["behind"])[0]
        if len(b):
            near, near3, onset3 = [], [], []
            cand = [f for f in fitted if f[4]]
            for i in b:
                d = np.array([np.linalg.norm(f[0] - c["src"][i]) + np.linalg.norm(f[1] - c["rec"][i]) for f in cand])
                order = np.argsort(d)[:3]
                w = 1.0 / (d[order] + 1e-3)
                basis = facing_basis(q.yaw[i:i + 1])[0]
                near.append(abs(basis @ cand[order[0]][2] - c["itd"][i]))
                near3.append(abs(basis @ (sum(wi * cand[j][2] for wi, j in zip(w, order)) / w.sum()) - c["itd"][i]))
                onset3.append(abs(sum(wi * cand[j][3] for wi, j in zip(w, order)) / w.sum() - c["late"][i]))
            print(f"  {split:8s} behind a wall ({len(b)}): ITD error, straight line {np.median(np.abs(wood[b] - c['itd'][b])) * 1e6:.0f} us, "
                  f"nearest pair's arrival {np.median(near) * 1e6:.0f} us, three nearest {np.median(near3) * 1e6:.0f} us; "
                  f"onset error, straight line {np.median(np.abs(c['late'][b])) * 1e3:.2f} ms, three nearest's delay {np.median(onset3) * 1e3:.2f} ms")
        s = np.where(~c["behind"])[0]
        line = [f"  {split:8s} in sight ({len(s)}): ITD error (median / 82nd percentile), Woodworth "
                f"{np.median(np.abs(wood[s] - c['itd'][s])) * 1e6:.0f} / {np.percentile(np.abs(wood[s] - c['itd'][s]), 82) * 1e6:.0f} us"]
        sight = ~t["behind"]
        for k in (1, 3, 5):
            coef, *_ = np.linalg.lstsq(np.sin(t["theta"][sight, None] * np.arange(1, k + 1)), t["itd"][sight], rcond=None)
            law = np.sin(c["theta"][s, None] * np.arange(1, k + 1)) @ coef
            e = np.abs(law - c["itd"][s]) * 1e6
            line.append(f"{k} harmonics {np.median(e):.0f} / {np.percentile(e, 82):.0f} us")
        print(", ".join(line))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
