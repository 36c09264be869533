"""Dragging the listener and the source with the mouse: press, move, release. No Qt, no VTK.

The view hands each mouse event's display position (VTK convention: pixels, origin at
the bottom left) to a :class:`DragController`. A press near a handle's projection grabs
it; each move casts the mouse ray onto the horizontal plane at the handle's height
(so the handle stays under the cursor and keeps its height) and writes the new position
into the :class:`~avgs_viewer.state.ViewerState`, which clamps it to the scene bounds.
A press on a handle the state keeps fixed (the source of a one-source scene) is taken, so
the camera does not orbit instead, but moves nothing: the state says why (``refused``).
The camera is reached only through a :class:`Projector`, so the logic is tested with a
plain orthographic camera and used with VTK's in the window. The camera does not move during a
handle drag, so the press fits the map from display pixels to the handle's plane once
(:class:`~avgs_viewer.pointer.PlaneMap`, from four of the camera's rays) and each move is a
3x3 product: no VTK call between a mouse event and its pose.
"""

from __future__ import annotations

from typing import Callable, Protocol

import numpy as np

from .state import Pose, ViewerState

HANDLES = ("listener", "source")

PoseAt = Callable[[float, float], Pose | None]
"""Display pixel (x, y) -> the pose a drag's move there makes (None: off the plane), from
:meth:`DragController.follow_map`; the window's mouse (:mod:`avgs_viewer.mouse`) hands its poses to
``LiveAudio.request``."""


class Projector(Protocol):
    """A camera as seen by the drag logic (display pixels, origin bottom left)."""

    def to_display(self, world: np.ndarray) -> np.ndarray:
        """[3] world point -> [2] display pixel (x, y)."""

    def ray(self, x: float, y: float) -> tuple[np.ndarray, np.ndarray]:
        """Display pixel -> (origin [3], unit direction [3]) of the ray through it."""


def ray_plane_z(origin: np.ndarray, direction: np.ndarray, z: float) -> np.ndarray | None:
    """Where the ray meets the horizontal plane at height ``z``; None if it never does."""
    dz = float(direction[2])
    if abs(dz) < 1e-9:
        return None
    t = (z - float(origin[2])) / dz
    if t < 0:
        return None
    return np.asarray(origin, dtype=np.float64) + t * np.asarray(direction, dtype=np.float64)


def pixel_radius(projector: Projector, centre: np.ndarray, radius: float) -> float:
    """How many display pixels a sphere of world ``radius`` at ``centre`` spans."""
    c = projector.to_display(centre)
    _, d = projector.ray(float(c[0]), float(c[1]))
    # A unit vector perpendicular to the view ray through the centre.
    helper = np.array([0.0, 0.0, 1.0]) if abs(d[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    perp = np.cross(d, helper)
    perp /= np.linalg.norm(perp)
    edge = projector.to_display(np.asarray(centre, dtype=np.float64) + radius * perp)
    return float(np.linalg.norm(edge - c))


def pick_handle(projector: Projector, handles: dict[str, np.ndarray], x: float, y: float,
                radius: float, min_pixels: float = 10.0) -> str | None:
    """The handle whose sphere (world ``radius``, at least ``min_pixels``) covers (x, y).

    When both cover the pixel, the one whose centre is nearer on screen wins.
    """
    best, best_d = None, np.inf
    for name, centre in handles.items():
        d = float(np.linalg.norm(projector.to_display(centre) - np.array([x, y])))
        reach = max(pixel_radius(projector, centre, radius), min_pixels)
        if d <= reach and d < best_d:
            best, best_d = name, d
    return best


class DragController:
    """Press -> move -> release over the listener and source handles of a ``ViewerState``.

    ``projector`` returns the current camera (it may change between drags).
    ``handle_radius`` is the spheres' world radius, used for picking.
    """

    def __init__(self, state: ViewerState, projector: Callable[[], Projector], handle_radius: float,
                 min_pick_pixels: float = 10.0):
        self.state = state
        self._projector = projector
        self.handle_radius = float(handle_radius)
        self.min_pick_pixels = float(min_pick_pixels)
        self.dragging: str | None = None
        self.held: str | None = None
        "A fixed handle pressed on: the press, its moves and its release are taken, and move nothing."
        self._offset = np.zeros(3)  # handle - hit point at press, so the handle does not jump
        self._height = 0.0
        self._plane = None  # PlaneMap of the drag in progress: display (x, y) -> (x, y) on its plane

    def _position(self, name: str) -> np.ndarray:
        return self.state.listener if name == "listener" else self.state.source

    def press(self, x: float, y: float) -> bool:
        """Grab the handle under (x, y); True when one was grabbed (the event is consumed)."""
        proj = self._projector()
        handles = {name: self._position(name) for name in HANDLES}
        name = pick_handle(proj, handles, x, y, self.handle_radius, self.min_pick_pixels)
        if name is None:
            return False
        if name == "source" and not self.state.source_movable:
            self.held = name
            self.state.refuse_source_move()
            return True
        self._height = float(handles[name][2])
        hit = ray_plane_z(*proj.ray(x, y), self._height)
        if hit is None:  # looking exactly along the plane: nothing sensible to drag
            return False
        self._offset = handles[name] - hit
        self._offset[2] = 0.0
        self._plane = self._fit_plane(proj, x, y, self._height)
        self.dragging = name
        self.state.set_interacting(True)
        return True

    def move(self, x: float, y: float) -> bool:
        """Move the grabbed handle under (x, y); True when a handle is being dragged."""
        if self.held is not None:
            return True
        if self.dragging is None:
            return False
        if self._plane is not None:
            flat = self._plane(x, y)
            hit = None if flat is None else np.array([flat[0], flat[1], self._height])
        else:  # the press could not fit a plane map
            hit = ray_plane_z(*self._projector().ray(x, y), self._height)
        if hit is None:
            return True
        target = hit + self._offset
        target[2] = self._height
        if self.dragging == "listener":
            self.state.set_listener(target)
        else:
            self.state.set_source(target)
        return True

    @staticmethod
    def _fit_plane(proj: Projector, x: float, y: float, height: float, span: float = 40.0):
        """The :class:`~avgs_viewer.pointer.PlaneMap` of ``proj`` onto the plane at ``height``, fitted
        on four display points around (x, y); None where a ray misses the plane."""
        from .pointer import PlaneMap

        display = np.array([[x - span, y - span], [x + span, y - span], [x + span, y + span], [x - span, y + span]])
        hits = [ray_plane_z(*proj.ray(float(a), float(b)), height) for a, b in display]
        if any(h is None for h in hits):
            return None
        try:
            return PlaneMap.fit(display, np.array([h[:2] for h in hits]))
        except ValueError:
            return None

    def follow_map(self, x: float, y: float) -> PoseAt | None:
        """For the drag in progress: display (x, y) -> the pose a move there makes, computed
        without the camera or the state changing (any thread; see :mod:`avgs_viewer.pointer`).
        None when nothing is dragged or the camera looks along the plane."""
        plane = self._plane
        if self.dragging is None or plane is None:
            return None
        name, offset, state, height = self.dragging, self._offset.copy(), self.state, self._height

        def pose_at(px: float, py: float) -> Pose | None:
            hit = plane(px, py)
            if hit is None:
                return None
            target = np.array([hit[0] + offset[0], hit[1] + offset[1], height])
            return state.pose_with(listener=target) if name == "listener" else state.pose_with(source=target)

        return pose_at

    def release(self, x: float, y: float) -> bool:
        """Drop the handle after a last move to (x, y); True when one was being dragged."""
        if self.held is not None:
            self.held = None
            return True
        if self.dragging is None:
            return False
        self.move(x, y)
        self.dragging = None
        self._plane = None
        self.state.set_interacting(False)
        return True

