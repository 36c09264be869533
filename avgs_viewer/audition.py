"""A/B audition: bypass, two stored poses to flip between, and the recorded ground truth.

- **Bypass** (D): the dry clip in both ears instead of the pose's filter
  (:attr:`avgs_viewer.audio.StreamEngine.bypass`, crossfaded over one block).
- **Poses A and B** (Shift+A / Shift+B store, A / B go, X flips): listener, yaw and source.
- **Ground truth** (N): on a scene with recordings (the RWAVS layout), the binaural recording
  at the recorded pose nearest the listener (position, then yaw), played once through the engine.
  A checkpoint names its scene (``scene.name``), not where it is: the recordings are looked for
  in a folder of that name beside the checkpoint or one level up (where ``avgs train`` is run
  on ``DATA_ROOT/SCENE_ID`` with ``--out DATA_ROOT/...``). Without them the entry is disabled
  and its tooltip says why.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PySide6 import QtCore, QtWidgets

from .help import key as help_key
from .menus import add_action
from .state import Pose, ViewerState

RWAVS_FILES = ("transforms_scale_train.json", "transforms_scale_val.json")


def recordings_folder(checkpoint: Path | None, scene_name: str) -> tuple[Path | None, str]:
    """(the scene's folder in the RWAVS layout, "") or (None, why there is none), for the checkpoint
    at ``checkpoint`` trained on scene ``scene_name``."""
    if checkpoint is None or not scene_name:
        return None, "No recordings: this scene was not loaded from a checkpoint that names its scene."
    here = Path(checkpoint).resolve().parent
    places = [here / scene_name, here.parent / scene_name]
    if here.name == scene_name:
        places.insert(0, here)
    for place in places:
        if all((place / f).is_file() for f in RWAVS_FILES):
            return place, ""
    return None, (f"No recordings: the checkpoint's scene {scene_name!r} was not found in the RWAVS layout "
                  f"(transforms_scale_*.json) at {' or '.join(str(p) for p in places)}.")


@dataclass(frozen=True)
class Recording:
    """One recorded pose of the scene: world position, yaw (degrees) and what was heard."""

    listener: np.ndarray  # [3] world
    yaw: float
    binaural: np.ndarray  # [2, T] float32
    name: str  # its split and index, for the status bar


def read_recordings(folder: Path, sample_rate: int) -> list[Recording]:
    """Every recorded pose (train and val) of the scene at ``folder``; ValueError naming a bad file."""
    from avgs.config import STFTConfig
    from avgs.data.rwavs import RWAVSScene

    recorded = RWAVSScene(folder, stft=STFTConfig(sample_rate=sample_rate))
    out = []
    for split, clips in (("train", recorded.train), ("val", recorded.val)):
        for i, clip in enumerate(clips):
            world = recorded.frame.to_world(np.asarray(clip.listener, dtype=np.float64).reshape(1, 3))[0]
            out.append(Recording(world, float(np.degrees(clip.yaw)) % 360.0,
                                 np.asarray(clip.binaural, dtype=np.float32), f"{split} #{i}"))
    return out


def nearest(recordings: list[Recording], listener, yaw: float) -> Recording:
    """The recording nearest ``listener`` [3] (world), ties broken by the smallest yaw difference."""
    where = np.array([r.listener for r in recordings])  # [R, 3]
    dist = np.round(np.linalg.norm(where - np.asarray(listener, dtype=np.float64), axis=1), 6)
    turn = np.array([abs((r.yaw - yaw + 180.0) % 360.0 - 180.0) for r in recordings])
    return recordings[int(np.lexsort((turn, dist))[0])]


class Audition(QtCore.QObject):
    """The Audition menu of ``window`` (a MainWindow): bypass, poses A and B, the ground truth."""

    def __init__(self, window, menu_bar: QtWidgets.QMenuBar, key_actions: dict):
        super().__init__(window)
        self.window = window
        self.stored: dict[str, Pose] = {}
        self._recordings: list[Recording] | None = None
        self._folder: Path | None = None
        menu = QtWidgets.QMenu("&Audition", menu_bar)
        menu_bar.insertMenu(menu_bar.actions()[-1], menu)  # before Help
        self.menu = menu
        self.bypass_action = add_action(window, menu, "&Bypass (dry clip)", self._bypass_toggled, "bypass", key_actions)
        self.bypass_action.setCheckable(True)
        menu.addSeparator()
        for name in ("a", "b"):
            add_action(window, menu, f"Store pose {name.upper()}", lambda n=name: self.store(n), f"store_{name}", key_actions)
        self.recall_actions = {n: add_action(window, menu, f"Go to pose {n.upper()}", lambda n=n: self.recall(n),
                                             f"recall_{n}", key_actions) for n in ("a", "b")}
        self.flip_action = add_action(window, menu, "&Flip A / B", self.flip, "flip_ab", key_actions)
        menu.addSeparator()
        self.truth_action = add_action(window, menu, "Play the &recording at the nearest recorded pose",
                                       self.play_ground_truth, "ground_truth", key_actions)
        self._update_enabled()
        self.scene_changed()

    # ------------------------------------------------------------------ bypass
    def set_bypass(self, on: bool) -> None:
        engine = self.window.engine
        if engine is not None:
            engine.bypass = bool(on)
        self.bypass_action.setChecked(bool(on))
        self.window.statusBar().showMessage("Bypass: the dry clip in both ears" if on else "Bypass off: the pose's filter", 3000)

    def _bypass_toggled(self) -> None:
        self.set_bypass(self.bypass_action.isChecked())

    # ------------------------------------------------------------------ A / B
    def store(self, name: str) -> None:
        state: ViewerState | None = self.window.state
        if state is not None:
            self.stored[name] = state.pose
            self.window.statusBar().showMessage(f"Stored this pose as {name.upper()}", 3000)
            self._update_enabled()

    def recall(self, name: str) -> None:
        pose, state = self.stored.get(name), self.window.state
        if pose is None or state is None:
            self.window.statusBar().showMessage(f"No pose {name.upper()} stored yet (Shift+{name.upper()} stores one)", 3000)
            return
        self.window.history.apply(pose, f"go to pose {name.upper()}")
        self.current = name
        self.window.statusBar().showMessage(f"Pose {name.upper()}", 3000)

    def flip(self) -> None:
        """Go to the stored pose the listener is not at (A first)."""
        state = self.window.state
        if state is None:
            return
        at = next((n for n, p in self.stored.items() if p == state.pose), None)
        self.recall("b" if at == "a" else "a")

    # ------------------------------------------------------------------ ground truth
    def scene_changed(self) -> None:
        """A new scene: its stored poses forgotten, its recordings looked for."""
        self.stored.clear()
        self._recordings = None
        renderer = self.window.renderer
        self._folder, why = recordings_folder(getattr(renderer, "path", None), getattr(renderer, "name", "")) \
            if renderer is not None else (None, "No scene loaded.")
        self.truth_action.setEnabled(self._folder is not None)
        self.truth_action.setToolTip(f"Recordings of {self._folder}" if self._folder else why)
        self.truth_action.setStatusTip(self.truth_action.toolTip())
        self.menu.setToolTipsVisible(True)
        self._update_enabled()

    def ground_truth(self) -> Recording | None:
        """The recording nearest the listener now, or None (no recordings: the entry's tooltip says why)."""
        state, renderer = self.window.state, self.window.renderer
        if self._folder is None or state is None:
            return None
        if self._recordings is None:
            try:
                self._recordings = read_recordings(self._folder, renderer.sample_rate)
            except (ValueError, FileNotFoundError) as exc:
                self.window.show_error("Cannot read the recordings", str(exc))
                self._folder = None
                self.truth_action.setEnabled(False)
                self.truth_action.setToolTip(f"No recordings: {exc}")
                return None
        return nearest(self._recordings, state.listener, state.yaw) if self._recordings else None

    def play_ground_truth(self) -> None:
        rec, engine = self.ground_truth(), self.window.engine
        if rec is None or engine is None:
            return
        engine.play_once(rec.binaural)
        self.window.meter_timer.start()
        self.last_played = rec
        d = float(np.linalg.norm(rec.listener - self.window.state.listener))
        self.window.statusBar().showMessage(
            f"Recording {rec.name}: {d:.2f} m away, yaw {rec.yaw:.0f} deg ({rec.binaural.shape[1] / engine.sample_rate:.1f} s)", 5000)

    def _update_enabled(self) -> None:
        for name, act in self.recall_actions.items():
            act.setEnabled(True)  # keys stay live; an empty slot says so in the status bar
            act.setToolTip("" if name in self.stored else f"Store it first ({' / '.join(help_key('store_' + name).keys)})")
