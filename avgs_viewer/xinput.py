"""Real window-system input for the benchmark and the window tests: the X server's XTEST extension.

XTEST is what ``xdotool`` uses: the server injects the events as if they came from the
mouse and keyboard, so they travel the whole way a user's do (X server -> Qt's xcb
connection -> the GUI thread's event queue, behind whatever it is drawing). Called
through ``ctypes`` (``libX11``, ``libXtst``) rather than by starting ``xdotool`` for
each event, so that the time an event is sent is known to the microsecond.
Coordinates are the X screen's (``QWidget.mapToGlobal``).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import subprocess
import threading
import time
from contextlib import contextmanager

KEYSYMS = {"space": 0x20, "Left": 0xFF51, "Right": 0xFF53, "Return": 0xFF0D, "Tab": 0xFF09,
           "BackSpace": 0xFF08, "period": 0x2E, "minus": 0x2D}
"X keysyms of the keys the viewer uses that are not a letter or digit (letters and digits are their ASCII code)."


def _load(name: str) -> ctypes.CDLL:
    path = ctypes.util.find_library(name)
    if path is None:
        raise OSError(f"lib{name} is not installed (Debian: libx11-6, libxtst6)")
    return ctypes.CDLL(path)


class XInput:
    """A connection to an X display that sends mouse and keyboard events through XTEST.

    Each call sends its events and flushes them to the server at once; the methods return
    ``time.perf_counter()`` taken just before the flush (the moment the event was sent).
    Safe to use from any one thread (the connection is not shared with Qt's).
    """

    def __init__(self, display: str | None = None):
        self._x11, self._xtst = _load("X11"), _load("Xtst")
        self._x11.XOpenDisplay.restype = ctypes.c_void_p
        self._x11.XOpenDisplay.argtypes = [ctypes.c_char_p]
        self._x11.XFlush.argtypes = self._x11.XCloseDisplay.argtypes = [ctypes.c_void_p]
        self._x11.XKeysymToKeycode.argtypes = [ctypes.c_void_p, ctypes.c_ulong]
        self._x11.XKeysymToKeycode.restype = ctypes.c_ubyte
        self._xtst.XTestFakeMotionEvent.argtypes = [ctypes.c_void_p, ctypes.c_int, ctypes.c_int, ctypes.c_int,
                                                    ctypes.c_ulong]
        self._xtst.XTestFakeButtonEvent.argtypes = [ctypes.c_void_p, ctypes.c_uint, ctypes.c_int, ctypes.c_ulong]
        self._xtst.XTestFakeKeyEvent.argtypes = [ctypes.c_void_p, ctypes.c_uint, ctypes.c_int, ctypes.c_ulong]
        name = display if display is not None else os.environ.get("DISPLAY", "")
        self._dpy = self._x11.XOpenDisplay(name.encode() or None)
        if not self._dpy:
            raise OSError(f"cannot open X display {name!r}")
        self._lock = threading.Lock()

    def _flush(self) -> float:
        t = time.perf_counter()
        self._x11.XFlush(self._dpy)
        return t

    def move(self, x: float, y: float) -> float:
        """Move the pointer to screen pixel (x, y)."""
        with self._lock:
            self._xtst.XTestFakeMotionEvent(self._dpy, -1, int(round(x)), int(round(y)), 0)
            return self._flush()

    def press(self, x: float, y: float, button: int = 1) -> float:
        """Move to (x, y) and press ``button`` (1 left, 2 middle, 3 right)."""
        with self._lock:
            self._xtst.XTestFakeMotionEvent(self._dpy, -1, int(round(x)), int(round(y)), 0)
            self._xtst.XTestFakeButtonEvent(self._dpy, button, 1, 0)
            return self._flush()

    def release(self, x: float, y: float, button: int = 1) -> float:
        """Move to (x, y) and release ``button``, sent together (a hand that stops and lets go)."""
        with self._lock:
            self._xtst.XTestFakeMotionEvent(self._dpy, -1, int(round(x)), int(round(y)), 0)
            self._xtst.XTestFakeButtonEvent(self._dpy, button, 0, 0)
            return self._flush()

    def key(self, name: str) -> float:
        """Press and release one key: a letter, a digit or a name of :data:`KEYSYMS`."""
        keysym = KEYSYMS.get(name, ord(name.lower()) if len(name) == 1 else None)
        if keysym is None:
            raise ValueError(f"unknown key {name!r}")
        with self._lock:
            code = self._x11.XKeysymToKeycode(self._dpy, keysym)
            if code == 0:
                raise ValueError(f"key {name!r} has no keycode on this display")
            self._xtst.XTestFakeKeyEvent(self._dpy, code, 1, 0)
            self._xtst.XTestFakeKeyEvent(self._dpy, code, 0, 0)
            return self._flush()

    def type(self, text: str, interval_s: float = 0.01) -> None:
        """Type ``text`` (letters, digits, '.', '-', ' '), one key every ``interval_s``."""
        names = {" ": "space", ".": "period", "-": "minus", "\n": "Return"}
        for ch in text:
            self.key(names.get(ch, ch))
            time.sleep(interval_s)

    def drag(self, start, end, steps: int = 12, interval_s: float = 1 / 60, button: int = 1) -> float:
        """Press at ``start``, move in ``steps`` equal steps towards ``end`` one every ``interval_s``,
        and release at ``end`` together with the last move; returns when the release was sent."""
        (x0, y0), (x1, y1) = start, end
        self.press(x0, y0, button)
        for i in range(1, steps):
            time.sleep(interval_s)
            f = i / steps
            self.move(x0 + f * (x1 - x0), y0 + f * (y1 - y0))
        time.sleep(interval_s)
        return self.release(x1, y1, button)

    def close(self) -> None:
        with self._lock:
            if self._dpy:
                self._x11.XCloseDisplay(self._dpy)
                self._dpy = None

    def __enter__(self) -> "XInput":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


@contextmanager
def virtual_display(width: int = 1600, height: int = 1000):
    """Start ``Xvfb`` on a free display number and set ``DISPLAY`` to it for the block;
    yields the display name. Used only where no display exists."""
    read, write = os.pipe()
    try:
        proc = subprocess.Popen(["Xvfb", "-displayfd", str(write), "-screen", "0", f"{width}x{height}x24",
                                 "-nolisten", "tcp"], pass_fds=(write,), stdout=subprocess.DEVNULL,
                                stderr=subprocess.DEVNULL)
    except FileNotFoundError as exc:
        os.close(read)
        os.close(write)
        raise OSError("no display and no Xvfb to start one (Debian: apt-get install xvfb)") from exc
    os.close(write)
    with os.fdopen(read) as f:
        number = f.readline().strip()
    if not number:
        proc.kill()
        raise OSError("Xvfb did not start")
    saved = os.environ.get("DISPLAY")
    os.environ["DISPLAY"] = f":{number}"
    try:
        yield os.environ["DISPLAY"]
    finally:
        if saved is None:
            os.environ.pop("DISPLAY", None)
        else:
            os.environ["DISPLAY"] = saved
        proc.terminate()
        try:
            proc.wait(5)
        except subprocess.TimeoutExpired:
            proc.kill()
