"""How well can the early ILD be predicted from the pose? Fitted on the training responses of each scene
and scored on the others, all on the simulator's own responses in sight of the source (no model):

- ``law``: three sine harmonics of the direction (``avgs.acoustics.interaural.ild_law``);
- ``+ image sources``: the law applied to the direct sound and to the first-order reflections of the
  floor, the ceiling and the floor plan's walls that arrive within the 5 ms window, each at its own
  lateral angle, with one fitted reflection factor per kind (robust least squares);
- ``+ local``: the law plus the residual of the 3 nearest training responses in listener, source and
  direction (``avgs.acoustics.interaural.local_correction``, what ``RIRConfig.ild_local`` does).

Prints the median absolute error (dB) per scene and split (docs/results.md, "The direction cues").

    python scripts/early_ild_ceiling.py data/rir/rect_small data/rir/two_rooms ...
"""

from __future__ import annotations

import json
import sys
import warnings
from pathlib import Path

import numpy as np
import torch
from scipy.optimize import least_squares

from avgs.acoustics.interaural import fit_ild_law, fit_local_scale, local_correction, local_features
from avgs.data.frame import signed_direction
from avgs.data.rir import RIRScene
from avgs.evaluation import spatial
from avgs.train.impulse_responses import speed_of_sound

WINDOW_S = 0.005


def measured(scene: RIRScene, split: str) -> dict:
    """Each response of ``split`` in sight of the source: world positions, direction, early ILD."""
    q = scene.responses(split)
    fs, c = scene.sample_rate, speed_of_sound(scene)
    S, R = scene.frame.to_world(q.source), scene.frame.to_world(q.receiver)
    theta = signed_direction(torch.as_tensor(np.asarray(q.receiver), dtype=torch.float64),
                             torch.as_tensor(np.radians(np.asarray(q.yaw, dtype=np.float64))),
                             torch.as_tensor(np.asarray(q.source), dtype=torch.float64)).numpy()
    onset = np.array([spatial.onset(h) for h in q.rir]) / fs
    ild = np.array([spatial.early_ild(h, fs) for h in q.rir])
    keep = spatial.in_sight(onset, np.linalg.norm(S - R, axis=1), c) & np.isfinite(ild)
    return {"S": S[keep], "R": R[keep], "theta": theta[keep], "ild": ild[keep], "c": c}


def law(theta, coef):
    """:func:`avgs.acoustics.interaural.ild_law` on numpy values (evaluated per path in the loops below)."""
    return np.sin(np.asarray(theta)[..., None] * np.arange(1, len(coef) + 1)) @ coef


def paths(S, R, theta, height, walls, c):
    """(theta of each path at its lateral angle, 1 / length relative to the direct path's, kind) of the
    direct sound and the first-order images arriving within the window: kind 0 direct, 1 floor, 2 ceiling, 3 wall."""
    d0 = np.linalg.norm(S - R)
    images = [(np.array([S[0], S[1], -S[2]]), 1), (np.array([S[0], S[1], 2 * height - S[2]]), 2)]
    for a, b in walls:
        t = b - a
        n = np.array([-t[1], t[0]]) / np.linalg.norm(t)
        s2 = S[:2] - 2 * np.dot(S[:2] - a, n) * n
        dv = s2 - R[:2]
        den = np.dot(dv, n)
        if abs(den) < 1e-9:
            continue
        u = np.dot(a - R[:2], n) / den
        p = R[:2] + u * dv
        w = np.dot(p - a, t) / np.dot(t, t)
        if 0 < u < 1 and 0 <= w <= 1:
            images.append((np.array([s2[0], s2[1], S[2]]), 3))
    out = [(theta, 1.0, 0)]
    for image, kind in images:
        v = image - R
        length = np.linalg.norm(v)
        if (length - d0) / c < WINDOW_S:
            elevation = np.arctan2(v[2], np.hypot(v[0], v[1]))
            lateral = np.arcsin(np.clip(np.cos(elevation) * np.sin(theta), -1, 1))
            out.append((lateral if np.cos(theta) >= 0 else np.pi - lateral, d0 / length, kind))
    return out


def with_images(p, data, height, walls):
    coef, factor = p[:3], np.r_[1.0, p[3:]]
    out = []
    for S, R, th in zip(data["S"], data["R"], data["theta"]):
        left = right = 0.0
        for t, amp, kind in paths(S, R, th, height, walls, data["c"]):
            g2, level = (amp * factor[kind]) ** 2, law(t, coef)
            left, right = left + g2 * 10 ** (level / 20), right + g2 * 10 ** (-level / 20)
        out.append(10 * np.log10(left / right))
    return np.array(out)


def features(data) -> torch.Tensor:
    return local_features(torch.as_tensor(data["R"]), torch.as_tensor(data["S"]), torch.as_tensor(data["theta"]))


def main(argv: list[str]) -> int:
    if not argv:
        print(__doc__)
        return 2
    warnings.simplefilter("ignore")
    print("| scene | split | responses | law dB | + image sources dB | + local dB |")
    print("|---|---|---|---|---|---|")
    for path in argv:
        scene = RIRScene(path)
        meta = json.loads((Path(path) / "scene.json").read_text())
        height = float(meta["bounds"][1][2])
        spec = meta.get("spec") if isinstance(meta.get("spec"), dict) else {}
        fp = [np.asarray(p, dtype=np.float64) for p in spec.get("footprint", [])]
        walls = [(fp[i], fp[(i + 1) % len(fp)]) for i in range(len(fp))]
        train = measured(scene, "train")
        coef = fit_ild_law(train["theta"], train["ild"])  # what training fits
        fit = least_squares(lambda p: with_images(p, train, height, walls) - train["ild"], np.r_[coef, 0.5, 0.5, 0.5],
                            bounds=([-40] * 3 + [0] * 3, [40] * 3 + [1.5] * 3), loss="soft_l1")
        at = features(train)
        scale = fit_local_scale(at)
        residual = torch.as_tensor(train["ild"] - law(train["theta"], coef))
        for split in ("val", "heldout"):
            q = measured(scene, split)
            if len(q["ild"]) == 0:
                continue
            plain = law(q["theta"], coef)
            local = plain + local_correction(features(q) / scale, at / scale, residual).numpy()
            err = [np.median(np.abs(x - q["ild"])) for x in (plain, with_images(fit.x, q, height, walls), local)]
            print(f"| {scene.name} | {split} | {len(q['ild'])} | " + " | ".join(f"{e:.2f}" for e in err) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
