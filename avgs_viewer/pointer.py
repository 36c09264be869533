"""A handle drag followed through the X server's pointer, off the GUI thread. No Qt, no VTK.

Qt delivers a mouse event only when the GUI thread is free: behind a software-GL render of
the 3D view (8-40 ms on two cores) a drag's last move and its release wait in the queue,
and the sound waits with them. While a handle is dragged, a :class:`PointerFollower`
asks the X server where the pointer is and whether the left button is still down
(``XQueryPointer``, on a connection of its own, every 2 ms) and hands each new position to
the audio path at once; the GUI thread draws the same moves when it gets to them. The
release ends the follow as soon as the server has it, so the released pose's filter is
computed while the GUI thread may still be drawing.

The pointer is mapped onto the dragged handle's horizontal plane by a :class:`PlaneMap`, a
homography fitted at the press from the camera's own rays (the camera does not move during
a handle drag), so this thread never touches VTK. Only on X11 (Qt's ``xcb`` platform);
elsewhere, or when the X pointer is not where Qt saw the press (events synthesised inside
Qt), the drag is Qt's alone, as before.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import threading
import time
from typing import Callable

import numpy as np

BUTTON1_MASK = 1 << 8
"X's state bit of the left button."
POLL_SECONDS = 0.002
"How often the follower asks the X server for the pointer."

ToDisplay = Callable[[int, int], tuple[float, float]]
"Root (screen) pixels -> display pixels of the 3D view (VTK's convention, origin bottom left)."
Moved = Callable[[float, float, bool], None]
"""``moved(x, y, final)``: the pointer at display pixel (x, y); ``final`` for the release (the window's
mouse, :mod:`avgs_viewer.mouse`, maps it through :data:`avgs_viewer.drag.PoseAt` to a pose for
``LiveAudio.request``)."""
Failed = Callable[[BaseException], None]
"The X server stopped answering: the drag is Qt's alone from then on."


class PlaneMap:
    """Display pixel ``(x, y)`` -> where its ray meets a horizontal plane, ``[2]`` (x, y) world.

    The map from a pinhole camera's image to a plane is a homography; four display points
    and their plane points (from the camera's rays) fix it. Points whose ray meets the plane
    behind the camera (above the horizon) give None, as :func:`avgs_viewer.drag.ray_plane_z` does.
    """

    def __init__(self, matrix: np.ndarray, sign: float):
        self.matrix = np.asarray(matrix, dtype=np.float64)  # [3, 3] display (x, y, 1) -> plane (X, Y, W)
        self.sign = float(sign)  # the sign of W in front of the camera

    @classmethod
    def fit(cls, display: np.ndarray, plane: np.ndarray) -> "PlaneMap":
        """From four display points ``[4, 2]`` and where their rays meet the plane ``[4, 2]``."""
        display, plane = np.asarray(display, dtype=np.float64), np.asarray(plane, dtype=np.float64)
        if display.shape != (4, 2) or plane.shape != (4, 2):
            raise ValueError(f"a plane map needs 4 display and 4 plane points, got {display.shape} and {plane.shape}")
        rows = []
        for (x, y), (u, v) in zip(display, plane):
            rows.append([x, y, 1, 0, 0, 0, -u * x, -u * y, -u])
            rows.append([0, 0, 0, x, y, 1, -v * x, -v * y, -v])
        _, s, vt = np.linalg.svd(np.asarray(rows))
        if s[-2] < 1e-9 * s[0]:
            raise ValueError("the four display points do not fix a plane map (three on a line?)")
        h = vt[-1].reshape(3, 3)
        w = h[2, 0] * display[0, 0] + h[2, 1] * display[0, 1] + h[2, 2]
        return cls(h, np.sign(w) or 1.0)

    def __call__(self, x: float, y: float) -> np.ndarray | None:
        X, Y, W = self.matrix @ np.array([x, y, 1.0])
        if W * self.sign <= 0.0:
            return None
        return np.array([X / W, Y / W])


class XPointer:
    """``XQueryPointer`` on a connection of its own: where the pointer is on the screen (root
    pixels) and whether the left button is down. Raises OSError where there is no X display."""

    def __init__(self, display: str | None = None):
        path = ctypes.util.find_library("X11")
        if path is None:
            raise OSError("libX11 is not installed (Debian: libx11-6)")
        x11 = ctypes.CDLL(path)
        x11.XOpenDisplay.restype = ctypes.c_void_p
        x11.XOpenDisplay.argtypes = [ctypes.c_char_p]
        x11.XDefaultRootWindow.restype = ctypes.c_ulong
        x11.XDefaultRootWindow.argtypes = [ctypes.c_void_p]
        x11.XCloseDisplay.argtypes = [ctypes.c_void_p]
        c_int_p, c_ulong_p = ctypes.POINTER(ctypes.c_int), ctypes.POINTER(ctypes.c_ulong)
        x11.XQueryPointer.argtypes = [ctypes.c_void_p, ctypes.c_ulong, c_ulong_p, c_ulong_p,
                                      c_int_p, c_int_p, c_int_p, c_int_p, ctypes.POINTER(ctypes.c_uint)]
        x11.XQueryPointer.restype = ctypes.c_int
        self._x11 = x11
        self._dpy = x11.XOpenDisplay(display.encode() if display else None)
        if not self._dpy:
            raise OSError(f"cannot open X display {display or '$DISPLAY'!r}")
        self._root = x11.XDefaultRootWindow(self._dpy)
        self._out = [ctypes.c_ulong(), ctypes.c_ulong(), ctypes.c_int(), ctypes.c_int(), ctypes.c_int(),
                     ctypes.c_int(), ctypes.c_uint()]
        self._lock = threading.Lock()

    def query(self) -> tuple[int, int, bool]:
        """(x, y, left button down) of the pointer, root pixels."""
        with self._lock:
            if not self._dpy:
                raise OSError("the X connection is closed")
            r, c, rx, ry, wx, wy, mask = self._out
            ok = self._x11.XQueryPointer(self._dpy, self._root, ctypes.byref(r), ctypes.byref(c), ctypes.byref(rx),
                                         ctypes.byref(ry), ctypes.byref(wx), ctypes.byref(wy), ctypes.byref(mask))
            if not ok:  # the pointer is on another screen
                raise OSError("the pointer left this X screen")
            return rx.value, ry.value, bool(mask.value & BUTTON1_MASK)

    def close(self) -> None:
        with self._lock:
            if self._dpy:
                self._x11.XCloseDisplay(self._dpy)
                self._dpy = None


class PointerFollower:
    """Follows one drag at a time on a daemon thread: ``moved(x, y, final)`` with display pixels
    (VTK's convention, origin bottom left) for each new pointer position, ``final`` True for
    the position at which the button came up; then the thread ends. ``failed(exc)`` if the
    X server stops answering (the drag is then Qt's alone)."""

    def __init__(self, pointer: XPointer):
        self.pointer = pointer
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self, to_display: ToDisplay, expect: tuple[float, float], moved: Moved, failed: Failed,
              tolerance_px: float = 2.0) -> bool:
        """Follow from now on. ``to_display(root_x, root_y)`` maps the screen to display pixels;
        ``expect`` is where the press was seen (display pixels). False (nothing started) when
        the X pointer is elsewhere or its button is up: the press did not come through X."""
        self.stop()
        try:
            rx, ry, down = self.pointer.query()
        except OSError:
            return False
        x, y = to_display(rx, ry)
        if not down or abs(x - expect[0]) > tolerance_px or abs(y - expect[1]) > tolerance_px:
            return False
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, args=(to_display, moved, failed, (rx, ry), self._stop),
                                        name="avgs-pointer", daemon=True)
        self._thread.start()
        return True

    def _run(self, to_display: ToDisplay, moved: Moved, failed: Failed, last: tuple[int, int],
             stop: threading.Event) -> None:
        try:
            while not stop.is_set():
                rx, ry, down = self.pointer.query()
                if (rx, ry) != last or not down:
                    last = (rx, ry)
                    if stop.is_set():
                        break
                    moved(*to_display(rx, ry), not down)
                if not down:
                    break
                time.sleep(POLL_SECONDS)
        except BaseException as exc:  # reported; the drag goes on through Qt
            failed(exc)

    def stop(self) -> None:
        """End the follow in progress (the GUI thread saw the release first); no callback after this returns
        except one already running."""
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(1.0)
        self._thread = None

    def close(self) -> None:
        self.stop()
        self.pointer.close()
