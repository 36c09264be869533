"""How long the impulse-response task should train: one row per scene and schedule length
(docs/results.md, "How long to train the impulse-response task").

Reads, in FOLDER, ``<scene>-<setting><N>.log.jsonl`` (the training log of a whole schedule of N
stage-2 iterations: its responses, batch and final validation log-magnitude error) and
``<scene>-<setting><N>.eval.json`` (``avgs eval --task rir --split both --json`` of its checkpoint),
and ``<scene>-baselines.eval.json`` (nearest and linear), and prints a markdown table.

    python scripts/rir_schedule_table.py benchmarks/cpu/rir_schedule
"""

from __future__ import annotations

import argparse
import json
import re
from pathlib import Path

from rir_defaults_table import overall  # {method: {split: scores}} of an avgs eval --json report (this folder)

RUN = re.compile(r"^(?P<scene>.+?)-(?P<setting>[a-z]+)(?P<iterations>\d+)\.log\.jsonl$")
COLUMNS = (("val", "t60_pct", "{:.1f}"), ("val", "c50_db", "{:.2f}"), ("val", "edt_s", "{:.3f}"),
           ("heldout", "t60_pct", "{:.1f}"), ("heldout", "c50_db", "{:.2f}"), ("heldout", "edt_s", "{:.3f}"))


def read_log(path: Path) -> dict:
    """The run's training responses, batch size, final validation error and stage-2 seconds."""
    out: dict = {}
    for line in path.read_text().splitlines():
        r = json.loads(line) if line.strip() else {}
        if r.get("event") == "task":
            out["responses"] = int(r["responses"])
        elif r.get("stage") == "stage2" and "seconds" in r:
            out["seconds"] = float(r["seconds"])
        elif r.get("stage") == "final":
            out["val_logmag"] = r.get("val_logmag")
    return out


def cells(by_split: dict[str, dict]) -> list[str]:
    return [fmt.format(by_split[split][key]) if split in by_split else "" for split, key, fmt in COLUMNS]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder", type=Path, help="a folder of runs' logs and eval reports")
    parser.add_argument("--batch-size", type=int, default=4, help="stage 2's batch (the runs': the default 4)")
    args = parser.parse_args()
    runs = sorted((m["scene"], m["setting"], int(m["iterations"]), p) for p in args.folder.glob("*.log.jsonl")
                  if (m := RUN.match(p.name)))
    if not runs:
        raise SystemExit(f"{args.folder}: no <scene>-<setting><N>.log.jsonl files")
    head = ["scene", "run", "iterations", "passes", "val log-mag error", "minutes"] + [f"{s} {k}" for s, k, _ in COLUMNS]
    print("| " + " | ".join(head) + " |")
    print("|" + "---|" * len(head))
    for scene in sorted({r[0] for r in runs}):
        base = args.folder / f"{scene}-baselines.eval.json"
        for method, by_split in (overall(base).items() if base.is_file() else ()):
            print("| " + " | ".join([scene, method, "", "", "", "", *cells(by_split)]) + " |")
        for _, setting, iterations, log in (r for r in runs if r[0] == scene):
            info = read_log(log)
            ev = log.with_name(log.name.replace(".log.jsonl", ".eval.json"))
            by_split = next(iter(overall(ev).values())) if ev.is_file() else {}
            passes = iterations * args.batch_size / info["responses"] if info.get("responses") else float("nan")
            err = info.get("val_logmag")
            row = [scene, setting, str(iterations), f"{passes:.0f}", "" if err is None else f"{err:.3f}",
                   f"{info['seconds'] / 60:.1f}" if "seconds" in info else "", *cells(by_split)]
            print("| " + " | ".join(row) + " |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
