"""Keyboard in the main window (issue 16): single-key shortcuts never fire while a button has the focus after a
click, nor while the user types in a field; Esc or a click on the frame gives them back; the representation,
window and display shortcuts of the frame view."""
import numpy as np
from PySide6 import QtCore, QtWidgets


def _open(qtbot, window, scene_copy):
    s = window.controller.open_scene(scene_copy)
    window.activateWindow()
    qtbot.waitUntil(window.isActiveWindow, timeout=3000)  # window shortcuts need the active window
    return s


def _state(s):
    c = s.scene.corrections
    return len(c.reviews), dict(c.object_deltas), s.view.t_us, s.view.representation


def test_typing_after_clicking_a_button_fires_no_shortcut(qtbot, window, scene_copy):
    """Issue 16: typing "blurred edges" after a click on a button made two rejected marks, a 9.8 mm nudge and
    started playback."""
    s = _open(qtbot, window, scene_copy)
    s.select("box")
    verified = window.reviews.buttons["verified"]
    qtbot.mouseClick(verified, QtCore.Qt.LeftButton)
    assert QtWidgets.QApplication.focusWidget() is verified
    assert [m.status for m in s.scene.corrections.reviews] == ["verified"]      # the click did its job
    before = _state(s)
    steps = len(s.history)
    clicks = []
    verified.clicked.connect(lambda: clicks.append(1))
    qtbot.keyClicks(verified, "blurred edges")
    assert _state(s) == before and len(s.history) == steps         # no mark, no nudge, no step
    assert clicks == []                                             # Space did not click the button again
    assert not window.timeline.is_playing                           # Space did not start playback
    assert "r" in window.shortcut_guard.blocked and "Space" in window.shortcut_guard.blocked
    assert "keyboard focus" in window.statusBar().currentMessage()
    # Esc gives the focus back to the frame: the shortcuts work again
    qtbot.keyClick(verified, QtCore.Qt.Key_Escape)
    assert QtWidgets.QApplication.focusWidget() is window.frame_view.glw
    qtbot.keyClick(window.frame_view.glw, QtCore.Qt.Key_D)
    assert "box" in s.scene.corrections.object_deltas
    # Ctrl shortcuts are never held back
    qtbot.mouseClick(verified, QtCore.Qt.LeftButton)
    n = len(s.history)
    qtbot.keyClick(verified, QtCore.Qt.Key_Z, QtCore.Qt.ControlModifier)
    assert len(s.history) == n and s.history.can_redo


def test_typing_on_a_drop_down_box_changes_neither_the_box_nor_the_view(qtbot, window, scene_copy):
    """A typed "5" (the counts representation) on the focused nudge-step box picked its "5 mm" item by the box's
    keyboard search: the next nudge would have been 5x larger."""
    s = _open(qtbot, window, scene_copy)
    combo = window.panel.trans_step
    combo.setFocus(QtCore.Qt.MouseFocusReason)
    qtbot.waitUntil(lambda: QtWidgets.QApplication.focusWidget() is combo, timeout=2000)
    before, rep = combo.currentText(), s.view.representation
    qtbot.keyClicks(combo, "52")
    assert combo.currentText() == before and s.view.representation == rep
    assert "5" in window.shortcut_guard.blocked


def test_typing_in_a_field_fires_no_shortcut(qtbot, window, scene_copy):
    s = _open(qtbot, window, scene_copy)
    s.select("box")
    note = window.reviews.note
    qtbot.mouseClick(note, QtCore.Qt.LeftButton)
    before = _state(s)
    qtbot.keyClicks(note, "blurred edges 1 4 [x]")
    assert note.text() == "blurred edges 1 4 [x]"
    assert _state(s) == before and len(s.history) == 0 and not window.timeline.is_playing


def test_frame_view_shortcuts_switch_representation_window_and_display(qtbot, window, scene_copy):
    s = _open(qtbot, window, scene_copy)
    glw = window.frame_view.glw
    qtbot.waitUntil(window.frame_up_to_date, timeout=30_000)
    vs, us = np.nonzero(window.frame.labels.label_map < 0)
    k = np.argmax((us > 20) & (vs > 20))                                          # a background pixel
    pt = glw.mapFromScene(window.frame_view.vb.mapViewToScene(QtCore.QPointF(us[k], vs[k])))
    qtbot.mouseClick(glw.viewport(), QtCore.Qt.LeftButton, pos=pt)                  # off the objects
    assert QtWidgets.QApplication.focusWidget() is glw
    assert glw.scene().focusItem() is window.frame_view.vb      # the view box has the keys now ("-" is ours)
    for key, rep in ((QtCore.Qt.Key_4, "time_surface"), (QtCore.Qt.Key_5, "counts"), (QtCore.Qt.Key_1, "polarity")):
        qtbot.keyClick(glw, key)
        assert s.view.representation == rep
        assert window.frame_view.toolbar.rep_combo.currentData() == rep
        assert window.representation_actions[rep].isChecked()
    assert window.frame_view.toolbar.rep_combo.itemText(3).endswith("(4)")          # the indicator names the keys
    qtbot.keyClick(glw, QtCore.Qt.Key_Minus)
    assert s.view.window_us == 5_000
    qtbot.keyClick(glw, QtCore.Qt.Key_Equal)
    qtbot.keyClick(glw, QtCore.Qt.Key_Equal)
    assert s.view.window_us == 20_000
    qtbot.keyClick(glw, QtCore.Qt.Key_H)
    assert s.view.selected_only and window.actions_by_name["selected_only"].isChecked()
    qtbot.keyClick(glw, QtCore.Qt.Key_C, QtCore.Qt.ShiftModifier)
    assert s.view.outline_only and window.frame_view.toolbar.outline_only_action.isChecked()
    assert "contour" in s.view.overlays                                               # Shift+C is not C
    # display options redraw what is on screen: no frame is computed again
    submitted = dict(window._submitted_serial)
    s.set_view_option(contrast=2.0, event_opacity=0.5, mask_alpha=0.6)
    assert window._submitted_serial == submitted
    assert window.frame_view.image_item.opacity() == 0.5
    s.set_representation("counts")
    assert window._submitted_serial["frame"] > submitted["frame"]
    # the hover readout in the status bar goes when the mouse leaves the frame, other messages stay
    window.frame_view.hoverText.emit("u 1, v 2 | 0 ev")
    assert window.statusBar().currentMessage() == "u 1, v 2 | 0 ev"
    window.frame_view.hoverText.emit("")
    assert window.statusBar().currentMessage() == ""
    window.statusBar().showMessage("saved")
    window.frame_view.hoverText.emit("")
    assert window.statusBar().currentMessage() == "saved"
