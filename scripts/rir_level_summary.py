"""One table of several ``scripts/rir_level_distance.py`` reports (their ``--table`` files): for each
distance scene and each wall scene, each method's worst level error against the simulator, per seed
and at most over the seeds (dB).

    python scripts/rir_level_summary.py benchmarks/cpu/rir_defaults/level/*.md

A report's name is ``<distance scene>-<wall scene>-s<seed>.md``; a wall scene checked by several
reports (the same pair of sources every time) is listed once per seed.
"""

from __future__ import annotations

import argparse
import re
from pathlib import Path

NAME = re.compile(r"(?P<distance>[a-z_]+?)-(?P<wall>[a-z_]+)-s(?P<seed>\d+)\.md$")


def tables(text: str) -> list[list[list[str]]]:
    """The markdown tables of ``text``, each a list of rows of cells (the separator row left out)."""
    out, rows = [], []
    for line in text.splitlines() + [""]:
        if line.startswith("|"):
            cells = [c.strip() for c in line.strip().strip("|").split("|")]
            if not all(set(c) <= set("-: ") for c in cells):
                rows.append(cells)
        elif rows:
            out.append(rows)
            rows = []
    return out


def read(path: Path) -> tuple[dict[str, float], dict[str, float]]:
    """({method: worst |pred - truth| against distance}, {method: wall error: |(behind - same) - truth's|})."""
    distance, wall = {}, {}
    for table in tables(path.read_text()):
        head = table[0]
        if head[:2] == ["method", "max abs(pred - truth) (dB)"]:
            distance = {row[0]: float(row[1]) for row in table[1:]}
        elif head[:1] == ["method"] and "behind minus same (dB)" in head:
            col = head.index("behind minus same (dB)")
            values = {row[0]: float(row[col]) for row in table[1:]}
            truth = values.pop("truth (simulator)")
            wall = {m: abs(v - truth) for m, v in values.items()}
    return distance, wall


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("reports", type=Path, nargs="+")
    args = parser.parse_args()
    rows: dict[tuple[str, str, str], dict[int, float]] = {}  # (check, scene, method) -> {seed: dB}
    for path in args.reports:
        m = NAME.search(path.name)
        if m is None:
            raise SystemExit(f"{path}: expected a name <distance scene>-<wall scene>-s<seed>.md")
        distance, wall = read(path)
        seed = int(m["seed"])
        for method, v in distance.items():
            rows.setdefault(("distance", m["distance"], method), {})[seed] = v
        for method, v in wall.items():
            rows.setdefault(("behind a wall", m["wall"], method), {})[seed] = v
    seeds = sorted({s for v in rows.values() for s in v})
    print("| check | scene | method | " + " | ".join(f"seed {s}" for s in seeds) + " | worst |")
    print("|---|---|---|" + "---|" * (len(seeds) + 1))
    for (check, scene, method), by_seed in sorted(rows.items()):
        cells = [f"{by_seed[s]:.2f}" if s in by_seed else "" for s in seeds]
        print(f"| {check} | {scene} | {method} | " + " | ".join(cells) + f" | {max(by_seed.values()):.2f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
