"""The interaural time difference on binaural scenes: a checkpoint's renders against its ITD baselines.

For each scene's validation clips: the true ITD (GCC-PHAT of the recording,
avgs.evaluation.spatial.itd), and the predicted ITD of
- the checkpoint's default render (the ears delayed by the fitted spherical head),
- the same checkpoint with the ear delays off (the same weights: the paper's synthesis timing),
- the spherical-head formula alone, with the default head (a = 8.75 cm) and with the fitted scale,
- nearest-neighbour interpolation: the measured ITD of the training clip nearest in position and facing.
Prints (and with --out writes, as Markdown) the median |ITD error| (us) and the lateralisation
agreement (%), and, for the two renders, MAG / ENV / ILD (avgs eval's), each per scene. Several
checkpoints of a scene (comma-separated: seeds) give the mean ± the standard deviation over them.

    .venv/bin/python scripts/itd_table.py data/presets/office_0=runs/office_0.ckpt [...] --out docs/itd_table.md
    .venv/bin/python scripts/itd_table.py data/presets/office_0=runs/office_0.ckpt,runs/office_0.seed1.ckpt,...
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
import warnings
from pathlib import Path

import numpy as np
import torch

from avgs.acoustics.interaural import DEFAULT_SCALE, woodworth_shape
from avgs.data.frame import signed_direction
from avgs.data.rwavs import RWAVSScene
from avgs.evaluation import metrics, spatial
from avgs.io.atomic import write_text
from avgs.render.renderer import SceneRenderer


def theta_of(clip, source) -> float:
    return float(signed_direction(torch.as_tensor(clip.listener[None], dtype=torch.float64),
                                  torch.tensor([clip.yaw], dtype=torch.float64),
                                  torch.as_tensor(source, dtype=torch.float64))[0])


def nearest_itd(clip, train, train_itd) -> float:
    """The measured ITD of the training clip nearest in position (normalised) and facing (1 rad ~ 1 unit)."""
    d = [float(np.linalg.norm(c.listener - clip.listener)) + abs(math.remainder(c.yaw - clip.yaw, 2 * math.pi))
         for c in train]
    return train_itd[int(np.argmin(d))]


def summary(true, pred) -> tuple[float, float | None]:
    err = spatial.median([abs(p - t) * 1e6 for p, t in zip(pred, true)])
    return err, spatial.lateralisation(true, pred)


def scene_rows(scene_dir: Path, ckpt: Path) -> dict:
    scene = RWAVSScene(scene_dir)
    r = SceneRenderer.load(ckpt)
    fs = scene.sample_rate
    true = [spatial.itd(c.binaural, fs) for c in scene.val]
    train_itd = [spatial.itd(c.binaural, fs) for c in scene.train]
    thetas = [theta_of(c, scene.source) for c in scene.val]
    scale = r.model.binauralizer.itd_scale
    fitted = float(scale) if scale is not None else None
    rows: dict[str, dict] = {}
    for label, zero in (("AV-GS (ears delayed)", False), ("AV-GS, delays off", True)):
        if zero and scale is not None:
            saved = scale.clone()
            scale.zero_()
        preds, mag, env, ild = [], [], [], []
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            for c in scene.val:
                world = scene.frame.to_world(c.listener)
                y = r.render(world, math.degrees(c.yaw), c.mono).binaural
                preds.append(spatial.itd(y, fs))
                mag.append(metrics.mag(y, c.binaural))
                env.append(metrics.env(y, c.binaural))
                ild.append(metrics.ild_error(y, c.binaural))
        if zero and scale is not None:
            scale.copy_(saved)
        rows[label] = {"itd": summary(true, preds), "mag": np.mean(mag), "env": np.mean(env), "ild": np.mean(ild)}
    shape = woodworth_shape(torch.tensor(thetas, dtype=torch.float64)).numpy()
    rows["spherical head, a = 8.75 cm"] = {"itd": summary(true, list(-DEFAULT_SCALE * shape))}
    if fitted is not None:
        rows[f"spherical head, fitted ({fitted * 1e6:.0f} us)"] = {"itd": summary(true, list(-fitted * shape))}
    rows["nearest training pose"] = {"itd": summary(true, [nearest_itd(c, scene.train, train_itd) for c in scene.val])}
    eligible = sum(abs(t) >= 150e-6 for t in true)
    return {"scene": scene.name, "clips": len(true), "eligible": eligible,
            "true_median_us": float(np.median(np.abs(true)) * 1e6), "rows": rows}


def combine(results: list[dict]) -> dict:
    """One scene's rows over several checkpoints (seeds): each number a list, one value per checkpoint."""
    out = dict(results[0])
    rows: dict[str, dict] = {}
    for res in results:
        for label, row in res["rows"].items():
            key = "spherical head, fitted" if label.startswith("spherical head, fitted") else label
            into = rows.setdefault(key, {"label": label})
            for name, value in row.items():
                if name == "itd":
                    into.setdefault("err", []).append(value[0])
                    into.setdefault("lat", []).append(value[1])
                else:
                    into.setdefault(name, []).append(value)
    out["rows"], out["seeds"] = rows, len(results)
    return out


def cell(values: list, fmt: str) -> str:
    values = [v for v in values if v is not None]
    if not values:
        return "n/a"
    if len(values) == 1:
        return fmt.format(values[0])
    spread = statistics.stdev(values)
    return f"{fmt.format(statistics.fmean(values))} ± {fmt.format(spread)}"


def markdown(results: list[dict], argv: list[str]) -> str:
    out = ["# The interaural time difference on binaural scenes", "",
           f"`{' '.join(['.venv/bin/python', 'scripts/itd_table.py', *argv])}`", "",
           "Median |ITD error| (us, GCC-PHAT over 0.2-1.5 kHz) and lateralisation agreement (% of the clips with a true "
           "|ITD| >= 150 us whose predicted ITD has its sign and is >= 50 us); MAG / ENV / ILD as `avgs eval` scores "
           "them. Definitions: docs/design.md, \"Spatial cues\".", ""]
    for res in results:
        seeds = f" ({res['seeds']} checkpoints: mean ± standard deviation)" if res["seeds"] > 1 else ""
        out += [f"## {res['scene']}: {res['clips']} val clips, {res['eligible']} with |ITD| >= 150 us, "
                f"true median |ITD| {res['true_median_us']:.0f} us{seeds}", "",
                "| method | ITD error (us) | agreement (%) | MAG | ENV | ILD (dB) |", "|---|---|---|---|---|---|"]
        for row in res["rows"].values():
            more = (f"{cell(row['mag'], '{:.4f}')} | {cell(row['env'], '{:.4f}')} | {cell(row['ild'], '{:.2f}')}"
                    if "mag" in row else " | | ")
            out.append(f"| {row['label']} | {cell(row['err'], '{:.0f}')} | {cell(row['lat'], '{:.0f}')} | {more} |")
        out.append("")
    return "\n".join(out)


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("pairs", nargs="+", metavar="SCENE_DIR=CKPT")
    p.add_argument("--out", help="Also write the table (Markdown).")
    args = p.parse_args(argv)
    torch.set_num_threads(max(1, torch.get_num_threads()))
    results = []
    for pair in args.pairs:
        scene_dir, _, ckpt = pair.partition("=")
        if not ckpt:
            p.error(f"{pair!r}: expected SCENE_DIR=CKPT")
        results.append(combine([scene_rows(Path(scene_dir), Path(c)) for c in ckpt.split(",")]))
    text = markdown(results, argv)
    print(text)
    if args.out:
        write_text(args.out, text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
