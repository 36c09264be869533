"""The impulse-response task's table with the direction cues (docs/results.md "Impulse responses"):
T60, C50, EDT and the onset, direct-sound ITD, early ILD and lateralisation of ``avgs eval --task rir``,
overall (the mean of the environments' means), for the baselines and for each sweep setting's
checkpoints (mean over seeds ± their standard deviation), each checkpoint also heard "before": the
same weights with the direct sound left to B (``direct_sound`` and everything fitted with it off, B's wall
term included: a fixed-seed noise phase from t = 0, what the task did before it placed the direct sound by
geometry).

    avgs sweep --data data/rir --out runs/rir_spatial --seeds 0 1 2 --eval-split none \\
        --common="--quick --rir-width 256 --iterations 400" --setting avgs="--task rir" \\
        --setting no-context="--task rir --no-context"
    avgs eval --task rir data/rir --methods nearest,linear --split both --out runs/rir_spatial/baselines.json
    python scripts/rir_spatial_table.py data/rir runs/rir_spatial        # scores the checkpoints, prints markdown

A run folder's ``*.ckpt`` may be a link (runs trained elsewhere, laid out for this script); ``--times``
reads the training log beside the file it links to.

Every checkpoint's scores go to ``<run folder>/spatial.json`` (made once: a second call reads them).
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
from pathlib import Path

from avgs.acoustics.rir_binauralizer import ILD_BUFFERS, ITD_BUFFERS, LEVEL_BUFFERS, WALL_BUFFERS
from avgs.io.checkpoint import load_checkpoint, save_checkpoint
from rir_defaults_table import last_stage2  # a training log's last stage-2 record (this folder)

METRICS = (("t60_pct", "T60 %", "{:.1f}"), ("c50_db", "C50 dB", "{:.2f}"), ("edt_s", "EDT s", "{:.3f}"),
           ("onset_ms", "onset ms", "{:.2f}"), ("itd_us", "ITD us", "{:.0f}"), ("ild_db", "ILD dB", "{:.2f}"),
           ("lat_pct", "LAT %", "{:.0f}"))
SPLITS = ("val", "heldout")


def without_direct_sound(ckpt: Path, out: Path) -> Path:
    """A copy of ``ckpt`` whose responses leave the direct sound to B (the task before it was placed):
    no placed impulse, no fitted ITD, ILD or level law, and no wall term (which counts the walls on the
    direct sound's straight path)."""
    if not out.is_file():
        data = load_checkpoint(ckpt)
        data["config"]["rir"]["direct_sound"] = False
        data["config"]["rir"]["direct_ild"] = False
        data["config"]["rir"]["direct_itd"] = False
        data["config"]["rir"]["ild_local"] = False
        data["config"]["rir"]["direct_level"] = False
        data["config"]["rir"]["wall_loss"] = False  # B's wall term is counted on the direct sound's straight path
        for key in ITD_BUFFERS + ILD_BUFFERS + LEVEL_BUFFERS + WALL_BUFFERS:
            data["binauralizer"].pop(key, None)  # the fitted head's, which such a model does not have
        save_checkpoint(data, out)
    return out


def environments(report: dict, method: str) -> dict[str, dict[str, dict[str, float]]]:
    """{split: {environment: {metric: value}}} of ``method`` in an ``avgs eval --json`` report."""
    return {split: r["methods"][method]["environments"] for split, r in report["splits"].items()}


def score(data: Path, run: Path, again: bool = False) -> dict:
    """The run's checkpoint scored as it is and without the placed direct sound (cached in spatial.json);
    ``again``: the checkpoint as it is scored anew with this code, "before" kept from the cache."""
    cached = run / "spatial.json"
    if cached.is_file() and not again:
        return json.loads(cached.read_text())
    ckpts = [p for p in run.glob("*.ckpt") if not p.name.endswith(".before.ckpt")]
    if len(ckpts) != 1:
        raise SystemExit(f"{run}: expected one checkpoint, found {[p.name for p in ckpts]}")
    ckpt = ckpts[0]
    before = without_direct_sound(ckpt, ckpt.with_suffix(".before.ckpt"))
    kept = json.loads(cached.read_text()) if again and cached.is_file() else None
    scene = run.parent.parent.name
    out = run / "spatial.eval.json"
    methods = [f"ckpt:{ckpt}"] + ([] if kept else [f"ckpt:{before}"])
    subprocess.run([sys.executable, "-m", "avgs.cli", "eval", "--task", "rir", str(data), "--scene", scene,
                    "--split", "both", *(a for m in methods for a in ("--method", m)),
                    "--json", str(out), "--no-progress"], check=True, stdout=subprocess.DEVNULL)
    report = json.loads(out.read_text())
    result = {"after": environments(report, f"ckpt:{ckpt}"),
              "before": kept["before"] if kept else environments(report, f"ckpt:{before}")}
    cached.write_text(json.dumps(result, indent=1))
    return result


def overall(envs: dict[str, dict[str, float]], metric: str) -> float:
    return statistics.fmean(e[metric] for e in envs.values())


def cell(values: list[float], fmt: str) -> str:
    if len(values) == 1:
        return fmt.format(values[0])
    return f"{fmt.format(statistics.fmean(values))} ± {fmt.format(statistics.stdev(values))}"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data", type=Path, help="the scenes' data root (data/rir)")
    parser.add_argument("sweep", type=Path, help="the sweep's folder: <scene>/<setting>/seed<k>/ and baselines.json")
    parser.add_argument("--again", action="store_true",
                        help="score the checkpoints as they are anew with this code (rendering changes); 'before' kept")
    parser.add_argument("--times", action="store_true",
                        help="also each setting's stage-2 iterations and training time, from each checkpoint's log")
    args = parser.parse_args()
    # {row: {split: {metric: [value per seed]}}}, each value the mean over the environments
    rows: dict[str, dict[str, dict[str, list[float]]]] = {}
    baselines = json.loads((args.sweep / "baselines.json").read_text())
    for method in baselines["splits"]["val"]["methods"]:
        envs = environments(baselines, method)
        rows[method] = {s: {k: [overall(envs[s], k)] for k, _, _ in METRICS} for s in SPLITS}
    settings = sorted({p.parent.name for p in args.sweep.glob("*/*/seed*")})
    for setting in settings:
        seeds = sorted({p.name for p in args.sweep.glob(f"*/{setting}/seed*")})
        for seed in seeds:
            runs = sorted(args.sweep.glob(f"*/{setting}/{seed}"))
            # {when: {split: {environment: [per-scene metric dicts]}}}
            per: dict[str, dict[str, dict[str, list[dict]]]] = {}
            for run in runs:
                for when, splits in score(args.data, run, args.again).items():
                    for split, envs in splits.items():
                        for env, m in envs.items():
                            per.setdefault(when, {}).setdefault(split, {}).setdefault(env, []).append(m)
            for when in ("before", "after"):
                name = f"{setting}, {'direct sound left to B' if when == 'before' else 'direct sound placed'}"
                for split in SPLITS:
                    envs = {env: {k: statistics.fmean(m[k] for m in ms) for k, _, _ in METRICS}
                            for env, ms in per[when][split].items()}
                    for k, _, _ in METRICS:
                        rows.setdefault(name, {}).setdefault(split, {}).setdefault(k, []).append(overall(envs, k))
    for split in SPLITS:
        print(f"\n{split}:\n")
        print("| method | " + " | ".join(label for _, label, _ in METRICS) + " |")
        print("|---|" + "---|" * len(METRICS))
        for name, splits in rows.items():
            n = len(splits[split]["t60_pct"])
            label = f"{name} ({n} seeds)" if n > 1 else name
            print("| " + " | ".join([label] + [cell(splits[split][k], fmt) for k, _, fmt in METRICS]) + " |")
    if args.times:
        print("\n| setting | runs | stage-2 iterations | stage-2 minutes: median (min - max) |\n|---|---|---|---|")
        for setting in settings:
            runs = [training_time(p) for p in sorted(args.sweep.glob(f"*/{setting}/seed*"))]
            minutes = sorted(s / 60 for _, s in runs)
            iterations = sorted({i for i, _ in runs})
            print(f"| {setting} | {len(runs)} | {', '.join(map(str, iterations))} | "
                  f"{statistics.median(minutes):.1f} ({minutes[0]:.1f} - {minutes[-1]:.1f}) |")
    return 0


def training_time(run: Path) -> tuple[int, float]:
    """(stage-2 iterations, seconds) of the run's checkpoint: its log's last stage-2 record (the log
    beside the checkpoint the run folder's ``*.ckpt`` is, or links to)."""
    ckpt = next(p for p in run.glob("*.ckpt") if not p.name.endswith(".before.ckpt")).resolve()
    last, _ = last_stage2(Path(f"{ckpt}.log.jsonl"))
    if last is None:
        raise SystemExit(f"{ckpt}.log.jsonl: no stage-2 record with its seconds")
    return int(last["iteration"]), float(last["seconds"])


if __name__ == "__main__":
    raise SystemExit(main())
