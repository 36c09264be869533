"""The window's menu bar (File, View, Help) and its actions; the Help dialog.

Every key comes from ``help.KEYS`` (:func:`~avgs_viewer.help.key`), the table the Help dialog
lists too, so the menus and the help cannot disagree. What each entry does is the window's
to say (:class:`MenuCommands`); the actions belong to the window, so their keys work anywhere in it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

from PySide6 import QtCore, QtGui, QtWidgets

from .help import help_html
from .help import key as help_key

YAW_STEP = 15.0  # degrees a turn key turns the listener


@dataclass(frozen=True)
class MenuCommands:
    """What the menu entries do."""

    choose_scene: Callable[[], object]
    choose_clip: Callable[[], object]
    choose_screenshot: Callable[[], object]
    choose_audio_export: Callable[[], object]
    quit: Callable[[], object]
    camera_preset: Callable[[str], object]  # camera_home, camera_top, camera_front, camera_listener
    toggle_playing: Callable[[], object]
    turn: Callable[[float], object]  # degrees counter-clockwise
    play_response: Callable[[], object]
    show_response: Callable[[bool], object]  # the impulse-response panel shown or hidden
    show_help: Callable[[], object]
    choose_impulse_export: Callable[[], object]  # the pose's binaural impulse response as a WAV
    choose_grid_export: Callable[[], object]  # a grid of responses as SOFA (a dialog: spacing, yaws, height)
    record_path: Callable[[bool], object]  # recording the listener's path on or off
    choose_path_save: Callable[[], object]  # the recorded path as keyframes JSON
    choose_flythrough: Callable[[], object]  # a fly-through MP4 (a dialog: path, fps, size, picture)


@dataclass(frozen=True)
class Menus:
    """The actions the window keeps: every action with keys by its name in ``help.KEYS``, and
    the entries it reads or checks."""

    key_actions: dict[str, QtGui.QAction]
    export_shot_action: QtGui.QAction
    export_audio_action: QtGui.QAction
    response_action: QtGui.QAction  # checkable: the impulse-response panel shown
    record_path_action: QtGui.QAction  # checkable: the listener's path being recorded
    export_actions: dict[str, QtGui.QAction]  # "impulse", "grid", "save_path", "flythrough"
    menus: dict[str, QtWidgets.QMenu]  # "file", "view", "help": where other parts add their entries


def add_action(window: QtWidgets.QWidget, menu: QtWidgets.QMenu, text: str, slot: Callable[[], object],
               key_name: str | None = None, key_actions: dict[str, QtGui.QAction] | None = None) -> QtGui.QAction:
    """A menu entry of ``window``; ``key_name`` names its keys in ``help.KEYS`` (kept in ``key_actions``)."""
    act = QtGui.QAction(text, window)
    if key_name is not None:
        act.setShortcuts([QtGui.QKeySequence(k) for k in help_key(key_name).keys])
        act.setShortcutContext(QtCore.Qt.ShortcutContext.WindowShortcut)
        if key_actions is not None:
            key_actions[key_name] = act
    act.triggered.connect(lambda _=False: slot())
    menu.addAction(act)
    return act


def build_menus(window: QtWidgets.QMainWindow, do: MenuCommands) -> Menus:
    """Make ``window``'s menu bar, its entries doing what ``do`` says."""
    key_actions: dict[str, QtGui.QAction] = {}

    def action(menu: QtWidgets.QMenu, text: str, slot: Callable[[], object],
               key_name: str | None = None) -> QtGui.QAction:
        """A menu entry; ``key_name`` names its keys in ``help.KEYS``."""
        return add_action(window, menu, text, slot, key_name, key_actions)

    # The bar and its menus are made here, not taken from Qt's getters: a wrapper PySide hands
    # back for a C++-made object can be a stale one of an object freed at the same address (a
    # QOffscreenSurface of pyvistaqt's, once, in a full test run).
    bar = QtWidgets.QMenuBar(window)
    window.setMenuBar(bar)

    def menu(title: str) -> QtWidgets.QMenu:
        m = QtWidgets.QMenu(title, bar)
        bar.addMenu(m)
        return m

    file_menu = menu("&File")
    action(file_menu, "&Open scene...", do.choose_scene, "open_scene")
    action(file_menu, "Open &clip...", do.choose_clip)
    file_menu.addSeparator()
    export_shot = action(file_menu, "Export &screenshot...", do.choose_screenshot)
    export_audio = action(file_menu, "Export &audio...", do.choose_audio_export)
    exports = {"impulse": action(file_menu, "Export &impulse response (WAV)...", do.choose_impulse_export),
               "grid": action(file_menu, "Export response &grid (SOFA)...", do.choose_grid_export)}
    file_menu.addSeparator()
    record = action(file_menu, "&Record path", lambda: do.record_path(record.isChecked()))
    record.setCheckable(True)
    exports["save_path"] = action(file_menu, "Save recorded &path...", do.choose_path_save)
    exports["flythrough"] = action(file_menu, "Export &fly-through video...", do.choose_flythrough)
    file_menu.addSeparator()
    action(file_menu, "&Quit", do.quit, "quit")
    view_menu = menu("&View")
    for name, text in (("camera_home", "&Reset camera"), ("camera_top", "Camera from &top"),
                       ("camera_front", "Camera from &front"), ("camera_listener", "Camera from the &listener")):
        action(view_menu, text, lambda n=name: do.camera_preset(n), name)
    view_menu.addSeparator()
    action(view_menu, "Play / pause", do.toggle_playing, "play")
    action(view_menu, "Turn left", lambda: do.turn(YAW_STEP), "turn_left")
    action(view_menu, "Turn right", lambda: do.turn(-YAW_STEP), "turn_right")
    view_menu.addSeparator()
    action(view_menu, "Play the &impulse response", do.play_response, "play_response")
    response = action(view_menu, "Impulse response &panel", lambda: do.show_response(response.isChecked()))
    response.setCheckable(True)
    response.setChecked(True)
    help_menu = menu("&Help")
    action(help_menu, "&Keys and mouse", do.show_help, "help")
    return Menus(key_actions, export_shot, export_audio, response, record, exports,
                 {"file": file_menu, "view": view_menu, "help": help_menu})


def help_dialog(parent: QtWidgets.QWidget) -> QtWidgets.QMessageBox:
    """Every key and mouse action (``help.KEYS`` and ``help.MOUSE``) in a dialog, to be shown non-blocking."""
    box = QtWidgets.QMessageBox(QtWidgets.QMessageBox.Icon.NoIcon, "AV-GS explorer: keys and mouse",
                                help_html(), QtWidgets.QMessageBox.StandardButton.Close, parent)
    box.setTextFormat(QtCore.Qt.TextFormat.RichText)
    return box
