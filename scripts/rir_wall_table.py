"""Impulse responses behind a wall: checkpoints (several seeds per label) on the responses in sight
of the source and on those behind a wall, per split.

A response is behind a wall when its true onset is more than 1 ms after distance / c (the
simulator has no diffraction or transmission: its first arrival is a reflection that passes a
door). Per group: the median onset error (ms), direct-sound ITD error (us), level error
(|10 log10| of the predicted over the true energy, dB, median) and the mean C50 error (dB); each as
mean +- std over the label's checkpoints.

    .venv/bin/python scripts/rir_wall_table.py data/rir/two_rooms avgs=runs/wall/avgs_s0.ckpt,... \
        nocontext=runs/wall/nocontext_s0.ckpt,... [--out docs/rir_wall.md]
"""

from __future__ import annotations

import argparse
import sys
import warnings

import numpy as np

from avgs.data.rir import RIRScene
from avgs.evaluation import metrics, spatial
from avgs.evaluation.impulse_response import load_method, predict
from avgs.io.atomic import write_text
from avgs.train.impulse_responses import speed_of_sound


def scores(scene: RIRScene, ckpt: str, split: str) -> dict[str, dict[str, float]]:
    fs = scene.sample_rate
    speed = speed_of_sound(scene)
    method = load_method("ckpt:" + ckpt)
    method = method.for_scene(scene) if hasattr(method, "for_scene") else method
    query = scene.responses(split)
    pred = predict(method, scene.responses("train"), query)
    distance = np.linalg.norm(scene.frame.to_world(query.source) - scene.frame.to_world(query.receiver), axis=1)
    true_on = np.array([spatial.onset(g) for g in query.rir]) / fs
    onset = np.abs(true_on - np.array([spatial.onset(p) for p in pred]) / fs) * 1e3
    itd = np.abs([spatial.response_itd(g, fs) - spatial.response_itd(p, fs) for g, p in zip(query.rir, pred)]) * 1e6
    energy = lambda h: float(np.sum(np.asarray(h, dtype=np.float64) ** 2))  # noqa: E731
    level = np.abs([10 * np.log10(max(energy(p), 1e-30) / max(energy(g), 1e-30)) for g, p in zip(query.rir, pred)])
    c50 = np.array([metrics.c50_error(p, g, fs) for g, p in zip(query.rir, pred)])
    behind = ~spatial.in_sight(true_on, distance, speed)
    out = {}
    for group, rows in (("in sight", ~behind), ("behind a wall", behind)):
        if rows.any():
            out[group] = {"n": int(rows.sum()), "onset": float(np.median(onset[rows])), "itd": float(np.median(itd[rows])),
                          "level": float(np.median(level[rows])), "c50": float(np.mean(c50[rows]))}
    return out


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("scene")
    p.add_argument("labels", nargs="+", metavar="LABEL=CKPT[,CKPT...]")
    p.add_argument("--out")
    args = p.parse_args(argv)
    warnings.simplefilter("ignore")
    scene = RIRScene(args.scene)
    lines = ["# Impulse responses behind a wall", "", f"`.venv/bin/python scripts/rir_wall_table.py {' '.join(argv)}`", "",
             "| split | group | responses | method | onset ms | ITD us | level dB | C50 dB |", "|---|---|---|---|---|---|---|---|"]
    for split in ("val", "heldout"):
        results = {}
        for spec in args.labels:
            label, _, ckpts = spec.partition("=")
            results[label] = [scores(scene, c, split) for c in ckpts.split(",")]
        for group in ("in sight", "behind a wall"):
            for label, runs in results.items():
                runs = [r[group] for r in runs if group in r]
                if not runs:
                    continue
                cell = lambda k, f: f"{np.mean([r[k] for r in runs]):{f}} ± {np.std([r[k] for r in runs]):{f}}"  # noqa: E731
                lines.append(f"| {split} | {group} | {runs[0]['n']} | {label} ({len(runs)} seeds) | {cell('onset', '.2f')} | "
                             f"{cell('itd', '.0f')} | {cell('level', '.2f')} | {cell('c50', '.2f')} |")
    text = "\n".join(lines)
    print(text)
    if args.out:
        write_text(args.out, text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
