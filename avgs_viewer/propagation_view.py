"""The propagation map on the floor, and the listener's view of G in a corner of the 3D view.

:class:`PropagationView` draws :mod:`avgs.render.propagation_map` (level or interaural level
difference over a grid of listener positions, for the current source and yaw) as a
coloured plane on the floor of any PyVista plotter, with a colour bar titled with its unit.
The map (the fast one: :class:`avgs.render.propagation_map.FastMap`) is computed on its own daemon
thread, with :data:`MAP_WORKERS` threads under it, coarse to fine, and drawn as it fills in;
a new source, yaw or listener height cancels the computation in progress (newest request
wins). Listener moves in the plane do not change the map. Before each small chunk of
cells (32, some 20 ms of one core) the threads wait while the audio render worker is busy
(``audio_busy``), so the map does not hold up what the user hears.

:class:`ListenerInset` shows G rendered from the listener's pose
(:class:`avgs.render.listener_view.ListenerView`) as an image in the lower right corner of the 3D
view, re-rendered on a background thread once the listener has stopped moving; it is part
of the VTK scene, so screenshots include it. Only for checkpoints saved with G.

No Qt here: results come back on the computing thread and are handed to ``post``, which
must run a callable on the thread that owns the plotter (the window passes
:func:`qt_poster`; headless code uses the default, which runs it at once).
"""

from __future__ import annotations

import enum
import threading
from typing import Any, Callable

import numpy as np
import pyvista as pv

from .overlay_layout import OverlayBoard, text_px
from .state import ViewerState
from .trained_scene import TrainedScene

MAP_BATCH = 128
"Cells per partial update of the map on screen."

MAP_WORKERS = 2
"""Threads computing the map (``workers`` of :func:`avgs.render.propagation_map.propagation_map`): two cores.
Each waits for the audio before every chunk of cells (``audio_busy``)."""

MAP_OPACITY = 0.85
INSET_CAPTION = "listener's view (G)"
TITLES = {"level": "Level (dB)", "ild": "ILD (dB, left - right)"}
CMAPS = {"level": "inferno", "ild": "RdBu_r"}


def bar_title(kind: str) -> str:
    """The colour bar's title (and its key in ``plotter.scalar_bars``): the unit, with a blank
    line below it so that the top label does not overlap it."""
    return TITLES[kind] + "\n"


class MapMode(str, enum.Enum):
    """What the floor shows."""

    OFF = "off"
    LEVEL = "level"
    ILD = "ild"


MODE_NAMES = {MapMode.OFF: "Off", MapMode.LEVEL: "Level (dB)", MapMode.ILD: "ILD (dB)"}


def qt_poster(parent=None) -> Callable[[Callable[[], None]], None]:
    """A ``post`` that runs callables on the Qt thread owning ``parent`` (a queued signal)."""
    from PySide6 import QtCore

    class _Poster(QtCore.QObject):
        call = QtCore.Signal(object)

        @QtCore.Slot(object)
        def run(self, fn) -> None:
            fn()

    poster = _Poster(parent)  # lives on parent's thread: the queued slot runs there
    poster.call.connect(poster.run, QtCore.Qt.ConnectionType.QueuedConnection)
    return poster.call.emit


def _run_now(fn: Callable[[], None]) -> None:
    fn()


def floor_height(scene: TrainedScene) -> float:
    """z of the floor: the room outline's lowest point, else the scene box's floor."""
    outline = scene.outline
    if outline is not None and len(outline):
        return float(np.asarray(outline)[..., 2].min())
    return float(np.asarray(scene.bounds)[0, 2])


def colour_limits(values: np.ndarray, kind: str) -> tuple[float, float]:
    """The colour bar's range: the computed cells' range; symmetric about 0 for the ILD."""
    v = values[np.isfinite(values)]
    if v.size == 0:
        return (-1.0, 1.0) if kind == "ild" else (-1.0, 0.0)
    if kind == "ild":
        top = max(float(np.abs(v).max()), 0.5)
        return -top, top
    lo, hi = float(v.min()), float(v.max())
    return (lo, hi) if hi - lo > 0.5 else (hi - 0.5, hi)


class MapWorker:
    """One daemon thread computing maps, newest request wins; the one running is cancelled.

    ``compute(request, cancelled)`` is a generator of partial results; ``on_partial(seq,
    request, result)`` and ``on_error(seq, request, exc)`` run on the worker thread.
    ``gate()`` is called before every chunk; while it returns False the thread waits.
    """

    def __init__(self, compute, on_partial, on_error=None, gate: Callable[[], bool] | None = None,
                 name: str = "avgs-map"):
        self._compute, self._on_partial, self._on_error = compute, on_partial, on_error
        self._gate = gate
        self._cond = threading.Condition()
        self._seq = 0  # the newest submission
        self._pending: tuple[int, Any] | None = None
        self._running: int | None = None
        self._closed = False
        self._thread = threading.Thread(target=self._loop, name=name, daemon=True)
        self._thread.start()

    def submit(self, request: Any) -> int:
        with self._cond:
            self._seq += 1
            self._pending = (self._seq, request)
            self._cond.notify_all()
            return self._seq

    def cancel(self) -> None:
        """Drop what is queued and stop what runs."""
        with self._cond:
            self._seq += 1
            self._pending = None
            self._cond.notify_all()

    def idle(self) -> bool:
        with self._cond:
            return self._pending is None and self._running is None

    def wait_idle(self, timeout: float = 30.0) -> bool:
        with self._cond:
            return self._cond.wait_for(lambda: self._pending is None and self._running is None, timeout)

    def close(self, timeout: float = 10.0) -> None:
        with self._cond:
            self._closed = True
            self._seq += 1
            self._pending = None
            self._cond.notify_all()
        if threading.current_thread() is not self._thread:
            self._thread.join(timeout)

    def _stale(self, seq: int) -> bool:
        if self._closed or self._seq != seq:
            return True
        gate = self._gate
        while gate is not None and not gate():  # audio first: wait while it renders
            with self._cond:
                self._cond.wait(0.02)
                if self._closed or self._seq != seq:
                    return True
        return False

    def _loop(self) -> None:
        from .newest import lower_priority

        lower_priority()  # below the sound's threads (the map and the inset)
        while True:
            with self._cond:
                while self._pending is None and not self._closed:
                    self._cond.wait()
                if self._closed:
                    return
                (seq, request), self._pending = self._pending, None
                self._running = seq
            try:
                for part in self._compute(request, lambda s=seq: self._stale(s)):
                    if self._stale(seq):
                        break
                    self._on_partial(seq, request, part)
            except BaseException as exc:  # reported, never kills the thread
                if self._on_error is not None:
                    self._on_error(seq, request, exc)
            finally:
                with self._cond:
                    self._running = None
                    self._cond.notify_all()

    @property
    def newest(self) -> int:
        return self._seq


class PropagationView:
    """The map's actor and colour bar in ``plotter``, following ``state``'s source, yaw and height.

    ``scene``: an ``avgs.SceneRenderer`` (typed :class:`~avgs_viewer.trained_scene.TrainedScene`, but the
    map reads the model inside it). ``post``: runs a callable on the plotter's thread
    (:func:`qt_poster` in the window). ``audio_busy``: True while the audio worker renders
    (the map waits). ``size``: cells a side.
    """

    def __init__(self, plotter: pv.Plotter, scene: TrainedScene, state: ViewerState, mode: MapMode | str = MapMode.OFF,
                 post: Callable[[Callable[[], None]], None] = _run_now, audio_busy: Callable[[], bool] | None = None,
                 size: int = 64, on_status: Callable[[str], None] | None = None):
        self.plotter, self.scene, self.state = plotter, scene, state
        self.size = int(size)
        self.floor_z = floor_height(scene)
        self._post = post
        self._on_status = on_status
        self.mode = MapMode(mode)
        self.latest = None  # the newest PropagationMap drawn (partial or complete)
        self.latest_key = None  # (source, yaw, z) it was computed for
        self._key = None  # (source, yaw, z) of the map in progress or shown
        self._actor = None
        self._mesh: pv.ImageData | None = None
        self._shown_kind: str | None = None
        self._lock = threading.Lock()
        self.all_sources: Callable[[], tuple] | None = None
        "Set: the map of all sources, ``((position, gain), ...)`` from it (:mod:`avgs_viewer.sources_map`)."
        gate = None if audio_busy is None else (lambda: not audio_busy())
        self.worker = MapWorker(self._compute, self._partial, self._failed, gate)
        ev = state.events
        self._subscriptions = [(ev.source, self._on_pose), (ev.yaw, self._on_pose), (ev.listener, self._on_pose)]
        for event, cb in self._subscriptions:
            event.connect(cb)
        if self.mode is not MapMode.OFF:
            self.request()

    # ------------------------------------------------------------------ public
    def set_mode(self, mode: MapMode | str) -> None:
        """Off, level or ILD; a map already computed for this pose is reused for either kind."""
        mode = MapMode(mode)
        if mode is self.mode:
            return
        self.mode = mode
        if mode is MapMode.OFF:
            self.worker.cancel()
            self._key = None
            self._remove_actor()
            self.plotter.render()
            return
        key = self._pose_key()
        if self.latest is not None and self.latest_key == key:
            self._draw(self.latest)
            if self.latest.complete:
                self._key = key
                return
        self.request(force=True)

    def request(self, force: bool = False) -> int | None:
        """Compute the map of the state's source, yaw and listener height (unless already under way)."""
        key = self._pose_key()
        if not force and key == self._key:
            return None
        self._key = key
        return self.worker.submit(key)

    def draw_now(self) -> Any:
        """Compute the whole map on this thread and draw it (headless export); returns it."""
        from avgs.render.propagation_map import compute_map

        self.worker.cancel()
        key = self._key = self._pose_key()
        if len(key) == 4:  # all sources
            pmap = list(self._compute(key, lambda: False))[-1]
        else:
            source, yaw, z = key
            pmap = compute_map(self.scene, source=np.array(source), yaw=yaw, z=z, size=self.size, workers=MAP_WORKERS)
        self.latest, self.latest_key = pmap, key
        if self.mode is not MapMode.OFF:
            self._draw(pmap)
        return pmap

    def wait(self, timeout: float = 60.0) -> bool:
        """Until no map is queued or computing (tests, headless export); False on timeout."""
        return self.worker.wait_idle(timeout)

    def values(self) -> np.ndarray | None:
        """The [ny, nx] values on screen (filled where not yet computed), or None."""
        if self.latest is None or self.mode is MapMode.OFF:
            return None
        return self.latest.filled(self.mode.value)

    def close(self) -> None:
        for event, cb in self._subscriptions:
            event.disconnect(cb)
        self._subscriptions = []
        self.worker.close()

    # ------------------------------------------------------------------ computing (worker thread)
    def set_all_sources(self, sources: Callable[[], tuple] | None) -> None:
        """The map of every source from ``sources()`` (``((position, gain), ...)``), or (None) of the state's."""
        self.all_sources = sources
        if self.mode is not MapMode.OFF:
            self.request()

    def _pose_key(self):
        s = self.state
        key = tuple(float(v) for v in s.source), float(s.yaw), float(s.listener[2])
        every = () if self.all_sources is None else self.all_sources()
        if len(every) > 1:
            return (*key, tuple((tuple(float(v) for v in p), float(g)) for p, g in every))
        return key

    def _compute(self, request, cancelled):
        from avgs.render.propagation_map import propagation_map

        if len(request) == 4:  # all sources: each map whole, then their summed powers
            from avgs.render.propagation_map import compute_map

            from .sources_map import sum_maps

            _, yaw, z, every = request
            maps = []
            for position, _gain in every:
                maps.append(compute_map(self.scene, source=np.array(position), yaw=yaw, z=z, size=self.size,
                                        batch=MAP_BATCH, cancel=cancelled, workers=MAP_WORKERS))
                if cancelled():
                    return
            yield sum_maps(maps, [g for _, g in every])
            return
        source, yaw, z = request
        yield from propagation_map(self.scene, source=np.array(source), yaw=yaw, z=z, size=self.size, batch=MAP_BATCH,
                                   cancel=cancelled, workers=MAP_WORKERS)

    def _partial(self, seq: int, request, pmap) -> None:
        self._post(lambda: self._apply(seq, request, pmap))

    def _failed(self, seq: int, request, exc: BaseException) -> None:
        message = f"Propagation map failed: {type(exc).__name__}: {exc}"
        if self._on_status is not None:
            self._post(lambda: self._on_status(message))

    # ------------------------------------------------------------------ drawing (plotter thread)
    def _on_pose(self, _value: Any) -> None:
        if self.mode is not MapMode.OFF and self._pose_key() != self._key:
            self.request()

    def _apply(self, seq: int, key, pmap) -> None:
        if seq != self.worker.newest or self._subscriptions == []:
            return  # a newer request (or closing) has replaced it
        self.latest, self.latest_key = pmap, key
        if self.mode is not MapMode.OFF:
            self._draw(pmap)
        if self._on_status is not None:
            self._on_status(self.describe())

    def describe(self) -> str:
        """One line on the map shown: its progress, or its size and range."""
        pmap = self.latest
        if pmap is None or self.mode is MapMode.OFF:
            return ""
        ny, nx = pmap.grid.shape
        if not pmap.complete:
            return f"computing: {pmap.done} of {nx * ny} cells"
        lo, hi = pmap.range(self.mode.value)
        return f"{nx} x {ny} cells at z = {pmap.grid.z:.2f}: {lo:+.1f} .. {hi:+.1f} dB"

    def _draw(self, pmap) -> None:
        kind = self.mode.value
        values = pmap.filled(kind)  # [ny, nx]
        clim = colour_limits(values, kind)
        if self._mesh is None or self._mesh.n_cells != values.size or self._shown_kind != kind:
            self._remove_actor()
            x0, x1, y0, y1 = pmap.grid.extent
            ny, nx = values.shape
            mesh = pv.ImageData(dimensions=(nx + 1, ny + 1, 1), spacing=((x1 - x0) / nx, (y1 - y0) / ny, 1.0),
                                origin=(x0, y0, self.floor_z))
            mesh.cell_data["map"] = values.ravel()  # x fastest, then y: the [iy, ix] order
            self._mesh = mesh
            self._actor = self.plotter.add_mesh(
                mesh, scalars="map", cmap=CMAPS[kind], clim=clim, nan_opacity=0.0, opacity=MAP_OPACITY,
                lighting=False, name="propagation_map", pickable=False, reset_camera=False,
                show_scalar_bar=True,
                scalar_bar_args=dict(title=bar_title(kind), vertical=True, n_labels=5, fmt="%+.1f",
                                     color=(0.9, 0.9, 0.9)),
            )
            self._shown_kind = kind
            bar = self.plotter.scalar_bars[bar_title(kind)]
            OverlayBoard.of(self.plotter).put("colour_bar", lambda: True, lambda r, _s, _o: place_bar(bar, r))
        else:
            self._mesh.cell_data["map"] = values.ravel()
            self._actor.mapper.scalar_range = clim
        self.plotter.render()

    def _remove_actor(self) -> None:
        if self._actor is not None:
            self.plotter.remove_actor(self._actor, render=False)
            title = bar_title(self._shown_kind) if self._shown_kind else None
            if title and title in self.plotter.scalar_bars:
                self.plotter.remove_scalar_bar(title, render=False)
            OverlayBoard.of(self.plotter).remove("colour_bar")
        self._actor, self._mesh, self._shown_kind = None, None, None


def place_bar(bar, rect) -> None:
    """The colour bar (a ``vtkScalarBarActor``) inside ``rect`` (normalised; None: hidden), its
    title, bar and labels all within it."""
    if rect is None:
        bar.SetVisibility(False)
        return
    bar.SetVisibility(True)
    bar.SetUnconstrainedFontSize(False)  # title and labels sized to fit the rectangle
    bar.SetBarRatio(0.3)
    bar.SetPosition(rect[0], rect[1])
    bar.SetPosition2(rect[2] - rect[0], rect[3] - rect[1])


class ListenerInset:
    """G seen from the listener, as an image in a corner of the 3D view; rendered on a background
    thread once the listener has stopped for ``settle_ms``.

    The sound comes first: the render starts only while no handle is dragged and the audio path
    is idle (``audio_busy``), waits between chunks of tiles while it is busy, and is abandoned at
    the next chunk when the pose changes (a :class:`MapWorker`, as the map's chunks).

    ``load_view()``: returns an :class:`avgs.render.listener_view.ListenerView` or None (run once, on
    the worker thread). ``timer``: a factory ``(ms, callback) -> object with start()/stop()``
    (a Qt single-shot timer in the window); None renders on every pose change.
    """

    def __init__(self, plotter: pv.Plotter, state: ViewerState, load_view: Callable[[], Any],
                 post: Callable[[Callable[[], None]], None] = _run_now, timer=None, settle_ms: int = 300,
                 size: tuple[int, int] = (192, 144), audio_busy: Callable[[], bool] | None = None):
        self.plotter, self.state = plotter, state
        self.size = size
        self._post = post
        self._load_view = load_view
        self._view = None
        self._view_loaded = False
        self.image: np.ndarray | None = None  # the newest [H, W, 3] uint8 shown
        self.shown_pose = None
        self._rep = None
        self.available = True
        self.stopped = 0
        "Renders abandoned for a newer pose."
        self._timer = None if timer is None else timer(settle_ms, self.request)

        def gate() -> bool:  # G rasterised on the CPU takes tens of ms: never beside a pose's filter
            return not state.interacting and (audio_busy is None or not audio_busy())

        self.worker = MapWorker(self._compute, self._rendered, self._failed, gate=gate, name="avgs-inset")
        ev = state.events
        self._subscriptions = [(ev.pose, self._on_pose), (ev.interacting, self._on_pose)]
        for event, cb in self._subscriptions:
            event.connect(cb)
        self.request()

    def request(self) -> None:
        if self.state.interacting:
            return  # rendered once the drag ends
        s = self.state
        self.worker.submit((tuple(float(v) for v in s.listener), float(s.yaw)))

    def wait(self, timeout: float = 30.0) -> bool:
        return self.worker.wait_idle(timeout)

    def close(self) -> None:
        for event, cb in self._subscriptions:
            event.disconnect(cb)
        self._subscriptions = []
        if self._timer is not None:
            self._timer.stop()
        self.worker.close()
        if self._rep is not None:
            hide_inset(self.plotter, self._rep)
            self._rep = None

    def _on_pose(self, _value: Any) -> None:
        self.worker.cancel()  # the render in progress is of a pose already left
        if self._timer is not None:
            self._timer.start()
        else:
            self.request()

    # worker thread
    def _compute(self, request, cancelled):
        from avgs.threads import Stopped

        if not self._view_loaded:
            self._view, self._view_loaded = self._load_view(), True
        if self._view is None:
            yield None
            return
        if cancelled():  # waits for the sound; True when a newer pose came meanwhile
            return
        listener, yaw = request
        try:
            image = self._view.render(listener, yaw, *self.size, stop=cancelled)
        except Stopped:
            self.stopped += 1
            return
        yield request, image

    def _rendered(self, seq, request, result) -> None:
        if result is None:
            self.available = False
            return
        self._post(lambda: self._show(*result))

    def _failed(self, seq, request, exc) -> None:
        self.available = False

    def relayout(self) -> None:
        """Place the inset and its caption again for the view's new size (the overlays' layout)."""
        if self._subscriptions and self.image is not None:
            OverlayBoard.of(self.plotter).relayout()

    # plotter thread
    def _show(self, pose, image: np.ndarray) -> None:
        if not self._subscriptions:
            return
        self.image, self.shown_pose = image, pose
        self._rep = show_inset(self.plotter, image, self._rep)
        self.plotter.render()


def show_inset(plotter: pv.Plotter, image: np.ndarray, rep=None):
    """Show ``image`` [H, W, 3] uint8 in ``plotter``'s view with its title above it, where the
    overlays' layout puts it (:mod:`avgs_viewer.overlay_layout`, the lower right corner); returns
    the VTK representation to pass back for the next image (headless export calls this directly)."""
    from vtkmodules.vtkInteractionWidgets import vtkLogoRepresentation

    h, w, _ = image.shape
    frame = image.copy()
    frame[[0, -1]] = 200  # a thin light border
    frame[:, [0, -1]] = 200
    data = pv.ImageData(dimensions=(w, h, 1))
    data.point_data["rgb"] = frame[::-1].reshape(-1, 3)  # VTK rows run bottom to top
    if rep is None:
        rep = vtkLogoRepresentation()
        rep.SetRenderer(plotter.renderer)
        rep.GetImageProperty().SetOpacity(1.0)
        rep.GetBorderProperty().SetOpacity(0.0)
        plotter.renderer.AddViewProp(rep)
    rep.SetImage(data)
    rep.Modified()
    title = plotter.add_text(INSET_CAPTION, position=(0.0, 0.0), viewport=True, font_size=9,
                             color=(0.85, 0.85, 0.85), name="listener_view_caption")

    def place(rect, _scale, out) -> None:
        rep.SetVisibility(rect is not None)
        title.SetVisibility(rect is not None)
        if rect is None:
            return
        line = text_px(out.height) / out.height  # the title's line, over the image
        rep.SetPosition(rect[0], rect[1])
        rep.SetPosition2(rect[2] - rect[0], rect[3] - rect[1] - line)
        title.SetPosition(rect[0], rect[3] - line + 2.0 / out.height)
        title.GetTextProperty().SetFontSize(max(int(0.7 * text_px(out.height)), 8))

    OverlayBoard.of(plotter).put("inset", lambda: h / w, place)
    return rep


def hide_inset(plotter: pv.Plotter, rep) -> None:
    """The inset and its title out of ``plotter``'s view (and out of the overlays' layout)."""
    plotter.renderer.RemoveViewProp(rep)
    plotter.remove_actor("listener_view_caption", render=False)
    OverlayBoard.of(plotter).remove("inset")


class MapControls:
    """The panel's "Propagation map" group (Off / Level / ILD and a progress line) and, per
    scene, the :class:`PropagationView` and the :class:`ListenerInset` it drives (Qt)."""

    def __init__(self, parent):
        from PySide6 import QtCore, QtWidgets

        self._parent = parent
        self.combo = QtWidgets.QComboBox()
        for mode, name in MODE_NAMES.items():
            self.combo.addItem(name, mode.value)
        self.note = QtWidgets.QLabel()
        self.note.setWordWrap(True)
        self.box = QtWidgets.QGroupBox("Propagation map (floor)")
        layout = QtWidgets.QVBoxLayout(self.box)
        layout.addWidget(self.combo)
        layout.addWidget(self.note)
        self.combo.currentIndexChanged.connect(self._changed)
        self._post = qt_poster(parent)
        self._qt_core = QtCore
        self.view: PropagationView | None = None
        self.inset: ListenerInset | None = None

    @property
    def mode(self) -> MapMode:
        return MapMode(self.combo.currentData())

    def set_mode(self, mode: MapMode | str) -> None:
        self.combo.setCurrentIndex(self.combo.findData(MapMode(mode).value))

    def install(self, plotter: pv.Plotter, scene: TrainedScene, state: ViewerState,
                audio_busy: Callable[[], bool] | None = None) -> None:
        """Draw into ``plotter`` for ``scene`` (an ``avgs.SceneRenderer``) and ``state``."""
        self.teardown()
        self.view = PropagationView(plotter, scene, state, mode=self.mode, post=self._post,
                                    audio_busy=audio_busy, on_status=self.note.setText)
        if scene.gaussians is not None and getattr(scene, "path", None) is not None:
            path = scene.path
            self.inset = ListenerInset(plotter, state, lambda: _load_listener_view(path), post=self._post,
                                       timer=self._timer, audio_busy=audio_busy)

    def teardown(self) -> None:
        for part in (self.view, self.inset):
            if part is not None:
                part.close()
        self.view = self.inset = None
        self.note.clear()

    def relayout(self) -> None:
        """The 3D view was resized: place the listener-view inset again."""
        if self.inset is not None:
            self.inset.relayout()

    def _changed(self, _index: int) -> None:
        if self.view is not None:
            self.view.set_mode(self.mode)
            self.note.setText(self.view.describe())

    def _timer(self, ms: int, callback: Callable[[], None]):
        t = self._qt_core.QTimer(self._parent)
        t.setSingleShot(True)
        t.setInterval(ms)
        t.timeout.connect(callback)
        return t


def _load_listener_view(path):
    """:meth:`avgs.render.listener_view.ListenerView.load`, with no garbage collection while it runs: a
    collection on a worker thread could delete Qt or VTK objects off the GUI thread (loading.py)."""
    import gc

    from avgs.render.listener_view import ListenerView

    collecting = gc.isenabled()
    gc.disable()
    try:
        return ListenerView.load(path)
    finally:
        if collecting:
            gc.enable()
