"""The real window under Xvfb on the bundled L-shaped house: typed poses, the room's outline,
keys and mouse as the Help lists them, meters and pictures, driven with real Qt events."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("pytestqt")
from PySide6 import QtCore, QtGui, QtWidgets  # noqa: E402

from avgs_viewer import colors, help  # noqa: E402
from avgs_viewer.window import MainWindow  # noqa: E402

pytestmark = pytest.mark.gui
DEMO = Path(__file__).resolve().parents[1] / "assets" / "demo" / "scene.ckpt"
Key = QtCore.Qt.Key


@pytest.fixture
def window(qtbot):
    if not DEMO.is_file():
        pytest.skip("no bundled demo scene")
    w = MainWindow(start_audio=False)
    qtbot.addWidget(w)
    w.resize(1100, 760)
    w.show()
    w.activateWindow()
    qtbot.waitActive(w)
    with qtbot.waitSignal(w.scene_loaded, timeout=60_000):
        w.open_scene(DEMO)
    yield w
    w.close()


def type_into(qtbot, box: QtWidgets.QDoubleSpinBox, text: str) -> None:
    """Click into a field, replace its text by typing, press Enter."""
    qtbot.mouseClick(box.lineEdit(), QtCore.Qt.MouseButton.LeftButton)
    box.lineEdit().selectAll()
    qtbot.keyClicks(box.lineEdit(), text)
    qtbot.keyClick(box.lineEdit(), Key.Key_Return)


def to_qt(w: MainWindow, display_xy) -> QtCore.QPoint:
    """VTK display pixels (origin bottom left) -> widget coordinates."""
    scale = w.plotter.devicePixelRatioF()
    return QtCore.QPoint(int(round(display_xy[0] / scale)), int(round(w.plotter.height() - 1 - display_xy[1] / scale)))


def picture(w: MainWindow) -> np.ndarray:
    return w.plotter.screenshot(return_img=True)[..., :3].astype(int)


def pixel(img: np.ndarray, display_xy) -> np.ndarray:
    return img[int(round(img.shape[0] - 1 - display_xy[1])), int(round(display_xy[0]))]


def heard_pose(qtbot, w: MainWindow) -> None:
    """Until the audio path plays the state's pose."""
    qtbot.waitUntil(lambda: w.live.last_request is not None and w.live.last_request.pose == w.state.pose,
                    timeout=30_000)


def test_typed_pose_moves_the_handles_and_the_sound(qtbot, window):
    w, pose = window, window.panel.pose
    assert [b.value() for b in pose.listener] == pytest.approx(list(w.state.listener), abs=0.005)
    type_into(qtbot, pose.listener[0], "2.5")
    type_into(qtbot, pose.listener[1], "1.25")
    type_into(qtbot, pose.listener[2], "1.4")
    type_into(qtbot, pose.yaw, "90")
    type_into(qtbot, pose.source[0], "7")
    movable = w.renderer.source_aware  # a scene trained with one source position keeps it (read-only fields)
    assert np.allclose(w.state.listener, (2.5, 1.25, 1.4)) and w.state.yaw == 90.0
    assert w.state.source[0] == (7.0 if movable else w.renderer.source[0]) and w.panel.yaw.value() == 90
    assert pose.notice.text() == ""  # all inside the room
    heard_pose(qtbot, w)  # what plays is the typed pose
    img = picture(w)
    proj = w.view.projector()
    for where, colour in ((w.state.listener, colors.LISTENER_COLOUR), (w.state.source, colors.SOURCE_COLOUR)):
        px = pixel(img, proj.to_display(where)) / 255
        assert np.abs(px - np.asarray(colour)).max() < 0.45  # the sphere is drawn where it was typed
    # A drag shows in the fields.
    w.state.set_source((6.0, 2.0, 1.0))
    assert [b.value() for b in pose.source] == pytest.approx([6.0, 2.0, 1.0] if movable else list(w.renderer.source),
                                                             abs=0.005)
    # Keys typed into a field being edited stay in it: no turn, no camera preset, no pause.
    field = (pose.source[1] if movable else pose.listener[1]).lineEdit()  # a field one can type into
    qtbot.mouseClick(field, QtCore.Qt.MouseButton.LeftButton)
    qtbot.keyClick(field, Key.Key_Backspace)  # a value being typed: letters stay in the field until Enter or Escape
    before = camera(w), w.state.yaw, w.state.playing
    for key in (Key.Key_Left, Key.Key_Right, Key.Key_Q, Key.Key_T, Key.Key_L, Key.Key_Space):
        qtbot.keyClick(field, key)
    after = camera(w), w.state.yaw, w.state.playing
    assert all(np.array_equal(x, y) for x, y in zip(before[0], after[0])) and before[1:] == after[1:]


def test_positions_stay_inside_the_room_with_a_visible_note(qtbot, window):
    w, pose = window, window.panel.pose
    ring = w.state.footprint.rings[0]
    hi = ring.max(axis=0)
    # Typed 2 m past the floor plan's far wall: moved back onto it (the floor-plan shapes
    # themselves, L-shaped rooms included: tests/test_viewer_outline.py).
    type_into(qtbot, pose.listener[0], f"{hi[0] + 2.0:.2f}")
    assert w.state.footprint.contains(w.state.listener[:2])
    assert hi[0] - 0.5 < w.state.listener[0] <= hi[0] + 1e-6
    assert "listener kept inside the room" in pose.notice.text()
    assert "listener kept inside the room" in w.position_notice.text()
    assert pose.listener[1].value() == pytest.approx(w.state.listener[1], abs=0.005)  # the field shows where it went
    type_into(qtbot, pose.source[2], "40")
    if w.renderer.source_aware:
        assert w.state.source[2] == pytest.approx(w.state.footprint.z_range[1]) and "source kept inside the room" in pose.notice.text()
    else:  # a scene trained with one source position: the source stays (tests/test_viewer_response_gui.py)
        assert w.state.source[2] == pytest.approx(w.renderer.source[2]) and pose.source[2].isReadOnly()

    # A real mouse drag of the listener past the floor plan's corner stops at the wall.
    lo = ring.min(axis=0)
    w.state.set_listener(((lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, w.state.listener[2]))
    w.plotter.render_now()
    QtWidgets.QApplication.processEvents()
    proj = w.view.projector()
    z = w.state.listener[2]
    start = to_qt(w, proj.to_display(w.state.listener))
    end = to_qt(w, proj.to_display(np.array([hi[0] + 1.5, hi[1] + 1.5, z])))
    qtbot.mousePress(w.plotter, QtCore.Qt.MouseButton.LeftButton, pos=start)
    assert w.drag.dragging == "listener"
    for t in np.linspace(0, 1, 8)[1:]:
        qtbot.mouseMove(w.plotter, pos=start + (end - start) * float(t))
    qtbot.mouseRelease(w.plotter, QtCore.Qt.MouseButton.LeftButton, pos=end)
    assert w.state.footprint.contains(w.state.listener[:2])
    assert np.all(w.state.listener[:2] <= hi + 1e-6) and np.all(w.state.listener[:2] > hi - 1.5)


def camera(w: MainWindow):
    c = w.plotter.camera
    return np.array(c.position), np.array(c.focal_point), np.array(c.up)


def test_vtk_default_keys_do_nothing_and_camera_keys_work(qtbot, window):
    w = window
    w.plotter.setFocus()
    points = w.view._points_actor.prop
    before = camera(w), points.point_size, points.style, w.plotter.render_window.GetStereoRender()
    img = picture(w)
    for key in "3wspjtuvf+-":  # stereo, wireframe, surface, pick, joystick, ..., point size
        if key in "tf":
            continue  # ours (camera presets), tested below
        qtbot.keyClick(w.plotter, key)
    after = camera(w), points.point_size, points.style, w.plotter.render_window.GetStereoRender()
    assert all(np.array_equal(a, b) for a, b in zip(before[0], after[0])) and before[1:] == after[1:]
    assert np.array_equal(picture(w), img) and w.isVisible()

    qtbot.keyClick(w.plotter, Key.Key_T)  # from above
    pos, focal, up = camera(w)
    assert np.allclose((focal - pos) / np.linalg.norm(focal - pos), (0, 0, -1)) and np.allclose(up, (0, 1, 0))
    qtbot.keyClick(w.plotter, Key.Key_F)  # from the front (the -y side)
    pos, focal, up = camera(w)
    assert np.allclose((focal - pos) / np.linalg.norm(focal - pos), (0, 1, 0))
    qtbot.keyClick(w.plotter, Key.Key_L)  # from the listener, along its yaw; it follows a turn
    pos, focal, _ = camera(w)
    assert np.allclose(pos, w.state.listener) and np.allclose(focal - pos, w.state.facing) and w.view.first_person
    qtbot.keyClick(w.plotter, Key.Key_Q)
    pos, focal, _ = camera(w)
    assert np.allclose(focal - pos, w.state.facing) and w.state.yaw == 15.0
    qtbot.keyClick(w.plotter, Key.Key_R)  # home: the listener's sphere shows again
    assert not w.view.first_person and w.view._listener_actor.GetVisibility()


def drag(qtbot, w, button, start, end, modifier=QtCore.Qt.KeyboardModifier.NoModifier):
    qtbot.mousePress(w.plotter, button, modifier, start)
    for t in np.linspace(0, 1, 6)[1:]:
        qtbot.mouseMove(w.plotter, pos=start + (end - start) * float(t))
    qtbot.mouseRelease(w.plotter, button, modifier, end)


def test_help_lists_every_key_and_the_mouse_does_what_it_says(qtbot, window):
    w = window
    qtbot.keyClick(w, Key.Key_F1)
    assert w.help_dialog is not None and w.help_dialog.isVisible()
    text = w.help_dialog.text()
    bound = {}
    for action in w.findChildren(QtGui.QAction):
        for seq in action.shortcuts():
            bound[seq.toString()] = action
    listed = set()
    for k in help.KEYS:
        assert f"<b>{' / '.join(k.keys)}</b>" in text and k.does in text
        assert [s.toString() for s in w.key_actions[k.name].shortcuts()] == list(k.keys)
        listed.update(k.keys)
    assert set(bound) == listed  # no key the Help does not list
    for gesture, does in help.MOUSE:
        assert gesture in text and does in text
    w.help_dialog.close()

    # The mouse, as listed, in the home view, from a corner away from the handles.
    qtbot.keyClick(w.plotter, Key.Key_R)
    rect = w.plotter.rect()
    a = QtCore.QPoint(int(rect.width() * 0.15), int(rect.height() * 0.12))
    b = a + QtCore.QPoint(60, 40)
    L = QtCore.Qt.MouseButton
    mods = QtCore.Qt.KeyboardModifier

    def direction(cam):
        d = cam[1] - cam[0]
        return d / np.linalg.norm(d)

    c0 = camera(w)
    drag(qtbot, w, L.LeftButton, a, b)  # orbit: the direction turns about the same focal point
    c1 = camera(w)
    assert np.allclose(c1[1], c0[1]) and not np.allclose(direction(c1), direction(c0), atol=1e-3)
    drag(qtbot, w, L.LeftButton, a, b, mods.ShiftModifier)  # pan: everything slides, same direction
    c2 = camera(w)
    assert np.allclose(direction(c2), direction(c1), atol=1e-6) and not np.allclose(c2[1], c1[1])
    drag(qtbot, w, L.MiddleButton, b, a)  # pan back
    c3 = camera(w)
    assert np.allclose(direction(c3), direction(c2), atol=1e-6) and not np.allclose(c3[1], c2[1])
    drag(qtbot, w, L.RightButton, a, b)  # zoom: nearer or farther along the same direction
    c4 = camera(w)
    assert np.allclose(direction(c4), direction(c3), atol=1e-6)
    assert np.linalg.norm(c4[1] - c4[0]) != pytest.approx(np.linalg.norm(c3[1] - c3[0]))
    dist = np.linalg.norm(c4[1] - c4[0])
    wheel = QtGui.QWheelEvent(QtCore.QPointF(a), QtCore.QPointF(w.plotter.mapToGlobal(a)), QtCore.QPoint(0, 0),
                              QtCore.QPoint(0, 120), L.NoButton, mods.NoModifier, QtCore.Qt.ScrollPhase.NoScrollPhase,
                              False)
    QtWidgets.QApplication.sendEvent(w.plotter, wheel)
    c5 = camera(w)
    assert np.linalg.norm(c5[1] - c5[0]) < dist  # the wheel zooms in
    drag(qtbot, w, L.LeftButton, a, b, mods.ControlModifier)  # roll: same direction, the up vector turns
    c6 = camera(w)
    assert np.allclose(direction(c6), direction(c5), atol=1e-6) and not np.allclose(c6[2], c5[2], atol=1e-3)


def test_window_picture_with_legend_and_caption_covers_no_handle(qtbot, window, tmp_path):
    w = window
    plain = w.export_screenshot(tmp_path / "plain.png")
    marked = w.export_screenshot(tmp_path / "marked.png", legend=True, caption=True)
    import pyvista as pv

    def read(path):
        img = pv.read(path)
        width, height = img.dimensions[:2]
        return img.point_data[img.point_data.keys()[0]].reshape(height, width, -1)[::-1, :, :3].astype(int)

    a, b = read(plain), read(marked)
    assert a.shape == b.shape and np.abs(a - b).sum() > 0  # legend and caption were drawn
    for c, r in w.view.handle_circles(margin=0):
        x, y = int(c[0]), int(a.shape[0] - 1 - c[1])
        patch = (slice(max(y - int(r), 0), y + int(r)), slice(max(x - int(r), 0), x + int(r)))
        assert np.array_equal(a[patch], b[patch])  # not one pixel of a handle changed
    assert w.view.legend_corner is None and w.view._caption is None  # and gone from the window after


def test_meters_are_labelled_and_no_sound_card_is_said_in_plain_words(window):
    w = window
    assert [label.text() for label in w.panel.meter_labels] == ["<b>L</b>", "<b>R</b>"]
    assert w.audio_status.text().startswith("Audio output off")  # this window was opened without audio
    from avgs_viewer.audio_path import audio_status_text

    text = audio_status_text("No audio device: Error querying device -1", 22050)
    assert text.startswith("No audio: no sound card found") and "Error" not in text and "-1" not in text
