"""Inference latency per pose: whole renders, the stages inside them, long inputs,
the same model without its caches, and reduced precision.

A "pose" is one call of :meth:`SceneRenderer.render` on a 1 s clip at a new listener
position (the source stays put, so C_S comes from the cache, as in the viewer). Poses
cycle over random positions inside the scene box; every figure is a median (and 95th
percentile) over ``repeats`` calls after ``warmup`` untimed ones.

A source-aware checkpoint (the impulse-response task, ``SceneRenderer.source_aware``) gets
its own, smaller set (:func:`measure_source_aware`): the per-pose cost of
``render(listener, yaw, mono, source=...)`` of a 1 s clip with the source moved at every
call (so C_S is recomputed: the worst case), and its stages (the vicinities and F, the RIR
network, the waveform from its log magnitudes, the convolution).
"""

from __future__ import annotations

import numpy as np
import torch

from avgs.bench.timing import Stopwatch, Timing, time_calls
from avgs.config import MID_PHASE_ITERATIONS, SynthesisConfig

def _sync(device) -> None:
    if torch.device(device).type == "cuda":
        torch.cuda.synchronize()


def random_poses(renderer, n: int, seed: int = 0) -> list[tuple[np.ndarray, float]]:
    """``n`` (listener world [3], yaw degrees) inside the scene box (middle 80 %)."""
    rng = np.random.default_rng(seed)
    lo, hi = np.asarray(renderer.bounds, dtype=np.float64)
    pad = 0.1 * (hi - lo)
    return [(rng.uniform(lo + pad, hi - pad), float(rng.uniform(-180, 180))) for _ in range(n)]


def test_signal(seconds: float, sample_rate: int, seed: int = 0) -> np.ndarray:
    return (0.3 * np.random.default_rng(seed).standard_normal(int(round(seconds * sample_rate)))).astype(np.float32)


def time_render(render, poses, mono, repeats: int, warmup: int = 3, device="cpu") -> Timing:
    """Median/p95 of ``render(listener, yaw, mono)`` cycling over ``poses``."""
    state = {"i": 0}

    def call():
        lis, yaw = poses[state["i"] % len(poses)]
        state["i"] += 1
        render(lis, yaw, mono)

    return time_calls(call, repeats=repeats, warmup=warmup, sync=lambda: _sync(device))


SYNTHESES = {
    "filter": SynthesisConfig(method="filter"),
    f"mid phase, {MID_PHASE_ITERATIONS} iterations (default)": SynthesisConfig(),
    "mid phase, 8 iterations": SynthesisConfig(phase_iterations=8),
    "mid phase, 12 iterations": SynthesisConfig(phase_iterations=12),
    "filter phase": SynthesisConfig(phase="filter"),
    "filter phase + 8 iterations": SynthesisConfig(phase="filter", phase_iterations=8),
    "source phase": SynthesisConfig(phase="source"),
    "source phase + 8 iterations": SynthesisConfig(phase="source", phase_iterations=8),
}
"The syntheses `avgs bench` compares (:class:`avgs.config.SynthesisConfig`): time on the demo, error on the bench's scenes."


def stage_breakdown(renderer, poses, mono, repeats: int) -> dict[str, Timing]:
    """Time the stages of :meth:`SceneRenderer.render` one by one, with its caches."""
    model, cache = renderer.model, renderer.cache
    dev = renderer.device
    sw = Stopwatch()
    with torch.inference_mode():
        for i in range(repeats + 3):
            lis_w, yaw = poses[i % len(poses)]
            lis, theta, src = renderer.pose(lis_w, yaw)
            c_s, _ = renderer.source_context(src)
            timed = i >= 3

            def run(name, fn):
                if not timed:
                    return fn()
                with sw(name):
                    out = fn()
                    _sync(dev)
                return out

            idx = run("vicinity", lambda: model.vicinity(lis, cache))
            ctx = None
            if model.field is not None:
                c_l = run("field", lambda: model.context_at(lis, idx, cache))
                ctx = torch.cat([c_s[None], c_l], dim=-1)
            masks = run("binauralizer", lambda: model.binauralizer(lis[:, :2], theta, ctx, cache.frequency))
            h = None
            if renderer.synthesis.method == "filter" or renderer.synthesis.phase == "filter":
                h = run("impulse response", lambda: renderer.task_model.impulse(masks))
            # the STFTs, the predicted magnitudes, their phase (retrieved, or the filter's), the inverse STFT
            run("synthesis", lambda: renderer.task_model.synthesise(masks, mono, renderer.synthesis, impulse=h))
    return sw.timings()


def with_precision(renderer, dtype: torch.dtype):
    """The same scene with its networks in ``dtype`` (for measurement)."""
    from avgs.io.checkpoint import load_checkpoint
    from avgs.render.renderer import SceneRenderer

    return SceneRenderer(load_checkpoint(renderer.path), device=renderer.device, path=renderer.path,
                         synthesis=renderer.synthesis, dtype=dtype)


def precision_error(renderer, other, poses, mono) -> float:
    """Largest |difference| of the binaural outputs of two renderers over ``poses`` (input peak 1)."""
    worst = 0.0
    for lis, yaw in poses:
        a = renderer.render(lis, yaw, mono).binaural
        b = other.render(lis, yaw, mono).binaural
        worst = max(worst, float(np.max(np.abs(a - b))) / max(1e-12, float(np.max(np.abs(mono)))))
    return worst


def random_sources(renderer, n: int, seed: int = 1) -> list[np.ndarray]:
    """``n`` source positions (world [3]) inside the scene box (middle 80 %)."""
    return [lis for lis, _ in random_poses(renderer, n, seed)]


def measure_source_aware(renderer, repeats: int = 50, progress=None) -> dict:
    """Latency of a source-aware renderer (task rir): render with a new source every call, and its stages."""
    from avgs.acoustics.impulse_response import convolve
    from avgs.acoustics.direct_placement import place_direct_sound
    from avgs.acoustics.rir_model import response_waveform

    dev = renderer.device
    mono = test_signal(1.0, renderer.sample_rate)
    poses = random_poses(renderer, 64)
    sources = random_sources(renderer, 64)
    say = progress or (lambda msg: None)
    out: dict = {"device": str(dev), "points": int(len(renderer.points)), "k": int(renderer.vicinity_size),
                 "task": renderer.task, "response_samples": int(renderer.config.rir.length),
                 "phase": renderer.config.rir.phase + (f" {renderer.config.rir.phase_iterations}"
                                                       if renderer.config.rir.phase == "griffin-lim" else "")}
    state = {"i": 0}

    def moving(l, y, m):
        state["i"] += 1
        return renderer.render(l, y, m, source=sources[state["i"] % len(sources)])

    say(f"latency ({dev}): source-aware render")
    out["render"] = time_render(moving, poses, mono, repeats, device=dev).to_dict()
    out["source_aware"] = out["render"]
    threads = torch.get_num_threads()
    if dev.type == "cpu" and threads != 1:
        torch.set_num_threads(1)
        try:
            out["render_1_thread"] = time_render(moving, poses, mono, repeats).to_dict()
        finally:
            torch.set_num_threads(threads)
    out["fixed_source"] = time_render(lambda l, y, m: renderer.render(l, y, m), poses, mono, repeats, device=dev).to_dict()
    out["masks"] = time_render(lambda l, y, m: renderer.masks(l, y), poses, mono, repeats, device=dev).to_dict()
    model, cache, rc = renderer.model, renderer.cache, renderer.config.rir
    sw = Stopwatch()
    with torch.inference_mode():
        for i in range(repeats + 3):
            lis_w, yaw = poses[i % len(poses)]
            lis, _, src = renderer.pose(lis_w, yaw, sources[i % len(sources)])
            yaw_t = torch.tensor([np.radians(yaw % 360.0)], dtype=lis.dtype, device=lis.device)
            timed = i >= 3

            def run(name, fn):
                if not timed:
                    return fn()
                with sw(name):
                    value = fn()
                    _sync(dev)
                return value

            ctx = run("vicinity + field", lambda: model.contexts(lis, src[None], cache))
            from avgs.data.frame import signed_direction

            theta = signed_direction(lis, yaw_t, src[None])
            log_mag = run("network", lambda: model.binauralizer(lis, src[None], theta, yaw_t, ctx[0], cache.frequency,
                                                                walls=model.walls(lis, src[None])))
            h = run("waveform", lambda: response_waveform(model.magnitudes(log_mag.float()).cpu(), rc.length, renderer.stft,
                                                          rc.phase, rc.phase_iterations)[0])
            if model.direct_sound(lis, yaw_t, src[None]) is not None:  # placed by geometry (RIRConfig.direct_sound)
                run("direct sound", lambda: place_direct_sound(h[None], model.direct_sound(lis, yaw_t, src[None]), renderer.stft))
            run("convolution", lambda: convolve(torch.from_numpy(mono), h))
    out["stages"] = {k: v.to_dict() for k, v in sw.timings().items()}
    return out


def measure(renderer, repeats: int = 50, long_seconds=(10.0, 60.0), long_repeats: int = 3, compare: bool = True,
            precisions=("bfloat16",), progress=None) -> dict:
    """All latency figures of one renderer (its device); see the module docstring."""
    from avgs.bench.reference import TrainingModePath, UncachedPath

    if getattr(renderer, "source_aware", False):
        return measure_source_aware(renderer, repeats, progress)

    dev = renderer.device
    sr = renderer.sample_rate
    mono = test_signal(1.0, sr)
    poses = random_poses(renderer, 64)
    say = progress or (lambda msg: None)
    out: dict = {"device": str(dev), "points": int(len(renderer.points)), "k": int(renderer.vicinity_size)}
    say(f"latency ({dev}): render")
    out["render"] = time_render(lambda l, y, m: renderer.render(l, y, m), poses, mono, repeats, device=dev).to_dict()
    threads = torch.get_num_threads()
    if dev.type == "cpu" and threads != 1:  # small ops: on a busy shared machine one thread can beat two
        torch.set_num_threads(1)
        try:
            out["render_1_thread"] = time_render(lambda l, y, m: renderer.render(l, y, m), poses, mono, repeats).to_dict()
        finally:
            torch.set_num_threads(threads)
    masks_t = time_render(lambda l, y, m: renderer.masks(l, y), poses, mono, repeats, device=dev)
    out["masks"] = masks_t.to_dict()
    say(f"latency ({dev}): stages")
    out["stages"] = {k: v.to_dict() for k, v in stage_breakdown(renderer, poses, mono, repeats).items()}
    if compare:
        for path_cls in (UncachedPath, TrainingModePath):
            say(f"latency ({dev}): {path_cls.name}")
            path = path_cls(renderer)
            n = repeats if path_cls is UncachedPath else max(5, repeats // 3)
            t = time_render(path.render, poses, mono, n, device=dev)
            err = max(float(np.max(np.abs(path.render(l, y, mono) - renderer.render(l, y, mono).binaural))) for l, y in poses[:4])
            out.setdefault("paths", {})[path_cls.name] = {**t.to_dict(), "max_abs_diff": err}
    out["syntheses"] = {}
    for label, synthesis in SYNTHESES.items():  # each synthesis, the same poses
        say(f"latency ({dev}): synthesis {label}")
        t = time_render(lambda l, y, m, s=synthesis: renderer.render(l, y, m, synthesis=s), poses, mono,
                        max(5, repeats // 2), device=dev)
        out["syntheses"][label] = t.to_dict()
    out["long"] = {}
    for seconds in long_seconds:
        say(f"latency ({dev}): {seconds:g} s of audio")
        sig = test_signal(seconds, sr, seed=1)
        t = time_render(lambda l, y, m: renderer.render(l, y, m), poses, sig, long_repeats, warmup=1, device=dev)
        out["long"][f"{seconds:g}"] = {**t.to_dict(), "realtime_factor": seconds / max(t.median, 1e-12)}
    out["precision"] = {}
    for name in precisions:
        dtype = getattr(torch, name)
        say(f"latency ({dev}): {name}")
        try:
            other = with_precision(renderer, dtype)
            t = time_render(lambda l, y, m: other.render(l, y, m), poses, mono, max(5, repeats // 3), device=dev)
            out["precision"][name] = {**t.to_dict(), "max_abs_diff": precision_error(renderer, other, poses[:4], mono)}
        except (RuntimeError, TypeError) as exc:  # a dtype the device cannot run
            out["precision"][name] = {"error": f"{type(exc).__name__}: {str(exc).splitlines()[0]}"}
    return out
