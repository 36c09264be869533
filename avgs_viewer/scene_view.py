"""The scene's PyVista actors, drawn into any plotter and kept in step with a ViewerState.

The same :class:`SceneView` draws into the window's ``pyvistaqt.QtInteractor`` and into a
plain ``pv.Plotter(off_screen=True)`` (EGL, no X server) for the command-line screenshot
and the rendering tests. It shows G_a's points (a deterministic subset when there are
many: Mesa under Xvfb manages ~13 FPS at 50k points) coloured by the state's colour mode,
hides those above the slice height, and draws the room outline, an axes marker, a blue
listener sphere with a facing arrow and a yellow source sphere. The handles live in a
second VTK layer on top of the points, ringed white and black, so no point hides them
and they stand out from every colour mode. While the camera or a handle moves the
points are drawn as plain squares and without multisample antialiasing (with software
GL, 4x multisampling is three quarters of a frame's cost: ~30 of ~40 ms); when idle, as
shaded spheres, antialiased as the plotter was set up.

Pictures can carry a legend and a caption with the pose, sized to the picture and put in
a corner where they cover no handle. VTK's own keys (``3`` stereo, ``w`` wireframe, ``+``
point size, ...) are switched off: the window's menus hold every key.

No Qt here; :class:`VtkProjector` gives the drag logic (``avgs_viewer.drag``) the camera.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
import pyvista as pv

from . import colors
from .drag import pixel_radius
from .overlay_layout import Layout, OverlayBoard
from .state import ColourMode, ViewerState
from .trained_scene import TrainedScene

if TYPE_CHECKING:
    from vtkmodules.vtkRenderingCore import vtkRenderer

BACKGROUND = (22, 24, 30)
POINT_SIZE = 6.0
FAST_POINTS = 4000
"Points drawn while anything moves (a fixed random subset): a software-GL frame then costs a fraction, leaving the CPU to the sound."
HALO = ((1.16, (1.0, 1.0, 1.0)), (1.36, (0.02, 0.02, 0.03)))
"Rings around each handle: (radius as a multiple of the handle's, colour), inner first."
AXES_VIEWPORT = (0.0, 0.0, 0.16, 0.16)  # the axes marker's corner until the overlays' layout places it


class VtkProjector:
    """The :class:`avgs_viewer.drag.Projector` of a VTK renderer's current camera."""

    def __init__(self, renderer: vtkRenderer):
        self.renderer = renderer  # VTK's renderer (a plotter's ``renderer``), not the scene's

    def to_display(self, world: np.ndarray) -> np.ndarray:
        x, y, z = (float(v) for v in np.asarray(world, dtype=np.float64)[:3])
        self.renderer.SetWorldPoint(x, y, z, 1.0)
        self.renderer.WorldToDisplay()
        return np.array(self.renderer.GetDisplayPoint()[:2], dtype=np.float64)

    def _unproject(self, x: float, y: float, depth: float) -> np.ndarray:
        self.renderer.SetDisplayPoint(float(x), float(y), depth)
        self.renderer.DisplayToWorld()
        wx, wy, wz, w = self.renderer.GetWorldPoint()
        return np.array([wx, wy, wz]) / (w if w else 1.0)

    def ray(self, x: float, y: float) -> tuple[np.ndarray, np.ndarray]:
        near, far = self._unproject(x, y, 0.0), self._unproject(x, y, 1.0)
        d = far - near
        return near, d / np.linalg.norm(d)


def _outline_mesh(outline: np.ndarray) -> pv.PolyData:
    """[K, 2, 3] world segments -> line PolyData."""
    outline = np.asarray(outline, dtype=np.float64)
    if outline.ndim != 3 or outline.shape[1:] != (2, 3):
        raise ValueError(f"room outline must be [K, 2, 3] segments, got shape {outline.shape}")
    k = len(outline)
    lines = np.column_stack([np.full(k, 2), 2 * np.arange(k), 2 * np.arange(k) + 1]).ravel()
    return pv.PolyData(outline.reshape(-1, 3), lines=lines)


def disable_vtk_keys(plotter: Any) -> None:
    """Switch off the keys VTK and PyVista bind by themselves (``3`` anaglyph stereo, ``w`` / ``s``
    wireframe / surface, ``+`` / ``-`` point size, ``q`` / ``e`` quit, ``f`` fly to, ``p`` pick,
    ``v`` isometric, ``Up`` / ``Down`` zoom, ...). Mouse interaction is untouched."""
    iren = getattr(plotter, "iren", None)
    if iren is None:  # an off-screen plotter has no interactor
        return
    iren.clear_key_event_callbacks()              # PyVista's own key table
    iren.interactor.RemoveObservers("CharEvent")  # the interactor style's OnChar


class SceneView:
    """Builds and updates the scene's actors in ``plotter`` from ``scene`` and ``state``.

    ``scene`` is a :class:`~avgs_viewer.trained_scene.TrainedScene` (an ``avgs.SceneRenderer``;
    only its ``points``, ``alpha``, ``gaussians``, ``outline`` and ``bounds`` are read).
    ``max_points`` caps the drawn points (a fixed random subset, seed 0). ``legend`` shows the
    colour legend in the 3D view (for exported pictures), ``axes`` an axes marker in the lower
    left corner.
    """

    def __init__(self, plotter: pv.Plotter, scene: TrainedScene, state: ViewerState, max_points: int = 40_000,
                 legend: bool = False, axes: bool = True):
        self.plotter = plotter
        self.state = state
        points = np.asarray(scene.points, dtype=np.float64)  # [N, 3]
        n = len(points)
        self.n_points = n
        if n > max_points:
            self.drawn = np.sort(np.random.default_rng(0).choice(n, max_points, replace=False))
        else:
            self.drawn = np.arange(n)
        self.points = points[self.drawn]  # [n_drawn, 3]
        bounds = np.asarray(scene.bounds, dtype=np.float64)
        self.bounds = bounds
        extent = bounds[1] - bounds[0]
        self.handle_radius = 0.035 * float(max(extent[0], extent[1], 1e-6))

        # Colours per mode, [n_drawn, 3] uint8; the alpha projection is fitted once.
        self.projection = colors.AlphaProjection.fit(np.asarray(scene.alpha))
        self._alpha_rgb = self.projection(np.asarray(scene.alpha)[self.drawn])
        self._gauss_rgb = None
        if scene.gaussians is not None:
            means, rgb = colors.gaussian_arrays(scene.gaussians)
            self._gauss_rgb = colors.rgb_from_gaussians(self.points, np.asarray(means), np.asarray(rgb))
        self.labels = np.zeros(len(self.drawn), dtype=np.int8)  # vicinity labels of drawn points

        disable_vtk_keys(plotter)
        plotter.set_background([c / 255 for c in BACKGROUND])
        self._points_actor = None
        self.point_size = POINT_SIZE  # pixels (View's point-size control: set_point_size)
        self._cloud: pv.PolyData | None = None
        self._emptied = False  # the points actor is hidden because the slice holds no point
        self._fast_cloud: pv.PolyData | None = None  # what is drawn while anything moves
        self._multi_samples = int(plotter.render_window.GetMultiSamples())  # restored when nothing moves
        self._legend_shown = False
        self.legend_corner: str | None = None
        self.caption_corner: str | None = None
        self._caption = None
        self._legend_box = self._caption_box = None
        self.overlay = None
        self.board = OverlayBoard.of(plotter)  # where the axes, inset, colour bar, legend and caption go
        self.board.avoid = self._avoid
        self._refresh_points()
        if scene.outline is not None:
            plotter.add_mesh(_outline_mesh(scene.outline), color=(0.75, 0.75, 0.8), line_width=2,
                             lighting=False, name="outline", pickable=False, reset_camera=False)
        if axes:
            plotter.add_axes(interactive=False, line_width=2, viewport=AXES_VIEWPORT)
            self.board.put("axes", lambda: True, self._place_axes, relayout=False)
        self._build_handles()
        self._first_person = False
        self._place_handles()
        self.camera_home()
        self._camera_observer = None
        if getattr(plotter, "iren", None) is not None:  # a camera orbit / pan / zoom by the mouse
            self._camera_observer = plotter.iren.interactor.AddObserver(
                "StartInteractionEvent", self._camera_moved_by_mouse)
        self.board.relayout()  # the axes marker (and whatever else the plotter shows) placed
        if legend:
            self.show_legend()

        ev = state.events
        self._subscriptions = [
            (ev.listener, self._on_pose), (ev.source, self._on_pose), (ev.yaw, self._on_pose),
            (ev.colour_mode, self._on_points), (ev.slice_height, self._on_points),
            (ev.interacting, self._on_interacting),
        ]
        for event, cb in self._subscriptions:
            event.connect(cb)

    # ------------------------------------------------------------------ handles
    def _build_handles(self) -> None:
        """Spheres, facing arrow and their rings in a renderer of their own, drawn after the points
        with a cleared depth buffer: always visible, however many points lie in front."""
        from vtkmodules.vtkRenderingCore import vtkRenderer

        main = self.plotter.renderer
        overlay = vtkRenderer()
        overlay.SetLayer(1)
        overlay.SetInteractive(False)  # mouse events go to the main renderer (camera, picking)
        overlay.SetViewport(*main.GetViewport())
        overlay.SetActiveCamera(main.GetActiveCamera())
        ren_win = self.plotter.render_window
        ren_win.SetNumberOfLayers(max(2, ren_win.GetNumberOfLayers()))
        ren_win.AddRenderer(overlay)
        # Not an observer re-syncing the camera before each frame: the tiled rendering of a
        # scaled screenshot swaps cameras itself, and re-syncing inside it crashes VTK.
        self.overlay = overlay

        r = self.handle_radius
        length = 4.0 * r

        def add(mesh: pv.PolyData, colour, *, shaded: bool = True, ring: bool = False) -> pv.Actor:
            actor = pv.Actor(mapper=pv.DataSetMapper(mesh))
            prop = actor.prop
            prop.color = colour
            if ring:  # only the far side of a larger shell shows: a ring around the handle
                prop.culling = "front"
                prop.lighting = False
            elif shaded:
                prop.interpolation = "phong"
                prop.specular, prop.specular_power = 0.3, 20.0
            actor.SetPickable(False)
            overlay.AddActor(actor)
            return actor

        def sphere(radius: float) -> pv.PolyData:
            return pv.Sphere(radius=radius, theta_resolution=32, phi_resolution=32)

        def arrow(grow: float) -> pv.PolyData:
            # A facing arrow (or its ring, ``grow`` world units fatter all round) along +x from the centre.
            size = length + 2 * grow
            return pv.Arrow(start=(-grow, 0, 0), direction=(1, 0, 0), scale=size,
                            tip_length=(0.3 * length + 1.5 * grow) / size,
                            tip_radius=(0.14 * length + grow) / size, shaft_radius=(0.05 * length + grow) / size)

        self._listener_parts, self._source_parts, self._facing_parts = [], [], []
        for scale, colour in reversed(HALO):
            self._listener_parts.append(add(sphere(scale * r), colour, ring=True))
            self._source_parts.append(add(sphere(scale * r), colour, ring=True))
        self._facing_parts.append(add(arrow(0.12 * r), HALO[-1][1], ring=True))
        self._facing_parts.append(add(arrow(0.0), colors.LISTENER_COLOUR))
        self._listener_actor = add(sphere(r), colors.LISTENER_COLOUR)
        self._source_actor = add(sphere(r), colors.SOURCE_COLOUR)
        self._listener_parts.append(self._listener_actor)
        self._source_parts.append(self._source_actor)
        self._arrow_actor = self._facing_parts[-1]

    def handle_circles(self, margin: float = 4.0) -> list[tuple[np.ndarray, float]]:
        """Where the handles are on screen: (centre [2] display px, radius px incl. rings) for the
        listener, the source and the arrow's tip."""
        proj = self.projector()
        r = self.handle_radius * HALO[-1][0]
        out = []
        tip = self.state.listener + 4.0 * self.handle_radius * self.state.facing
        for centre, radius in ((self.state.listener, r), (self.state.source, r), (tip, 0.5 * r)):
            out.append((proj.to_display(centre), pixel_radius(proj, centre, radius) + margin))
        return out

    # ------------------------------------------------------------------ public
    def set_vicinity(self, listener_idx: np.ndarray, source_idx: np.ndarray) -> None:
        """New vicinity sets (indices into ``scene.points``) from the latest render."""
        full = colors.vicinity_labels(self.n_points, listener_idx, source_idx)
        labels = full[self.drawn]
        if np.array_equal(labels, self.labels):
            return
        self.labels = labels
        if self.state.colour_mode is ColourMode.VICINITY:
            self._refresh_points()
            self.plotter.render()

    def colours(self) -> np.ndarray:
        """[n_drawn, 3] uint8 colours of the drawn points in the current mode."""
        mode = self.state.colour_mode
        if mode is ColourMode.ALPHA:
            return self._alpha_rgb
        if mode is ColourMode.RGB and self._gauss_rgb is not None:
            return self._gauss_rgb
        return colors.vicinity_colours(self.labels)

    def legend_rows(self) -> list[tuple[str, tuple[int, int, int]]]:
        mode = self.state.colour_mode
        if mode is ColourMode.ALPHA:
            return self.projection.legend()
        if mode is ColourMode.RGB:
            return colors.rgb_legend()
        return colors.vicinity_legend()

    def _window_pixels(self) -> tuple[int, int]:
        w, h = self.plotter.render_window.GetSize()
        return max(int(w), 1), max(int(h), 1)

    def _avoid(self) -> list[tuple[np.ndarray, float]]:
        """The handles on screen (pixels), projected with the camera's aspect for the window now."""
        render_now = getattr(self.plotter, "render_now", self.plotter.render)
        render_now()  # the camera's aspect must be the window's before projecting
        return self.handle_circles()

    def relayout(self) -> Layout:
        """Place every overlay again (:mod:`avgs_viewer.overlay_layout`): after a resize, a handle
        moved under a legend, or an overlay shown or hidden."""
        return self.board.relayout()

    @property
    def overlay_notes(self) -> list[str]:
        """What the last layout shrank or left out, in words."""
        return [] if self.board.last is None else list(self.board.last.notes)

    def _place_axes(self, rect, _scale: float, _layout) -> None:
        widget = getattr(self.plotter.renderer, "axes_widget", None)
        if widget is not None and rect is not None:
            widget.SetViewport(*rect)

    def show_legend(self) -> None:
        """The colour mode's legend inside the 3D view, sized to the window, placed by the overlays'
        layout in a corner that covers neither handle (as ``legend_corner``)."""
        rows = [[text, [c / 255 for c in colour]] for text, colour in self.legend_rows()]
        rows += [["listener (arrow: facing)", list(colors.LISTENER_COLOUR)], ["source", list(colors.SOURCE_COLOUR)]]
        self.hide_legend()
        _, h = self._window_pixels()
        row = float(np.clip(0.028 * h, 11.0, 26.0))  # pixels per row
        longest = max(len(text) for text, _ in rows)
        size_px = (row * (1.8 + 0.55 * longest), row * len(rows) + 0.6 * row)
        self._legend_actor = legend = self.plotter.add_legend(rows, bcolor=[c / 255 for c in BACKGROUND], size=(0.2, 0.2),
                                         loc="upper right", name="legend", face="circle")
        self._legend_shown = True

        def place(rect, _scale, out) -> None:
            if rect is None:
                legend.SetVisibility(False)
                self.legend_corner = self._legend_box = None
                return
            legend.SetVisibility(True)
            legend.SetPosition(rect[0], rect[1])
            legend.SetPosition2(rect[2] - rect[0], rect[3] - rect[1])
            self.legend_corner, self._legend_box = out.corners["legend"], out.pixels["legend"]

        self.board.put("legend", lambda: size_px, place)

    def hide_legend(self) -> None:
        if self._legend_shown:
            self.board.remove("legend", relayout=False)
            self.plotter.remove_legend(render=False)
            self.board.relayout()
        self._legend_shown = False
        self.legend_corner = self._legend_box = None

    def caption_text(self) -> str:
        """Two lines naming the pose (x, y, z; yaw in degrees), as drawn by :meth:`show_caption`."""
        def xyz(p):
            return "(" + ", ".join(f"{v:.2f}" for v in p) + ")"
        return (f"listener {xyz(self.state.listener)}  yaw {self.state.yaw:.0f}\N{DEGREE SIGN}\n"
                f"source   {xyz(self.state.source)}")

    def show_caption(self) -> None:
        """The pose as a caption placed by the overlays' layout (``caption_corner``), sized to the window."""
        from vtkmodules.vtkRenderingCore import vtkTextActor

        self.hide_caption()
        text = self.caption_text()
        _, h = self._window_pixels()
        font = float(np.clip(0.02 * h, 10.0, 18.0))
        lines = text.split("\n")
        size_px = (0.62 * font * max(len(line) for line in lines) + font, 1.25 * font * len(lines) + 0.6 * font)
        actor = vtkTextActor()
        actor.SetInput(text)
        tp = actor.GetTextProperty()
        tp.SetFontFamilyToCourier()
        tp.SetColor(0.92, 0.92, 0.95)
        tp.SetBackgroundColor(*[c / 255 for c in BACKGROUND])
        tp.SetBackgroundOpacity(0.85)
        tp.SetVerticalJustificationToBottom()
        coord = actor.GetPositionCoordinate()
        coord.SetCoordinateSystemToNormalizedViewport()
        self.plotter.renderer.AddViewProp(actor)
        self._caption = actor

        def place(rect, scale, out) -> None:
            if rect is None:
                actor.SetVisibility(False)
                self.caption_corner = self._caption_box = None
                return
            f = max(int(font * scale), 6)
            box = out.pixels["caption"]
            tp.SetFontSize(f)
            actor.SetVisibility(True)
            coord.SetValue((box[0] + 0.5 * f) / out.width, (box[1] + 0.3 * f) / out.height)
            self.caption_corner, self._caption_box = out.corners["caption"], box

        self.board.put("caption", lambda: size_px, place)

    def hide_caption(self) -> None:
        if self._caption is not None:
            self.board.remove("caption", relayout=False)
            self.plotter.renderer.RemoveViewProp(self._caption)
            self.board.relayout()
        self._caption = None
        self.caption_corner = self._caption_box = None

    @property
    def visible(self) -> np.ndarray:
        """[n_drawn] bool: drawn points below the slice height."""
        return self.points[:, 2] <= self.state.slice_height

    # ------------------------------------------------------------------ camera
    def _look(self, position, focal, up=(0.0, 0.0, 1.0), view_angle: float = 30.0, fit: bool = True) -> None:
        self._set_first_person(False)
        camera = self.plotter.camera
        if self.overlay.GetActiveCamera() is not camera:  # PyVista gave the view a new camera
            self.overlay.SetActiveCamera(camera)
        camera.view_angle = view_angle
        self.plotter.camera_position = [tuple(map(float, position)), tuple(map(float, focal)), tuple(up)]
        if fit:
            lo, hi = self.bounds
            self.plotter.reset_camera(bounds=[lo[0], hi[0], lo[1], hi[1], lo[2], min(hi[2], self.state.slice_height)])
        else:
            self.plotter.renderer.ResetCameraClippingRange()

    def camera_home(self) -> None:
        """A three-quarter view from above one corner, fitted to the scene (as the paper's figures)."""
        lo, hi = self.bounds
        centre = 0.5 * (lo + hi)
        centre[2] = lo[2] + 0.35 * (hi[2] - lo[2])
        direction = np.array([-0.45, -1.0, 1.05])
        direction /= np.linalg.norm(direction)
        diag = float(np.linalg.norm(hi - lo)) or 1.0
        self._look(centre + 2.0 * diag * direction, centre)

    def camera_top(self) -> None:
        """Straight down onto the floor plan, +y up the screen."""
        lo, hi = self.bounds
        centre = 0.5 * (lo + hi)
        self._look(centre + np.array([0.0, 0.0, 2.0 * float(np.linalg.norm(hi - lo) or 1.0)]), centre, up=(0, 1, 0))

    def camera_front(self) -> None:
        """From the -y side, level, +z up: the room as an elevation."""
        lo, hi = self.bounds
        centre = 0.5 * (lo + hi)
        self._look(centre - np.array([0.0, 2.0 * float(np.linalg.norm(hi - lo) or 1.0), 0.0]), centre)

    def camera_listener(self) -> None:
        """What the listener faces: the camera at its head, looking along its yaw (wide angle).
        The listener's own sphere and arrow hide meanwhile; the camera follows the listener as
        it turns or is moved, until the camera is moved by the mouse or another preset."""
        self._look(self.state.listener, self.state.listener + self.state.facing, view_angle=70.0, fit=False)
        self._set_first_person(True)

    @property
    def first_person(self) -> bool:
        """True while the camera is the listener's (``camera_listener``)."""
        return self._first_person

    def _set_first_person(self, on: bool) -> None:
        self._first_person = on
        for actor in self._listener_parts + self._facing_parts:
            actor.SetVisibility(not on)

    def _camera_moved_by_mouse(self, *_args) -> None:
        if self._first_person:
            self._set_first_person(False)

    def projector(self) -> VtkProjector:
        return VtkProjector(self.plotter.renderer)

    def close(self) -> None:
        for event, cb in self._subscriptions:
            event.disconnect(cb)
        self._subscriptions = []
        for name in ("axes", "legend", "caption"):
            self.board.remove(name, relayout=False)
        self.board.avoid = lambda: ()
        if self._camera_observer is not None and getattr(self.plotter, "iren", None) is not None:
            self.plotter.iren.interactor.RemoveObserver(self._camera_observer)
            self._camera_observer = None
        if self.plotter.render_window is not None:  # a scene closed mid-drag leaves the next one antialiased
            self.plotter.render_window.SetMultiSamples(self._multi_samples)
        if self.overlay is not None:
            self.overlay.RemoveAllViewProps()
            if self.plotter.render_window is not None:
                self.plotter.render_window.RemoveRenderer(self.overlay)
            self.overlay = None

    # ------------------------------------------------------------------ updates
    def _refresh_points(self) -> None:
        visible = self.visible
        empty = not visible.any()  # the slice is below every point: nothing to draw
        if self._points_actor is not None and empty != self._emptied:
            self._points_actor.SetVisibility(not empty)  # only what emptying hid is shown again
            self._emptied = empty
        if empty:
            return
        cloud = pv.PolyData(self.points[visible])
        cloud.point_data["colours"] = self.colours()[visible]
        self._cloud = cloud
        self._fast_cloud = cloud
        if cloud.n_points > FAST_POINTS:
            pick = np.random.default_rng(0).permutation(cloud.n_points)[:FAST_POINTS]
            self._fast_cloud = pv.PolyData(cloud.points[pick])
            self._fast_cloud.point_data["colours"] = cloud.point_data["colours"][pick]
        shown = self._fast_cloud if self.state.interacting else cloud
        if self._points_actor is None:
            self._points_actor = self.plotter.add_mesh(
                shown, scalars="colours", rgb=True, style="points", point_size=self.point_size,
                render_points_as_spheres=not self.state.interacting, lighting=False,
                name="audio_points", pickable=False, reset_camera=False)
        else:
            self._points_actor.mapper.SetInputData(shown)
        if self._legend_shown:
            self.show_legend()

    def _place_handles(self) -> None:
        listener, source = tuple(self.state.listener), tuple(self.state.source)
        for actor in self._listener_parts:
            actor.position = listener
        for actor in self._facing_parts:
            actor.position = listener
            actor.orientation = (0.0, 0.0, self.state.yaw)
        for actor in self._source_parts:
            actor.position = source

    def _on_pose(self, _value: Any) -> None:
        self._place_handles()
        if self._first_person:
            self.camera_listener()
        self.plotter.render()

    def _on_points(self, _value: Any) -> None:
        self._refresh_points()
        self.plotter.render()

    def _on_interacting(self, moving: bool) -> None:
        self.set_fast(moving)

    def set_fast(self, fast: bool) -> None:
        """Cheap drawing while anything moves (FAST_POINTS of the points, plain squares, no
        multisampling); all points as shaded spheres, antialiased, when idle."""
        self.plotter.render_window.SetMultiSamples(0 if fast else self._multi_samples)
        if self._points_actor is None:
            return
        if self._cloud is not None:
            self._points_actor.mapper.SetInputData(self._fast_cloud if fast else self._cloud)
        prop = self._points_actor.prop
        prop.render_points_as_spheres = not fast
        prop.point_size = max(self.point_size - 2, 1.0) if fast else self.point_size
        self.plotter.render()

    def set_point_size(self, size: float) -> None:
        """The audio points' size on screen, pixels."""
        self.point_size = float(size)
        self.set_fast(self.state.interacting)

    def show_sources(self, positions) -> None:
        """A yellow sphere at each of ``positions`` [K, 3]: the sources other than the selected one
        (which is the ringed handle a drag moves; :mod:`avgs_viewer.sources`)."""
        if self.overlay is None:
            return
        for actor in getattr(self, "_other_sources", []):
            self.overlay.RemoveActor(actor)
        self._other_sources = []
        for p in np.asarray(positions, dtype=np.float64).reshape(-1, 3):
            actor = pv.Actor(mapper=pv.DataSetMapper(pv.Sphere(radius=self.handle_radius, center=tuple(p),
                                                               theta_resolution=24, phi_resolution=24)))
            actor.prop.color = colors.SOURCE_COLOUR
            actor.prop.interpolation = "phong"
            actor.SetPickable(False)
            self.overlay.AddActor(actor)
            self._other_sources.append(actor)
        self.plotter.render()
