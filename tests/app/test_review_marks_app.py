"""Review marks in the app (issue 11 item 8): Home / End / a timeline click mark grid windows, a
second mark over a window replaces the first, stale marks are shown as stale in the review panel and
the timeline, and the export's done message counts the marked windows it could not use."""
from PySide6 import QtCore

from evpose.app.controller import export_done_text


def _grid(s, m):
    return (m.t0_us - s.time_range[0]) % s.view.window_us == 0 and m.t1_us - m.t0_us == s.view.window_us


def test_home_end_click_and_keys_mark_grid_windows(qtbot, window, scene_copy):
    s = window.controller.open_scene(scene_copy)
    a = window.actions_by_name
    a["go_start"].trigger()
    a["mark_verified"].trigger()
    a["go_end"].trigger()
    a["mark_verified"].trigger()
    a["step_back"].trigger()
    a["mark_verified"].trigger()
    window.timeline.request_time(s.time_range[0] + 333_333)           # a click on the timeline
    a["mark_verified"].trigger()
    marks = s.scene.corrections.reviews
    assert len(marks) == 4 and all(_grid(s, m) for m in marks)
    # the same window again, now rejected: one mark, rejected (no verified+rejected, no duplicate)
    a["mark_rejected"].trigger()
    assert len(s.scene.corrections.reviews) == 4
    assert s.scene.corrections.review_status(s.view.t_us) == "rejected"
    assert window.reviews.list.count() == 4


def test_stale_marks_are_shown_in_panel_and_timeline(qtbot, window, scene_copy):
    s = window.controller.open_scene(scene_copy)
    s.set_time(s.time_range[0] + 100_000)
    window.actions_by_name["mark_verified"].trigger()
    assert not window.reviews.stale and not any(r.stale for r in window.timeline.marks)
    prior = s.scene.manifest.clock_offset_us
    window.panel.offset_spin.setValue(1_500)
    item = window.reviews.list.item(0)
    assert f"STALE: verified at offset {prior} us (now {prior + 1500} us)" in item.text()
    assert item.font().italic() and "1 stale" in window.reviews.status.text()
    region = window.timeline.marks[0]
    assert region.stale and region.item.brush.style() == QtCore.Qt.BDiagPattern
    assert "STALE" in region.item.toolTip()
    window.actions_by_name["undo"].trigger()                           # back to the marked clock
    assert not window.reviews.stale and not window.timeline.marks[0].stale


def test_export_done_message_counts_unused_marked_windows(qtbot, window, scene_copy, tmp_path):
    s = window.controller.open_scene(scene_copy)
    s.set_offset_correction_us(-20_000)
    t0 = s.time_range[0]
    s.add_review("verified", t0 + 100_000, t0 + 120_000)              # two whole windows
    s.add_review("verified", t0 + 205_000, t0 + 215_000)              # off the grid: two partly covered
    window.controller.start_export(fmt="epose", out_dir=str(tmp_path / "out"), window_us=10_000, only_verified=True)
    qtbot.waitUntil(lambda: bool(window.last_export is not None or window.last_error), timeout=120_000)
    summary = window.last_export
    assert summary is not None, window.last_error
    msg = window.statusBar().currentMessage()
    assert msg == export_done_text(summary)
    assert "verified marks touch 4 windows: 2 exported, 2 not used (2 partly covered)" in msg
