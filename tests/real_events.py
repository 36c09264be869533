"""Helpers of the tests that drive the real window with X events (XTEST, as ``xdotool`` sends them)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

DEMO = Path(__file__).resolve().parents[1] / "assets" / "demo" / "scene.ckpt"
"The bundled demo scene (scripts/make_demo.sh)."


def screen_xy(w, world) -> tuple[float, float]:
    """Where on the screen (global pixels) the window ``w``'s 3D view draws the world point ``world``."""
    from PySide6 import QtCore

    p = w.view.projector().to_display(np.asarray(world, dtype=np.float64))
    scale = w.plotter.devicePixelRatioF()
    g = w.plotter.mapToGlobal(QtCore.QPointF(p[0] / scale, w.plotter.height() - 1 - p[1] / scale))
    return g.x(), g.y()


def open_window(qtbot, path):
    """The real main window at the screen's top left, active (real key and pointer events reach it), ``path`` loaded."""
    from avgs_viewer.window import MainWindow

    w = MainWindow()
    qtbot.addWidget(w)
    w.move(0, 0)
    w.show()
    w.activateWindow()
    qtbot.waitActive(w)
    with qtbot.waitSignal(w.scene_loaded, timeout=60_000):
        w.open_scene(path)
    return w


def demo_window(qtbot):
    """The real window on the bundled demo, its first pose heard; the test is skipped without the demo.
    The caller closes it (a fixture: ``w = demo_window(qtbot); yield w; w.close()``)."""
    import pytest

    if not DEMO.is_file():
        pytest.skip("the bundled demo scene is missing (scripts/make_demo.sh)")
    w = open_window(qtbot, DEMO)
    qtbot.waitUntil(lambda: w.live is not None and w.live.heard is not None, timeout=30_000)
    return w


def drag_handle(qtbot, w, x, handle: str, start, end, steps: int = 12) -> None:
    """Press on ``handle``'s sphere at screen point ``start``, move to ``end`` in ``steps``, release (XTEST)."""
    import numpy as np

    x.press(*start)
    qtbot.waitUntil(lambda: w.drag.dragging == handle, timeout=5000)
    for t in np.linspace(0, 1, steps)[1:-1]:
        x.move(start[0] + t * (end[0] - start[0]), start[1] + t * (end[1] - start[1]))
        qtbot.wait(20)
    x.release(*end)
    qtbot.waitUntil(lambda: w.drag.dragging is None, timeout=5000)
