"""Behind a wall, the first sound from the walls' first reflection or from the straight line
(``RIRConfig.reflected_arrival``): each checkpoint scored as trained and with ``reflected_arrival`` set to
the straight line's, on both splits, then a table of the mean and spread over the checkpoints of a scene
(seeds) of each metric, both ways, and how the fits chose.

    python scripts/reflected_arrival_table.py data/rir/two_rooms_s3=runs/a.ckpt,runs/b.ckpt ... > TABLE.md

Each SCENE=CKPTS argument: a scene folder and its checkpoints, comma-separated. What docs/results.md reports
("The first sound behind a wall").
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from avgs.io.checkpoint import load_checkpoint, save_checkpoint

METRICS = ("itd_us", "lat_pct", "onset_ms", "ild_db", "c50_db", "edt_s", "t60_pct")
DIGITS = {"itd_us": 0, "lat_pct": 1, "onset_ms": 2, "ild_db": 2, "c50_db": 2, "edt_s": 4, "t60_pct": 1}


def straight_copy(ckpt: str, out: Path) -> Path:
    """``ckpt`` with ``reflected_arrival`` (direction, delay) both the straight line's."""
    data = load_checkpoint(ckpt)
    data["binauralizer"]["reflected_arrival"].zero_()
    save_checkpoint(data, out)
    return out


def scores(scene: str, ckpts: list[str], work: Path) -> tuple[dict, list[list[bool]]]:
    """{(split, "straight" | "as trained"): {metric: [per checkpoint]}} and each checkpoint's (direction, delay) choice."""
    out: dict = {}
    chosen = []
    for i, ckpt in enumerate(ckpts):
        chosen.append([bool(float(v) > 0.5) for v in load_checkpoint(ckpt)["binauralizer"]["reflected_arrival"]])
        straight = straight_copy(ckpt, work / f"straight{i}.ckpt")
        report = work / f"eval{i}.json"
        subprocess.run([sys.executable, "-m", "avgs.cli", "eval", scene, "--task", "rir", "--split", "both", "--method",
                        f"ckpt:{straight}", "--method", f"ckpt:{ckpt}", "--out", str(report), "--no-progress"],
                       check=True, stdout=subprocess.DEVNULL)
        splits = json.loads(report.read_text())["splits"]
        for split, result in splits.items():
            for way, key in (("straight", f"ckpt:{straight}"), ("as trained", f"ckpt:{ckpt}")):
                overall = result["methods"][key]["overall"]
                for metric in METRICS:
                    out.setdefault((split, way), {}).setdefault(metric, []).append(overall[metric])
    return out, chosen


def cell(values: list[float], digits: int) -> str:
    v = np.asarray(values, dtype=np.float64)
    return f"{v.mean():.{digits}f} ± {v.std():.{digits}f}" if len(v) > 1 else f"{v[0]:.{digits}f}"


def main(argv: list[str]) -> int:
    if not argv or any("=" not in a for a in argv):
        print(__doc__)
        return 2
    print("| scene | split | first sound behind a wall | " + " | ".join(METRICS) + " |")
    print("|---|---|---|" + "---|" * len(METRICS))
    notes = []
    with tempfile.TemporaryDirectory() as tmp:
        for arg in argv:
            scene, ckpts = arg.split("=", 1)
            table, chosen = scores(scene, ckpts.split(","), Path(tmp))
            name = Path(scene).name
            for split in ("val", "heldout"):
                for way in ("straight", "as trained"):
                    row = table[(split, way)]
                    print(f"| {name} | {split} | {way} | " + " | ".join(cell(row[m], DIGITS[m]) for m in METRICS) + " |")
            notes.append(f"{name}: (direction, delay) from the first reflection: "
                         + ", ".join(f"({'yes' if d else 'no'}, {'yes' if t else 'no'})" for d, t in chosen))
    print()
    for note in notes:
        print(f"- {note}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
