"""Help, menus and navigation (issue 16 point 6): F1 help fits or scrolls and Esc closes it; the Review menu lists
every review action; menus use sentence case; N / Shift+N wrap around; progress and result boxes stay off the frame
view."""
import re

import pytest
from PySide6 import QtCore, QtWidgets

from evpose.app.actions import SHORTCUTS
from evpose.app.workers import Job, progress_dialog
from evpose.widgets.help_overlay import CLOSE_TEXT, balance_columns


def settle(qtbot, ms=100):
    QtWidgets.QApplication.processEvents()
    qtbot.wait(ms)


def focus_target(qtbot, window):
    window.activateWindow()
    qtbot.waitUntil(window.isActiveWindow, timeout=3000)      # window shortcuts need the active window
    return QtWidgets.QApplication.focusWidget() or window


def test_esc_closes_the_help_and_every_row_is_reachable(qtbot, window, scene_copy):
    window.controller.open_scene(scene_copy)
    window.resize(1366, 698)
    settle(qtbot)
    focus_target(qtbot, window)
    help = window.help
    window.actions_by_name["help"].trigger()
    settle(qtbot)
    assert help.isVisible() and help.geometry() == window.rect()
    assert QtWidgets.QApplication.focusWidget() is help         # so that Esc reaches it
    # at 1366 px the sections stand in columns and all of them fit: nothing to scroll
    assert help.content.sizeHint().height() <= help.scroll.viewport().height()
    assert help.scroll.verticalScrollBar().maximum() == 0
    assert len({lab.x() for lab in help.section_labels}) >= 3
    texts = "".join(lab.text() for lab in help.section_labels)
    for sc in SHORTCUTS:
        assert sc.text.split(" (")[0] in texts, sc.text
    qtbot.keyClick(help, QtCore.Qt.Key_Escape)
    assert not help.isVisible()
    # a small window: the help scrolls, and the last row can be brought into view
    window.resize(700, 420)
    settle(qtbot)
    window.actions_by_name["help"].trigger()
    settle(qtbot)
    bar = help.scroll.verticalScrollBar()
    assert bar.maximum() > 0
    bar.setValue(bar.maximum())
    settle(qtbot)
    last = help.section_labels[-1]
    bottom = last.mapTo(help.scroll.viewport(), QtCore.QPoint(0, last.height()))
    assert 0 < bottom.y() <= help.scroll.viewport().height()
    assert help.close_hint.isVisible() and CLOSE_TEXT in help.close_hint.text()
    # Esc through the window (a window-wide Esc shortcut must not take it), then F1 toggles
    qtbot.keyClick(QtWidgets.QApplication.focusWidget(), QtCore.Qt.Key_Escape)
    assert not help.isVisible()
    target = focus_target(qtbot, window)
    qtbot.keyClick(target, QtCore.Qt.Key_F1)
    assert help.isVisible()
    qtbot.keyClick(QtWidgets.QApplication.focusWidget(), QtCore.Qt.Key_F1)
    assert not help.isVisible()


def test_balanced_columns_keep_the_order():
    assert balance_columns([7, 4, 13, 3, 6, 5, 4], 3) == [[0, 1], [2, 3], [4, 5, 6]]
    assert balance_columns([5, 5], 4) == [[0], [1]]
    assert balance_columns([3, 3, 3], 1) == [[0, 1, 2]]


def _menu_actions(menu, path=""):
    for act in menu.actions():
        if act.isSeparator():
            continue
        if act.menu() is not None:
            yield f"{path}{act.text()}", act
            if act.menu().title() != "Open &recent":       # file paths
                yield from _menu_actions(act.menu(), f"{path}{act.text()} ▸ ")
        else:
            yield f"{path}{act.text()}", act


def test_menus_use_sentence_case(qtbot, window, scene_copy):
    window.controller.open_scene(scene_copy)
    seen = 0
    for top in window.menuBar().actions():
        for where, act in _menu_actions(top.menu(), top.text().replace("&", "") + " ▸ "):
            words = act.text().replace("&", "").split()
            assert words[0][0].isupper() or not words[0][0].isalpha(), where
            for w in words[1:]:
                core = re.sub(r"[^\w-]", "", w)
                # later words are lower case unless they are acronyms or names (ON, OFF, E-POSE, HDF5, BOP)
                assert not core[:1].isupper() or core.upper() == core, f"title case in {where!r}"
            seen += 1
    assert seen > 40


def test_the_review_menu_lists_every_review_action(qtbot, window, scene_copy):
    s = window.controller.open_scene(scene_copy)
    review = [m for m in window.menuBar().actions() if m.text() == "&Review"][0].menu()
    a = window.actions_by_name
    names = {n for n, act in a.items() if act in review.actions()}
    assert names == {"mark_verified", "mark_rejected", "mark_flagged", "review_range", "review_remove",
                     "next_unreviewed", "next_flagged"}
    # every button of the review panel has its menu entry
    panel_buttons = [b.text() for b in window.reviews.findChildren(QtWidgets.QPushButton)]
    assert len(panel_buttons) == 7
    # range start from the menu: the next mark covers the range
    t0 = s.time_range[0]
    s.set_time(t0 + 50_000)
    a["review_range"].trigger()
    assert window.reviews.range_button.isChecked()
    s.set_time(t0 + 95_000)
    a["mark_flagged"].trigger()
    (mark,) = s.scene.corrections.reviews
    assert (mark.t0_us, mark.t1_us, mark.status) == (t0 + 50_000, t0 + 100_000, "flagged")
    window.reviews.list.setCurrentRow(0)
    a["review_remove"].trigger()
    assert s.scene.corrections.reviews == []


def test_n_and_shift_n_wrap_around(qtbot, window, scene_copy):
    s = window.controller.open_scene(scene_copy)
    t0, t1 = s.time_range
    w = s.view.window_us
    s.add_review("flagged", t0 + 100_000, t0 + 110_000)
    s.add_review("flagged", t0 + 300_000, t0 + 310_000)
    s.add_review("verified", t0, t0 + 50_000)
    a = window.actions_by_name
    s.set_time(t0 + 200_005)
    a["next_flagged"].trigger()
    assert s.view.window().t0_us == t0 + 300_000
    a["next_flagged"].trigger()                       # past the last flagged window: back to the first
    assert s.view.window().t0_us == t0 + 100_000
    assert "wrapped" in window.reviews.status.text()
    a["next_flagged"].trigger()
    assert s.view.window().t0_us == t0 + 300_000 and "wrapped" not in window.reviews.status.text()
    # N from the last window: the first unreviewed window after the verified ones at the start
    s.set_time(t1 - 1)
    a["next_unreviewed"].trigger()
    assert s.view.window().t0_us == t0 + 50_000
    # with the keys, from the frame view
    s.set_time(t0 + 350_005)
    window.frame_view.setFocus()
    target = focus_target(qtbot, window)
    qtbot.keyClick(target, QtCore.Qt.Key_N, QtCore.Qt.ShiftModifier)
    assert s.view.window().t0_us == t0 + 100_000
    qtbot.keyClick(target, QtCore.Qt.Key_N)
    assert s.view.window().t0_us == t0 + 110_000
    # only one flagged window left, and it is the current one: Shift+N stays there
    s.remove_review([m for m in s.scene.corrections.reviews if m.t0_us == t0 + 300_000][0])
    s.set_time(t0 + 100_005)
    assert window.reviews.goto_next(lambda st: st == "flagged")
    assert s.view.window().t0_us == t0 + 100_000 and w == 10_000


@pytest.mark.parametrize("kind", ["progress", "message"])
def test_progress_and_result_boxes_leave_the_frame_view_visible(qtbot, window, scene_copy, kind):
    window.controller.open_scene(scene_copy)
    settle(qtbot, 300)
    if kind == "progress":
        job = Job(lambda progress, cancel: None)
        dlg = progress_dialog(window, "Export", "Exporting the scene (epose)…", job)
        dlg.show()
    else:
        dlg = QtWidgets.QMessageBox(QtWidgets.QMessageBox.Information, "Export done",
                                    "export done: 301 windows written, 0 already complete", parent=window)
        dlg.addButton("Open folder", QtWidgets.QMessageBox.ActionRole)
        dlg.show()
    qtbot.addWidget(dlg)
    settle(qtbot, 200)
    frame = QtCore.QRect(window.frame_view.mapToGlobal(QtCore.QPoint(0, 0)), window.frame_view.size())
    assert window.dialog_placer.placed >= 1
    assert not dlg.frameGeometry().intersects(frame), (dlg.frameGeometry(), frame)
    assert window.screen().availableGeometry().contains(dlg.frameGeometry())
    dlg.close()
