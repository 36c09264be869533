"""The table of scripts/device/rir_defaults.sh's runs (docs/results.md): the baselines, then AV-GS
and ``--no-context`` (mean over seeds ± their standard deviation), every metric of
``avgs eval --task rir`` on both splits, and each run's stage-2 iterations and time.

    tar -xzf results.tgz -C /tmp/rd && python scripts/rir_defaults_table.py /tmp/rd/w
    python scripts/rir_defaults_table.py benchmarks/h200/rir_defaults      # the run kept in the repository
"""

from __future__ import annotations

import argparse
import json
import re
import statistics
from pathlib import Path

METRICS = (("t60_pct", "T60 %", "{:.1f}"), ("c50_db", "C50 dB", "{:.2f}"), ("edt_s", "EDT s", "{:.3f}"),
           ("onset_ms", "onset ms", "{:.2f}"), ("itd_us", "ITD us", "{:.0f}"), ("ild_db", "ILD dB", "{:.2f}"),
           ("lat_pct", "LAT %", "{:.0f}"))
SPLITS = ("val", "heldout")
RUN = re.compile(r"(?P<setting>.+)-s(?P<seed>\d+)\.eval\.json$")


def overall(path: Path) -> dict[str, dict[str, dict]]:
    """{method: {split: {metric: value}}} of one ``avgs eval --json`` file."""
    report = json.loads(path.read_text())
    out: dict[str, dict[str, dict]] = {}
    for split, r in report["splits"].items():
        for method, scores in r["methods"].items():
            out.setdefault(method, {})[split] = scores["overall"]
    return out


def cell(values: list[float], fmt: str) -> str:
    if len(values) == 1:
        return fmt.format(values[0])
    return f"{fmt.format(statistics.fmean(values))} ± {fmt.format(statistics.stdev(values))}"


def last_stage2(log: Path) -> tuple[dict | None, bool]:
    """(the last stage-2 record of a training log that carries its seconds, or None; whether the log
    ends the run with a "final" record)."""
    recs = [json.loads(line) for line in log.read_text().splitlines() if line.strip()]
    stage2 = [r for r in recs if r.get("stage") == "stage2" and "seconds" in r]
    return (stage2[-1] if stage2 else None), any(r.get("stage") == "final" for r in recs)


def training(folder: Path) -> list[str]:
    """One line per run: its stage-2 iterations and seconds (the log's last stage-2 record)."""
    lines = []
    for log in sorted(folder.glob("*-s*.log.jsonl")):
        last, finished = last_stage2(log)
        if last is not None:
            lines.append(f"{log.name.split('.')[0]}: {last['iteration']} iterations in {last['seconds']:.0f} s "
                         f"({1e3 * last['seconds'] / max(1, last['iteration']):.1f} ms/it)"
                         + ("" if finished else ", no final record (stopped)"))
    return lines


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder", type=Path, help="the results' w/ folder (results.tgz unpacked)")
    args = parser.parse_args()
    rows: dict[str, dict[str, dict[str, list[float]]]] = {}
    base = args.folder / "baselines.eval.json"
    if base.is_file():
        for method, splits in overall(base).items():
            rows[method] = {s: {k: [v] for k, v in m.items()} for s, m in splits.items()}
    for path in sorted(args.folder.glob("*-s*.eval.json")):
        setting = RUN.search(path.name)["setting"]
        name = "AV-GS" if setting == "avgs" else "AV-GS, --no-context"
        for splits in overall(path).values():
            for split, m in splits.items():
                for k, v in m.items():
                    rows.setdefault(name, {}).setdefault(split, {}).setdefault(k, []).append(v)
    head = ["method"] + [f"{split} {label}" for split in SPLITS for _, label, _ in METRICS]
    print("| " + " | ".join(head) + " |")
    print("|" + "---|" * len(head))
    for name, splits in rows.items():
        seeds = max((len(v) for s in splits.values() for v in s.values()), default=0)
        label = f"{name} ({seeds} seeds)" if seeds > 1 else name
        cells = [cell(splits.get(split, {}).get(k, [float("nan")]), fmt) for split in SPLITS for k, _, fmt in METRICS]
        print("| " + " | ".join([label] + cells) + " |")
    print()
    for line in training(args.folder):
        print(f"- {line}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
