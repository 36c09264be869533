"""``avgs bench [--quick]``: inference latency, speed against error, training throughput.

Writes ``benchmarks/REPORT.md`` (with the machine, versions and this exact command),
plots and ``results.json``; prints the tables and ends with the line
``inference median X ms per pose (cpu, demo scene)``. Scenes are generated with
``avgs synth`` when the generator is installed (and reused from ``--work`` on re-runs),
or given with ``--data``. Trained bench models are cached in ``--work`` too.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

DEMO_CKPT = "assets/demo/scene.ckpt"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--quick", action="store_true", help="A few minutes on two cores: one small scene, short training, fewer repeats.")
    parser.add_argument("--ckpt", default=DEMO_CKPT, help=f"Demo checkpoint for the latency section (default {DEMO_CKPT}; "
                        "when absent, the bench's own 15 %% model of the first scene stands in).")
    parser.add_argument("--out", default="benchmarks", help="Where REPORT.md, the plots and results.json go (default benchmarks).")
    parser.add_argument("--work", help="Cache for generated scenes and trained bench models (default OUT/work, git-ignored).")
    parser.add_argument("--data", action="append", default=[], metavar="DATA_ROOT/SCENE_ID", help="An existing scene to benchmark on (repeatable).")
    parser.add_argument("--presets", help="Presets to generate with 'avgs synth' (comma-separated; default office,apartment, --quick: office; '' for none).")
    parser.add_argument("--poses", type=int, help="Poses per generated scene (default 48, --quick 20).")
    parser.add_argument("--iterations", type=int, help="Stage-2 iterations of each bench model (default 1500, --quick 150).")
    parser.add_argument("--points", type=int, help="Audio points each bench model starts from (default 6000, --quick 1500).")
    parser.add_argument("--repeats", type=int, help="Timed calls per latency figure (default 100, --quick 30).")
    parser.add_argument("--threads", type=int, default=2, help="Torch CPU threads (default 2: our machines' cores).")
    parser.add_argument("--skip", action="append", default=[], choices=("latency", "speed-error", "training", "simulator"),
                        help="Leave a section out (repeatable): the report keeps it from OUT/results.json, marked with "
                             "the run that measured it, where that file has it.")
    parser.add_argument("--no-cuda", action="store_true", help="Do not measure on CUDA even when it is present.")
    parser.add_argument("--seed", type=int, default=0, help="Seed of generated scenes.")


def _defaults(args) -> dict:
    q = args.quick
    return {
        "presets": [p for p in ((args.presets if args.presets is not None else ("office" if q else "office,apartment")).split(",")) if p],
        "poses": args.poses or (20 if q else 48),
        "iterations": args.iterations or (150 if q else 1500),
        "points": args.points or (1500 if q else 6000),
        "repeats": args.repeats or (30 if q else 100),
        "vicinities": (5.0, 10.0, 15.0, 20.0, 25.0),
        "budgets": (0.5, 0.25, 0.1) if q else (0.5, 0.25, 0.1, 0.05),
        "orders": (0, 1, 3, 10) if q else tuple(range(11)),
        "sim_poses": 2 if q else 4,
        "long_seconds": (10.0, 60.0),
        "train_iterations": 20 if q else 60,
        "stage1_iterations": 5 if q else 20,
    }


def generate_scenes(work: Path, presets: list[str], poses: int, seed: int, quick: bool, say) -> tuple[list[Path], str | None]:
    """Scene folders made by ``avgs synth`` (reused when already there), or ([], why not)."""
    import importlib.util

    from avgs.data.rwavs import is_scene_dir

    if importlib.util.find_spec("avgs.commands.synth") is None:
        return [], "the scene generator ('avgs synth', avgs.synth) is not installed yet"
    from avgs.cli import main as cli_main

    root = work / "scenes"
    dirs = []
    for preset in presets:
        scene_id = f"{preset}_bench{seed}"
        d = root / scene_id
        if not is_scene_dir(d):
            say(f"generating scene {scene_id} ({poses} poses)")
            argv = ["synth", str(root), "--preset", preset, "--scene-id", scene_id, "--poses", str(poses), "--seed", str(seed)]
            try:
                rc = cli_main(argv + (["--quick"] if quick else []))
            except SystemExit as exc:  # argparse rejected the arguments
                rc = exc.code
            if rc != 0 or not is_scene_dir(d):
                return dirs, f"'avgs {' '.join(argv)}' failed (exit {rc})"
        dirs.append(d)
    return dirs, None


def demo_renderer(args, scenes_result: dict | None, work: Path, settings: dict, say):
    """(SceneRenderer, description) for the latency section."""
    from avgs.render.renderer import SceneRenderer

    if Path(args.ckpt).is_file():
        return SceneRenderer.load(args.ckpt), f"`{args.ckpt}`"
    if scenes_result and scenes_result.get("scenes"):
        sc = scenes_result["scenes"][0]["scene"]
        path = work / sc / "avgs_v15.ckpt"
        if path.is_file():
            return SceneRenderer.load(path), f"{args.ckpt} absent; the bench's 15 % model of {sc}"
    import numpy as np

    from avgs.io.checkpoint import untrained_checkpoint

    n = settings["points"]
    say(f"{args.ckpt} absent and no scene: latency on an untrained {n}-point model (same cost as trained)")
    from avgs.io.checkpoint import save_checkpoint

    pts = np.random.default_rng(0).uniform([0, 0, 0], [6, 4, 3], size=(n, 3))
    path = save_checkpoint(untrained_checkpoint(pts, [4.5, 2.5, 1.2]), work / "demo_untrained.ckpt")
    return SceneRenderer.load(path), f"{args.ckpt} absent; untrained {n}-point model"


SKIPPABLE = {"latency": ("latency", "demo"), "speed-error": ("speed_error",), "training": ("training",)}
"``--skip`` choices whose section a run can keep from the last one: the results.json keys of each."


def carry_skipped(results: dict, previous_path: Path, skipped: list[str], say) -> None:
    """Copy the sections ``skipped`` this run from the results.json at ``previous_path`` into ``results``, each
    with the date and command of the run that measured it (``results["carried"]``): a partial run refreshes
    what it measured and loses nothing else. A section that run had carried keeps its first provenance."""
    import json

    wanted = [key for s in dict.fromkeys(skipped) for key in SKIPPABLE.get(s, ())]
    if not wanted or not previous_path.is_file():
        return
    try:
        previous = json.loads(previous_path.read_text())
        machine = previous["machine"]
        origin = {"date_utc": machine["date_utc"], "command": machine["command"]}
    except (OSError, ValueError, KeyError, TypeError) as exc:
        say(f"not keeping the skipped sections: {previous_path} is not a results.json of avgs bench ({exc})")
        return
    if bool(previous.get("quick")) != bool(results["quick"]):
        say(f"not keeping the skipped sections: {previous_path} is from a run with{'' if previous.get('quick') else 'out'} --quick")
        return
    carried = results.setdefault("carried", {})
    for key in wanted:
        if key in previous:
            results[key] = previous[key]
            carried[key] = previous.get("carried", {}).get(key, origin)
            say(f"kept '{key}' from the run of {carried[key]['date_utc']}")


def print_tables(results: dict) -> None:
    lat = results.get("latency", {})
    for dev, d in lat.items():
        st = "  ".join(f"{k} {v['median_ms']:.3f}" for k, v in d["stages"].items())
        print(f"[{dev}] render {d['render']['median_ms']:.2f} ms (p95 {d['render']['p95_ms']:.2f}); stages ms: {st}")
        for name, t in d.get("paths", {}).items():
            print(f"[{dev}]   {name}: {t['median_ms']:.2f} ms")
    summary = results.get("speed_error", {}).get("summary", [])
    if summary:
        print(f"{'method':<44}{'ms/pose':>10}{'MAG':>9}{'ENV':>9}")
        for r in sorted(summary, key=lambda r: r["latency_ms"]):
            print(f"{r['label']:<44}{r['latency_ms']:>10.3g}{r['MAG']:>9.3f}{r['ENV']:>9.4f}")
    for t in results.get("training", []):
        rate = t.get("error") or f"{t.get('it_per_s', 0):.1f} it/s, peak {t.get('peak_mb', 0):.0f} MB"
        sfm = f", SfM {t['sfm_points']} points in {t['sfm_seconds']:.1f} s" if "sfm_seconds" in t else ""
        print(f"training stage {t.get('stage')} ({t.get('device')}, {t.get('init', 'box')} points{sfm}): {rate}")


def run(args: argparse.Namespace) -> int:
    import torch
    from tqdm.auto import tqdm

    from avgs.bench import latency as latency_mod
    from avgs.bench import speed_error, training
    from avgs.bench.machine import machine_info
    from avgs.bench.report import headline, write_report

    torch.set_num_threads(max(1, int(args.threads)))
    settings = _defaults(args)
    out = Path(args.out)
    work = Path(args.work) if args.work else out / "work"
    work.mkdir(parents=True, exist_ok=True)
    if not (work / ".gitignore").exists():
        (work / ".gitignore").write_text("*\n")
    cuda = torch.cuda.is_available() and not args.no_cuda

    def say(msg: str) -> None:
        tqdm.write(f"avgs bench: {msg}")

    results: dict = {"quick": bool(args.quick), "machine": machine_info(), "settings": {k: list(v) if isinstance(v, tuple) else v for k, v in settings.items()}, "notes": []}
    notes = results["notes"]
    carry_skipped(results, out / "results.json", args.skip, say)

    scene_dirs = [Path(d) for d in args.data]
    if "speed-error" not in args.skip:
        generated, why = generate_scenes(work, settings["presets"], settings["poses"], args.seed, args.quick, say)
        scene_dirs += generated
        if why:
            notes.append(f"Generated scenes: {why}.")
    if args.quick:
        scene_dirs = scene_dirs[:1]

    se = None
    if "speed-error" not in args.skip and scene_dirs:
        per_scene = []
        for d in tqdm(scene_dirs, desc="speed against error", unit="scene"):
            per_scene.append(speed_error.bench_scene(
                d, work, iterations=settings["iterations"], n_points=settings["points"], repeats=max(10, settings["repeats"] // 3),
                vicinities=settings["vicinities"], budgets=settings["budgets"],
                orders=() if "simulator" in args.skip else settings["orders"], sim_poses=settings["sim_poses"], cuda=cuda, progress=say))
        se = {"scenes": per_scene, "summary": speed_error.summarise(per_scene),
              "settings": {"iterations": settings["iterations"], "points": settings["points"]}}
        results["speed_error"] = se
    elif "speed-error" not in args.skip:
        results["speed_error"] = {"note": "Not run: no scenes (pass --data DATA_ROOT/SCENE_ID, or install the generator)."}

    if "latency" not in args.skip:
        renderer, source = demo_renderer(args, se, work, settings, say)
        results["demo"] = {"source": source, "points": int(len(renderer.points))}
        results["latency"] = {"cpu": latency_mod.measure(renderer, repeats=settings["repeats"], long_seconds=settings["long_seconds"], progress=say)}
        if cuda:
            from avgs.render.renderer import SceneRenderer

            path = renderer.path
            if path is not None:
                results["latency"]["cuda"] = latency_mod.measure(SceneRenderer.load(path, device="cuda"), repeats=settings["repeats"],
                                                                 long_seconds=settings["long_seconds"], precisions=("float16", "bfloat16"), progress=say)

    if "training" not in args.skip:
        tr = []
        target = str(scene_dirs[0]) if scene_dirs else None
        if target is None:
            notes.append("Training throughput: no scene to train on.")
        else:
            devices = ["cpu"] + (["cuda"] if cuda else [])
            for dev in devices:
                for init in ("box", "random", "sfm"):
                    say(f"training throughput, stage 2 ({dev}, {init} points)")
                    tr.append(training.measure({"stage": 2, "scene_dir": target, "n_points": settings["points"], "vicinity": 15.0,
                                                "iterations": settings["train_iterations"], "device": dev, "threads": args.threads,
                                                "init": init}))
                for init in ("random", "sfm"):
                    say(f"training throughput, stage 1 ({dev}, {init} points)")
                    tr.append(training.measure({"stage": 1, "scene_dir": target, "iterations": settings["stage1_iterations"],
                                                "device": dev, "threads": args.threads, "init": init}))
            notes.append("Training throughput without geometry: 'random' and 'sfm' rows start from points made from the frames "
                         "and poses alone (scene.json unread, as for a real recording): random points along the training rays, "
                         "or SfM points triangulated from the frames (avgs.gaussians.sfm; the time it took is in results.json "
                         "as sfm_seconds). The first stage-2 row is the bench's fixed-N model (points in the box around the poses).")
        results["training"] = tr

    notes += [
        f"CPU figures use {args.threads} torch threads; timings are medians over repeats on a shared machine: compare "
        "numbers from one run only.",
        "The syntheses ('AV-GS synthesis' rows and the default's, the reference vicinity row) are timed taking turns "
        "in blocks of four poses, each block after one untimed call, so their ratios hold while the machine's load "
        "moves; the other rows are timed one after the other. Every AV-GS row renders one 1 s clip at pose after pose, "
        "as the explorer does: a renderer keeps the last clip's source analysis (STFT, tail power, first phase), so a "
        "pose costs only its own part; the default is also timed beside them with a new clip at every call "
        "(results.json: new_clip_ms), what a pose costs when nothing of the clip is kept.",
        "Bench models skip stage 1: G_a starts from points uniform in the box around the listeners and the source "
        "(widened by 0.3 normalised units) with random alpha, and stage 2 runs the given iterations (the paper: 40k). "
        "Their errors rank settings against each other; they are not the paper's numbers.",
        "Simulator error: the scene's whole source convolved with the pose's binaural RIR, cut to the clip, one gain for "
        "both ears matched to the ground truth's energy per clip (the two WAVs are peak-normalised separately). Its time "
        "per pose is the RIR computation plus the convolution. Non-shoebox rooms cap the image-source order at the "
        "scene's own polygon order.",
        "Mono-Energy and Stereo-Energy read the ground-truth energy of the clip they predict (oracles).",
        "Reduced precision: on CPUs without native bfloat16/float16 matrix units the networks run far slower in them, "
        "so float32 stays the default; see the precision rows.",
        "The viewer's drag-to-audio latency (avgs_viewer.bench) is the render time above plus at most one audio block "
        "and the crossfade; the viewer renders on a worker thread that keeps only the newest request.",
    ]
    if "demo" in results:
        notes.append("The demo checkpoint: " + results["demo"]["source"] + ".")
    if hasattr(os, "getloadavg"):
        results["machine"]["load_average_1m_at_end"] = round(os.getloadavg()[0], 2)
    report = write_report(results, out)
    print_tables(results)
    print(headline(results.get("speed_error", {}).get("summary", [])))
    print(f"wrote {report}")
    if "latency" in results:
        print(f"inference median {results['latency']['cpu']['render']['median_ms']:.2f} ms per pose (cpu, demo scene)")
    return 0
