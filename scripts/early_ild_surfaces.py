"""Which reflections set the early ILD, on the simulator's own responses: the direct sound alone, or mixed
with the first-order image sources of the scene's surfaces (scene.json's polygons, each keeping the
amplitude sqrt(1 - mean absorption)), each arrival within 5 ms of the direct sound given a law of its own
direction (three sine harmonics, dB) and a common gain, fitted to the training responses in sight of the
source (soft L1) and scored on the val and held-out ones in sight (median |error| dB, train / val / held out).

    python scripts/early_ild_surfaces.py data/rir/two_rooms [data/rir/l_room ...]

Rows: the law alone; with the floor and ceiling; with the walls (and partitions); with every surface;
with the walls, neither leg tested against the other surfaces; and with the walls, also without the test
that the reflection point lies on the polygon (infinite planes).
"""

from __future__ import annotations

import json
import math
import sys

import numpy as np
from scipy.optimize import least_squares

from avgs.data.rir import RIRScene
from avgs.evaluation import spatial

WINDOW_S = 0.005
WALLS = ("wall", "partition")


def surfaces(meta: dict) -> list[tuple[str, np.ndarray, np.ndarray, float]]:
    out = []
    for s in meta["surfaces"]:
        corners = np.array(s["corners"], dtype=np.float64)
        n = np.cross(corners[1] - corners[0], corners[2] - corners[0])
        alpha = float(np.mean(meta["materials"][s["material"]]["absorption"]["coeffs"]))
        out.append((s["kind"], corners, n / np.linalg.norm(n), math.sqrt(max(0.0, 1.0 - alpha))))
    return out


def on_polygon(corners: np.ndarray, n: np.ndarray, x: np.ndarray) -> bool:
    keep = [i for i in range(3) if i != int(np.argmax(np.abs(n)))]
    p, q, inside = corners[:, keep], x[keep], False
    for a, b in zip(p, np.roll(p, -1, axis=0)):
        if (a[1] > q[1]) != (b[1] > q[1]) and q[0] < a[0] + (q[1] - a[1]) * (b[0] - a[0]) / (b[1] - a[1]):
            inside = not inside
    return inside


def crosses(a: np.ndarray, b: np.ndarray, surf, skip: int | None = None) -> bool:
    for j, (_, corners, n, _) in enumerate(surf):
        da, db = float(np.dot(a - corners[0], n)), float(np.dot(b - corners[0], n))
        if j == skip or da * db >= 0:
            continue
        t = da / (da - db)
        if 1e-6 < t < 1 - 1e-6 and on_polygon(corners, n, a + t * (b - a)):
            return True
    return False


def arrivals(src, lis, surf, legs: bool, polygon: bool) -> list[tuple[float, np.ndarray, float, str]]:
    out = [(float(np.linalg.norm(src - lis)), src - lis, 1.0, "direct")]
    for j, (kind, corners, n, amplitude) in enumerate(surf):
        ds, dl = float(np.dot(src - corners[0], n)), float(np.dot(lis - corners[0], n))
        if ds * dl <= 0:
            continue
        image = src - 2 * ds * n
        x = lis + dl / (dl + ds) * (image - lis)
        if polygon and not on_polygon(corners, n, x):
            continue
        if legs and (crosses(src, x, surf, j) or crosses(x, lis, surf, j)):
            continue
        out.append((float(np.linalg.norm(image - lis)), image - lis, amplitude, kind))
    return out


def rows(scene: RIRScene, surf, split: str, legs: bool, polygon: bool) -> list:
    r, out = scene.responses(split), []
    for i in range(len(r)):
        src = scene.frame.to_world(r.source[i][None])[0]
        lis = scene.frame.to_world(r.receiver[i][None])[0]
        if crosses(src, lis, surf):
            continue  # in sight only
        yaw, d0 = math.radians(r.yaw[i]), float(np.linalg.norm(src - lis))
        items = []
        for d, v, amplitude, kind in arrivals(src, lis, surf, legs, polygon):
            azimuth = math.atan2(-math.sin(yaw) * v[0] + math.cos(yaw) * v[1], math.cos(yaw) * v[0] + math.sin(yaw) * v[1])
            items.append(((d - d0) / 343.0, azimuth, amplitude / d, kind))
        out.append((spatial.early_ild(r.rir[i], scene.sample_rate), items))
    return out


def predict(q: np.ndarray, data: list, kinds) -> np.ndarray:
    law, gain, pred = q[:3], q[3], []
    for _, items in data:
        left = right = 0.0
        for k, (dt, azimuth, amplitude, kind) in enumerate(items):
            if k and ((kinds is not None and kind not in kinds) or dt > WINDOW_S):
                continue
            ild = sum(c * math.sin((m + 1) * azimuth) for m, c in enumerate(law))
            weight = amplitude**2 * (1.0 if k == 0 else gain**2)
            share = 1.0 / (1.0 + 10 ** (-ild / 10))
            left, right = left + weight * share, right + weight * (1 - share)
        pred.append(10 * math.log10(left / right))
    return np.array(pred)


def main(scene_dir: str) -> None:
    scene = RIRScene(scene_dir)
    surf = surfaces(json.loads((scene.scene_dir / "scene.json").read_text()))
    print(scene.name)
    for label, kinds, legs, polygon in (("law alone", (), True, True), ("+ floor and ceiling", ("floor", "ceiling"), True, True),
                                        ("+ walls", WALLS, True, True), ("+ every surface", None, True, True),
                                        ("+ walls, legs not tested", WALLS, False, True),
                                        ("+ walls, infinite planes", WALLS, False, False)):
        data = {s: rows(scene, surf, s, legs, polygon) for s in ("train", "val", "heldout")}
        truth = {s: np.array([d[0] for d in v]) for s, v in data.items()}
        fit = least_squares(lambda q: predict(q, data["train"], kinds) - truth["train"], np.array([9.0, 1.0, 0.5, 0.7]),
                            loss="soft_l1", f_scale=1.0, bounds=([-40, -40, -40, 0.0], [40, 40, 40, 1.5]))
        errors = [np.median(np.abs(predict(fit.x, data[s], kinds) - truth[s])) for s in ("train", "val", "heldout")]
        print(f"  {label:26s} {errors[0]:.2f} / {errors[1]:.2f} / {errors[2]:.2f} dB  (law {np.round(fit.x[:3], 1)}, gain {fit.x[3]:.2f})")


if __name__ == "__main__":
    if len(sys.argv) < 2:
        print(__doc__)
        sys.exit(2)
    for path in sys.argv[1:]:
        main(path)
