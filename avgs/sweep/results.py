"""A sweep's scores in one report: per scene, environment and overall, per setting, mean and
spread over seeds; and the table of which runs ran, which failed and why.

Each run's score is ``avgs eval``'s report of its checkpoint (``eval-<split>.json``). For a
setting and a seed, environments and overall follow RWAVS (:func:`avgs.evaluation.binaural.aggregate`:
an environment is the mean of its scenes, overall the mean of the environments), counted
only for a seed that has every scene of the sweep, so that no seed's overall leaves a scene
out. Then each row is the mean over seeds, the sample standard deviation (``std``, null with
one seed) and the number of seeds ``n``.

``results.json``::

    {"split": "val", "metrics": [...], "settings": [...], "scenes": [...], "seeds": [...],
     "environments": {scene: env},
     "runs": [{"run", "scene", "setting", "seed", "status", "seconds", "reason", "scores"}],
     "results": {setting: {"scenes": {scene: {metric: {"mean", "std", "n"}}},
                           "environments": {...}, "overall": {...}}}}
"""

from __future__ import annotations

import math

import numpy as np

from avgs.evaluation.binaural import aggregate
from avgs.sweep.spec import Run
from avgs.sweep.state import scores_of

FORMATS = {"MAG": ".4f", "ENV": ".4f", "ILD": ".2f", "MAGp": ".4f", "T60": ".2f", "C50": ".3f", "EDT": ".4f"}
"Each metric's number format in the tables (others: .4f)."


def stats(scores: list[dict[str, float]]) -> dict[str, dict]:
    """``{metric: {"mean", "std", "n"}}`` over a list of ``{metric: value}`` (std: sample, None for one)."""
    out = {}
    for metric in dict.fromkeys(m for s in scores for m in s):
        values = np.array([s[metric] for s in scores if isinstance(s.get(metric), (int, float))], dtype=np.float64)
        if len(values) == 0:
            continue
        std = float(values.std(ddof=1)) if len(values) > 1 else None
        out[metric] = {"mean": float(values.mean()), "std": std, "n": int(len(values))}
    return out


def collect(runs: list[Run], records: dict[str, dict], split: str) -> dict:
    """The report of the sweep (module docstring) from its runs, the status ``records`` by run
    name, and each run's ``eval-<split>.json`` (``split`` "none": no scores)."""
    settings = list(dict.fromkeys(r.setting for r in runs))
    scenes = list(dict.fromkeys(r.scene for r in runs))
    seeds = list(dict.fromkeys(r.seed for r in runs))
    environments: dict[str, str] = {}
    scored: dict[str, dict[int, dict[str, dict[str, float]]]] = {s: {} for s in settings}
    rows = []
    for run in runs:
        record = records.get(run.name, {})
        got = scores_of(run, split) if split != "none" else None
        if got is not None:
            scores, environments[run.scene] = got
            scored[run.setting].setdefault(run.seed, {})[run.scene] = scores
        rows.append({"run": run.name, "scene": run.scene, "setting": run.setting, "seed": run.seed,
                     "status": record.get("status", "not run"), "seconds": record.get("seconds"),
                     "reason": record.get("reason"), "folder": str(run.folder), "scores": got[0] if got else None})
    results = {}
    for setting in settings:
        per_seed = scored[setting]
        if not per_seed:
            continue
        whole = [aggregate(per_seed[seed], environments) for seed in per_seed if len(per_seed[seed]) == len(scenes)]
        entry = {"scenes": {}, "environments": {}, "overall": stats([w["overall"] for w in whole])}
        for scene in scenes:
            found = [per_seed[seed][scene] for seed in per_seed if scene in per_seed[seed]]
            if found:
                entry["scenes"][scene] = stats(found)
        for env in dict.fromkeys(environments[s] for s in scenes if s in environments):
            entry["environments"][env] = stats([w["environments"][env] for w in whole])
        results[setting] = entry
    metrics = list(dict.fromkeys(m for r in rows if r["scores"] for m in r["scores"]
                                 if isinstance(r["scores"][m], (int, float))))
    return {"split": split, "metrics": metrics, "settings": settings, "scenes": scenes, "seeds": seeds,
            "environments": {s: environments[s] for s in scenes if s in environments}, "runs": rows, "results": results}


def cell(stat: dict | None, fmt: str, markdown: bool = False) -> str:
    """``mean ± std`` (``mean`` alone for one seed, ``-`` for none)."""
    if not stat:
        return "-"
    mean = format(stat["mean"], fmt)
    if stat["std"] is None or not math.isfinite(stat["std"]):
        return mean
    return f"{mean} ± {format(stat['std'], fmt)}"


def _rows(report: dict) -> list[tuple[str, str, dict]]:
    """(label, setting, {metric: stat}) of every table row: scenes, environments, overall."""
    rows = []
    results = report["results"]
    for scene in report["scenes"]:
        for setting in results:
            if scene in results[setting]["scenes"]:
                rows.append((f"scene {scene}", setting, results[setting]["scenes"][scene]))
    envs = list(dict.fromkeys(report["environments"].values()))
    if len(envs) < len(report["environments"]):  # an environment of several scenes: its row says something new
        for env in envs:
            for setting in results:
                if results[setting]["environments"].get(env):
                    rows.append((f"env   {env}", setting, results[setting]["environments"][env]))
    for setting in results:
        rows.append(("overall", setting, results[setting]["overall"]))
    return rows


def format_results(report: dict) -> str:
    """Plain-text table: rows scene x setting, environment x setting, overall x setting;
    columns each metric's mean ± std over seeds and the number of seeds."""
    if not report["results"]:
        return "no scores (no run finished and was scored)"
    rows = _rows(report)
    cells = [[label, setting, *(cell(s.get(m), FORMATS.get(m, ".4f")) for m in report["metrics"]),
              str(max((v["n"] for v in s.values()), default=0))] for label, setting, s in rows]
    head = ["", "setting", *report["metrics"], "seeds"]
    widths = [max(len(r[i]) for r in [head, *cells]) for i in range(len(head))]
    lines = [f"{report['split']} clips; mean ± std over seeds"]
    for r in [head, *cells]:
        lines.append("  ".join(f"{v:<{w}}" if i < 2 else f"{v:>{w}}" for i, (v, w) in enumerate(zip(r, widths))).rstrip())
    return "\n".join(lines)


def format_markdown(report: dict) -> str:
    """The same rows as a Markdown table, the form of the README's results tables."""
    if not report["results"]:
        return "No scores.\n"
    metrics = report["metrics"]
    lines = [f"{report['split']} clips, mean ± std over seeds.", "",
             "| | setting | " + " | ".join(metrics) + " | seeds |", "|---|---|" + "---|" * (len(metrics) + 1)]
    for label, setting, s in _rows(report):
        n = max((v["n"] for v in s.values()), default=0)
        lines.append(f"| {label} | {setting} | " + " | ".join(cell(s.get(m), FORMATS.get(m, ".4f")) for m in metrics) + f" | {n} |")
    return "\n".join(lines) + "\n"


def format_runs(report: dict) -> str:
    """Which runs ran, which were skipped, which failed and why: one line per run."""
    rows = [(r["run"], r["status"], "" if r["seconds"] is None else f"{r['seconds']:.0f} s", r["reason"] or "")
            for r in report["runs"]]
    head = ("run", "status", "time", "")
    widths = [max(len(r[i]) for r in [head, *rows]) for i in range(3)]
    lines = []
    for r in [head, *rows]:
        lines.append(f"{r[0]:<{widths[0]}}  {r[1]:<{widths[1]}}  {r[2]:>{widths[2]}}  {r[3]}".rstrip())
    counts = {}
    for r in report["runs"]:
        counts[r["status"]] = counts.get(r["status"], 0) + 1
    lines.append(", ".join(f"{n} {status}" for status, n in counts.items()))
    return "\n".join(lines)
