"""The impulse-response task's results table (README, docs/results.md) from one sweep and one
baseline evaluation, both made by scripts/reproduce_results.sh (or by hand):

    avgs eval --task rir data/rir --methods nearest,linear,opus-nearest,opus-linear,aac-nearest,aac-linear \
        --split both --out runs/rir/baselines.json
    avgs sweep --data data/rir --setting avgs="--task rir" --setting no-context="--task rir --no-context" \
        --seeds 0 1 2 --common="..." --eval-split heldout --out runs/rir      (then again with --eval-split val;
        after each, copy runs/rir/results.json to runs/rir/results-<split>.json)
    python scripts/rir_table.py runs/rir            # prints markdown

Rows: every baseline, then each sweep setting (mean over seeds, ± the spread over seeds);
columns: T60 %, C50 dB, EDT s overall (the mean of the environment means), per split.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

METRICS = (("t60_pct", "{:.1f}"), ("c50_db", "{:.2f}"), ("edt_s", "{:.3f}"))
SPLITS = ("val", "heldout")


def _read(path: Path) -> dict:
    if not path.is_file():
        raise SystemExit(f"{path}: not found (see this script's docstring for the commands that make it)")
    return json.loads(path.read_text())


def _baselines(path: Path) -> dict[str, dict[str, dict]]:
    """{method: {split: overall {metric: value}}}."""
    report = _read(path)
    splits = report["splits"] if "splits" in report else {report["split"]: report}
    out: dict[str, dict[str, dict]] = {}
    for split, r in splits.items():
        for method, scores in r["methods"].items():
            out.setdefault(method, {})[split] = scores["overall"]
    return out


def _sweep(runs: Path) -> dict[str, dict[str, dict]]:
    """{setting: {split: overall {metric: {"mean", "std", "n"}}}} from the sweep's per-split results."""
    out: dict[str, dict[str, dict]] = {}
    for split in SPLITS:
        path = runs / f"results-{split}.json"
        if not path.is_file():
            continue
        report = _read(path)
        for setting, r in report["results"].items():
            out.setdefault(setting, {})[split] = r["overall"]
    return out


def _cell(value, fmt: str) -> str:
    if value is None:
        return "-"
    if isinstance(value, dict):
        if value.get("mean") is None:
            return "-"
        text = fmt.format(value["mean"])
        return text + (f" ± {fmt.format(value['std'])}" if value.get("std") is not None else "")
    return fmt.format(value)


def table(runs: Path, baselines: Path) -> str:
    rows = [(m, s) for m, s in _baselines(baselines).items()] + [(f"AV-GS ({k})" if k != "avgs" else "AV-GS", s)
                                                                for k, s in _sweep(runs).items()]
    head = "| method | " + " | ".join(f"{sp} T60 % | C50 dB | EDT s" for sp in SPLITS) + " |"
    rule = "|---|" + "---|---|---|" * len(SPLITS)
    lines = [head, rule]
    for name, by_split in rows:
        cells = [_cell((by_split.get(sp) or {}).get(metric), fmt) for sp in SPLITS for metric, fmt in METRICS]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("runs", type=Path, help="The sweep's output folder (results-val.json, results-heldout.json).")
    parser.add_argument("--baselines", type=Path, help="avgs eval --task rir --split both JSON (default: RUNS/baselines.json).")
    args = parser.parse_args()
    print(table(args.runs, args.baselines or args.runs / "baselines.json"))


if __name__ == "__main__":
    main()
