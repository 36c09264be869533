"""The early ILD on the simulator's own responses, without a trained network: the law of the straight
direction alone against the law mixed with the walls' first reflections (avgs.acoustics.early_reflections),
the walls found in a checkpoint's audio points, both fitted to the training responses in sight of the
source as training fits them, scored on the val and held-out responses whose straight path the points
leave free (where the model uses them); behind a wall, whether a free first-order reflection would
tell the first arrival's ILD.

    python scripts/early_ild_walls.py data/rir/two_rooms runs/two_rooms.ckpt

Prints the walls found (normal and offset, metres) and the median |error| per split.
"""

from __future__ import annotations

import sys

import numpy as np
import torch

from avgs.acoustics import early_reflections as er
from avgs.acoustics.interaural import fit_ild_law, ild_law
from avgs.acoustics.line_of_sight import points_on_path
from avgs.data.frame import signed_direction
from avgs.data.rir import RIRScene
from avgs.evaluation import spatial
from avgs.io.checkpoint import load_checkpoint


def main(scene_dir: str, ckpt_path: str) -> None:
    ckpt = load_checkpoint(ckpt_path)
    b = ckpt["binauralizer"]
    points = ckpt["audio_points"]["X"].double()
    scale = float(ckpt["frame"]["scale"])
    c = float(ckpt["config"]["rir"]["sound_speed"])
    walls = er.find_walls(points, scale, seed=int(ckpt["config"]["seed"]))
    print(f"{scene_dir}: {len(points)} points, {walls.shape[0]} walls (n_x, n_y, d m):")
    for w in walls.tolist():
        print(f"  {w[0]:+.2f} {w[1]:+.2f} {w[2] / scale:+.2f}")
    test = er.ReflectionTest.at_scale(scale, b["sight_radius"], b["sight_margin"], b["sight_blocked"])
    scene = RIRScene(scene_dir)

    def split(name: str) -> dict:
        r = scene.responses(name)
        lis, src = torch.as_tensor(r.receiver), torch.as_tensor(r.source)
        yaw = torch.as_tensor(np.radians(r.yaw))
        theta = signed_direction(lis, yaw, src)
        distance = torch.linalg.vector_norm(src - lis, dim=-1)
        onsets = np.array([spatial.onset(h) for h in r.rir]) / scene.sample_rate
        found = er.wall_reflections(lis, src, walls, points, test, longest=distance + er.WINDOW_S * c)
        reflected = er.image_directions(lis, yaw, found.image)
        return {"theta": theta, "distance": distance, "reflected": reflected, "path": found.path, "happens": found.happens,
                "ild": np.array([spatial.early_ild(h, scene.sample_rate) for h in r.rir]),
                "sight": spatial.in_sight(onsets, distance.numpy(), c),
                "free": points_on_path(points, lis, src, test.sight_radius, test.sight_margin).numpy() < test.sight_blocked}

    train = split("train")
    m = train["sight"]
    law = fit_ild_law(train["theta"].numpy()[m], train["ild"][m])
    fit = er.fit_early_ild(train["theta"][m], train["distance"][m], train["reflected"][m], train["path"][m],
                           train["happens"][m], train["ild"][m], law)
    if law is None or fit is None:
        print("  no fit (too few training responses in sight, or no reflection in the window)")
        return
    print(f"  law alone {np.round(law, 2)} dB; with the walls {np.round(fit[0], 2)} dB, gain {fit[1]:.2f}; "
          f"{float(train['happens'][m].double().sum(-1).mean()):.2f} reflections per training pair in sight")
    for name in ("val", "heldout"):
        d = split(name)
        free = d["free"]
        alone = ild_law(d["theta"], torch.as_tensor(law)).numpy()
        mixed = er.early_ild(d["theta"], d["distance"], d["reflected"], d["path"], d["happens"], torch.as_tensor(fit[0]),
                             fit[1]).numpy()
        print(f"  {name}: {int(free.sum())} of {len(free)} free by the points: median |error| law alone "
              f"{np.median(np.abs(alone - d['ild'])[free]):.2f} dB, with the walls {np.median(np.abs(mixed - d['ild'])[free]):.2f} dB")
        behind = ~free
        if behind.any():  # the first arrival behind a wall: the earliest free first-order reflection and those 5 ms after it
            happens, path = d["happens"][behind], d["path"][behind]
            first = torch.where(happens, path, torch.full_like(path, float("inf"))).min(-1).values
            weight = torch.where(happens & (path <= first[:, None] + er.WINDOW_S * c), path.clamp_min(1e-9) ** -2,
                                 torch.zeros_like(path))
            share = er.ear_shares(ild_law(d["reflected"][behind], torch.as_tensor(fit[0])))
            guess = 10 * torch.log10((weight * share).sum(-1).clamp_min(1e-300) / (weight * (1 - share)).sum(-1).clamp_min(1e-300))
            has = happens.any(-1).numpy()
            errors = np.abs(guess.numpy() - d["ild"][behind])[has]
            print(f"    behind a wall: {int(behind.sum())} responses, {int(has.sum())} with a free first-order reflection, "
                  f"its ILD {np.median(errors) if len(errors) else float('nan'):.2f} dB off (true median |ILD| "
                  f"{np.median(np.abs(d['ild'][behind])):.2f} dB)")


if __name__ == "__main__":
    if len(sys.argv) != 3:
        print(__doc__)
        sys.exit(2)
    main(sys.argv[1], sys.argv[2])
