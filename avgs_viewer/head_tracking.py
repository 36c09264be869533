"""Head tracking: the listener's yaw (and position) from a head tracker's OSC messages.

The format is the one of the IEM SceneRotator and of supperware's head tracker (and the many
bridges that speak it), over UDP on ``127.0.0.1``-reachable port :data:`DEFAULT_PORT`
(``avgs-viewer --osc-port N``, or View > Head tracking (OSC)):

- ``/ypr yaw pitch roll``: degrees. Yaw is positive when the head turns **left**
  (counter-clockwise seen from above, the ambisonic convention of the SceneRotator), as the
  explorer's yaw is. The listener's yaw becomes the yaw it had when tracking was switched on
  plus the tracker's yaw; pitch and roll are not used (the model knows no head tilt).
- ``/xyz x y z``: metres, the head's offset from where it was when tracking was switched on,
  along the scene's x, y, z; the listener moves there (kept inside the room, as a drag is).

Messages arrive on the server's thread and reach the window on the GUI thread by a queued Qt
signal (:class:`HeadTracker`), where they are applied like any pose change.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np
from PySide6 import QtCore

DEFAULT_PORT = 9000
"The port the SceneRotator's and most head-tracker bridges' examples send to."
YPR_ADDRESS = "/ypr"
XYZ_ADDRESS = "/xyz"


@dataclass
class Reference:
    """The listener's pose when tracking was switched on: the tracker's zero."""

    yaw: float  # degrees ccw from +x
    listener: np.ndarray  # [3] world


def tracked_yaw(reference: Reference, yaw: float) -> float:
    """The listener's yaw (degrees ccw from +x) for a tracker yaw (degrees, positive: turned left)."""
    return (reference.yaw + float(yaw)) % 360.0


def tracked_position(reference: Reference, xyz) -> np.ndarray:
    """[3] world: the reference position moved by the tracker's offset (metres)."""
    return np.asarray(reference.listener, dtype=np.float64) + np.asarray(xyz, dtype=np.float64)[:3]


class HeadTracker(QtCore.QObject):
    """An OSC server on a thread of its own; ``ypr`` and ``xyz`` are emitted on the receiver's (GUI) thread."""

    ypr = QtCore.Signal(float, float, float)  # degrees
    xyz = QtCore.Signal(float, float, float)  # metres

    def __init__(self, parent: QtCore.QObject | None = None):
        super().__init__(parent)
        self._server = None
        self._thread: threading.Thread | None = None
        self.port: int | None = None
        self.received = 0
        "Messages of either address taken since start."

    @property
    def running(self) -> bool:
        return self._server is not None

    def start(self, port: int = DEFAULT_PORT, host: str = "127.0.0.1") -> int:
        """Listen on ``host:port`` (0: any free port); returns the port. OSError naming the port when it is taken."""
        from pythonosc.dispatcher import Dispatcher
        from pythonosc.osc_server import BlockingOSCUDPServer

        self.stop()
        dispatcher = Dispatcher()
        dispatcher.map(YPR_ADDRESS, self._on_ypr)
        dispatcher.map(XYZ_ADDRESS, self._on_xyz)
        try:
            server = BlockingOSCUDPServer((host, int(port)), dispatcher)
        except OSError as exc:
            raise OSError(f"head tracking: cannot listen on UDP port {port}: {exc.strerror or exc}") from exc
        self._server = server
        self.port = int(server.server_address[1])
        self.received = 0
        self._thread = threading.Thread(target=server.serve_forever, kwargs={"poll_interval": 0.1},
                                        name="avgs-osc", daemon=True)
        self._thread.start()
        return self.port

    def stop(self) -> None:
        server, self._server = self._server, None
        if server is not None:
            server.shutdown()
            server.server_close()
            self._thread.join(timeout=2.0)
        self._thread, self.port = None, None

    # -- the server's thread
    @staticmethod
    def _floats(args, n: int) -> tuple[float, ...] | None:
        try:
            values = tuple(float(a) for a in args[:n])
        except (TypeError, ValueError):
            return None
        return values if len(values) == n and all(np.isfinite(values)) else None

    def _on_ypr(self, _address: str, *args) -> None:
        values = self._floats(args, 3) or self._floats(args, 1)  # a yaw alone is taken too
        if values is not None:
            self.received += 1
            self.ypr.emit(*(values + (0.0,) * (3 - len(values))))

    def _on_xyz(self, _address: str, *args) -> None:
        values = self._floats(args, 3)
        if values is not None:
            self.received += 1
            self.xyz.emit(*values)
