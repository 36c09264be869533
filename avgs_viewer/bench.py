"""``avgs-viewer --bench``: the explorer measured as a user feels it, through the real window.

Everything goes through the X server: the benchmark opens the real :class:`MainWindow`
(on ``$DISPLAY``, or on an ``Xvfb`` it starts itself) and drives it with window-system
events sent through XTEST (:mod:`avgs_viewer.xinput`, what ``xdotool`` uses). Measured:

- **drag to audio**: press on the listener's sphere, move at 60 Hz for 200 ms (the GUI
  thread busy drawing, as in a real drag), then move the last step and release at once.
  The time runs from sending that release to the moment the first audio block computed
  with the released pose's filter leaves the audio engine (the sound card's callback, or
  the simulated clock's where there is no card: the same code either way). Each drag
  starts from a standing window; no wait for an idle worker.
- **drag to full render** (a scene whose render is not its filter: :mod:`avgs_viewer.refine`):
  from sending the release to the first block wholly of the loop rendered in full at the
  released pose; the next drag waits for it (or 10 s).
- **idle CPU**: the process's CPU time (all threads) over a few seconds with nothing
  touched, sound playing (and, reported beside it, paused).
- **orbit**: a real left-button drag on empty space of the view for a few seconds,
  pointer moves every 10 ms; frames drawn per second.
"""

from __future__ import annotations

import threading
import time
from contextlib import contextmanager
from typing import Any, Callable

import numpy as np


def _summary(samples_s: list[float]) -> dict:
    ms = np.asarray(samples_s, dtype=np.float64) * 1e3
    if ms.size == 0:
        return {"n": 0}
    return {"n": int(ms.size), "median_ms": float(np.median(ms)), "p95_ms": float(np.percentile(ms, 95)),
            "min_ms": float(ms.min()), "max_ms": float(ms.max())}


def orbit_fps(plotter: Any, frames: int = 60, degrees: float = 360.0) -> dict:
    """Frames per second of camera azimuth steps rendered one after the other (``frames`` renders).

    Works on the window's canvas and on an off-screen ``pv.Plotter``; the camera is put
    back afterwards. Returns ``{frames, fps, ms_per_frame}``. (The window benchmark measures
    the orbit with real mouse drags instead: :func:`run_viewer_bench`.)
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


class GuiCall:
    """Run a function on the GUI thread from another thread and wait for its result."""

    def __init__(self):
        from PySide6 import QtCore

        class _Invoker(QtCore.QObject):
            call = QtCore.Signal(object)

        self._invoker = _Invoker()
        self._invoker.call.connect(self._run, QtCore.Qt.ConnectionType.QueuedConnection)

    @staticmethod
    def _run(job) -> None:
        fn, box, done = job
        try:
            box["value"] = fn()
        except BaseException as exc:  # handed back to the caller
            box["error"] = exc
        done.set()

    def post(self, fn: Callable[[], Any]) -> None:
        """Queue ``fn`` on the GUI thread without waiting (dropped if the event loop has ended)."""
        self._invoker.call.emit((fn, {}, threading.Event()))

    def __call__(self, fn: Callable[[], Any], timeout: float = 30.0) -> Any:
        box, done = {}, threading.Event()
        self._invoker.call.emit((fn, box, done))
        if not done.wait(timeout):
            raise TimeoutError(f"the GUI thread did not run {fn} within {timeout} s")
        if "error" in box:
            raise box["error"]
        return box.get("value")


class _ReleaseClock:
    """Event filter that notes when Qt delivers each left-button release to the view."""

    def __init__(self, widget):
        from PySide6 import QtCore

        clock = self

        class _Filter(QtCore.QObject):
            def eventFilter(self, obj, event):  # noqa: N802
                if event.type() == QtCore.QEvent.Type.MouseButtonRelease:
                    clock.times.append(time.perf_counter())
                return False

        self.times: list[float] = []
        self._filter = _Filter()
        widget.installEventFilter(self._filter)


def _screen_xy(w, world) -> tuple[float, float]:
    """Screen pixel of a world point in the window's 3D view (GUI thread)."""
    from PySide6 import QtCore

    p = w.view.projector().to_display(np.asarray(world, dtype=np.float64))
    scale = w.plotter.devicePixelRatioF()
    local = QtCore.QPointF(p[0] / scale, w.plotter.height() - 1 - p[1] / scale)
    g = w.plotter.mapToGlobal(local)
    return float(g.x()), float(g.y())


def _sleep_cpu(seconds: float) -> float:
    """Per cent of one core the process used over ``seconds`` of wall time."""
    c0, t0 = time.process_time(), time.perf_counter()
    time.sleep(seconds)
    return 100.0 * (time.process_time() - c0) / (time.perf_counter() - t0)


def drive(w, gui: GuiCall, x, n: int = 30, idle_s: float = 5.0, orbit_s: float = 3.0,
          rng: np.random.Generator | None = None) -> dict:
    """The measurements on an open window with a scene loaded and sound playing (driver thread)."""
    rng = rng or np.random.default_rng(0)
    releases = gui(lambda: _ReleaseClock(w.plotter))
    bounds = np.asarray(w.state.bounds)
    centre = bounds.mean(axis=0)
    radius = 0.28 * float(min(bounds[1, :2] - bounds[0, :2]))
    latency, delivery, submitted, ready, missed, offsets = [], [], [], [], 0, []
    refines = gui(lambda: w.live.refiner is not None)
    full, full_missed = [], 0
    paints0 = gui(lambda: w.plotter.frames)
    for i in range(n):
        angle = 2 * np.pi * i / max(n, 1) * 2.3 + 0.4
        z = float(gui(lambda: w.state.listener[2]))
        target = np.array([centre[0] + radius * np.cos(angle), centre[1] + radius * np.sin(angle), z])
        start = gui(lambda: _screen_xy(w, w.state.listener))
        end = gui(lambda t=target: _screen_xy(w, t))
        seen = len(releases.times)
        t_send = x.drag(start, end, steps=12, interval_s=1 / 60)
        deadline = time.perf_counter() + 10
        while len(releases.times) <= seen and time.perf_counter() < deadline:
            time.sleep(0.001)
        seq, listener, dragging = gui(lambda: (w.live.seq, w.state.listener.copy(), w.drag.dragging))
        t_live = w.engine.wait_live(seq, timeout=10)
        heard = w.live.heard
        for _ in range(1000):  # the worker notes the levels just after the engine has the filter
            if heard is not None and heard.request.seq >= seq:
                break
            time.sleep(0.001)
            heard = w.live.heard
        if t_live is None or dragging is not None or len(releases.times) <= seen or heard.request.seq != seq:
            missed += 1
        else:
            latency.append(t_live - t_send)
            delivery.append(releases.times[seen] - t_send)
            submitted.append(heard.request.submitted_at - t_send)
            ready.append(heard.ready_at - t_send)
            offsets.append(float(np.linalg.norm(listener[:2] - target[:2])))
        if refines:
            t_full = w.engine.wait_live(("loop", seq), timeout=10)
            if t_full is None or w.live.seq != seq:
                full_missed += 1
            else:
                full.append(t_full - t_send)
        time.sleep(float(rng.uniform(0.15, 0.4)))  # the user looks, listens, grabs again
    paints = gui(lambda: list(w.plotter.paint_seconds)[-(w.plotter.frames - paints0):] if w.plotter.frames > paints0 else [])
    time.sleep(1.0)
    idle_playing = _sleep_cpu(idle_s)
    gui(lambda: w.state.set_playing(False))
    time.sleep(1.0)
    idle_paused = _sleep_cpu(idle_s)
    gui(lambda: w.state.set_playing(True))

    # Orbit: drag on empty space near the view's lower-left corner, around a small circle.
    def corner() -> tuple[int, int]:
        from PySide6 import QtCore

        g = w.plotter.mapToGlobal(QtCore.QPoint(int(0.12 * w.plotter.width()), int(0.88 * w.plotter.height())))
        return g.x(), g.y()

    x0, y0 = gui(corner)
    frames0 = gui(lambda: w.plotter.frames)
    x.press(x0, y0)
    t0 = time.perf_counter()
    k = 0
    while time.perf_counter() - t0 < orbit_s:
        k += 1
        time.sleep(0.01)
        a = 2 * np.pi * k / 150
        x.move(x0 + 120 * np.sin(a), y0 - 40 * (1 - np.cos(a)))
    elapsed = time.perf_counter() - t0
    frames = gui(lambda: w.plotter.frames) - frames0
    x.release(x0 + 120 * np.sin(2 * np.pi * k / 150), y0 - 40 * (1 - np.cos(2 * np.pi * k / 150)))
    time.sleep(0.5)
    gui(lambda: (w.view.camera_home(), w.plotter.render()))
    followed = gui(lambda: bool(w.mouse.follower))
    return {"pointer_follow": followed, "drag_to_audio": _summary(latency),
            "drag_to_audio_each_ms": [round(1e3 * t, 3) for t in latency],  # in drag order: runs can be pooled
            "release_delivery": _summary(delivery),
            "drag_to_full_render": _summary(full) if refines else None, "full_render_missed": full_missed,
            "pose_submitted": _summary(submitted), "filter_ready": _summary(ready), "paint": _summary(paints), "drags": n,
            "missed": missed, "max_handle_offset": max(offsets) if offsets else None,
            "idle_cpu_playing": idle_playing, "idle_cpu_paused": idle_paused,
            "orbit": {"seconds": elapsed, "frames": int(frames), "fps": frames / elapsed, "pointer_moves": k}}


@contextmanager
def _display():
    import os

    if os.environ.get("DISPLAY"):
        yield os.environ["DISPLAY"], False
        return
    from .xinput import virtual_display

    with virtual_display() as name:
        yield name, True


def run_viewer_bench(scene_path: Any, out: Any, n: int = 30, idle_s: float = 5.0, orbit_s: float = 3.0) -> dict:
    """Open the window on ``scene_path``, drive it with real X events, write ``out`` (Markdown); the numbers."""
    import json
    import os
    from pathlib import Path

    import torch

    from avgs.io.atomic import write_text
    from avgs.bench.machine import machine_info

    from .xinput import XInput

    torch.set_num_threads(1)  # as the window runs (app.run_window)
    info = machine_info()
    with _display() as (display, virtual):
        from PySide6 import QtCore, QtWidgets

        app = QtWidgets.QApplication.instance() or QtWidgets.QApplication(["avgs-viewer"])
        from .window import MainWindow

        w = MainWindow()
        w.show()
        gui = GuiCall()
        box: dict = {}

        def driver() -> None:
            try:
                deadline = time.perf_counter() + 120
                while not (w.live is not None and w.live.heard is not None and w.engine.live_tag is not None):
                    if time.perf_counter() > deadline:
                        raise TimeoutError("the scene did not load within 120 s")
                    time.sleep(0.05)
                time.sleep(1.0)  # first paints done
                box["setup"] = gui(lambda: {
                    "gl": next((ln.strip() for ln in w.plotter.ren_win.ReportCapabilities().splitlines()
                                if "OpenGL renderer string" in ln), "unknown"),
                    "view": [w.plotter.width(), w.plotter.height()], "window": [w.width(), w.height()],
                    "view_kind": type(w.plotter).__name__,
                    "points": int(len(w.renderer.points)), "drawn": int(len(w.view.drawn)),
                    "audio": w.output.message or "sound card", "block": w.engine.block,
                    "sample_rate": w.engine.sample_rate, "filter_taps": int(w.live.heard.result.impulse.shape[1]),
                    "clip_seconds": len(w.live.clip) / w.engine.sample_rate,
                    "settle_s": None if w.live.refiner is None else w.live.refiner.settle})
                with XInput(display) as x:
                    box["result"] = drive(w, gui, x, n=n, idle_s=idle_s, orbit_s=orbit_s)
            except BaseException as exc:
                box["error"] = exc
            finally:
                # Closing the last window may end the event loop itself: the quit is posted, not
                # waited for (a call left unanswered would hold the join below for its 10 s).
                try:
                    gui(w.close, timeout=60)
                finally:
                    gui.post(app.quit)

        QtCore.QTimer.singleShot(0, lambda: w.open_scene(scene_path))
        thread = threading.Thread(target=driver, name="bench-driver", daemon=True)
        thread.start()
        app.exec()
        thread.join(10)
    if "error" in box:
        raise box["error"]
    r, setup = box["result"], box["setup"]
    lat, orbit = r["drag_to_audio"], r["orbit"]
    result = {"scene": str(scene_path), "display": "Xvfb started by the benchmark" if virtual else display,
              **setup, **r}
    block_ms = 1e3 * setup["block"] / setup["sample_rate"]
    lines = [
        "# Viewer benchmark",
        "",
        f"Command: `{info['command']}` ({info['date_utc']})  ",
        f"Machine: {info['cpu']}, {info['cpu_cores_available']} cores, load {info.get('load_average_1m_at_start')} "
        f"at start; torch {info['torch']}  ",
        f"GL: {setup['gl']}; display {result['display']}; 3D view: "
        + {"NativeCanvas": "a native window VTK draws into", "GLWidgetCanvas": "pyvistaqt's QOpenGLWidget, composed by Qt"
           }.get(setup["view_kind"], setup["view_kind"]) + " (avgs_viewer/canvas.py)  ",
        f"Scene: `{scene_path}`, {setup['points']} audio points ({setup['drawn']} drawn); window "
        f"{setup['window'][0]}x{setup['window'][1]}, 3D view {setup['view'][0]}x{setup['view'][1]}  ",
        f"Audio: {setup['audio']}; blocks of {setup['block']} samples ({block_ms:.1f} ms), "
        f"pose filters of {setup['filter_taps']} taps, a {setup['clip_seconds']:.1f} s loop"
        + ("; a settled pose plays its loop rendered in full" if setup["settle_s"] is not None else "") + "  ",
        "Drags: " + ("followed through the X pointer ahead of Qt's event queue (avgs_viewer/pointer.py; "
                     "`AVGS_VIEWER_NO_POINTER=1` measures without)" if r["pointer_follow"]
                     else "through Qt's mouse events only, as on Wayland, macOS and Windows ("
                     + ("`AVGS_VIEWER_NO_POINTER=1`" if os.environ.get("AVGS_VIEWER_NO_POINTER") else "no X pointer")
                     + "; the press's plane map per move, renders spaced by a frame interval: avgs_viewer/canvas.py)"),
        "",
        f"real-event drag to audio: median {lat['median_ms']:.1f} ms, p95 {lat['p95_ms']:.1f} ms",
        f"idle CPU: {r['idle_cpu_playing']:.1f} % of one core",
        f"orbit: {orbit['fps']:.1f} FPS",
        "",
        "| measure | value | notes |",
        "|---|---|---|",
        f"| drag to audio | median {lat['median_ms']:.1f} ms, p95 {lat['p95_ms']:.1f} ms, max {lat['max_ms']:.1f} ms | "
        f"{lat['n']} of {r['drags']} drags ({r['missed']} missed); from sending the release (XTEST) to the first "
        f"block of the released pose's filter leaving the audio engine |",
        *([] if not (r["drag_to_full_render"] or {}).get("n") else [
            f"| drag to full render | median {r['drag_to_full_render']['median_ms']:.0f} ms, p95 "
            f"{r['drag_to_full_render']['p95_ms']:.0f} ms | {r['drag_to_full_render']['n']} drags "
            f"({r['full_render_missed']} missed); from sending the release to the first block wholly of the loop "
            f"rendered in full at the released pose (settles {setup['settle_s']:.2f} s first; avgs_viewer/refine.py) |"]),
        *(f"| {name} | median {r[key]['median_ms']:.1f} ms, p95 {r[key]['p95_ms']:.1f} ms | {note} |"
          for name, key, note in (
              ("release delivered to Qt", "release_delivery", "from sending it to the view's event filter"),
              ("pose submitted", "pose_submitted", "from sending it to the released pose reaching the audio path"),
              ("filter ready", "filter_ready", "from sending it to the engine having the pose's filter"),
              ("paint", "paint", f"each VTK render into the 3D view during the drags ({r['paint']['n']} paints)"))),
        f"| idle CPU | {r['idle_cpu_playing']:.1f} % of one core playing, {r['idle_cpu_paused']:.1f} % paused | "
        f"process CPU time over {idle_s:.0f} s, nothing touched |",
        f"| orbit | {orbit['fps']:.1f} FPS | real left-button drag on the view for {orbit['seconds']:.1f} s, "
        f"{orbit['pointer_moves']} pointer moves, {orbit['frames']} frames drawn |",
        "",
        "How: the real window, driven through the X server with XTEST (the extension `xdotool` uses, called",
        "through ctypes so the send time is exact): each drag presses on the listener's sphere, moves 11 steps",
        "at 60 Hz, then moves the last step and releases at once. Between drags 0.15-0.4 s pass; nothing",
        "waits for the audio worker. Without a sound card the engine is pulled by a simulated clock at the",
        "card's pace (the same callback). Timings taken under load (see the load at start) are upper",
        "bounds: the GUI thread, the filter worker and the audio clock all wait for a core.",
        "",
        "```json",
        json.dumps({k: v for k, v in result.items()}, indent=1),
        "```",
        "",
    ]
    write_text(Path(out), "\n".join(lines))
    return result
