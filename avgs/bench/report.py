"""``benchmarks/REPORT.md``, its plots (PNG) and ``results.json`` from one bench run."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from avgs.io.atomic import atomic_path, write_text

PAPER_ANCHORS_S = {"AV-NeRF (paper)": 1.4, "AV-GS (paper)": 0.08}
"Inference time per pose quoted by the AV-GS paper (its GPU; ours is measured here)."
SECTIONS = ("Headline", "Machine", "Inference latency", "Speed against error", "Point budgets", "Training throughput", "Notes")
"Second-level headings of REPORT.md, in order (tests check them)."
FAMILY_STYLE = {
    "baseline": ("tab:gray", "s"),
    "AV-GS vicinity": ("tab:blue", "o"),
    "AV-GS points": ("tab:cyan", "v"),
    "AV-GS precision": ("tab:purple", "D"),
    "AV-GS synthesis": ("tab:green", "P"),
    "simulator (image source)": ("tab:orange", "^"),
    "simulator (rays)": ("tab:red", "^"),
}


def _f(v, fmt="{:.3f}") -> str:
    if v is None or (isinstance(v, float) and not np.isfinite(v)):
        return "-"
    return fmt.format(v)


def _table(head: list[str], rows: list[list]) -> list[str]:
    out = ["| " + " | ".join(head) + " |", "|" + "|".join("---" for _ in head) + "|"]
    out += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return out


# -- plots ------------------------------------------------------------------------------


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_latency(latency: dict, path: Path) -> Path:
    """Stacked stage bars per device (the stages the latency section timed: a mask model's or an
    impulse-response model's), and, where they were timed, the before/after paths (ms per pose)."""
    plt = _plt()
    devices = list(latency)
    stages = list(dict.fromkeys(s for d in devices for s in latency[d].get("stages", {})))
    paths = any(latency[d].get("paths") for d in devices)
    fig, axes = plt.subplots(1, 2 if paths else 1, figsize=(10 if paths else 6, 3.6), squeeze=False)
    axes = axes[0]
    ax = axes[0]
    left = np.zeros(len(devices))
    for s in stages:
        vals = np.array([latency[d]["stages"].get(s, {}).get("median_ms", 0.0) for d in devices])
        ax.barh(devices, vals, left=left, label=s)
        left += vals
    totals = [latency[d]["render"]["median_ms"] for d in devices]
    ax.barh(devices, np.maximum(np.array(totals) - left, 0), left=left, label="the rest of the render", color="lightgray")
    ax.set_xlabel("ms per pose (median, 1 s clip)")
    ax.set_title("where the time goes")
    ax.legend(fontsize=7, loc="lower right")
    if paths:
        ax = axes[1]
        labels, vals = [], []
        for d in devices:
            for name, t in latency[d].get("paths", {}).items():
                labels.append(f"{d}: {name}")
                vals.append(t["median_ms"])
            labels.append(f"{d}: cached (render)")
            vals.append(latency[d]["render"]["median_ms"])
        ax.barh(labels, vals, color=["tab:gray" if "now" not in label else "tab:green" for label in labels])
        ax.set_xlabel("ms per pose (median)")
        ax.set_title("before / after")
        ax.tick_params(axis="y", labelsize=7)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=90)
    plt.close(fig)
    return path


def plot_speed_error(summary: list[dict], path: Path) -> Path:
    """Latency (log) against MAG and ENV, one marker per method / setting."""
    plt = _plt()
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    for ax, metric in zip(axes, ("MAG", "ENV")):
        for family, (colour, marker) in FAMILY_STYLE.items():
            pts = [r for r in summary if r["family"] == family]
            if not pts:
                continue
            x = [max(r["latency_ms"], 1e-3) for r in pts]
            ax.scatter(x, [r[metric] for r in pts], c=colour, marker=marker, label=family, s=28, zorder=3)
            if family.startswith("simulator"):
                for r in pts:
                    ax.annotate(str(r.get("order", "")), (max(r["latency_ms"], 1e-3), r[metric]), fontsize=6,
                                xytext=(2, 2), textcoords="offset points")
        for name, s in PAPER_ANCHORS_S.items():
            ax.axvline(1e3 * s, ls="--", lw=0.8, c="k", alpha=0.5)
            ax.text(1e3 * s, ax.get_ylim()[1], " " + name, rotation=90, va="top", fontsize=7, alpha=0.7)
        ax.set_xscale("log")
        ax.set_xlabel("latency per pose, ms (log)")
        ax.set_ylabel(f"{metric} (lower is better)")
        ax.grid(alpha=0.3, which="both")
    axes[0].legend(fontsize=7)
    fig.suptitle("speed against error (numbers on simulator points: image-source order)", fontsize=9)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=90)
    plt.close(fig)
    return path


def plot_points(budgets: list[dict], path: Path) -> Path:
    """MAG against point count and against checkpoint size."""
    plt = _plt()
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6))
    for scene in sorted({b["scene"] for b in budgets}):
        rows = sorted((b for b in budgets if b["scene"] == scene), key=lambda b: b["points"])
        axes[0].plot([b["points"] for b in rows], [b["MAG"] for b in rows], "o-", label=scene)
        axes[1].plot([b["ckpt_bytes"] / 1e6 for b in rows], [b["MAG"] for b in rows], "o-", label=scene)
    axes[0].set_xlabel("audio points")
    axes[1].set_xlabel("checkpoint size, MB")
    for ax in axes:
        ax.set_xscale("log")
        ax.set_ylabel("MAG")
        ax.grid(alpha=0.3, which="both")
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=90)
    plt.close(fig)
    return path


# -- the headline -----------------------------------------------------------------------

POSE_TARGET_MS = 5.0
"What a binaural-task pose (1 s clip, default synthesis) may cost on 2 CPU cores."


def headline(summary: list[dict]) -> str:
    """Where the reference AV-GS point sits against the simulator's points."""
    avgs = [r for r in summary if r["family"] == "AV-GS vicinity"]
    sims = [r for r in summary if r["family"].startswith("simulator")]
    if not avgs:
        return "No AV-GS model was scored in this run (no scenes): see 'Speed against error'."
    ref = next((r for r in avgs if "15 %" in r["label"]), avgs[0])
    text = f"{ref['label']} answers a pose in **{ref['latency_ms']:.2f} ms** with MAG {ref['MAG']:.3f} / ENV {ref['ENV']:.4f}."
    if "new_clip_ms" in ref:
        text += (f" That is the default synthesis of a 1 s clip heard from pose after pose, as in the explorer (the clip's "
                 f"source analysis kept); with a new clip at every pose, as evaluation renders, **{ref['new_clip_ms']:.2f} ms** "
                 f"(target for either: at most {POSE_TARGET_MS:g} ms on 2 CPU cores).")
    if not sims:
        return text + _synthesis_line(ref, summary) + " The simulator was not timed in this run (no generated scenes with scene.json)."
    full = max(sims, key=lambda r: (r.get("ray_tracing", False), r.get("order", 0)))
    text += (f" The scene's own simulator at full quality ({full['label']}) takes {full['latency_ms']:.0f} ms per pose "
             f"(**{full['latency_ms'] / max(ref['latency_ms'], 1e-9):.0f}x** slower) for MAG {full['MAG']:.3f}.")
    text += _synthesis_line(ref, summary)
    as_good = [r for r in sims if r["MAG"] <= ref["MAG"]]
    if as_good:
        cheapest = min(as_good, key=lambda r: r["latency_ms"])
        text += (f" The cheapest simulator setting at least as accurate in MAG is {cheapest['label']}: "
                 f"{cheapest['latency_ms']:.0f} ms ({cheapest['latency_ms'] / max(ref['latency_ms'], 1e-9):.0f}x AV-GS's time).")
    else:
        best = min(sims, key=lambda r: r["MAG"])
        text += f" No simulator setting reaches AV-GS's MAG here (best: {best['label']}, MAG {best['MAG']:.3f})."
    return text


def _synthesis_line(ref: dict, summary: list[dict]) -> str:
    """The default synthesis (the reference row) against the eight-iteration ones of the same run."""
    eight = [r for r in summary if r["family"] == "AV-GS synthesis" and r["label"].endswith("+ 8 iterations")]
    if not eight:
        return ""
    parts = [f"{r['label'].split('% ', 1)[-1]} {r['MAG']:.4f} / {r['ENV']:.4f} in {r['latency_ms']:.2f} ms" for r in eight]
    verdict = "at least as good in MAG as" if all(ref["MAG"] <= r["MAG"] for r in eight) else "not as good in MAG as"
    return (f" Its default synthesis (MAG {ref['MAG']:.4f} / ENV {ref['ENV']:.4f}) is {verdict} eight phase iterations "
            f"per ear ({'; '.join(parts)}).")


# -- the report -------------------------------------------------------------------------


def _carried(results: dict, key: str) -> list[str]:
    """The line that says a section was kept from an earlier run (``avgs bench --skip``), or nothing."""
    origin = results.get("carried", {}).get(key)
    if not origin:
        return []
    return [f"*Kept from the run of {origin['date_utc']} (`{origin['command']}`): this run skipped it.*", ""]


def write_report(results: dict, out_dir: str | Path) -> Path:
    """Write REPORT.md, the PNGs and results.json into ``out_dir``; returns the report's path."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    write_text(out / "results.json", json.dumps(results, indent=1, default=str) + "\n")
    lat = results.get("latency", {})
    se = results.get("speed_error", {})
    summary = se.get("summary", [])
    budgets = [b for sc in se.get("scenes", []) for b in sc.get("budgets", [])]
    m = results["machine"]
    L = [f"# AV-GS benchmarks{' (--quick)' if results.get('quick') else ''}", "",
         f"Command: `{m['command']}`  ", f"Date: {m['date_utc']}", ""]

    L += ["## Headline", "", headline(summary), ""]
    if summary and results.get("carried", {}).get("speed_error"):
        L += [f"(Speed against error from the run of {results['carried']['speed_error']['date_utc']}.)", ""]
    demo = lat.get("cpu")
    if demo:
        L += [f"Inference on the demo scene ({results['demo']['source']}, {demo['points']} audio points, k = {demo['k']}): "
              f"median **{demo['render']['median_ms']:.2f} ms** per pose on the CPU ({m['torch_threads']} threads), "
              f"95th percentile {demo['render']['p95_ms']:.2f} ms.", ""]

    L += ["## Machine", ""]
    L += _table(["what", "value"], [[k, f"`{v}`" if k == "command" else v] for k, v in m.items()])
    L += [""]

    L += ["## Inference latency", ""]
    L += _carried(results, "latency")
    if lat:
        L += ["One pose = `SceneRenderer.render` of a 1 s clip at a new listener position (source fixed: C_S cached). "
              "Median and 95th percentile over repeats.", ""]
        rows = []
        for dev, d in lat.items():
            rows.append([dev, d["points"], d["k"], _f(d["render"]["median_ms"], "{:.2f}"), _f(d["render"]["p95_ms"], "{:.2f}"),
                         _f(d["masks"]["median_ms"], "{:.2f}")] + [_f(d["stages"].get(s, {}).get("median_ms"), "{:.3f}") for s in
                                                                   ("vicinity", "field", "binauralizer", "impulse response", "synthesis")])
        L += _table(["device", "points", "k", "render ms (median)", "p95", "masks only", "vicinity", "field F", "binauralizer B",
                     "impulse response", "synthesis"], rows)
        for dev, d in lat.items():
            if "source_aware" in d:  # a checkpoint of the impulse-response task (avgs.bench.latency.measure_source_aware)
                t, st = d["source_aware"], d.get("stages", {})
                L += ["", f"Source-aware render ({dev}, task {d.get('task')}, {d.get('response_samples')}-sample responses, "
                      f"phase {d.get('phase')}): `render(listener, yaw, mono, source=...)` of a 1 s clip with a new source "
                      f"every call (C_S recomputed), median **{t['median_ms']:.2f} ms**, p95 {t['p95_ms']:.2f} ms per pose "
                      f"(target: under 10 ms on 2 CPU cores); source fixed: {d['fixed_source']['median_ms']:.2f} ms. Stages: "
                      + ", ".join(f"{k} {v['median_ms']:.2f} ms" for k, v in st.items()) + "."]
        for dev, d in lat.items():
            if "render_1_thread" in d:
                t = d["render_1_thread"]
                L += ["", f"The same renders with 1 torch thread ({dev}): median {t['median_ms']:.2f} ms, p95 {t['p95_ms']:.2f} ms "
                      "(the per-pose work is many small operations; when other processes share the two cores, "
                      "two threads wait on each other)."]
        rows = []
        for dev, d in lat.items():
            now = d["render"]["median_ms"]
            for name, t in d.get("paths", {}).items():
                rows.append([dev, name, _f(t["median_ms"], "{:.2f}"), _f(t["p95_ms"], "{:.2f}"), f"{t['median_ms'] / now:.1f}x",
                             _f(t["max_abs_diff"], "{:.1e}")])
            if d.get("paths"):
                rows.append([dev, "**cached (render)**", f"**{now:.2f}**", _f(d["render"]["p95_ms"], "{:.2f}"), "1.0x", "0"])
        if rows:
            L += ["", "The cached render against the same model code without caches, side by side in this run (same poses, "
                      "same output to float rounding):", ""]
            L += _table(["device", "path", "median ms", "p95 ms", "time vs cached", "max abs diff"], rows)
        rows = [[dev, label, _f(t["median_ms"], "{:.2f}"), _f(t["p95_ms"], "{:.2f}"),
                 f"{t['median_ms'] / d['render']['median_ms']:.2f}x"]
                for dev, d in lat.items() for label, t in d.get("syntheses", {}).items()]
        if rows:  # a binaural-task checkpoint (a source-aware one's render is its convolution)
            L += ["", "Each synthesis (`--synthesis`, `--phase`, `--phase-iterations`), the same poses; their error on "
                      "the bench's scenes is in the speed-against-error table:", ""]
            L += _table(["device", "synthesis", "median ms", "p95 ms", "time vs default"], rows)
        rows = [[dev, f"{s} s", _f(t["median_ms"], "{:.1f}"), f"{t['realtime_factor']:.0f}x"] for dev, d in lat.items()
                for s, t in d.get("long", {}).items()]
        if rows:
            L += ["", "Long inputs (one call, any length: the masks are time-invariant):", ""]
            L += _table(["device", "audio", "ms (median)", "faster than real time"], rows)
        rows = []
        for dev, d in lat.items():
            for name, t in d.get("precision", {}).items():
                rows.append([dev, name, t.get("error") or _f(t["median_ms"], "{:.2f}"), _f(t.get("max_abs_diff"), "{:.1e}"),
                             "-" if "error" in t else f"{t['median_ms'] / d['render']['median_ms']:.2f}x"])
        if rows:
            L += ["", "Reduced precision (networks in the given dtype; error: max |diff| vs float32, input peak 1):", ""]
            L += _table(["device", "dtype", "median ms", "max abs diff", "time vs float32"], rows)
        L += ["", "![latency](latency.png)", ""]
    else:
        L += ["(not run)", ""]

    L += ["## Speed against error", ""]
    L += _carried(results, "speed_error")
    if summary:
        scenes = [f"{sc['scene']} ({sc['train_clips']} train / {sc['val_clips']} val clips)" for sc in se["scenes"]]
        L += [f"Scenes: {', '.join(scenes)}. MAG and ENV are means over the val clips (then over scenes); latency is the "
              "median per pose on this machine's CPU unless the label says cuda. AV-GS models: "
              f"{se['settings']['iterations']} stage-2 iterations from {se['settings']['points']} points (see Notes).", ""]
        rows = [[r["label"], r["family"], _f(r["latency_ms"], "{:.3g}"), _f(r["MAG"]), _f(r["ENV"], "{:.4f}"), r.get("points", "")]
                for r in sorted(summary, key=lambda r: r["latency_ms"])]
        L += _table(["method", "family", "ms per pose", "MAG", "ENV", "points"], rows)
        L += ["", "Paper anchors (their GPU, per inference): " + ", ".join(f"{k} {v:g} s" for k, v in PAPER_ANCHORS_S.items()) + ".", ""]
        L += ["![speed against error](speed_error.png)", ""]
        for sc in se["scenes"]:
            if sc.get("sim_note"):
                L += [f"- {sc['sim_note']}"]
            t = sc.get("ground_truth_settings")
            if t:
                L += [f"- {sc['scene']}: ground truth simulated at image-source order {t.get('max_order')}"
                      f"{' + ray tracing' if t.get('ray_tracing') else ''} (polygon rooms: order {t.get('max_order_polygon')})."]
        L += [""]
    else:
        L += [se.get("note", "(not run)"), ""]

    L += ["## Point budgets", ""]
    L += _carried(results, "speed_error")
    if budgets:
        L += ["The vicinity-15 % model: all points; pruned exactly to the walkable area (every vicinity a listener or the "
              "source can have there is kept, k fixed: identical output inside the area); then random subsets "
              "(k back at 15 % of the subset). Checkpoint sizes are without G.", ""]
        rows = [[b["scene"], b["label"].replace("AV-GS ", ""), b["points"], b["k"], _f(b["ckpt_bytes"] / 1e6, "{:.2f}"),
                 _f(b["MAG"]), _f(b["ENV"], "{:.4f}"), _f(b["latency_ms"], "{:.2f}")] for b in budgets]
        L += _table(["scene", "points", "N", "k", "ckpt MB", "MAG", "ENV", "ms per pose"], rows)
        for sc in se["scenes"]:
            p = sc["prune"]
            L += ["", f"{sc['scene']}: pruning to the walkable area kept {p['points_after']} of {p['points_before']} points."]
        L += ["", "![error against points and size](points.png)", ""]
    else:
        L += ["(not run)", ""]

    L += ["## Training throughput", ""]
    L += _carried(results, "training")
    tr = results.get("training", [])
    if tr:
        rows = [[t.get("stage"), t.get("device"), t.get("init", ""), t.get("points", t.get("gaussians", "")),
                 t.get("iterations"), t.get("error") or _f(t.get("it_per_s"), "{:.1f}"), _f(t.get("peak_mb"), "{:.0f}"),
                 t.get("peak_note", "")]
                for t in tr]
        L += _table(["stage", "device", "initial points", "points / Gaussians", "iterations timed", "it/s", "peak MB",
                     "peak is"], rows)
        L += [""]
    else:
        L += ["(not run)", ""]

    L += ["## Notes", ""]
    L += [f"- {n}" for n in results.get("notes", [])]
    L += ["", f"Reproduce: `{m['command']}` (results.json holds every number above).", ""]
    path = out / "REPORT.md"
    write_text(path, "\n".join(L))
    if lat:
        plot_latency(lat, out / "latency.png")
    if summary:
        plot_speed_error(summary, out / "speed_error.png")
    if budgets:
        plot_points(budgets, out / "points.png")
    return path
