"""The app notices another program saving corrections.json (issue 11 item 2): with no unsaved edits
it reloads silently and says so; with unsaved edits it merges (or reloads, or defers to the save);
a real conflict names the field and both values. The change taken over is one labelled undo step."""
import json
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np

from evpose.core.document.corrections import Corrections

EVPOSE = str(Path(sys.executable).with_name("evpose"))

#: Another program: load corrections.json, change one field, save (through the checked save path).
OTHER = textwrap.dedent('''
    import sys
    from evpose.core.document.corrections import Corrections
    path, key, value = sys.argv[1], sys.argv[2], sys.argv[3]
    try:
        doc = Corrections.load(path)
    except Exception:
        doc = Corrections()
    if key == "offset_us":
        doc.set(("offset_us",), int(value))
    else:
        doc.set(("skew_ppm",), float(value))
    doc.save(path)
''')


def other_program_saves(scene_dir, key, value):
    subprocess.run([sys.executable, "-c", OTHER, str(scene_dir / "corrections.json"), key, str(value)],
                   check=True, timeout=60)


def status(window) -> str:
    return window.statusBar().currentMessage()


def test_cli_apply_while_the_app_is_open_reloads_silently(qtbot, window, scene_copy):
    s = window.controller.open_scene(scene_copy)
    assert not window.isWindowModified()
    run = subprocess.run([EVPOSE, "sync", str(scene_copy), "--apply", "-q", "--json"], capture_output=True,
                         text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    applied = json.loads(run.stdout)["correction"]["offset_us"]
    assert applied != 0
    qtbot.waitUntil(lambda: s.scene.corrections.offset_us == applied, timeout=15_000)
    assert "changed by another program" in status(window) and "reloaded" in status(window)
    assert not window.isWindowModified()                    # the document equals the file
    assert "reload corrections.json (revision 1" in s.history.undo_text
    # the external change is an undo step of its own: undo goes back, and the window shows it unsaved
    window.actions_by_name["undo"].trigger()
    assert s.scene.corrections.offset_us == 0 and window.isWindowModified()
    window.actions_by_name["redo"].trigger()
    assert s.scene.corrections.offset_us == applied and not window.isWindowModified()


def test_unsaved_edits_merge_with_the_external_change(qtbot, window, scene_copy):
    s = window.controller.open_scene(scene_copy)
    s.nudge_object("box", "camera", trans_mm=(1, 0, 0), mergeable=False)      # unsaved local edit
    box = s.scene.corrections.object_delta("box")
    window.auto_answer["Corrections changed on disk"] = "merge"
    other_program_saves(scene_copy, "skew_ppm", 3.5)
    qtbot.waitUntil(lambda: s.scene.corrections.skew_ppm == 3.5, timeout=15_000)
    assert np.array_equal(s.scene.corrections.object_delta("box"), box)      # ours kept
    assert window.isWindowModified() and "merged" in status(window)
    assert "merge another program's change" in s.history.undo_text
    window.actions_by_name["save"].trigger()
    saved = Corrections.load(scene_copy / "corrections.json")
    assert saved.skew_ppm == 3.5 and np.array_equal(saved.object_delta("box"), box)
    assert saved.revision == 2 and not window.isWindowModified()


def test_conflict_names_the_field_and_both_values_and_keeps_the_choice(qtbot, window, scene_copy):
    s = window.controller.open_scene(scene_copy)
    s.set_offset_correction_us(1_000, mergeable=False)
    window.auto_answer["Corrections changed on disk"] = "merge"
    window.auto_answer["Conflicting change on disk"] = "cancel"
    other_program_saves(scene_copy, "offset_us", 2_000)
    qtbot.waitUntil(lambda: "not merged" in status(window), timeout=15_000)
    msg = status(window)
    assert "clock.offset_us" in msg and "1000 us" in msg and "2000 us" in msg
    assert s.scene.corrections.offset_us == 1_000                              # nothing changed
    # saving now is refused the same way until the user picks a side
    assert window.controller.save() is False
    assert Corrections.load(scene_copy / "corrections.json").offset_us == 2_000
    window.auto_answer["Conflicting change on disk"] = "local"
    assert window.controller.save() is True
    assert Corrections.load(scene_copy / "corrections.json").offset_us == 1_000


def test_reload_discards_unsaved_edits_and_undo_brings_them_back(qtbot, window, scene_copy):
    s = window.controller.open_scene(scene_copy)
    s.set_offset_correction_us(1_000, mergeable=False)
    window.auto_answer["Corrections changed on disk"] = "reload"
    other_program_saves(scene_copy, "skew_ppm", -2.0)
    qtbot.waitUntil(lambda: s.scene.corrections.skew_ppm == -2.0, timeout=15_000)
    assert s.scene.corrections.offset_us == 0 and not window.isWindowModified()
    window.actions_by_name["undo"].trigger()
    assert s.scene.corrections.offset_us == 1_000 and s.scene.corrections.skew_ppm == 0.0


def test_later_defers_to_the_save_which_merges(qtbot, window, scene_copy):
    s = window.controller.open_scene(scene_copy)
    s.set_offset_correction_us(1_000, mergeable=False)
    window.auto_answer["Corrections changed on disk"] = "later"
    other_program_saves(scene_copy, "skew_ppm", 7.0)
    qtbot.waitUntil(lambda: "merged when you save" in status(window), timeout=15_000)
    assert s.scene.corrections.skew_ppm == 0.0
    qtbot.wait(2_500)                                  # not asked again for the same change (poll ran)
    assert "merged when you save" in status(window)
    assert window.controller.save()
    assert "merged clock.skew_ppm" in status(window)
    doc = Corrections.load(scene_copy / "corrections.json")
    assert (doc.offset_us, doc.skew_ppm) == (1_000, 7.0)
    assert s.scene.corrections.skew_ppm == 7.0 and not window.isWindowModified()


def test_own_saves_are_not_reported_as_external(qtbot, window, scene_copy):
    s = window.controller.open_scene(scene_copy)
    s.set_offset_correction_us(500, mergeable=False)
    window.actions_by_name["save"].trigger()
    n = len(s.history)
    qtbot.wait(2_500)                                  # watcher debounce and one poll
    assert window.controller.on_disk_change() is None
    assert len(s.history) == n and "revision 1" in status(window)


def test_unknown_object_in_corrections_is_reported_on_open(qtbot, window, scene_copy):
    T = np.eye(4)
    T[0, 3] = 0.001
    (scene_copy / "corrections.json").write_text(json.dumps(
        {"format": "evpose-corrections/1", "objects": {"ghost": {"dT_base": T.tolist()}}}))
    window.controller.open_scene(scene_copy)
    assert window.controller.open_warnings and "ghost" in window.controller.open_warnings[0]
    assert "ghost" in status(window) and "corrections.json" in status(window)
