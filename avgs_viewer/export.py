"""Screenshot and audio export, from the window or from the command line without one.

The command-line path builds the same :class:`~avgs_viewer.scene_view.SceneView` into a
``pv.Plotter(off_screen=True)``, which renders through EGL with no X server. Every file
is written atomically (a temporary file in the target folder, then ``os.replace``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from avgs import atomic


def write_wav(path: str | Path, binaural: np.ndarray, sample_rate: int, inputs=()) -> Path:
    """Write binaural [2, T] audio as a 2-channel float WAV (left first); never over one of ``inputs``."""
    binaural = np.asarray(binaural, dtype=np.float32)
    if binaural.ndim != 2 or binaural.shape[0] != 2:
        raise ValueError(f"binaural audio must be [2, T], got shape {binaural.shape}")
    path = Path(path)
    if path.suffix.lower() != ".wav":
        raise ValueError(f"audio export must be a .wav file, got {path}")
    atomic.check_output(path, inputs=inputs, what="audio export")
    return atomic.write_wav(path, binaural, sample_rate, make_parents=False)


def write_screenshot(plotter: Any, path: str | Path, scale: int = 1, transparent: bool = False, inputs=()) -> Path:
    """Save the plotter's view as a PNG, ``scale`` times its window size; never over one of ``inputs``."""
    path = Path(path)
    if path.suffix.lower() != ".png":
        raise ValueError(f"screenshot must be a .png file, got {path}")
    scale = int(scale)
    if not 1 <= scale <= 8:
        raise ValueError(f"screenshot scale must be an integer from 1 to 8, got {scale}")
    atomic.check_output(path, inputs=inputs, what="screenshot")
    with atomic.atomic_path(path, make_parents=False) as tmp:
        plotter.screenshot(str(tmp), transparent_background=bool(transparent), scale=scale, return_img=False)
    return path


def export_headless(renderer: Any, *, listener, yaw: float, source=None, screenshot: str | Path | None = None,
                    audio: str | Path | None = None, clip: np.ndarray | None = None, scale: int = 1,
                    transparent: bool = False, window_size=(1024, 768), colour_mode: str = "vicinity",
                    legend: bool = True):
    """Render one pose with no window: a PNG of the point pattern and/or the binaural WAV.

    ``renderer`` is an ``avgs.SceneRenderer``; positions are world coordinates, ``yaw``
    degrees. ``clip`` is the mono signal to binauralise (default: the bundled demo clip,
    else one second of a test tone). Returns the ``RenderResult``.
    """
    from .state import ViewerState

    state = ViewerState(renderer.bounds, renderer.source if source is None else source,
                        listener=listener, yaw=yaw, has_rgb=renderer.gaussians is not None)
    state.set_colour_mode(colour_mode)
    if clip is None:
        clip = default_clip(renderer.sample_rate)
    pose = state.pose
    result = renderer.render(listener=pose.listener, yaw=pose.yaw, mono=clip, source=pose.source)
    if screenshot is not None:
        import pyvista as pv

        from .scene_view import SceneView

        plotter = pv.Plotter(off_screen=True, window_size=list(window_size))
        try:
            view = SceneView(plotter, renderer, state, legend=legend)
            view.set_vicinity(result.listener_vicinity, result.source_vicinity)
            write_screenshot(plotter, screenshot, scale=scale, transparent=transparent)
            view.close()
        finally:
            plotter.close()
    if audio is not None:
        write_wav(audio, result.binaural, renderer.sample_rate)
    return result


DEMO_CLIP = Path(__file__).resolve().parents[1] / "assets" / "demo" / "clip.wav"


def default_clip(sample_rate: int) -> np.ndarray:
    """The bundled demo clip, or (until it exists) two seconds of a decaying tone burst train."""
    from .audio import load_clip

    if DEMO_CLIP.is_file():
        return load_clip(DEMO_CLIP, sample_rate)
    t = np.arange(2 * sample_rate) / sample_rate
    bursts = np.exp(-12.0 * (t % 0.25))  # four bursts a second
    tone = np.sin(2 * np.pi * 440.0 * t) + 0.5 * np.sin(2 * np.pi * 1320.0 * t)
    return (0.3 * bursts * tone).astype(np.float32)
