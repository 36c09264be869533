"""How an impulse-response run's scores move over its schedule (docs/results.md, the 40k schedule).

Reads ``FOLDER/snapshots/<setting>-it<N>.eval.json`` (``avgs eval --task rir --split both --json`` of the
checkpoint as it was at iteration N) and ``FOLDER/<setting>-s<seed>.log.jsonl`` (the run's training log:
its validation log-magnitude error at each evaluation), and prints one markdown row per setting and
iteration.

    python scripts/rir_snapshot_table.py benchmarks/cpu/rir_40k

The snapshots were taken while the runs trained: the checkpoint (written every 2,000 iterations) copied
whenever it changed, and each copy scored, e.g.
``while sleep 20; do m=$(stat -c %Y X.ckpt); [ -e snaps/X.$m ] || cp X.ckpt snaps/X.$m; done``, then
``avgs eval DATA --task rir --split both --method ckpt:snaps/X.$m --json ...`` and ``avgs info`` for its iteration.
"""

from __future__ import annotations

import argparse
import json
import re
from pathlib import Path

SNAPSHOT = re.compile(r"(?P<setting>.+)-it(?P<iteration>\d+)\.eval\.json$")
COLUMNS = (("val", "t60_pct", "{:.1f}"), ("val", "c50_db", "{:.2f}"), ("val", "edt_s", "{:.3f}"),
           ("heldout", "t60_pct", "{:.1f}"), ("heldout", "c50_db", "{:.2f}"), ("heldout", "edt_s", "{:.3f}"),
           ("heldout", "itd_us", "{:.0f}"), ("heldout", "ild_db", "{:.2f}"), ("heldout", "lat_pct", "{:.0f}"))


def validation_errors(folder: Path, setting: str) -> dict[int, float]:
    """{iteration: validation log-magnitude error} from the setting's training log (any seed's)."""
    out: dict[int, float] = {}
    for log in folder.glob(f"{setting}-s*.log.jsonl"):
        for line in log.read_text().splitlines():
            r = json.loads(line) if line.strip() else {}
            if r.get("stage") == "stage2" and "val_logmag" in r:
                out[int(r["iteration"])] = float(r["val_logmag"])
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder", type=Path, help="a folder with snapshots/ and the runs' logs")
    args = parser.parse_args()
    rows = []
    for path in (args.folder / "snapshots").glob("*.eval.json"):
        m = SNAPSHOT.search(path.name)
        if m is None:
            continue
        report = json.loads(path.read_text())
        scores = {split: next(iter(r["methods"].values()))["overall"] for split, r in report["splits"].items()}
        rows.append((m["setting"], int(m["iteration"]), scores))
    if not rows:
        raise SystemExit(f"{args.folder / 'snapshots'}: no <setting>-it<N>.eval.json files")
    errors = {s: validation_errors(args.folder, s) for s in {r[0] for r in rows}}
    head = ["setting", "iteration", "val log-mag error"] + [f"{split} {key}" for split, key, _ in COLUMNS]
    print("| " + " | ".join(head) + " |")
    print("|" + "---|" * len(head))
    for setting, iteration, scores in sorted(rows):
        err = errors[setting].get(iteration)
        cells = [setting, str(iteration), "" if err is None else f"{err:.3f}"]
        cells += [fmt.format(scores[split][key]) for split, key, fmt in COLUMNS]
        print("| " + " | ".join(cells) + " |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
