"""Speed against error on scenes with physical ground truth.

Every point is (latency per pose, MAG, ENV) on a scene's val clips:

- the three baselines (oracle energy for two of them), timed per clip;
- AV-GS at vicinity 5/10/15/20/25 % (one model trained per setting);
- AV-GS at point budgets: the 15 % model pruned exactly to the walkable area
  (:mod:`avgs.render.prune`), then random subsets of it (k at 15 % of the subset);
- AV-GS with each synthesis of :data:`avgs.bench.latency.SYNTHESES` (the 15 % model): the pose's filter, and the
  predicted magnitudes with the filter's or the source's phase and 0, 2 or 8 phase iterations;
- AV-GS in reduced precision (bfloat16 on the CPU, float16 on CUDA) where it runs;
- the simulator that made the scene (pyroomacoustics, image-source order 0..10, with
  and without ray tracing), timed per pose (RIR + convolution of the clip).

AV-GS and the baselines are scored by :func:`avgs.evaluation.binaural.score_scene` (MAG/ENV of the
val clips as they are). The simulator's prediction is the scene's whole source signal
convolved with the pose's binaural RIR, cut to the clip's window (so reverberation
from before the window is present, as in the ground truth), then **gain-matched per
clip**: one gain for both ears so that its energy equals the ground truth's (as
Mono-Energy does). The two clips of a scene are peak-normalised separately, so an
absolute level cannot be compared; the gain keeps the interaural level difference.
"""

from __future__ import annotations

import dataclasses
import itertools
import time
from pathlib import Path

import numpy as np
import torch

from avgs.bench.latency import SYNTHESES, random_poses, test_signal, time_render, with_precision
from avgs.bench.timing import Timing
from avgs.config import STFT, SynthesisConfig

VICINITIES = (5.0, 10.0, 15.0, 20.0, 25.0)
BUDGET_FRACTIONS = (0.5, 0.25, 0.1, 0.05)
SIM_ORDERS = tuple(range(11))



# -- models --------------------------------------------------------------------------


def initial_points(scene, n: int, seed: int = 0) -> "AudioPoints":  # noqa: F821
    """``n`` points uniform in the box around the listeners and the source (normalised),
    widened by 0.3 and clipped to [-1, 1]^3: G_a without stage 1 (the bench skips it)."""
    from avgs.acoustics.points import AudioPoints

    pos = np.stack([c.listener for c in scene.train + scene.val] + [scene.source])
    lo = np.clip(pos.min(0) - 0.3, -1.0, 1.0)
    hi = np.clip(pos.max(0) + 0.3, -1.0, 1.0)
    g = torch.Generator().manual_seed(seed)
    X = torch.as_tensor(lo, dtype=torch.float32) + torch.rand(n, 3, generator=g) * torch.as_tensor(hi - lo, dtype=torch.float32)
    return AudioPoints(X, torch.randn(n, 52, generator=g) * 0.5)


def bench_config(iterations: int, vicinity: float, n_points: int, device: str = "cpu", seed: int = 0):
    """The stage-2 configuration the bench trains with (the ``--quick`` preset, scaled)."""
    from avgs.train.pipeline import quick_config

    cfg = quick_config()
    cfg.acoustic.iterations = int(iterations)
    cfg.acoustic.vicinity_percentile = float(vicinity)
    cfg.points.max_points = int(max(n_points * 1.5, 100))
    cfg.points.densify_every = max(25, iterations // 6)
    cfg.points.prune_every = max(75, iterations // 2)
    cfg.eval_every = cfg.checkpoint_every = int(iterations)
    cfg.log_every = max(10, iterations // 20)
    cfg.device, cfg.seed, cfg.store_gaussians = device, seed, False
    return cfg


def train_model(scene_dir, out: Path, iterations: int, vicinity: float, n_points: int, device="cpu", seed=0) -> dict:
    """Train (or reuse, when ``out`` was trained with the same settings) one AV-GS model."""
    from avgs.io.checkpoint import load_checkpoint
    from avgs.data.rwavs import RWAVSScene
    from avgs.train.pipeline import train_scene

    key = {"iterations": int(iterations), "vicinity": float(vicinity), "points": int(n_points), "seed": int(seed)}
    if out.is_file():
        try:
            ck = load_checkpoint(out)
            if ck.get("bench_key") == key:
                return {"reused": True, **ck.get("metrics", {})}
        except ValueError:
            pass
    scene = RWAVSScene(scene_dir)
    cfg = bench_config(iterations, vicinity, n_points, device, seed)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # small ops: robust when other processes share the cores (not timed here)
    t0 = time.perf_counter()
    try:
        final = train_scene(scene_dir, out, cfg, progress=False, initial_points=initial_points(scene, n_points, seed))
    finally:
        torch.set_num_threads(threads)
    seconds = time.perf_counter() - t0
    ck = load_checkpoint(out)
    ck["bench_key"] = key
    ck.pop("train_state", None)
    from avgs.io.checkpoint import save_checkpoint

    save_checkpoint(ck, out)
    return {"reused": False, "train_seconds": seconds, **final}


# -- methods as (callable, latency) ---------------------------------------------------


class RendererMethod:
    """A :class:`SceneRenderer` as an evaluation method."""

    def __init__(self, renderer):
        self.renderer = renderer

    def __call__(self, clip, scene):
        import math

        lis = scene.frame.to_world(clip.listener)
        return self.renderer.render(tuple(float(v) for v in lis), math.degrees(clip.yaw), clip.mono).binaural


def renderer_latency(renderer, repeats: int) -> Timing:
    mono = test_signal(1.0, renderer.sample_rate)
    poses = random_poses(renderer, 32, seed=3)
    return time_render(lambda l, y, m: renderer.render(l, y, m), poses, mono, repeats, device=renderer.device)


NEW_CLIP = "default, a new clip every pose"
"The label of the default synthesis timed with a different clip at every call (:func:`synthesis_latencies`)."


def synthesis_latencies(renderers: dict, repeats: int, new_clip=None) -> dict[str, Timing]:
    """:func:`renderer_latency` of each renderer (label -> renderer), timed taking turns in blocks
    on the same poses (:func:`avgs.bench.timing.time_interleaved`). Each renders one clip at
    every pose, as the explorer does (the renderer keeps the clip's source analysis);
    ``new_clip``, a renderer timed beside them (label :data:`NEW_CLIP`) with a different clip at
    every call, as evaluation renders: nothing of the clip is kept."""
    from avgs.bench.timing import time_interleaved

    first = next(iter(renderers.values()))
    mono = test_signal(1.0, first.sample_rate)
    poses = random_poses(first, 32, seed=3)

    def call(renderer):
        def render(i: int):
            lis, yaw = poses[i % len(poses)]
            renderer.render(lis, yaw, mono)
        return render

    fns = {label: call(r) for label, r in renderers.items()}
    if new_clip is not None:
        clips = [test_signal(1.0, first.sample_rate, seed=s) for s in range(1, 8)]
        count = itertools.count()

        def fresh(i: int):  # consecutive calls never share a clip, the untimed one of a block included
            lis, yaw = poses[i % len(poses)]
            new_clip.render(lis, yaw, clips[next(count) % len(clips)])

        fns[NEW_CLIP] = fresh
    return time_interleaved(fns, repeats=repeats)


def method_latency(method, scene, repeats: int) -> Timing:
    clips = scene.val
    state = {"i": 0}

    def call():
        method(clips[state["i"] % len(clips)], scene)
        state["i"] += 1

    from avgs.bench.timing import time_calls

    return time_calls(call, repeats=repeats, warmup=2)


def score(method, scene) -> dict:
    from avgs.evaluation.binaural import score_scene

    return score_scene(method, scene, progress=False)


# -- the simulator ---------------------------------------------------------------------


def simulator_available() -> str | None:
    """None when ``avgs.synth.simulate`` offers the contract we need, else why not."""
    try:
        import pyroomacoustics  # noqa: F401

        from avgs.synth.simulate import SimSettings, binaural_rirs, load_spec  # noqa: F401
    except ImportError as exc:
        return f"avgs.synth.simulate not importable ({exc})"
    return None


def simulator_points(scene_dir, scene, orders=SIM_ORDERS, ray_tracing=(False, True), max_poses: int = 4, progress=None) -> list[dict]:
    """One row per (order, ray tracing): per-pose seconds and gain-matched MAG/ENV on val clips."""
    from scipy.signal import fftconvolve

    from avgs.evaluation import metrics
    from avgs.data.rwavs import SOURCE_FILE, clip_window, read_wav
    from avgs.synth import simulate as sim

    spec = sim.load_spec(scene_dir)
    try:
        base = sim.load_settings(scene_dir)
    except (FileNotFoundError, ValueError, AttributeError):
        base = sim.SimSettings()
    sr = scene.stft.sample_rate if hasattr(scene, "stft") else STFT.sample_rate
    mono_full = read_wav(Path(scene_dir) / SOURCE_FILE, 1, sr)[0].astype(np.float64)  # [L]
    clips = scene.val[:max_poses]
    rows = []
    if clips:  # untimed warm-up: the KEMAR ear directivities are built once per process (~1 s)
        c = clips[0]
        sim.binaural_rirs(spec, scene.frame.to_world(c.listener), float(np.degrees(c.yaw)),
                          dataclasses.replace(base, max_order=0, ray_tracing=False))
    for rt in ray_tracing:
        for order in orders:
            settings = dataclasses.replace(base, max_order=int(order), ray_tracing=bool(rt),
                                           max_order_polygon=min(int(order), base.max_order_polygon))
            secs, mags, envs = [], [], []
            for clip in clips:
                lis = scene.frame.to_world(clip.listener)
                yaw = float(np.degrees(clip.yaw))
                t0 = time.perf_counter()
                rir = sim.binaural_rirs(spec, lis, yaw, settings)  # [2, L]
                start, stop = clip_window(clip.time, sr)
                s0 = start - rir.shape[1] + 1
                seg = np.zeros(stop - s0)
                lo, hi = max(s0, 0), min(stop, len(mono_full))
                if hi > lo:
                    seg[lo - s0 : hi - s0] = mono_full[lo:hi]
                pred = np.stack([fftconvolve(seg, h)[start - s0 : stop - s0] for h in rir.astype(np.float64)])  # [2, T]
                secs.append(time.perf_counter() - t0)
                pred = pred[:, : clip.binaural.shape[1]]
                e_pred, e_gt = float(np.sum(pred**2)), float(np.sum(clip.binaural.astype(np.float64) ** 2))
                pred = pred * (np.sqrt(e_gt / e_pred) if e_pred > 0 else 0.0)
                mags.append(metrics.mag(pred.astype(np.float32), clip.binaural))
                envs.append(metrics.env(pred.astype(np.float32), clip.binaural))
            label = f"simulator order {order}" + (" + rays" if rt else "")
            if progress:
                progress(f"{label}: {1e3 * np.median(secs):.0f} ms/pose")
            rows.append({"family": "simulator (rays)" if rt else "simulator (image source)", "label": label,
                         "order": int(order), "ray_tracing": bool(rt), "latency_ms": 1e3 * float(np.median(secs)),
                         "MAG": float(np.mean(mags)), "ENV": float(np.mean(envs)), "poses": len(clips)})
    return rows


# -- one scene -------------------------------------------------------------------------


def bench_scene(scene_dir, work: Path, *, iterations: int, n_points: int, repeats: int, vicinities=VICINITIES,
                budgets=BUDGET_FRACTIONS, orders=SIM_ORDERS, sim_poses: int = 4, cuda: bool = False,
                progress=None) -> dict:
    """All speed-against-error rows of one scene, plus the point-budget curve."""
    from avgs.render.prune import checkpoint_bytes, prune_checkpoint, scene_listener_box, subsample_checkpoint
    from avgs.evaluation.baselines import BASELINES
    from avgs.io.checkpoint import load_checkpoint, save_checkpoint
    from avgs.data.rwavs import RWAVSScene
    from avgs.render.renderer import SceneRenderer

    say = progress or (lambda msg: None)
    scene = RWAVSScene(scene_dir)
    work = Path(work) / scene.name
    work.mkdir(parents=True, exist_ok=True)
    rows: list[dict] = []
    base = {"scene": scene.name}

    for name, method in BASELINES.items():
        s = score(method, scene)
        t = method_latency(method, scene, repeats)
        rows.append({**base, "family": "baseline", "label": name, "latency_ms": t.median_ms, **s})
        say(f"{scene.name}: {name} MAG {s['MAG']:.3f}")

    models: dict[float, Path] = {}
    training: dict[str, dict] = {}
    for v in vicinities:
        path = work / f"avgs_v{v:g}.ckpt"
        say(f"{scene.name}: training AV-GS at vicinity {v:g} % ({iterations} iterations, {n_points} points)")
        training[f"{v:g}"] = train_model(scene_dir, path, iterations, v, n_points)
        models[v] = path
        r = SceneRenderer.load(path)
        s = score(RendererMethod(r), scene)
        t = renderer_latency(r, repeats)
        rows.append({**base, "family": "AV-GS vicinity", "label": f"AV-GS vicinity {v:g} %", "latency_ms": t.median_ms,
                     "p95_ms": t.p95_ms, "points": len(r.points), "k": r.vicinity_size, **s})
        say(f"{scene.name}: AV-GS {v:g} % MAG {s['MAG']:.3f}, {t.median_ms:.2f} ms")

    ref_v = 15.0 if 15.0 in models else list(models)[len(models) // 2]
    ref_ckpt = load_checkpoint(models[ref_v])
    budget_rows = []
    region, listeners = scene_listener_box(scene_dir, 0.25)
    pruned, info = prune_checkpoint(ref_ckpt, region, listeners_world=listeners)
    variants = [("all points", ref_ckpt), ("pruned to walkable (exact)", pruned)]
    n_pruned = info["points_after"]
    for frac in budgets:
        n = max(8, int(round(frac * n_pruned)))
        if n < n_pruned:
            variants.append((f"{n} points ({frac:.0%})", subsample_checkpoint(pruned, n, seed=1)))
    for label, ck in variants:
        path = save_checkpoint(ck, work / f"budget_{len(budget_rows)}.ckpt")
        r = SceneRenderer.load(path)
        s = score(RendererMethod(r), scene)
        t = renderer_latency(r, repeats)
        row = {**base, "family": "AV-GS points", "label": f"AV-GS {label}", "latency_ms": t.median_ms, "p95_ms": t.p95_ms,
               "points": len(r.points), "k": r.vicinity_size, "ckpt_bytes": path.stat().st_size, **s}
        if "gaussians" in ck:
            row["ckpt_bytes_without_g"] = checkpoint_bytes({k: v for k, v in ck.items() if k != "gaussians"})
        budget_rows.append(row)
        say(f"{scene.name}: {label}: MAG {s['MAG']:.3f}, {t.median_ms:.2f} ms, {row['ckpt_bytes'] / 1e6:.2f} MB")
    rows += budget_rows[1:]  # 'all points' is the vicinity row already

    # The syntheses: speed against error of each, timed taking turns in blocks of poses (with the
    # default: the reference row's time is that one), so that their ratios hold on a busy machine.
    renderers = {label: SceneRenderer.load(models[ref_v], synthesis=synthesis) for label, synthesis in SYNTHESES.items()}
    timings = synthesis_latencies(renderers, repeats, new_clip=SceneRenderer.load(models[ref_v]))
    ref_row = next(r for r in rows if r["family"] == "AV-GS vicinity" and r["label"] == f"AV-GS vicinity {ref_v:g} %")
    fresh = timings[NEW_CLIP]
    for label, synthesis in SYNTHESES.items():
        t = timings[label]
        if synthesis == SynthesisConfig():  # the vicinity row: its score, this time (and a new clip's)
            ref_row.update(latency_ms=t.median_ms, p95_ms=t.p95_ms, timed_with_syntheses=True,
                           new_clip_ms=fresh.median_ms, new_clip_p95_ms=fresh.p95_ms)
            continue
        s = score(RendererMethod(renderers[label]), scene)
        rows.append({**base, "family": "AV-GS synthesis", "label": f"AV-GS {ref_v:g} % {label}",
                     "latency_ms": t.median_ms, "p95_ms": t.p95_ms, **s})
        say(f"{scene.name}: {label}: MAG {s['MAG']:.3f}, {t.median_ms:.2f} ms")

    r = SceneRenderer.load(models[ref_v])
    precisions = [("cpu", torch.bfloat16)] + ([("cuda", torch.float16), ("cuda", torch.float32)] if cuda else [])
    for device, dtype in precisions:
        try:
            rr = r if device == "cpu" else SceneRenderer.load(models[ref_v], device=device)
            other = with_precision(rr, dtype) if dtype != torch.float32 else rr
            s = score(RendererMethod(other), scene)
            t = renderer_latency(other, max(5, repeats // 3))
        except (RuntimeError, TypeError) as exc:
            say(f"{scene.name}: {device} {dtype}: {exc}")
            continue
        name = str(dtype).replace("torch.", "")
        rows.append({**base, "family": "AV-GS precision", "label": f"AV-GS {ref_v:g} % {name} ({device})",
                     "latency_ms": t.median_ms, "p95_ms": t.p95_ms, **s})

    why_not = simulator_available()
    sim_note, truth = None, None
    if not orders:
        sim_note = f"simulator skipped on {scene.name}: --skip simulator"
    elif why_not is None and (Path(scene_dir) / "scene.json").is_file():
        try:
            from avgs.synth.simulate import load_settings

            truth = dataclasses.asdict(load_settings(scene_dir))
            rows += [{**base, **row} for row in simulator_points(scene_dir, scene, orders, max_poses=sim_poses, progress=lambda m: say(f"{scene.name}: {m}"))]
        except (FileNotFoundError, ValueError, KeyError) as exc:
            sim_note = f"simulator skipped on {scene.name}: {exc}"
    else:
        sim_note = f"simulator skipped on {scene.name}: " + (why_not or "no scene.json (not a generated scene)")
    if sim_note:
        say(sim_note)
    return {"scene": scene.name, "rows": rows, "budgets": budget_rows, "prune": info, "training": training,
            "sim_note": sim_note, "ground_truth_settings": truth, "val_clips": len(scene.val), "train_clips": len(scene.train)}


def summarise(scenes: list[dict]) -> list[dict]:
    """Rows averaged over scenes by label: mean MAG/ENV, median latency."""
    by: dict[str, list[dict]] = {}
    for sc in scenes:
        for row in sc["rows"]:
            by.setdefault(row["label"], []).append(row)
    out = []
    for label, rows in by.items():
        r0 = rows[0]
        out.append({"label": label, "family": r0["family"], "scenes": len(rows),
                    "latency_ms": float(np.median([r["latency_ms"] for r in rows])),
                    "MAG": float(np.mean([r["MAG"] for r in rows])), "ENV": float(np.mean([r["ENV"] for r in rows])),
                    **{k: r0[k] for k in ("points", "k", "ckpt_bytes", "order", "ray_tracing") if k in r0},
                    **({"new_clip_ms": float(np.median([r["new_clip_ms"] for r in rows]))} if "new_clip_ms" in r0 else {})})
    return out
