"""The autosave journal through the app (issue 22 item 1): a journal is removed whenever the document comes back
to the saved content (undo, redo), on every save and on every clean quit, so an intermediate state autosaved
during an undo excursion is never offered later; a real crash still offers the unsaved work. Driven through the
main window's own actions and autosave timer, as a user would."""
import json

import pytest
from PySide6 import QtCore

from evpose.app.restore_dialog import TITLE as RESTORE_TITLE

DISCARD = 0x00800000


def _new_window(qtbot, tmp_path, name):
    from evpose.app.main_window import MainWindow
    from evpose.app.settings import Settings

    w = MainWindow(Settings(QtCore.QSettings(str(tmp_path / f"{name}.ini"), QtCore.QSettings.IniFormat)))
    w.modal_dialogs = False
    qtbot.addWidget(w)
    w.show()
    return w


def _tick(window):
    """One autosave timer tick (the timer's own slot)."""
    window._autosave.timeout.emit()


def _saved(scene_dir) -> dict:
    data = json.loads((scene_dir / "corrections.json").read_text())
    return {"clock": data["clock"], "reviews": len(data["reviews"])}


@pytest.mark.parametrize("saved_before_undo", [True, False])
def test_undo_redo_save_quit_reopen_offers_nothing_and_keeps_the_saved_work(qtbot, window, scene_copy, tmp_path,
                                                                          saved_before_undo):
    s = window.controller.open_scene(scene_copy)
    a = window.actions_by_name
    t0 = s.time_range[0]
    s.set_offset_correction_us(12_000, mergeable=False)
    _tick(window)
    for k in range(5):                                    # five review marks, autosaved as the user goes
        s.add_review("verified", t0 + 20_000 * k, t0 + 20_000 * k + 10_000)
        _tick(window)
    assert s.journal_path.exists()
    if saved_before_undo:
        a["save"].trigger()
        assert not s.journal_path.exists()
    while s.history.can_undo:                             # undo everything, autosaving on the way
        a["undo"].trigger()
        _tick(window)
        if s.history.can_undo:
            assert s.journal_path.exists() == s.unsaved   # an intermediate state is unsaved work while it lasts
    assert s.unsaved == saved_before_undo
    while s.history.can_redo:                             # redo everything
        a["redo"].trigger()
        _tick(window)
    assert window.isWindowModified() != saved_before_undo  # clean again when the end state was saved
    a["save"].trigger()
    assert not s.journal_path.exists()
    expected = _saved(scene_copy)
    assert expected["clock"]["offset_us"] == 12_000 and expected["reviews"] == 5
    window.close()                                        # quit
    assert not s.journal_path.exists()

    again = _new_window(qtbot, tmp_path, "again")
    s2 = again.controller.open_scene(scene_copy)
    assert RESTORE_TITLE not in again.controller.questions      # nothing offered
    assert s2.scene.corrections.offset_us == 12_000 and len(s2.scene.corrections.reviews) == 5
    assert _saved(scene_copy) == expected
    again.close()


def test_a_clean_quit_removes_a_journal_and_a_crash_keeps_it(qtbot, window, scene_copy, tmp_path):
    s = window.controller.open_scene(scene_copy)
    s.set_offset_correction_us(3_000, mergeable=False)
    _tick(window)
    s.set_offset_correction_us(0, mergeable=False)        # back to the saved value, not by undo: nothing to save
    assert not window.isWindowModified() and not s.unsaved and not s.dirty
    _tick(window)
    assert not s.journal_path.exists()
    s.set_offset_correction_us(4_000, mergeable=False)
    _tick(window)
    s.history.clear()                                     # a crash: the app goes without asking or saving
    window.close()
    assert s.journal_path.exists()
    crashed = _new_window(qtbot, tmp_path, "crashed")
    crashed.auto_answer[RESTORE_TITLE] = 0x00004000       # Yes
    s2 = crashed.controller.open_scene(scene_copy)
    assert "clock offset correction +4.000 ms (now +0.000 ms)" in crashed.controller.questions[RESTORE_TITLE]
    assert s2.scene.corrections.offset_us == 4_000 and crashed.isWindowModified()
    crashed.auto_answer["Unsaved corrections"] = DISCARD
    crashed.close()                                       # quit, discarding the restored edits
    assert not s2.journal_path.exists()
