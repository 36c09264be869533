"""Per preset, the impulse-response task against its best baseline: for each scene of a sweep laid out as
``scripts/rir_spatial_table.py`` reads (``<scene>/<setting>/seed<k>/spatial.eval.json``, which that
script writes, and ``baselines.json``), the mean over seeds of each setting's score and, in brackets,
the better of the nearest and linear baselines (the higher lateralisation, the lower error otherwise).

    python scripts/rir_spatial_table.py data/rir runs/def6/table     # scores the checkpoints first
    python scripts/rir_scene_table.py runs/def6/table
"""

from __future__ import annotations

import argparse
import json
import statistics
from pathlib import Path

METRICS = (("t60_pct", "T60 %", "{:.1f}"), ("c50_db", "C50 dB", "{:.2f}"), ("edt_s", "EDT s", "{:.3f}"),
           ("ild_db", "early ILD dB", "{:.2f}"), ("lat_pct", "LAT %", "{:.0f}"))
SETTINGS = ("avgs", "no-context")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sweep", type=Path, help="the sweep's folder: <scene>/<setting>/seed<k>/spatial.eval.json, baselines.json")
    args = parser.parse_args()
    base = json.loads((args.sweep / "baselines.json").read_text())
    scenes = sorted(p.name for p in args.sweep.iterdir() if p.is_dir())
    for split in ("val", "heldout"):
        print(f"\n{split}: {' / '.join(SETTINGS)}, mean over seeds (best baseline)\n")
        print("| scene | " + " | ".join(label for _, label, _ in METRICS) + " |")
        print("|---|" + "---|" * len(METRICS))
        for scene in scenes:
            cells = []
            for key, _, fmt in METRICS:
                baselines = [base["splits"][split]["methods"][m]["scenes"][scene][key] for m in ("nearest", "linear")]
                best = max(baselines) if key == "lat_pct" else min(baselines)
                means = []
                for setting in SETTINGS:
                    values = []
                    for report in sorted((args.sweep / scene / setting).glob("seed*/spatial.eval.json")):
                        r = json.loads(report.read_text())["splits"][split]["methods"]
                        method = next(m for m in r if not m.endswith(".before.ckpt"))  # as trained, not "before"
                        values.append(r[method]["scenes"][scene][key])
                    means.append(fmt.format(statistics.fmean(values)))
                cells.append(f"{' / '.join(means)} ({fmt.format(best)})")
            print(f"| {scene} | " + " | ".join(cells) + " |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
