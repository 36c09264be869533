"""The scene's PyVista actors, drawn into any plotter and kept in step with a ViewerState.

The same :class:`SceneView` draws into the window's ``pyvistaqt.QtInteractor`` and into a
plain ``pv.Plotter(off_screen=True)`` (EGL, no X server) for the command-line screenshot
and the rendering tests. It shows G_a's points (a deterministic subset when there are
many: Mesa under Xvfb manages ~13 FPS at 50k points) coloured by the state's colour mode,
hides those above the slice height, and draws the room outline, a blue listener sphere
with a facing arrow and a yellow source sphere. While the camera or a handle moves the
points are drawn as plain squares; when idle, as shaded spheres.

No Qt here; :class:`VtkProjector` gives the drag logic (``avgs_viewer.drag``) the camera.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pyvista as pv

from . import colors
from .state import ColourMode, ViewerState

BACKGROUND = (22, 24, 30)
POINT_SIZE = 6.0


class VtkProjector:
    """The :class:`avgs_viewer.drag.Projector` of a VTK renderer's current camera."""

    def __init__(self, renderer: Any):
        self.renderer = renderer

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


class SceneView:
    """Builds and updates the scene's actors in ``plotter`` from ``scene`` and ``state``.

    ``scene`` is an ``avgs.SceneRenderer`` (only its public ``points``, ``alpha``,
    ``gaussians``, ``outline`` and ``bounds`` are read). ``max_points`` caps the drawn
    points (a fixed random subset, seed 0).
    """

    def __init__(self, plotter: pv.Plotter, scene: Any, state: ViewerState, max_points: int = 40_000,
                 legend: bool = False):
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

        plotter.set_background([c / 255 for c in BACKGROUND])
        self._points_actor = None
        self._cloud: pv.PolyData | None = None
        self._legend_shown = False
        self._refresh_points()
        if scene.outline is not None:
            plotter.add_mesh(_outline_mesh(scene.outline), color=(0.75, 0.75, 0.8), line_width=2,
                             lighting=False, name="outline", pickable=False, reset_camera=False)
        r = self.handle_radius
        self._listener_actor = plotter.add_mesh(pv.Sphere(radius=r, theta_resolution=24, phi_resolution=24),
                                                color=colors.LISTENER_COLOUR, smooth_shading=True,
                                                name="listener", reset_camera=False)
        self._arrow_actor = plotter.add_mesh(
            pv.Arrow(start=(0, 0, 0), direction=(1, 0, 0), scale=4.0 * r, tip_length=0.3,
                     tip_radius=0.14, shaft_radius=0.05),
            color=colors.LISTENER_COLOUR, name="facing", reset_camera=False)
        self._source_actor = plotter.add_mesh(pv.Sphere(radius=r, theta_resolution=24, phi_resolution=24),
                                              color=colors.SOURCE_COLOUR, smooth_shading=True,
                                              name="source", reset_camera=False)
        if legend:
            self.show_legend()
        self._place_handles()
        self.camera_home()

        ev = state.events
        self._subscriptions = [
            (ev.listener, self._on_pose), (ev.source, self._on_pose), (ev.yaw, self._on_pose),
            (ev.colour_mode, self._on_points), (ev.slice_height, self._on_points),
            (ev.interacting, self._on_interacting),
        ]
        for event, cb in self._subscriptions:
            event.connect(cb)

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

    def show_legend(self) -> None:
        """A legend of the colour mode inside the 3D view (used for exported pictures)."""
        rows = [[text, [c / 255 for c in colour]] for text, colour in self.legend_rows()]
        rows += [["listener", list(colors.LISTENER_COLOUR)], ["source", list(colors.SOURCE_COLOUR)]]
        # VTK fits the text to the box: size the box by the longest label so no row is cut.
        longest = max(len(text) for text, _ in rows)
        size = (min(0.6, 0.05 + 0.0125 * longest), min(0.4, 0.045 * len(rows)))
        legend = self.plotter.add_legend(rows, bcolor=[c / 255 for c in BACKGROUND], size=size,
                                         loc="upper right", name="legend", face="circle")
        legend.SetPosition(0.98 - size[0], 0.98 - size[1])  # flush with the top right corner
        legend.SetPosition2(*size)
        self._legend_shown = True

    @property
    def visible(self) -> np.ndarray:
        """[n_drawn] bool: drawn points below the slice height."""
        return self.points[:, 2] <= self.state.slice_height

    def camera_home(self) -> None:
        """A three-quarter view from above one corner, fitted to the scene (as the paper's figures)."""
        lo, hi = self.bounds
        centre = 0.5 * (lo + hi)
        centre[2] = lo[2] + 0.35 * (hi[2] - lo[2])
        direction = np.array([-0.45, -1.0, 1.05])
        direction /= np.linalg.norm(direction)
        diag = float(np.linalg.norm(hi - lo)) or 1.0
        self.plotter.camera_position = [tuple(centre + 2.0 * diag * direction), tuple(centre), (0, 0, 1)]
        self.plotter.reset_camera(bounds=[lo[0], hi[0], lo[1], hi[1], lo[2], min(hi[2], self.state.slice_height)])

    def projector(self) -> VtkProjector:
        return VtkProjector(self.plotter.renderer)

    def close(self) -> None:
        for event, cb in self._subscriptions:
            event.disconnect(cb)
        self._subscriptions = []

    # ------------------------------------------------------------------ updates
    def _refresh_points(self) -> None:
        visible = self.visible
        cloud = pv.PolyData(self.points[visible])
        cloud.point_data["colours"] = self.colours()[visible]
        if self._points_actor is None:
            self._points_actor = self.plotter.add_mesh(
                cloud, scalars="colours", rgb=True, style="points", point_size=POINT_SIZE,
                render_points_as_spheres=not self.state.interacting, lighting=False,
                name="audio_points", pickable=False, reset_camera=False)
        else:
            self._points_actor.mapper.SetInputData(cloud)
        self._cloud = cloud
        if self._legend_shown:
            self.show_legend()

    def _place_handles(self) -> None:
        listener, source = self.state.listener, self.state.source
        self._listener_actor.position = tuple(listener)
        self._arrow_actor.position = tuple(listener)
        self._arrow_actor.orientation = (0.0, 0.0, self.state.yaw)
        self._source_actor.position = tuple(source)

    def _on_pose(self, _value: Any) -> None:
        self._place_handles()
        self.plotter.render()

    def _on_points(self, _value: Any) -> None:
        self._refresh_points()
        self.plotter.render()

    def _on_interacting(self, moving: bool) -> None:
        self.set_fast(moving)

    def set_fast(self, fast: bool) -> None:
        """Cheap point style (plain squares) while anything moves; shaded spheres when idle."""
        prop = self._points_actor.prop
        prop.render_points_as_spheres = not fast
        prop.point_size = POINT_SIZE - 2 if fast else POINT_SIZE
        self.plotter.render()
