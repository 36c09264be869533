"""Viewer benchmarks (called by ``avgs bench``): drag-to-audio latency and orbit frame rate.

Measurements only, no pass/fail. The latency path is the viewer's own: a pose change
on the :class:`~avgs_viewer.state.ViewerState` -> the newest-wins render worker ->
``SceneRenderer.render`` on the looped clip -> the audio engine, whose callback is pumped
at the device's pace by a simulated audio clock (no sound card needed) until the new
buffer starts playing.
"""

from __future__ import annotations

import threading
import time
from typing import Any

import numpy as np


def _summary(samples_s: list[float]) -> dict:
    ms = np.asarray(samples_s) * 1e3
    return {"n": int(len(ms)), "median_ms": float(np.median(ms)), "p95_ms": float(np.percentile(ms, 95)),
            "min_ms": float(ms.min()), "max_ms": float(ms.max())}


def drag_to_audio_latency(renderer: Any, n: int = 30, clip: np.ndarray | None = None, blocksize: int = 512,
                          timeout_s: float = 30.0) -> dict:
    """Median and p95 time from a listener move until its binaural buffer is live (ms).

    The listener steps around a circle about the scene's centre; each step waits for the
    audio callback to adopt the new buffer (the start of its crossfade); moves land at a
    random phase of the audio block. Includes the render of the whole clip (default: the
    demo clip), up to one audio block of ``blocksize`` samples, and the rest of the
    previous crossfade when moves come faster than it (as in a drag). The first buffer
    is the draft (the source's phase); with phase iterations the refined one follows,
    timed as ``refined`` (each move waits until the previous pose was refined, as when
    a user stops). Returns ``{n, median_ms, p95_ms, min_ms, max_ms, clip_s, block_ms,
    render_ms, draft_render_ms, refined: {n, median_ms, ...} or None}``.
    """
    from .audio import LoopEngine
    from .export import default_clip
    from .state import ViewerState
    from .worker import LiveRender

    sr = int(renderer.sample_rate)
    clip = default_clip(sr) if clip is None else np.asarray(clip, dtype=np.float32)
    bounds = np.asarray(renderer.bounds, dtype=np.float64)
    state = ViewerState(bounds, renderer.source)
    engine = LoopEngine(sr)
    live = LiveRender(renderer, state, engine, clip)
    stop = threading.Event()
    block_s = blocksize / sr

    def audio_clock() -> None:  # a sound card: one callback per block, in real time
        out = np.zeros((blocksize, 2), dtype=np.float32)
        next_t = time.perf_counter()
        while not stop.is_set():
            engine.callback(out, blocksize)
            next_t += block_s
            time.sleep(max(0.0, next_t - time.perf_counter()))

    clock = threading.Thread(target=audio_clock, name="bench-audio-clock", daemon=True)
    clock.start()
    samples, refined = [], []
    passes = 2 if live.draft_synthesis is not None else 1
    try:
        live.request()
        _wait_all_live(live, engine, timeout_s)
        centre = bounds.mean(axis=0)
        radius = 0.3 * float(min(bounds[1, :2] - bounds[0, :2]))
        z = state.listener[2]
        rng = np.random.default_rng(0)
        for i in range(n):
            live.worker.wait_idle(timeout_s)  # the previous pose refined: the user had stopped
            time.sleep(rng.uniform(0, block_s))  # a move lands anywhere within an audio block
            angle = 2 * np.pi * (i + 1) / max(n, 1) + 0.1
            target = engine.generation + 1
            t0 = time.perf_counter()
            state.set_listener((centre[0] + radius * np.cos(angle), centre[1] + radius * np.sin(angle), z))
            _wait_generation(engine, target, timeout_s)
            samples.append(time.perf_counter() - t0)
            if passes == 2:  # (a refined buffer that comes before the draft went live replaces it)
                _wait_all_live(live, engine, timeout_s)
                refined.append(time.perf_counter() - t0)
    finally:
        stop.set()
        clock.join(5)
        live.close()
    out = _summary(samples)
    out["refined"] = _summary(refined) if refined else None

    def render_ms(**extra) -> float:  # the model's share: one render of the whole loop clip
        times = []
        for _ in range(min(n, 5)):
            t0 = time.perf_counter()
            renderer.render(listener=state.listener, yaw=state.yaw, mono=clip, **extra)
            times.append(time.perf_counter() - t0)
        return 1e3 * float(np.median(times))

    out.update(clip_s=len(clip) / sr, block_ms=1e3 * block_s, render_ms=render_ms(),
               draft_render_ms=render_ms(synthesis=live.draft_synthesis) if passes == 2 else None)
    return out


def _latency_rows(latency: dict) -> list[str]:
    """Markdown table rows for :func:`drag_to_audio_latency`'s result."""
    if latency.get("refined") is None:
        return [f"| drag end -> new audio live | {latency['median_ms']:.1f} ms | {latency['p95_ms']:.1f} ms | "
                f"{latency['n']} moves; render of the {latency['clip_s']:.1f} s clip {latency['render_ms']:.1f} ms, "
                f"audio block {latency['block_ms']:.1f} ms |"]
    refined = latency["refined"]
    return [
        f"| drag end -> draft audio live | {latency['median_ms']:.1f} ms | {latency['p95_ms']:.1f} ms | "
        f"{latency['n']} moves; draft render of the {latency['clip_s']:.1f} s clip {latency['draft_render_ms']:.1f} ms, "
        f"audio block {latency['block_ms']:.1f} ms |",
        f"| drag end -> refined audio live | {refined['median_ms']:.1f} ms | {refined['p95_ms']:.1f} ms | "
        f"render with phase iterations {latency['render_ms']:.1f} ms |",
    ]


def _wait_all_live(live: Any, engine: Any, timeout_s: float) -> None:
    """Until every render is done and the audio thread has adopted the last buffer."""
    if not live.worker.wait_idle(timeout_s):
        raise TimeoutError(f"the render worker did not finish within {timeout_s} s")
    _wait_until(lambda: not engine.has_pending, timeout_s)


def _wait_generation(engine: Any, target: int, timeout_s: float) -> None:
    _wait_until(lambda: engine.generation >= target, timeout_s)


def _wait_until(done, timeout_s: float) -> None:
    """Poll ``done()`` until it is true; TimeoutError after ``timeout_s``."""
    deadline = time.perf_counter() + timeout_s
    while not done():
        if time.perf_counter() > deadline:
            raise TimeoutError(f"the new audio buffer did not go live within {timeout_s} s")
        time.sleep(0.0005)


def orbit_fps(plotter: Any, frames: int = 60, degrees: float = 360.0) -> dict:
    """Frames per second while orbiting the camera about the scene (``frames`` renders).

    Works on the window's ``QtInteractor`` and on an off-screen ``pv.Plotter``; the
    camera is put back afterwards. Returns ``{frames, fps, ms_per_frame}``.
    """
    camera = plotter.camera
    saved = plotter.camera_position
    step = degrees / max(frames, 1)
    render_window = plotter.render_window
    render_window.Render()
    t0 = time.perf_counter()
    for _ in range(frames):
        camera.Azimuth(step)
        render_window.Render()
    elapsed = time.perf_counter() - t0
    plotter.camera_position = saved
    return {"frames": int(frames), "fps": frames / elapsed if elapsed > 0 else float("inf"),
            "ms_per_frame": 1e3 * elapsed / max(frames, 1)}


def run_viewer_bench(scene_path: Any, out: Any, n: int = 30, frames: int = 60, size: tuple[int, int] = (1024, 768)) -> dict:
    """``avgs-viewer --bench``: drag-to-audio latency and orbit frame rate on a checkpoint; writes
    ``out`` (Markdown) with the machine and the command, and returns the numbers.

    The orbit is drawn off screen (EGL, or Mesa under Xvfb): the points as the window draws them.
    """
    import json
    from pathlib import Path

    import pyvista as pv
    import torch

    from avgs import SceneRenderer
    from avgs.atomic import write_text
    from avgs.bench.machine import machine_info

    from .scene_view import SceneView
    from .state import ViewerState

    torch.set_num_threads(1)  # as the window renders
    renderer = SceneRenderer.load(scene_path)
    latency = drag_to_audio_latency(renderer, n=n)
    plotter = pv.Plotter(off_screen=True, window_size=list(size))
    try:
        state = ViewerState(renderer.bounds, renderer.source)
        SceneView(plotter, renderer, state)
        orbit = orbit_fps(plotter, frames=frames)
        gl = plotter.render_window.ReportCapabilities().splitlines()
    finally:
        plotter.close()
    renderer_line = next((line.strip() for line in gl if "OpenGL renderer string" in line), "unknown")
    info = machine_info()
    result = {"scene": str(scene_path), "points": int(len(renderer.points)), "latency": latency, "orbit": orbit,
              "gl_renderer": renderer_line, "window": list(size), "machine": info}
    out = Path(out)
    lines = [
        "# Viewer benchmark",
        "",
        f"Command: `{info['command']}` ({info['date_utc']})  ",
        f"Machine: {info['cpu']}, {info['cpu_cores_available']} cores; torch {info['torch']}; {renderer_line}  ",
        f"Scene: `{scene_path}`, {len(renderer.points)} audio points; window {size[0]}x{size[1]}",
        "",
        "| measure | median | p95 | notes |",
        "|---|---|---|---|",
        *_latency_rows(latency),
        f"| orbit | {orbit['fps']:.1f} FPS | | {orbit['ms_per_frame']:.1f} ms per frame over {orbit['frames']} frames |",
        "",
        "The latency is the viewer's own path: a pose change on the state, the newest-wins render worker,",
        "`SceneRenderer.render` of the whole looped clip, and the audio engine adopting the new buffer at",
        "the next block of a simulated real-time audio clock (the start of its crossfade). The draft is",
        "rendered with the source's phase; the refined buffer, with the renderer's phase iterations,",
        "replaces it when no newer pose has come.",
        "",
        "```json",
        json.dumps({k: v for k, v in result.items() if k != "machine"}, indent=1),
        "```",
        "",
    ]
    write_text(out, "\n".join(lines))
    return result
