"""The viewer's state: plain Python with observer callbacks, no Qt.

The Qt window and the PyVista scene view are handed a :class:`ViewerState` and
subscribe to its events (napari's habit: the model knows nothing of its views). Every
setter validates, clamps to the scene and emits only when the value really changed, so
a widget that mirrors the state can set it back without an endless loop.

Coordinates are world coordinates, yaw is degrees counter-clockwise from +x
(ARCHITECTURE.md). A drag moves the listener at its own height, the source anywhere;
both stay inside the room's floor plan and the scene's box (:func:`avgs.data.floor_plan.keep_inside`,
the clamp ``avgs render`` uses too), or the box alone when the checkpoint has no outline; a
source put in a wall (within :data:`WALL_NOTE` of one) is noted (the ``wall`` event). A scene trained with one source position keeps its source
where it is (``source_fixed``): a move is refused with the reason (the ``refused`` event).
"""

from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import Any, Callable, Generic, TypeVar

import numpy as np

from .outline import Footprint, keep_inside

WALL_NOTE = 0.1
"A source nearer a wall than this (world units: metres) is said to be in it."


class ColourMode(str, enum.Enum):
    """What the audio points' colours show."""

    ALPHA = "alpha"
    "A fixed 3-component projection of the learned audio-guidance parameters."
    RGB = "rgb"
    "The colour of the nearest Gaussian of G (only when the checkpoint carries G)."
    VICINITY = "vicinity"
    "Membership of the listener's and the source's vicinity sets."


T = TypeVar("T")
"The value an :class:`Event` carries."


class Event(Generic[T]):
    """A list of callbacks called with one value, in connection order."""

    def __init__(self, name: str):
        self.name = name
        self._callbacks: list[Callable[[T], None]] = []

    def connect(self, callback: Callable[[T], None]) -> Callable[[T], None]:
        if callback not in self._callbacks:
            self._callbacks.append(callback)
        return callback

    def disconnect(self, callback: Callable[[T], None]) -> None:
        if callback in self._callbacks:
            self._callbacks.remove(callback)

    def emit(self, value: T) -> None:
        for callback in list(self._callbacks):
            callback(value)


class ViewerEvents:
    """One :class:`Event` per state field, plus ``pose`` for any listener/yaw/source change."""

    NAMES = ("listener", "yaw", "source", "pose", "colour_mode", "slice_height",
             "volume", "playing", "interacting", "clamped", "refused", "wall")
    """``clamped`` carries a message naming a position that was moved back inside the scene;
    ``refused`` the reason a move was refused (the source of a one-source scene); ``wall`` a note
    that the source is in a wall (a clamp that put it there says so in ``clamped`` instead)."""

    listener: Event[np.ndarray]  # [3] world
    yaw: Event[float]  # degrees
    source: Event[np.ndarray]  # [3] world
    pose: Event[Pose]  # after any of the three: what the audio path renders (avgs_viewer.worker)
    colour_mode: Event[ColourMode]
    slice_height: Event[float]
    volume: Event[float]
    playing: Event[bool]
    interacting: Event[bool]
    clamped: Event[str]
    refused: Event[str]
    wall: Event[str]

    def __init__(self):
        for name in self.NAMES:
            setattr(self, name, Event(name))


@dataclass(frozen=True)
class Pose:
    """What one binaural render depends on (world coordinates, yaw in degrees)."""

    listener: tuple[float, float, float]
    yaw: float
    source: tuple[float, float, float]


def _vec3(value: Any, what: str) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64).reshape(-1)
    if arr.shape != (3,) or not np.all(np.isfinite(arr)):
        raise ValueError(f"{what} must be 3 finite numbers (x, y, z), got {value!r}")
    return arr


class ViewerState:
    """Listener, yaw, source, colour mode, slice height, volume and play state.

    ``bounds`` [2, 3] world (min corner, max corner) constrains both positions; with the
    room's ``outline`` ([K, 2, 3] world segments, ``SceneRenderer.outline``) they are kept
    inside its floor plan and height instead (:class:`~avgs_viewer.outline.Footprint`).
    ``source_fixed``: why the source cannot move (a scene trained with one source position),
    or None when it can; a refused move leaves it where it is and emits ``refused``.
    """

    def __init__(self, bounds: np.ndarray, source: Any, listener: Any = None, yaw: float = 0.0,
                 colour_mode: ColourMode = ColourMode.VICINITY, has_rgb: bool = False, outline: Any = None,
                 source_fixed: str | None = None):
        bounds = np.asarray(bounds, dtype=np.float64)
        if bounds.shape != (2, 3) or not np.all(np.isfinite(bounds)) or np.any(bounds[1] < bounds[0]):
            raise ValueError(f"bounds must be [2, 3] finite (min, max) corners with max >= min, got {bounds!r}")
        self.bounds = bounds  # [2, 3]
        self.footprint = Footprint.from_outline(outline, bounds)
        self.region = "room" if self.footprint.from_outline else "scene"
        "What positions are kept inside, in words: the room (its outline) or the scene (its box)."
        self.has_rgb = bool(has_rgb)
        self.source_fixed = source_fixed or None
        "Why the source cannot move, in words; None when it can."
        self.events = ViewerEvents()
        self._source = self._clamp(_vec3(source, "source"))
        if listener is None:
            listener = self.default_listener()
        self._listener = self._clamp(_vec3(listener, "listener"))
        self._yaw = self._wrap(yaw)
        self._colour_mode = self._check_mode(colour_mode)
        self._slice_height = self.default_slice_height()
        self._volume = 0.8
        self._playing = True
        self._interacting = False

    # ------------------------------------------------------------------ defaults
    def default_listener(self) -> np.ndarray:
        """The source mirrored through the room's centre in xy, at the source's height."""
        centre = self.bounds.mean(axis=0)
        mirrored = 2.0 * centre - self._source
        mirrored[2] = self._source[2]
        return self._clamp(mirrored)

    def default_slice_height(self) -> float:
        """Halfway between the higher of listener and source and the ceiling."""
        top = max(self._listener[2], self._source[2])
        return float(top + 0.5 * (self.bounds[1, 2] - top))

    # ------------------------------------------------------------------ helpers
    def _clamp(self, xyz: np.ndarray, what: str | None = None) -> np.ndarray:
        """``xyz`` moved to the nearest place inside the room's floor plan and height (the
        scene's box without an outline); a move by the user (``what`` given) that had to be
        clamped emits ``clamped`` with a message naming both positions."""
        inside = keep_inside(xyz, self.footprint, self.bounds)
        wall = self.wall_note(inside) if what == "source" else ""
        if what is not None and not np.array_equal(inside, xyz):
            self.events.clamped.emit(
                f"{what} kept inside the {self.region}: ({', '.join(f'{v:.2f}' for v in xyz)}) -> "
                f"({', '.join(f'{v:.2f}' for v in inside)})" + (f"; {wall}" if wall else ""))
        elif wall:
            self.events.wall.emit(wall)
        return inside

    def wall_note(self, xyz) -> str:
        """A note when ``xyz`` lies in a wall of the room (within :data:`WALL_NOTE`), else ''."""
        d = self.footprint.wall_distance(np.asarray(xyz)[:2])
        if d >= WALL_NOTE:
            return ""
        return (f"the source is in or against a wall ({d:.2f} m from its face): the model has heard no source there; "
                f"move it at least {WALL_NOTE:.2f} m into the room")

    @staticmethod
    def _wrap(yaw: float) -> float:
        yaw = float(yaw)
        if not np.isfinite(yaw):
            raise ValueError(f"yaw must be a finite number of degrees, got {yaw!r}")
        return yaw % 360.0

    def _check_mode(self, mode: Any) -> ColourMode:
        try:
            mode = ColourMode(mode)
        except ValueError:
            choices = ", ".join(m.value for m in ColourMode)
            raise ValueError(f"colour mode must be one of {choices}, got {mode!r}") from None
        if mode is ColourMode.RGB and not self.has_rgb:
            raise ValueError("colour mode 'rgb' needs the Gaussians G, which this checkpoint does not carry")
        return mode

    def _emit_pose(self) -> None:
        self.events.pose.emit(self.pose)

    # ------------------------------------------------------------------ pose
    @property
    def listener(self) -> np.ndarray:
        return self._listener.copy()

    def _placed_listener(self, xyz: Any, keep_height: bool, what: str | None = None) -> np.ndarray:
        """Where the listener goes for ``xyz``: at its own height if ``keep_height``, inside the room
        (``what`` given: a clamp is announced, see :meth:`_clamp`)."""
        xyz = _vec3(xyz, "listener").copy()
        if keep_height:
            xyz[2] = self._listener[2]
        return self._clamp(xyz, what)

    def set_listener(self, xyz: Any, keep_height: bool = True) -> None:
        """Move the listener in xy, kept at its own height (unless ``keep_height`` is False,
        as for a typed position) and inside the room."""
        xyz = self._placed_listener(xyz, keep_height, "listener")
        if np.array_equal(xyz, self._listener):
            return
        self._listener = xyz
        self.events.listener.emit(self.listener)
        self._emit_pose()

    @property
    def source(self) -> np.ndarray:
        return self._source.copy()

    @property
    def source_movable(self) -> bool:
        return self.source_fixed is None

    def refuse_source_move(self) -> None:
        """Say why the source stays where it is (``refused``), as an attempt to move it does."""
        if self.source_fixed is not None:
            self.events.refused.emit(self.source_fixed)

    def set_source(self, xyz: Any) -> None:
        """Move the source anywhere inside the room; refused (``refused`` says why) when it is fixed."""
        if self.source_fixed is not None:
            _vec3(xyz, "source")  # a bad value is still an error
            self.refuse_source_move()
            return
        xyz = self._clamp(_vec3(xyz, "source"), "source")
        if np.array_equal(xyz, self._source):
            return
        self._source = xyz
        self.events.source.emit(self.source)
        self._emit_pose()

    @property
    def yaw(self) -> float:
        return self._yaw

    def set_yaw(self, degrees: float) -> None:
        yaw = self._wrap(degrees)
        if yaw == self._yaw:
            return
        self._yaw = yaw
        self.events.yaw.emit(yaw)
        self._emit_pose()

    def turn(self, degrees: float) -> None:
        """Turn the listener by ``degrees`` (positive = counter-clockwise, to the left)."""
        self.set_yaw(self._yaw + float(degrees))

    @property
    def facing(self) -> np.ndarray:
        """[3] unit facing direction in the xy plane."""
        rad = np.deg2rad(self._yaw)
        return np.array([np.cos(rad), np.sin(rad), 0.0])

    @property
    def pose(self) -> Pose:
        return Pose(tuple(map(float, self._listener)), self._yaw, tuple(map(float, self._source)))

    def pose_with(self, listener: Any = None, source: Any = None) -> Pose:
        """The pose that :meth:`set_listener` (keeping the listener's height) or :meth:`set_source`
        would make, without making it: nothing changes and nothing is emitted (any thread)."""
        lis, src, yaw = self._listener, self._source, self._yaw
        if listener is not None:
            lis = self._placed_listener(listener, keep_height=True)
        if source is not None and self.source_fixed is None:
            src = self._clamp(_vec3(source, "source"))
        return Pose(tuple(map(float, lis)), yaw, tuple(map(float, src)))

    # ------------------------------------------------------------------ display
    @property
    def colour_mode(self) -> ColourMode:
        return self._colour_mode

    def set_colour_mode(self, mode: Any) -> None:
        self._change("colour_mode", self._check_mode(mode))

    @property
    def slice_height(self) -> float:
        """Points above this height (world z) are hidden: the ceiling is sliced off."""
        return self._slice_height

    def set_slice_height(self, z: float) -> None:
        self._change("slice_height", float(np.clip(float(z), self.bounds[0, 2], self.bounds[1, 2])))

    @property
    def interacting(self) -> bool:
        """True while the camera or a handle is being dragged (views draw cheaply)."""
        return self._interacting

    def set_interacting(self, flag: bool) -> None:
        self._change("interacting", bool(flag))

    # ------------------------------------------------------------------ playback
    @property
    def volume(self) -> float:
        return self._volume

    def set_volume(self, volume: float) -> None:
        self._change("volume", float(np.clip(float(volume), 0.0, 1.0)))

    @property
    def playing(self) -> bool:
        return self._playing

    def set_playing(self, flag: bool) -> None:
        self._change("playing", bool(flag))

    def _change(self, name: str, value: Any) -> bool:
        """Set ``self._<name>`` and emit ``events.<name>`` only when the value changes."""
        if value == getattr(self, f"_{name}"):
            return False
        setattr(self, f"_{name}", value)
        getattr(self.events, name).emit(value)
        return True

    def toggle_playing(self) -> None:
        self.set_playing(not self._playing)
