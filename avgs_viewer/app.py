"""``avgs-viewer``: the desktop explorer, or a one-shot headless export.

    avgs-viewer [scene.ckpt] [--clip clip.wav]
    avgs-viewer scene.ckpt --screenshot out.png --listener X Y Z --yaw DEG --source X Y Z
                [--scale S] [--transparent] [--audio out.wav]

With ``--screenshot`` and/or ``--audio`` nothing is shown: the scene is drawn into an
off-screen plotter (EGL, no X server needed), the files are written and the program
exits. Otherwise the window opens at once and the checkpoint loads in the background.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

DEMO_SCENE = Path(__file__).resolve().parents[1] / "assets" / "demo" / "scene.ckpt"
PROG = "avgs-viewer"


def version() -> str:
    """The installed package's version (pyproject.toml's)."""
    from importlib.metadata import PackageNotFoundError
    from importlib.metadata import version as installed

    try:
        return installed("avgs")
    except PackageNotFoundError:
        return "unknown (not installed)"


def warn(message: str) -> None:
    """One line on standard error, as ``avgs render`` says what it changed."""
    print(f"{PROG}: warning: {message}", file=sys.stderr)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=PROG, description="Explore a trained AV-GS scene: drag a listener and a "
                                "sound source and hear the binaural result.")
    p.add_argument("scene", nargs="?", type=Path, default=None,
                   help=f"checkpoint to open (default: the bundled demo, {DEMO_SCENE})")
    p.add_argument("--clip", type=Path, default=None, help="mono (or down-mixed) audio clip to loop")
    p.add_argument("--osc-port", type=int, default=None, metavar="N",
                   help="head tracking: follow OSC /ypr (and /xyz) on UDP port N (default off; the usual port: 9000)")
    p.add_argument("--version", action="version", version=f"%(prog)s {version()}")
    g = p.add_argument_group("headless export (no window)")
    g.add_argument("--screenshot", type=Path, default=None, help="write a PNG of the point pattern and exit")
    g.add_argument("--audio", type=Path, default=None, help="write the binaural WAV of the clip and exit")
    g.add_argument("--listener", type=float, nargs=3, metavar=("X", "Y", "Z"), default=None,
                   help="listener position, world coordinates (default: opposite the source)")
    g.add_argument("--yaw", type=float, default=0.0, help="listener yaw, degrees ccw from +x (default 0)")
    g.add_argument("--source", type=float, nargs=3, metavar=("X", "Y", "Z"), default=None,
                   help="source position, world coordinates (default: the trained source)")
    g.add_argument("--scale", type=int, default=1, help="screenshot scale factor, 1..8 (default 1; at most "
                   "16384 pixels a side after scaling)")
    g.add_argument("--transparent", action="store_true", help="transparent screenshot background")
    g.add_argument("--size", type=int, nargs=2, metavar=("W", "H"), default=(1024, 768),
                   help="screenshot window size in pixels before scaling, 64..8192 each (default 1024 768)")
    g.add_argument("--colour-mode", choices=("vicinity", "alpha", "rgb"), default="vicinity",
                   help="what the point colours show (default vicinity)")
    g.add_argument("--no-legend", action="store_true", help="leave the legend out of the screenshot")
    g.add_argument("--caption", action="store_true", help="add a caption naming the pose to the screenshot")
    g.add_argument("--map", choices=("off", "level", "ild"), default="off",
                   help="draw the propagation map (each ear's level, or the ILD, over listener positions) on the floor")
    g.add_argument("--inset", action="store_true",
                   help="add the listener's view (G from the listener's head) in a corner, as in the window")
    f = p.add_argument_group("fly-through video (no window; avgs_viewer.flythrough)")
    f.add_argument("--flythrough", type=Path, default=None, metavar="PATH.json",
                   help='a listener path, [{"t": s, "listener": [x, y, z], "yaw": deg}, ...]: write --video and exit')
    f.add_argument("--video", type=Path, default=None, metavar="OUT.mp4", help="the fly-through's MP4 (H.264 + AAC); "
                   "the picture is the 3D view at --size (even numbers)")
    f.add_argument("--fps", type=float, default=30.0, help="fly-through frames per second (default 30)")
    b = p.add_argument_group("benchmark")
    b.add_argument("--bench", type=Path, default=None, metavar="OUT.md",
                   help="drive the real window with X events (XTEST; an Xvfb of its own without a display): "
                   "drag-to-audio latency, idle CPU, orbit frame rate; write OUT.md and exit")
    b.add_argument("--bench-drags", type=int, default=30, metavar="N",
                   help="listener drags the benchmark times (default 30; more give a steadier p95)")
    return p


def resolve_scene(scene: Path | None) -> Path:
    """The checkpoint to open; errors name what is missing and how to make it."""
    if scene is None:
        if not DEMO_SCENE.is_file():
            raise FileNotFoundError(
                f"no scene given and the bundled demo scene {DEMO_SCENE} does not exist yet; "
                f"pass a checkpoint written by 'avgs train' (avgs-viewer path/to/scene.ckpt)")
        return DEMO_SCENE
    if not scene.is_file():
        raise FileNotFoundError(f"scene checkpoint {scene} does not exist")
    return scene


def run_headless(args: argparse.Namespace, scene: Path) -> int:
    if not os.environ.get("DISPLAY") and not os.environ.get("WAYLAND_DISPLAY"):
        # No X server: go straight to EGL rather than have VTK try X first and warn.
        os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")
    from avgs import SceneRenderer
    from avgs.io.atomic import check_output

    from .audio_path import load_clip_noted
    from .export import export_headless

    for path, what in ((args.screenshot, "--screenshot"), (args.audio, "--audio")):
        if path is not None:
            check_output(path, inputs=[scene, args.clip], what=what)
    renderer = SceneRenderer.load(scene)
    clip = None
    if args.clip:
        clip, notes = load_clip_noted(args.clip, renderer.sample_rate)
        for note in notes:
            warn(note)
    listener = args.listener
    if listener is None:
        from .state import ViewerState

        listener = ViewerState(renderer.bounds, renderer.source if args.source is None else args.source,
                               outline=renderer.outline).listener
    export_headless(renderer, listener=listener, yaw=args.yaw, source=args.source, screenshot=args.screenshot,
                    audio=args.audio, clip=clip, scale=args.scale, transparent=args.transparent,
                    window_size=tuple(args.size), colour_mode=args.colour_mode, legend=not args.no_legend,
                    caption=args.caption, map_mode=args.map, inset=args.inset, warn=warn)
    for path in (args.screenshot, args.audio):
        if path is not None:
            print(f"wrote {path}")
    return 0


def run_window(args: argparse.Namespace, scene: Path) -> int:
    import torch
    from PySide6 import QtCore, QtWidgets

    # One render is a few ms of small matrix work: one thread is as fast on a quiet machine and
    # never stalls on a busy one (two threads waiting on each other turned 7 ms into 600 ms under load).
    torch.set_num_threads(1)

    from .native_view import prefer_xwayland

    prefer_xwayland()  # a Wayland session with XWayland: the native view (avgs_viewer/canvas.py)
    app = QtWidgets.QApplication.instance() or QtWidgets.QApplication([PROG])
    from .window import MainWindow

    window = MainWindow(clip_path=args.clip)
    window.show()
    if args.osc_port is not None:
        window.set_head_tracking(True, args.osc_port)
    QtCore.QTimer.singleShot(0, lambda: window.open_scene(scene))  # after the window is on screen
    return app.exec()


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        from .export import check_picture_size

        check_picture_size(*args.size, args.scale, names=("--size", "--scale"))  # before any work: one line, not a page of GL errors
        scene = resolve_scene(args.scene)
        if args.bench is not None:
            from avgs.io.atomic import check_output

            from .bench import run_viewer_bench

            check_output(args.bench, inputs=[scene, args.clip], what="--bench")
            if args.bench_drags < 1:
                raise ValueError(f"--bench-drags must be at least 1, got {args.bench_drags}")
            # The real window, driven with X events (an Xvfb of its own when there is no display).
            r = run_viewer_bench(scene, args.bench, n=args.bench_drags)
            lat = r["drag_to_audio"]
            print(f"real-event drag to audio: median {lat['median_ms']:.1f} ms, p95 {lat['p95_ms']:.1f} ms; "
                  f"idle CPU {r['idle_cpu_playing']:.1f} %; orbit {r['orbit']['fps']:.1f} FPS; wrote {args.bench}")
            return 0
        if args.flythrough is not None:  # a fly-through video, no window
            from .flythrough import run_flythrough
            return run_flythrough(args, scene)
        if args.screenshot is not None or args.audio is not None:
            return run_headless(args, scene)
    except (ValueError, OSError) as exc:  # bad input or an unwritable output: one line, no traceback
        print(f"{PROG}: error: {exc}", file=sys.stderr)
        return 2
    return run_window(args, scene)


if __name__ == "__main__":
    sys.exit(main())
