"""Every key and mouse action of the explorer, in one table: the window's menus (:mod:`avgs_viewer.menus`)
bind their keys from it and the Help dialog (F1) lists it, so the two cannot disagree.

VTK's own keys are switched off (:func:`avgs_viewer.scene_view.disable_vtk_keys`): the keys
here are the only ones. No Qt here.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Key:
    """One command: its name in the code, the keys that run it and what it does, in words."""

    name: str
    keys: tuple[str, ...]  # Qt key sequences, portable text ("Ctrl+O", "Left", "F1")
    does: str


KEYS: tuple[Key, ...] = (
    Key("turn_left", ("Q", "Left"), "turn the listener 15 degrees to the left (counter-clockwise)"),
    Key("turn_right", ("E", "Right"), "turn the listener 15 degrees to the right"),
    Key("play", ("Space",), "play or pause the sound"),
    Key("play_response", ("I",), "play the current pose's impulse response once, then the clip again"),
    Key("camera_home", ("R",), "camera: reset to the three-quarter view of the whole scene"),
    Key("camera_top", ("T",), "camera: from above (floor plan, +y up)"),
    Key("camera_front", ("F",), "camera: from the front (the -y side, level)"),
    Key("camera_listener", ("L",), "camera: from the listener, looking where it faces"),
    Key("bypass", ("D",), "audition: bypass on or off (the dry clip in both ears, no filter)"),
    Key("store_a", ("Shift+A",), "audition: store the current pose as A"),
    Key("store_b", ("Shift+B",), "audition: store the current pose as B"),
    Key("recall_a", ("A",), "audition: go to pose A"),
    Key("recall_b", ("B",), "audition: go to pose B"),
    Key("flip_ab", ("X",), "audition: flip between poses A and B"),
    Key("ground_truth", ("N",), "audition: play the recording at the nearest recorded pose once (scenes with recordings)"),
    Key("undo", ("Ctrl+Z",), "undo the last pose change (a drag, a typed value, a turn, a recalled pose)"),
    Key("redo", ("Ctrl+Shift+Z", "Ctrl+Y"), "redo the pose change undone"),
    *(Key(f"save_view_{i}", (f"Ctrl+{i}",), f"save the camera as viewpoint {i}") for i in range(1, 5)),
    *(Key(f"recall_view_{i}", (f"{i}",), f"camera: go to viewpoint {i}") for i in range(1, 5)),
    Key("open_scene", ("Ctrl+O",), "open another scene (checkpoint)"),
    Key("help", ("F1",), "this help"),
    Key("quit", ("Ctrl+Q",), "quit"),
)

MOUSE: tuple[tuple[str, str], ...] = (
    ("Left-drag a sphere", "move it: the blue listener (its arrow is the facing) at its own height, "
                           "the yellow source at its height; both stay inside the room. A scene trained "
                           "with one source position keeps its source fixed"),
    ("Left-drag elsewhere", "orbit the camera"),
    ("Shift + left-drag, or middle-drag", "pan"),
    ("Right-drag, or the wheel", "zoom"),
    ("Ctrl + left-drag", "roll the view about its centre"),
)

FIELDS = ("Pose panel: type a listener x, y, z or yaw, or a source x, y, z, and press Enter (Escape: "
          "leave the field unchanged); either gives the keys back to the window. Letter keys act even while a "
          "field has focus, unless a value is being typed in it; digits go to the field. "
          "Drop a .ckpt (scene) or a .wav (clip) file onto the window to open it. A "
          "position outside the room is moved to the nearest place inside it, and the panel says so. "
          "The source's fields are read-only when the scene was trained with one source position.")


def key(name: str) -> Key:
    """The :class:`Key` called ``name``."""
    for k in KEYS:
        if k.name == name:
            return k
    raise KeyError(f"no key binding named {name!r}")


def _keys_text(keys: tuple[str, ...]) -> str:
    return " / ".join(keys)


def help_html() -> str:
    """The Help dialog's text: every mouse action, every key, the pose fields."""
    def table(rows):
        cells = "".join(f"<tr><td style='padding-right:14px'><b>{a}</b></td><td>{b}</td></tr>" for a, b in rows)
        return f"<table>{cells}</table>"

    return ("<h3>Mouse (in the 3D view)</h3>" + table(MOUSE)
            + "<h3>Keys</h3>" + table([(_keys_text(k.keys), k.does) for k in KEYS])
            + f"<p>{FIELDS}</p>"
            + "<p>VTK's own keys (stereo, wireframe, point size, ...) are switched off.</p>")


def help_text() -> str:
    """The same as plain text (for a terminal or a test)."""
    lines = ["Mouse (in the 3D view):"] + [f"  {a}: {b}" for a, b in MOUSE]
    lines += ["Keys:"] + [f"  {_keys_text(k.keys)}: {k.does}" for k in KEYS]
    return "\n".join(lines + [FIELDS])
