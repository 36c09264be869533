"""A fly-through video of the explorer's 3D view: the same :class:`~avgs_viewer.scene_view.SceneView`
the headless screenshot draws (:mod:`avgs_viewer.export`), off screen, its listener and
source handles following the path and its points coloured by the vicinity sets heard then;
or G seen from the listener's head. The sound and the file are :mod:`avgs.export.flythrough`'s.

    avgs-viewer scene.ckpt --flythrough path.json --video out.mp4 [--fps 30] [--size W H] [--clip x.wav]
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

import numpy as np

from avgs.export.flypath import PathPose

from .trained_scene import TrainedScene


class SceneViewFrames:
    """Frames of the 3D view (home camera) following a path, drawn off screen."""

    def __init__(self, renderer: TrainedScene, width: int, height: int, colour_mode: str = "vicinity"):
        import pyvista as pv

        from .scene_view import SceneView
        from .state import ViewerState

        self.state = ViewerState(renderer.bounds, renderer.source, has_rgb=renderer.gaussians is not None,
                                 outline=renderer.outline)
        self.state.set_colour_mode(colour_mode)
        self.size = (int(width), int(height))
        self.plotter = pv.Plotter(off_screen=True, window_size=list(self.size))
        self.view = SceneView(self.plotter, renderer, self.state)

    def __call__(self, pose: PathPose, heard) -> np.ndarray:
        """RGB ``[H, W, 3]`` uint8 of the view at ``pose`` (``heard``: the RenderResult playing then, or None)."""
        self.state.set_listener(pose.listener, keep_height=False)
        self.state.set_yaw(pose.yaw)
        if pose.source is not None:
            self.state.set_source(pose.source)
        if heard is not None:
            self.view.set_vicinity(heard.listener_vicinity, heard.source_vicinity)
        self.plotter.render()
        img = np.asarray(self.plotter.screenshot(return_img=True))[..., :3]  # [H, W, 3]
        w, h = self.size
        if img.shape[:2] != (h, w):  # a HiDPI render window: back to the asked size
            img = img[np.linspace(0, img.shape[0] - 1, h).astype(int)][:, np.linspace(0, img.shape[1] - 1, w).astype(int)]
        return np.ascontiguousarray(img, dtype=np.uint8)

    def close(self) -> None:
        self.view.close()
        self.plotter.close()


def run_flythrough(args: argparse.Namespace, scene: Path) -> int:
    """``avgs-viewer --flythrough path.json --video out.mp4``: the 3D view's fly-through, no window."""
    if not os.environ.get("DISPLAY") and not os.environ.get("WAYLAND_DISPLAY"):
        os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")  # as the headless screenshot
    from avgs import SceneRenderer
    from avgs.config import SynthesisConfig
    from avgs.export.flypath import read_path
    from avgs.export.flythrough import FlythroughConfig, check_config, render_flythrough, tqdm_progress
    from avgs.io.atomic import check_output

    from .audio import load_clip
    from .export import default_clip

    if args.video is None:
        raise ValueError("--flythrough needs --video out.mp4")
    check_output(args.video, inputs=[scene, args.clip, args.flythrough], what="--video")
    config = check_config(FlythroughConfig(fps=args.fps, width=args.size[0], height=args.size[1]))
    keyframes = read_path(args.flythrough)
    # What the explorer plays: the clip through the pose's filter, block by block.
    renderer = SceneRenderer.load(scene, synthesis=SynthesisConfig(method="filter"))
    clip = load_clip(args.clip, renderer.sample_rate) if args.clip else default_clip(renderer.sample_rate)
    frames = SceneViewFrames(renderer, config.width, config.height, args.colour_mode)
    progress, close = tqdm_progress("fly-through")
    try:
        result = render_flythrough(renderer, keyframes, clip, args.video, frames, config, progress,
                                   inputs=[scene, args.clip, args.flythrough])
    finally:
        close()
        frames.close()
    print(f"wrote {args.video} ({result.frames} frames at {args.fps:g} fps, {result.codec} + AAC)")
    return 0
