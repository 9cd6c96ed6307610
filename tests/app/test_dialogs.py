"""The crash-restore question and the export dialog (issue 16 point 6): the question names what a restore sets;
the export dialog defaults beside the scene, remembers format and options, counts the windows it will write
(and the verified ones), and a done message offers "Open folder"."""
import shiboken6
from PySide6 import QtCore, QtGui

from evpose.app.export_dialog import ExportDialog, window_counts
from evpose.app.restore_dialog import TITLE as RESTORE_TITLE
from evpose.core.export.windows import build_windows, scene_staleness, verified_mask

YES = 0x00004000


def test_the_restore_question_names_what_it_restores(qtbot, window, scene_copy):
    s = window.controller.open_scene(scene_copy)
    t0 = s.time_range[0]
    s.set_offset_correction_us(7_000)
    s.nudge_object("box", "camera", trans_mm=(2.0, 0, 0))
    s.nudge_object("cylinder", "camera", rot_deg=(0, 0, 3.0))
    s.add_review("verified", t0, t0 + 10_000)
    s.add_review("flagged", t0 + 50_000, t0 + 60_000)
    assert s.write_journal() is not None
    s.history.clear()                                   # a crash: reopen without saving
    window.auto_answer[RESTORE_TITLE] = YES
    s2 = window.controller.open_scene(scene_copy)
    text = window.controller.questions[RESTORE_TITLE]
    assert "clock offset correction +7.000 ms (now +0.000 ms)" in text
    assert "poses of 2 objects: box, cylinder" in text and "flatbox" not in text
    assert "2 review marks (now 0)" in text
    assert "skew" not in text and "hand-eye" not in text          # only what changes
    assert s2.scene.corrections.offset_us == 7_000 and len(s2.scene.corrections.reviews) == 2


def _dialog(qtbot, window, s):
    dlg = ExportDialog(window, s.scene, window.settings)
    qtbot.addWidget(dlg)
    return dlg


def test_export_dialog_defaults_remembers_and_counts(qtbot, window, scene_copy):
    s = window.controller.open_scene(scene_copy)
    dlg = _dialog(qtbot, window, s)
    name = s.scene.name
    assert dlg.out.text() == str(scene_copy.parent / f"{name}_epose")      # beside the scene
    dlg.fmt.setCurrentIndex(dlg.fmt.findData("bop"))
    assert dlg.out.text() == str(scene_copy.parent / f"{name}_bop")        # follows the format until edited
    dlg.out.setText("/somewhere/else")
    dlg.fmt.setCurrentIndex(dlg.fmt.findData("h5"))
    assert dlg.out.text() == "/somewhere/else"
    # counts: every window of the tiling, and the verified ones
    store = s.scene.events
    n = len(build_windows(store, window_us=10_000))
    assert dlg.n_windows == n and dlg.n_verified == 0
    assert f"{n:,}</b> windows of 10 ms will be written (0 of them verified)" in dlg.counts.text()
    t0 = s.time_range[0]
    s.add_review("verified", t0 + 100_000, t0 + 130_000)                   # three windows
    s.add_review("verified", t0 + 205_000, t0 + 215_000)                   # off the grid: none whole
    dlg.only_verified.setChecked(True)
    assert dlg.n_verified == 3 and "<b>3</b> windows will be written" in dlg.counts.text()
    dlg.window_ms.setValue(20.0)                                            # [100, 120) only
    assert dlg.n_windows == len(build_windows(store, window_us=20_000)) and dlg.n_verified == 1
    dlg.window_events.setValue(5_000)
    keep = verified_mask(build_windows(store, window_events=5_000), s.scene.corrections.reviews,
                         list(s.object_names), scene_staleness(s.scene))
    assert dlg.n_windows == len(build_windows(store, window_events=5_000)) and dlg.n_verified == int(keep.sum())
    assert "windows of 5,000 events" in dlg.counts.text()
    # a clock change makes the marks stale: not counted, unless stale marks are included
    dlg.window_events.setValue(0)
    dlg.window_ms.setValue(10.0)
    s.set_offset_correction_us(1_000)
    dlg.update_counts()
    assert dlg.n_verified == 0
    dlg.include_stale.setChecked(True)
    assert dlg.n_verified == 3
    # remembered: format and options (not the folder, which follows the scene)
    dlg.jobs.setValue(dlg.jobs.maximum())
    dlg.label_at.setCurrentIndex(dlg.label_at.findData("end"))
    opts = dlg.options()
    dlg.remember()
    again = _dialog(qtbot, window, s)
    assert again.options() == {**opts, "out_dir": str(scene_copy.parent / f"{name}_h5")}
    assert window_counts(s.scene, window_us=10_000, include_stale=True) == (n, 3)


def test_export_done_message_opens_the_folder(qtbot, window, scene_copy, tmp_path, monkeypatch):
    s = window.controller.open_scene(scene_copy)
    t0 = s.time_range[0]
    s.add_review("verified", t0 + 100_000, t0 + 120_000)
    opened = []
    monkeypatch.setattr(QtGui.QDesktopServices, "openUrl", lambda url: opened.append(url.toLocalFile()) or True)
    window.controller.start_export(fmt="epose", out_dir=str(tmp_path / "out"), window_us=10_000, only_verified=True)
    qtbot.waitUntil(lambda: bool(window.controller.done_box is not None or window.last_error), timeout=120_000)
    box = window.controller.done_box
    assert box is not None, window.last_error
    assert box.isVisible() and not box.isModal()
    assert "export done: 2 windows written" in box.text() and str(tmp_path / "out") in box.informativeText()
    frame = QtCore.QRect(window.frame_view.mapToGlobal(QtCore.QPoint(0, 0)), window.frame_view.size())
    qtbot.wait(50)
    assert not box.frameGeometry().intersects(frame)                # the frame stays visible
    box.open_button.click()
    assert opened == [str(tmp_path / "out")]
    qtbot.waitUntil(lambda: not shiboken6.isValid(box) or not box.isVisible(), timeout=3000)   # and it closes


def test_export_dialog_counts_once_per_entered_value_not_per_keystroke(qtbot, window, scene_copy, monkeypatch):
    import evpose.app.export_dialog as ed

    s = window.controller.open_scene(scene_copy)
    dlg = _dialog(qtbot, window, s)
    calls = []
    real = ed.window_counts
    monkeypatch.setattr(ed, "window_counts", lambda *a, **k: calls.append(k) or real(*a, **k))
    box = dlg.window_events
    box.lineEdit().selectAll()
    qtbot.keyClicks(box.lineEdit(), "5000")
    assert calls == []                                   # typing: no recount (up to 4000 event reads each)
    qtbot.keyClick(box.lineEdit(), QtCore.Qt.Key_Return)
    assert len(calls) == 1 and calls[0]["window_events"] == 5000 and "5,000 events" in dlg.counts.text()
