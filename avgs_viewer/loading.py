"""A checkpoint loaded on a background thread, handed to the GUI thread by a queued signal.

The model never loads on the GUI thread: torch is first imported on the loading thread, so
the window shows before it is. Every failure becomes a message (the window shows it in a
dialog), never a crash.
"""

from __future__ import annotations

import gc
import threading
import traceback
from pathlib import Path

import numpy as np
from PySide6 import QtCore


class SceneLoader(QtCore.QObject):
    """:meth:`load` a checkpoint on a thread of its own; ``loaded`` or ``load_failed`` on the GUI thread."""

    loaded = QtCore.Signal(object, object)      # (path, SceneRenderer)
    load_failed = QtCore.Signal(object, str)    # (path, message)

    def load(self, path: Path) -> None:
        def load() -> None:
            # A garbage collection run on this thread could delete Qt or VTK objects (a closed
            # window's cycles) off the GUI thread, which aborts the process: none runs while loading.
            collecting = gc.isenabled()
            gc.disable()
            try:
                from avgs import SceneRenderer  # torch is imported here, off the GUI thread
                from avgs.evaluation.metrics import rt60

                renderer = SceneRenderer.load(path)
                rt60(np.zeros(1))  # its imports too (the response panel's T60), not on the GUI thread
            except Exception as exc:  # every failure becomes a dialog, never a crash
                message = str(exc) if isinstance(exc, (ValueError, FileNotFoundError)) else \
                    f"{type(exc).__name__}: {exc}\n\n{traceback.format_exc(limit=3)}"
                self.load_failed.emit(path, message)
            else:
                self.loaded.emit(path, renderer)
            finally:
                if collecting:
                    gc.enable()

        gc.collect()  # here, on the GUI thread, what was left behind since the last scene was settled
        threading.Thread(target=load, name="avgs-load", daemon=True).start()


def settle_heap() -> None:
    """Once a scene is shown (GUI thread): unfreeze, collect, freeze what is left (``gc.freeze``).

    The scene's long-lived objects (VTK and Qt wrappers, torch modules, the points) then leave the
    collector's generations, and a collection during a drag, on whatever thread allocates, walks
    only what was made since. Sampled in the window on the bundled demo: full collections took
    100-200 ms and the first gen-1 collection after loading 94 ms, every Python thread (the
    filter's included) stopped meanwhile. The scene shown before, frozen at its own settle, stays
    frozen while the next one loads (no collection on another thread can free its Qt or VTK
    objects) and is freed here, on the GUI thread: one full collection a scene."""
    gc.unfreeze()
    gc.collect()
    gc.freeze()
