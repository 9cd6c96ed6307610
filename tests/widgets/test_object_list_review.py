from PySide6 import QtCore

from evpose.widgets.object_list import ObjectList
from evpose.widgets.review_panel import ReviewPanel


def test_object_list_visibility_selection_scores(qtbot, session):
    w = ObjectList(session)
    qtbot.addWidget(w)
    w.item(0, 0).setCheckState(QtCore.Qt.Unchecked)
    assert session.object_names[0] in session.view.hidden
    session.set_object_visible(session.object_names[0], True)
    assert w.item(0, 0).checkState() == QtCore.Qt.Checked
    w.selectRow(2)
    assert session.view.selected == session.object_names[2]
    # the selected row keeps its colour swatch (the selection does not paint over it)
    assert w.item(2, 2).isSelected() and not w.item(2, 1).isSelected()
    assert w.item(2, 1).background().color().getRgb()[:3] == session.color(session.object_names[2])
    w.set_scores({"box": 0.234, "cylinder": None})
    assert w.item(0, 5).text() == "+0.23" and w.item(1, 5).text() == "–"
    session.nudge_object("box", "base", trans_mm=(1, 0, 0))
    assert w.item(0, 4).text() == "yes"


def test_review_marks_and_navigation(qtbot, session):
    w = ReviewPanel(session)
    qtbot.addWidget(w)
    win = session.view.window()
    w.note.setText("looks right")
    qtbot.mouseClick(w.buttons["verified"], QtCore.Qt.LeftButton)
    m = session.scene.corrections.reviews[-1]
    assert (m.t0_us, m.t1_us, m.status, m.note) == (win.t0_us, win.t1_us, "verified", "looks right")
    assert w.list.count() == 1
    # a range: start here, go 3 windows on, flag
    w.range_button.setChecked(True)
    session.step_windows(3)
    w.scope.setCurrentText("box")
    w.mark("flagged")
    f = session.scene.corrections.reviews[-1]
    assert f.t0_us == win.t0_us and f.t1_us == win.t1_us + 3 * session.view.window_us and f.object == "box"
    # next unreviewed skips the covered windows
    session.set_time(win.t_label_us)
    assert w.goto_next(lambda s: s is None)
    assert session.view.t_us >= win.t_label_us + 4 * session.view.window_us
    session.history.undo()
    assert len(session.scene.corrections.reviews) == 1 and w.list.count() == 1
