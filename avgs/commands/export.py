"""``avgs export``: what a listener hears, in the formats the field uses.

    avgs export scene.ckpt --ir out.wav --listener X Y Z --yaw DEG [--source X Y Z]
    avgs export scene.ckpt --sofa grid.sofa [--spacing 0.5] [--yaws 0 90 180 270] [--height Z]
                [--sources X Y Z [X Y Z ...]]
    avgs export scene.ckpt --video out.mp4 --path path.json [--fps 30] [--size W H] [--clip clip.wav]

``--ir``: the pose's binaural impulse response as a 2-channel float32 WAV (channel 0 = left).
``--sofa``: responses over a grid of listener positions x yaws (x sources, with a checkpoint of
``--task rir``) as a SOFA file (convention SingleRoomSRIR; :mod:`avgs.export.sofa`).
``--video``: a fly-through along a path of keyframes (:mod:`avgs.export.flypath`): G seen from
the listener's head and the binaural track as the listener moves (``avgs-viewer --flythrough``
draws the explorer's 3D view instead). World coordinates, yaws in degrees ccw from +x.
"""

from __future__ import annotations

import argparse

import numpy as np


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("checkpoint", metavar="scene.ckpt", help="Checkpoint written by 'avgs train'.")
    what = parser.add_mutually_exclusive_group(required=True)
    what.add_argument("--ir", metavar="out.wav", help="Write the pose's binaural impulse response (2 channels, float32).")
    what.add_argument("--sofa", metavar="grid.sofa", help="Write a grid of responses as a SOFA file (SingleRoomSRIR).")
    what.add_argument("--video", metavar="out.mp4", help="Write a fly-through along --path (H.264 + AAC).")
    pose = parser.add_argument_group("--ir: the pose")
    pose.add_argument("--listener", nargs=3, type=float, metavar=("X", "Y", "Z"), help="Listener position, world.")
    pose.add_argument("--yaw", type=float, metavar="DEG", help="Listener facing, degrees ccw from +x.")
    pose.add_argument("--source", nargs=3, type=float, metavar=("X", "Y", "Z"),
                      help="Source position, world (default: the trained one).")
    grid = parser.add_argument_group("--sofa: the grid")
    grid.add_argument("--spacing", type=float, default=0.5, metavar="M", help="Listener grid spacing in x and y (default 0.5).")
    grid.add_argument("--yaws", type=float, nargs="+", default=[0.0, 90.0, 180.0, 270.0], metavar="DEG",
                      help="Listener yaws at every position (default 0 90 180 270).")
    grid.add_argument("--height", type=float, metavar="Z", help="Listener height (default: the source's).")
    grid.add_argument("--sources", type=float, nargs="+", metavar="X Y Z",
                      help="Source positions, three numbers each (default: the trained source; several need --task rir).")
    video = parser.add_argument_group("--video: the fly-through")
    video.add_argument("--path", metavar="path.json",
                       help='Keyframes: [{"t": s, "listener": [x, y, z], "yaw": deg, "source": [x, y, z] (optional)}, ...].')
    video.add_argument("--fps", type=float, default=30.0, help="Frames per second (default 30).")
    video.add_argument("--size", type=int, nargs=2, default=(640, 480), metavar=("W", "H"),
                       help="Picture size, even pixels (default 640 480).")
    video.add_argument("--clip", metavar="clip.wav", help="Mono clip looped along the path (default: noise bursts).")
    parser.add_argument("--device", default="cpu", help="Torch device (cpu or cuda).")


def _sources(values) -> tuple:
    if not values:
        return ()
    if len(values) % 3:
        raise ValueError(f"--sources takes three numbers (x y z) per source, got {len(values)} numbers")
    return tuple(tuple(values[i : i + 3]) for i in range(0, len(values), 3))


def run(args: argparse.Namespace) -> int:
    from avgs.io.atomic import check_output

    out = args.ir or args.sofa or args.video
    inputs = [args.checkpoint, args.path, args.clip]
    flag, suffix = ("--ir", ".wav") if args.ir else ("--sofa", ".sofa") if args.sofa else ("--video", ".mp4")
    if not str(out).lower().endswith(suffix):  # before any work
        raise ValueError(f"{flag} {out}: must be written to a {suffix} file")
    check_output(out, inputs=inputs, what=flag)
    if args.ir:
        if args.listener is None or args.yaw is None:
            raise ValueError("--ir needs the pose: --listener X Y Z and --yaw DEG")
        return _impulse(args, inputs)
    if args.sofa:
        return _grid(args, inputs)
    return _video(args, inputs)


def _impulse(args: argparse.Namespace, inputs) -> int:
    from avgs.export.sofa import write_impulse_wav
    from avgs.render.renderer import SceneRenderer

    renderer = SceneRenderer.load(args.checkpoint, device=args.device)
    result = renderer.binaural_filter(args.listener, args.yaw, source=args.source)
    write_impulse_wav(args.ir, result.impulse, renderer.sample_rate, inputs=inputs)
    print(f"wrote {args.ir} ({result.impulse.shape[1]} samples at {renderer.sample_rate} Hz, 2 channels, left first)")
    return 0


def _grid(args: argparse.Namespace, inputs) -> int:
    from tqdm import tqdm

    from avgs.export.grid import GridSpec, check_spec, compute_grid
    from avgs.export.sofa import write_grid
    from avgs.render.renderer import SceneRenderer

    spec = check_spec(GridSpec(spacing=args.spacing, yaws=tuple(args.yaws), height=args.height,
                               sources=_sources(args.sources)))
    renderer = SceneRenderer.load(args.checkpoint, device=args.device)
    with tqdm(total=1, desc="responses", unit="pose", dynamic_ncols=True) as bar:
        def progress(done: int, total: int) -> None:
            bar.total = total
            bar.update(done - bar.n)

        grid = compute_grid(renderer, spec, progress)
    write_grid(args.sofa, grid, title=f"AV-GS scene {renderer.name!r}", inputs=inputs)
    S, P, Y = grid.shape
    print(f"wrote {args.sofa} ({S} source(s) x {P} listener positions x {Y} yaws = {S * P * Y} responses of "
          f"{grid.ir.shape[-1]} samples, SingleRoomSRIR)")
    return 0


def default_clip(sample_rate: int, seconds: float = 2.0) -> np.ndarray:
    """Four bursts of noise a second: easy to place by ear."""
    t = np.arange(int(seconds * sample_rate)) / sample_rate
    noise = np.random.default_rng(0).standard_normal(t.size)
    return (0.2 * np.exp(-10.0 * (t % 0.25)) * noise).astype(np.float32)


def _video(args: argparse.Namespace, inputs) -> int:
    from avgs.config import SynthesisConfig
    from avgs.export.flypath import read_path
    from avgs.export.flythrough import FlythroughConfig, check_config, listener_frames, render_flythrough, tqdm_progress
    from avgs.io.audio_input import read_mono
    from avgs.render.listener_view import ListenerView
    from avgs.render.renderer import SceneRenderer

    if args.path is None:
        raise ValueError("--video needs --path path.json (keyframes of the listener's path)")
    config = check_config(FlythroughConfig(fps=args.fps, width=args.size[0], height=args.size[1]))
    keyframes = read_path(args.path)
    view = ListenerView.load(args.checkpoint, device=args.device)
    if view is None:
        raise ValueError(f"{args.checkpoint} was saved without G (--no-gaussians): nothing to see from the listener's "
                         "head; 'avgs-viewer --flythrough' draws the explorer's 3D view instead")
    # What the explorer plays: the input through the pose's filter, block by block.
    renderer = SceneRenderer.load(args.checkpoint, device=args.device, synthesis=SynthesisConfig(method="filter"))
    clip = read_mono(args.clip, renderer.sample_rate) if args.clip else default_clip(renderer.sample_rate)
    progress, close = tqdm_progress("fly-through")
    try:
        result = render_flythrough(renderer, keyframes, clip, args.video,
                                   listener_frames(view, config.width, config.height), config, progress, inputs)
    finally:
        close()
    print(f"wrote {args.video} ({result.frames} frames at {args.fps:g} fps, {result.codec} + AAC, "
          f"{result.samples / renderer.sample_rate:.2f} s of sound)")
    return 0
