"""Screenshot and audio export, from the window or from the command line without one.

The command-line path builds the same :class:`~avgs_viewer.scene_view.SceneView` into a
``pv.Plotter(off_screen=True)``, which renders through EGL with no X server. Every file
is written atomically (a temporary file in the target folder, then ``os.replace``).
"""

from __future__ import annotations

import contextlib
from pathlib import Path
from typing import TYPE_CHECKING, Any, Iterator

import numpy as np

from avgs.io import atomic

from .trained_scene import Position, TrainedScene

if TYPE_CHECKING:
    from avgs.render.renderer import RenderResult

MAX_SCALE = 8
MIN_SIZE, MAX_SIZE = 64, 8192  # window pixels before scaling
MAX_PIXELS = 16384  # a side after scaling (rendered in tiles); 16384 x 16384 RGBA is already 1 GiB


def check_picture_size(width: Any, height: Any, scale: Any = 1, names=("picture size", "screenshot scale")
                       ) -> tuple[int, int, int]:
    """(width, height, scale) as whole numbers, or one ValueError saying what is allowed
    (``names``: how the error calls the size and the scale, e.g. the command line's flags)."""
    def whole(v: Any) -> int | None:
        try:
            f = float(v)
        except (TypeError, ValueError):
            return None
        return int(f) if np.isfinite(f) and f == int(f) else None

    w, h, s = whole(width), whole(height), whole(scale)
    if w is None or h is None or not (MIN_SIZE <= w <= MAX_SIZE and MIN_SIZE <= h <= MAX_SIZE):
        raise ValueError(f"{names[0]} must be two whole numbers of pixels from {MIN_SIZE} to {MAX_SIZE} "
                         f"(width height), got {width} {height}")
    if s is None or not 1 <= s <= MAX_SCALE:
        raise ValueError(f"{names[1]} must be a whole number from 1 to {MAX_SCALE}, got {scale}")
    if max(w, h) * s > MAX_PIXELS:
        raise ValueError(f"a {w} x {h} picture at scale {s} is {w * s} x {h * s} pixels; at most {MAX_PIXELS} "
                         f"a side: lower the {names[0]} or the {names[1]}")
    return w, h, s


@contextlib.contextmanager
def annotated(view: Any, legend: bool = True, caption: bool = False) -> Iterator[Any]:
    """The view with its legend and/or a caption naming the pose while the block runs (for a
    picture), each sized to the window and in a corner that covers no handle; removed after."""
    if view is None:  # no scene yet: a picture of the empty view
        yield view
        return
    try:
        if legend:
            view.show_legend()
        if caption:
            view.show_caption()
        yield view
    finally:
        if caption:
            view.hide_caption()
        if legend:
            view.hide_legend()
        view.plotter.render()


def write_wav(path: str | Path, binaural: np.ndarray, sample_rate: int, inputs=()) -> Path:
    """Write binaural [2, T] audio as a 2-channel float WAV (left first); never over one of ``inputs``."""
    return atomic.write_binaural_wav(path, binaural, sample_rate, inputs, what="audio export", make_parents=False)


@contextlib.contextmanager
def scaled_marks(plotter: Any, scale: int) -> Iterator[None]:
    """Every 3D actor's point size and line width (in every renderer of the plotter's window:
    the scene, the handles' layer, the axes marker) ``scale`` times larger while the block runs,
    restored after: a picture rendered ``scale`` times larger (in tiles, whose text VTK already
    scales) then looks as the window does, not thinner."""
    saved = []
    if scale != 1:
        renderers = plotter.render_window.GetRenderers()
        renderers.InitTraversal()
        for _ in range(renderers.GetNumberOfItems()):
            ren = renderers.GetNextItem()
            actors = ren.GetActors()
            actors.InitTraversal()
            for _ in range(actors.GetNumberOfItems()):
                prop = actors.GetNextActor().GetProperty()
                saved.append((prop, prop.GetPointSize(), prop.GetLineWidth()))
                prop.SetPointSize(prop.GetPointSize() * scale)
                prop.SetLineWidth(prop.GetLineWidth() * scale)
            widget = getattr(ren, "axes_widget", None)
            axes = None if widget is None else widget.GetOrientationMarker()
            if axes is not None and hasattr(axes, "GetXAxisShaftProperty"):
                for get in ("GetXAxisShaftProperty", "GetYAxisShaftProperty", "GetZAxisShaftProperty"):
                    prop = getattr(axes, get)()
                    saved.append((prop, prop.GetPointSize(), prop.GetLineWidth()))
                    prop.SetLineWidth(prop.GetLineWidth() * scale)
    try:
        yield
    finally:
        for prop, size, width in saved:
            prop.SetPointSize(size)
            prop.SetLineWidth(width)


def write_screenshot(plotter: Any, path: str | Path, scale: int = 1, transparent: bool = False, inputs=()) -> Path:
    """Save the plotter's view as a PNG, ``scale`` times its window size, points and lines
    ``scale`` times wider (:func:`scaled_marks`); never over one of ``inputs``."""
    path = Path(path)
    if path.suffix.lower() != ".png":
        raise ValueError(f"screenshot must be a .png file, got {path}")
    size = plotter.render_window.GetSize()
    _, _, scale = check_picture_size(max(size[0], MIN_SIZE), max(size[1], MIN_SIZE), scale)
    atomic.check_output(path, inputs=inputs, what="screenshot")
    with atomic.atomic_path(path, make_parents=False) as tmp:
        with scaled_marks(plotter, scale):
            plotter.screenshot(str(tmp), transparent_background=bool(transparent), scale=scale, return_img=False)
    return path


def export_headless(renderer: TrainedScene, *, listener: Position, yaw: float, source: Position | None = None,
                    screenshot: str | Path | None = None,
                    audio: str | Path | None = None, clip: np.ndarray | None = None, scale: int = 1,
                    transparent: bool = False, window_size=(1024, 768), colour_mode: str = "vicinity",
                    legend: bool = True, caption: bool = False, map_mode: str = "off", inset: bool = False,
                    warn=None) -> RenderResult:
    """Render one pose with no window: a PNG of the point pattern and/or the binaural WAV.

    ``renderer`` is an ``avgs.SceneRenderer`` (:class:`~avgs_viewer.trained_scene.TrainedScene`);
    positions are world coordinates, ``yaw`` degrees (kept inside the room as in the window).
    ``clip`` is the mono signal to binauralise (default: the bundled demo clip, else one second
    of a test tone).
    ``legend`` and ``caption`` (the pose) are drawn where they cover no handle; ``map_mode``
    ``"level"`` or ``"ild"`` adds the propagation map on the floor; ``inset`` G seen from the
    listener's head (a checkpoint with G). All are placed by one layout
    (:mod:`avgs_viewer.overlay_layout`). The WAV is what the explorer plays: the clip through the
    pose's filter. ``warn(message)`` hears of positions moved into the room and of overlays
    shrunk or left out (as the window's status bar does). Returns the ``RenderResult``.
    """
    from avgs.config import SynthesisConfig

    from .state import ViewerState

    if screenshot is not None:
        check_picture_size(*window_size, scale)
    warn = warn or (lambda message: None)
    state = ViewerState(renderer.bounds, renderer.source, yaw=yaw, has_rgb=renderer.gaussians is not None,
                        outline=renderer.outline)
    state.events.clamped.connect(warn)  # typed positions moved into the room are said, as in the window
    state.events.wall.connect(warn)
    if source is not None:
        state.set_source(source)
    state.set_listener(listener, keep_height=False)
    state.set_colour_mode(colour_mode)
    if clip is None:
        clip = default_clip(renderer.sample_rate)
    pose = state.pose
    result = renderer.render(listener=pose.listener, yaw=pose.yaw, mono=clip, source=pose.source,
                             synthesis=SynthesisConfig(method="filter"))
    if screenshot is not None:
        import pyvista as pv

        from .scene_view import SceneView

        plotter = pv.Plotter(off_screen=True, window_size=list(window_size))
        try:
            view = SceneView(plotter, renderer, state)
            view.set_vicinity(result.listener_vicinity, result.source_vicinity)
            floor_map = None
            if map_mode != "off":
                from .propagation_view import PropagationView

                floor_map = PropagationView(plotter, renderer, state, mode=map_mode)
                floor_map.draw_now()
            rep = None
            if inset:
                rep = _show_listener_view(plotter, renderer, state, warn)
            with annotated(view, legend=legend, caption=caption):
                for note in view.overlay_notes:
                    warn(note)
                write_screenshot(plotter, screenshot, scale=scale, transparent=transparent)
            if floor_map is not None:
                floor_map.close()
            view.close()
        finally:
            plotter.close()
    if audio is not None:
        write_wav(audio, result.binaural, renderer.sample_rate)
    return result


def _show_listener_view(plotter: Any, renderer: TrainedScene, state: Any, warn) -> Any:
    """G from the listener's head as the window's inset, or a warning why there is none."""
    from avgs.render.listener_view import ListenerView

    from .propagation_view import show_inset

    path = getattr(renderer, "path", None)
    view = ListenerView.load(path) if path is not None and renderer.gaussians is not None else None
    if view is None:
        warn("listener's view inset left out: the checkpoint carries no Gaussians G")
        return None
    return show_inset(plotter, view.render(state.listener, state.yaw, 192, 144))


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
