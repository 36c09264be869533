"""The six-preset overall (the mean of the three environments' means) with the runs here in place of the old ones:
each preset's scores from runs/ and baselines.json here where they are (three_rooms on the fixed truth; two_rooms,
u_room and l_room with this code), else from ../rir_defaults/reflections/runs (2026-11-28) and
../rir_defaults/baselines.json. Prints a markdown table per split, and which presets came from where.

    python benchmarks/cpu/rir_fixed/overall.py

"avgs-ild" and "no-context-ild": the same checkpoints with the early ILD's factor behind a wall (blocked_ild.sh);
"avgs-geo" and "no-context-geo": those with the straight path's tests fitted again on their own final points, what
training now does at its end (geometry.sh). rect_small and rect_large keep their runs: no training pair there is
behind a wall, so neither changes them.
"""

import json
import statistics as st
from collections import defaultdict
from pathlib import Path

HERE = Path(__file__).parent
OLD = HERE.parent / "rir_defaults"
ENVIRONMENT = {"rect_small": "rectangular", "rect_large": "rectangular", "l_room": "non-rectangular",
               "u_room": "non-rectangular", "two_rooms": "multi-room", "three_rooms": "multi-room"}
KEYS = (("t60_pct", "{:.1f}"), ("c50_db", "{:.2f}"), ("edt_s", "{:.3f}"), ("onset_ms", "{:.2f}"), ("itd_us", "{:.0f}"),
        ("ild_db", "{:.2f}"), ("lat_pct", "{:.0f}"))


def overall(scenes: dict[str, dict]) -> dict[str, float]:
    envs = defaultdict(list)
    for scene, m in scenes.items():
        envs[ENVIRONMENT[scene]].append(m)
    return {k: st.fmean(st.fmean(m[k] for m in ms) for ms in envs.values()) for k, _ in KEYS}


def run_scores(path: Path, split: str, when: str = "after") -> dict:
    (m,) = json.loads(path.read_text())[when][split].values()  # one scene: one environment
    return m


def main() -> None:
    old, new = (json.loads((d / "baselines.json").read_text()) for d in (OLD, HERE))
    for split in ("val", "heldout"):
        print(f"\n{split}:\n\n| method | " + " | ".join(k for k, _ in KEYS) + " |\n|---|" + "---|" * len(KEYS))
        for method in ("nearest", "linear"):
            scenes = dict(old["splits"][split]["methods"][method]["scenes"])
            for scene, m in new["splits"][split]["methods"][method]["scenes"].items():
                scenes[scene.removesuffix("_fixed")] = m
            o = overall(scenes)
            print(f"| {method} | " + " | ".join(f.format(o[k]) for k, f in KEYS) + " |")
        for setting, when in (("avgs", "before"), ("avgs", "after"), ("avgs-ild", "after"), ("avgs-geo", "after"),
                              ("no-context", "before"), ("no-context", "after"), ("no-context-ild", "after"),
                              ("no-context-geo", "after")):
            plain = setting.removesuffix("-ild").removesuffix("-geo")
            seeds = []
            for k in range(3):
                scenes = {}
                # the runs here last: they replace; a "-ild" or "-geo" setting (blocked_ild.sh, geometry.sh) over its
                # plain one's, where a preset has no pair behind a wall (rect_small, rect_large) they change nothing
                for folder, name in ((OLD / "reflections" / "runs", plain), (HERE / "runs", plain), (HERE / "runs", setting)):
                    scenes.update({p.name.split(f"-{name}-seed")[0]: run_scores(p, split, when)
                                   for p in folder.glob(f"*-{name}-seed{k}.spatial.json")})
                seeds.append(overall(scenes))
            label = setting + (", direct sound left to B" if when == "before" else "")
            print(f"| {label} (3 seeds) | " + " | ".join(
                f"{f.format(st.fmean(s[k] for s in seeds))} ± {f.format(st.stdev(s[k] for s in seeds))}" for k, f in KEYS) + " |")
    here = sorted({p.name.split("-")[0] for p in (HERE / "runs").glob("*.spatial.json")})
    print(f"\nfrom runs/ here: {', '.join(here)}; the rest from ../rir_defaults/reflections/runs")


if __name__ == "__main__":
    main()
