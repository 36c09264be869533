"""Impulse responses behind a wall: checkpoints (several seeds per label) on the responses in sight
of the source and on those behind a wall, per split.

A response is behind a wall when its true onset is more than 1 ms after distance / c (the
simulator has no diffraction or transmission: its first arrival is a reflection that passes a
door). Per group: the median onset error (ms), direct-sound ITD error (us), level error
(|10 log10| of the predicted over the true energy, dB, median), its median sign (the bias: + too
loud) and the mean C50 error (dB); each as mean +- std over the label's checkpoints.

With ``--pair``, also the fixed check of scripts/rir_level_distance.py: one listener, a source in its
room and one behind a partition at 2.5 m, the simulator's level against each checkpoint's (per seed).

    .venv/bin/python scripts/rir_wall_table.py data/rir/two_rooms avgs=runs/wall/avgs_s0.ckpt,... \
        nocontext=runs/wall/nocontext_s0.ckpt,... [--pair] [--out docs/rir_wall.md]
"""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

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
    signed = np.array([10 * np.log10(max(energy(p), 1e-30) / max(energy(g), 1e-30)) for g, p in zip(query.rir, pred)])
    level = np.abs(signed)
    c50 = np.array([metrics.c50_error(p, g, fs) for g, p in zip(query.rir, pred)])
    behind = ~spatial.in_sight(true_on, distance, speed)
    out = {}
    for group, rows in (("in sight", ~behind), ("behind a wall", behind)):
        if rows.any():
            out[group] = {"n": int(rows.sum()), "onset": float(np.median(onset[rows])), "itd": float(np.median(itd[rows])),
                          "level": float(np.median(level[rows])), "bias": float(np.median(signed[rows])),
                          "c50": float(np.mean(c50[rows]))}
    return out


def pair_lines(scene: RIRScene, labels: list[str]) -> list[str]:
    """The wall pair of scripts/rir_level_distance.py on ``scene``: a Markdown table of the levels (dB)."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import rir_level_distance as level_check

    from avgs.render.renderer import SceneRenderer
    from avgs.synth.simulate import load_spec

    meta = scene.metadata["rir"]
    sources = np.asarray(meta["sources_world"], dtype=np.float64)
    trained = np.unique(scene.responses("train").source_index)
    pair = level_check.wall_pair(load_spec(scene.scene_dir), np.asarray(meta["receivers_world"], dtype=np.float64),
                                 float(np.mean(sources[:, 2])), 2.5, sources[trained])
    where, yaws = np.stack([pair.same_room, pair.behind]), [float(y) for y in scene.orientations]
    truth = level_check.level_db(level_check.simulated(scene.scene_dir, where, pair.listener, yaws))
    out = [f"Wall pair: listener {pair.listener.round(3).tolist()}, in its room {pair.same_room.round(3).tolist()}, "
           f"behind the wall {pair.behind.round(3).tolist()} (m); truth {truth[0]:.2f} / {truth[1]:.2f} dB "
           f"(behind minus same {truth[1] - truth[0]:+.2f} dB)", "",
           "| method | same room dB (per seed) | behind the wall dB | behind minus same dB | behind: abs(pred - truth) dB |",
           "|---|---|---|---|---|"]
    for spec in labels:
        label, _, ckpts = spec.partition("=")
        levels = [level_check.level_db(level_check.predicted(SceneRenderer.load(c), where, pair.listener, yaws))
                  for c in ckpts.split(",")]
        cells = [" / ".join(f"{x:.2f}" for x in col) for col in
                 ([v[0] for v in levels], [v[1] for v in levels], [v[1] - v[0] for v in levels],
                  [abs(v[1] - truth[1]) for v in levels])]
        out.append(f"| {label} | " + " | ".join(cells) + " |")
    return out


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("scene")
    p.add_argument("labels", nargs="+", metavar="LABEL=CKPT[,CKPT...]")
    p.add_argument("--out")
    p.add_argument("--pair", action="store_true", help="also the wall pair of scripts/rir_level_distance.py")
    args = p.parse_args(argv)
    warnings.simplefilter("ignore")
    scene = RIRScene(args.scene)
    lines = ["# Impulse responses behind a wall", "", f"`.venv/bin/python scripts/rir_wall_table.py {' '.join(argv)}`", "",
             "| split | group | responses | method | onset ms | ITD us | level dB | level bias dB | C50 dB |",
             "|---|---|---|---|---|---|---|---|---|"]
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
                             f"{cell('itd', '.0f')} | {cell('level', '.2f')} | {cell('bias', '+.2f')} | {cell('c50', '.2f')} |")
    if args.pair:
        lines += ["", *pair_lines(scene, args.labels)]
    text = "\n".join(lines)
    print(text)
    if args.out:
        write_text(args.out, text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
