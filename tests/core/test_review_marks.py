"""Review marks (issue 11 item 8): marks on the export grid, one status per window, no duplicates,
stale marks after a clock or pose change, and what an only-verified export does with marked windows."""
import json

import pytest

from evpose.app.cli.export import summary_text
from evpose.core.document.corrections import Corrections, ReviewMark
from evpose.core.document.review import MarkState, effective_status, grid_window, insert_mark, normalize_marks
from evpose.core.export import export_scene
from evpose.core.export.windows import (
    REVIEW_MIXED,
    REVIEW_NO_LABEL,
    REVIEW_PARTLY,
    REVIEW_STALE,
    review_usage,
    verified_mask,
)
from evpose.core.label.windows import Window
from evpose.core.session.model import Session


# ---------------------------------------------------------------------------- the mark algebra
def test_new_mark_replaces_older_marks_of_its_scope_on_the_overlap():
    marks = insert_mark([], ReviewMark(0, 100, "verified"))
    marks = insert_mark(marks, ReviewMark(40, 60, "rejected"))
    assert [(m.t0_us, m.t1_us, m.status) for m in marks] == [(0, 40, "verified"), (40, 60, "rejected"),
                                                            (60, 100, "verified")]
    # the same window twice: one mark, not two
    again = insert_mark(marks, ReviewMark(40, 60, "rejected"))
    assert again == marks
    # no instant is covered by two marks of one scope
    for t in range(0, 100):
        assert sum(m.covers(t) for m in again if m.object is None) == 1


def test_scopes_object_mark_wins_and_later_all_objects_mark_trims_it():
    marks = insert_mark([], ReviewMark(0, 100, "verified"))
    marks = insert_mark(marks, ReviewMark(20, 30, "rejected", object="box"))
    assert effective_status(marks, 25, "box") == "rejected"
    assert effective_status(marks, 25, "cylinder") == "verified"
    # a later mark for all objects is the newer decision for box too
    marks = insert_mark(marks, ReviewMark(0, 100, "verified"))
    assert effective_status(marks, 25, "box") == "verified"
    assert [m.object for m in marks] == [None]


@pytest.mark.parametrize("order,expected", [(("box", None), "verified"), ((None, "box"), "rejected")])
def test_files_without_revision_keep_most_recent_wins(tmp_path, order, expected):
    """Files written before the rules: the later mark in the list won, across scopes too."""
    marks = {"box": {"t0_us": 0, "t1_us": 10, "status": "rejected", "object": "box"},
             None: {"t0_us": 0, "t1_us": 10, "status": "verified"}}
    if expected == "rejected":
        marks["box"]["status"], marks[None]["status"] = "rejected", "verified"
    p = tmp_path / "corrections.json"
    p.write_text(json.dumps({"format": "evpose-corrections/1", "reviews": [marks[k] for k in order]}))
    doc = Corrections.load(p)
    assert doc.review_status(5, "box") == expected
    assert doc.review_status(5, "cylinder") == "verified"


def test_normalize_is_idempotent_and_order_free():
    raw = [ReviewMark(0, 50, "verified"), ReviewMark(30, 80, "flagged"), ReviewMark(10, 20, "rejected", object="a")]
    n1 = normalize_marks(raw)
    assert normalize_marks(n1) == n1
    assert normalize_marks(list(reversed(n1))) == n1


def test_grid_window():
    assert grid_window(1_000, 1_000, 10) == (1_000, 1_010)
    assert grid_window(1_009, 1_000, 10) == (1_000, 1_010)
    assert grid_window(1_010, 1_000, 10) == (1_010, 1_020)
    assert grid_window(900, 1_000, 10) == (1_000, 1_010)      # before the first event: first cell


# ---------------------------------------------------------------------------- the app model (Session)
def _grid_ok(session, mark):
    o, w = session.time_range[0], session.view.window_us
    return (mark.t0_us - o) % w == 0 and mark.t1_us - mark.t0_us == w


def test_home_end_and_arbitrary_times_mark_grid_windows(scene_copy):
    s = Session.open(scene_copy)
    t0, t1 = s.time_range
    for t in (t0, t1, t0 + 123_457, t0 + 4_999, t0 + 5_001, t1 - 1):
        s.set_time(t)
        m = s.add_review("verified")
        assert _grid_ok(s, m), (t - t0, m.t0_us - t0, m.t1_us - t0)
        assert m.covers(s.view.t_us)
    # the frame the user looks at is the window that was marked
    s.set_time(t0 + 123_457)
    w = s.view.window()
    assert (w.t0_us, w.t1_us) == (t0 + 120_000, t0 + 130_000)
    assert w.t_label_us == t0 + 125_000


def test_verified_then_rejected_is_one_mark_and_undo_restores(scene_copy):
    s = Session.open(scene_copy)
    s.set_time(s.time_range[0] + 50_000)
    s.add_review("verified")
    s.add_review("verified")
    assert len(s.scene.corrections.reviews) == 1
    s.add_review("rejected")
    assert [m.status for m in s.scene.corrections.reviews] == ["rejected"]
    s.history.undo()
    assert [m.status for m in s.scene.corrections.reviews] == ["verified"]
    # an object's own mark, then a mark for all objects over it: the newer decision holds for that object
    s.add_review("rejected", obj="box")
    assert s.scene.corrections.review_status(s.view.t_us, "box") == "rejected"
    s.add_review("verified")
    assert s.scene.corrections.review_status(s.view.t_us, "box") == "verified"
    assert len(s.scene.corrections.reviews) == 1


def test_mark_records_state_and_goes_stale_on_clock_and_pose_changes(scene_copy):
    s = Session.open(scene_copy)
    s.set_time(s.time_range[0] + 100_000)
    m_all = s.add_review("verified")
    s.step_windows(1)
    m_cyl = s.add_review("verified", obj="cylinder")
    prior = s.scene.manifest.clock_offset_us
    assert m_all.at.offset_us == prior and {n for n, _ in m_all.at.poses} == set(s.object_names)
    assert [n for n, _ in m_cyl.at.poses] == ["cylinder"]
    assert s.stale_reasons(m_all) == [] and s.stale_reasons(m_cyl) == []

    s.set_offset_correction_us(1_500, mergeable=False)
    reasons = s.stale_reasons(m_all)
    assert reasons == [f"verified at offset {prior} us (now {prior + 1500} us)"]
    assert s.stale_reasons(m_cyl)
    s.history.undo()
    assert s.stale_reasons(m_all) == []

    s.nudge_object("box", "camera", trans_mm=(1, 0, 0), mergeable=False)
    assert s.stale_reasons(m_all) == ["pose of box changed since marking"]
    assert s.stale_reasons(m_cyl) == []          # cylinder's label did not change
    s.history.undo()
    s.nudge_hand_eye(rot_deg=(0.1, 0, 0), mergeable=False)
    assert "pose of cylinder changed since marking" in s.stale_reasons(m_cyl)


def test_mark_state_survives_save_and_load(scene_copy):
    s = Session.open(scene_copy)
    m = s.add_review("verified")
    s.save()
    back = Corrections.load(scene_copy / "corrections.json")
    assert back.reviews == [m] and isinstance(back.reviews[0].at, MarkState)
    s2 = Session.open(scene_copy)
    assert s2.stale_reasons(s2.scene.corrections.reviews[0]) == []


# ---------------------------------------------------------------------------- the export
def W(i, a, b):
    return Window(i, a, b, (a + b) // 2)


def test_review_usage_reasons():
    wins = [W(k, 100 * k, 100 * (k + 1)) for k in range(6)]
    old = MarkState(0, 0.0, (("a", "x"),))
    marks = [ReviewMark(0, 100, "verified"),                 # window 0: exported
             ReviewMark(150, 300, "verified"),               # window 1 partly, window 2 full
             ReviewMark(300, 400, "verified"), ReviewMark(350, 360, "rejected"),   # window 3 mixed
             ReviewMark(400, 500, "verified", at=old)]       # window 4: stale under is_stale
    is_stale = lambda m, obj: m.at is old                   # noqa: E731
    keep, touched, reasons = review_usage(wins, marks, ["a"], is_stale)
    assert keep.tolist() == [True, False, True, False, False, False]
    assert touched.tolist() == [True, True, True, True, True, False]
    assert reasons[:5] == [None, REVIEW_PARTLY, None, REVIEW_MIXED, REVIEW_STALE]
    assert verified_mask(wins, marks, ["a"]).tolist() == [True, False, True, False, True, False]
    # the mask agrees with the effective status at every microsecond
    fresh = normalize_marks(marks)
    for w, k in zip(wins, verified_mask(wins, marks, ["a"])):
        assert k == all(effective_status(fresh, t, "a") == "verified" for t in range(w.t0_us, w.t1_us))


def _mark_home_end(s, n_start=5, n_end=6):
    t0, t1 = s.time_range
    s.set_time(t0)                       # Home
    s.add_review("verified")
    for _ in range(n_start - 1):
        s.step_windows(1)
        s.add_review("verified")
    s.set_time(t1)                       # End
    s.add_review("verified")
    for _ in range(n_end - 1):
        s.step_windows(-1)
        s.add_review("verified")


def test_eleven_windows_verified_after_home_and_end_all_export(scene_copy, tmp_path):
    """The user's report: 11 windows verified after Home/End, the only-verified BOP export wrote 9."""
    s = Session.open(scene_copy)
    s.set_offset_correction_us(-20_000)      # a clock under which the first and last windows have labels
    _mark_home_end(s)
    assert len(s.scene.corrections.reviews) == 11
    s.save()
    summary = export_scene(scene_copy, "bop", tmp_path / "out", only_verified=True)
    assert summary.written == 11, summary_text(summary)
    assert (summary.review_marked, summary.review_unused) == (11, 0)
    gt = json.loads((tmp_path / "out" / "scene_gt.json").read_text()) if (tmp_path / "out" / "scene_gt.json").exists() \
        else json.loads(next((tmp_path / "out").rglob("scene_gt.json")).read_text())
    assert len(gt) == 11


def test_export_counts_unused_marked_windows_and_says_why(scene_copy, tmp_path):
    s = Session.open(scene_copy)
    s.set_offset_correction_us(-20_000)
    t0, t1 = s.time_range
    s.set_time(t0 + 400_000)
    s.add_review("verified", obj="box")
    s.nudge_object("box", "camera", trans_mm=(2, 0, 0), mergeable=False)  # that mark is now stale
    s.add_review("verified", t0 + 100_000, t0 + 130_000)              # 3 windows, exported
    s.add_review("verified", t0 + 205_000, t0 + 225_000)              # off grid: 1 full, 2 partly
    s.add_review("verified", t0 + 300_000, t0 + 310_000)
    s.add_review("flagged", t0 + 305_000, t0 + 306_000)               # mixed
    s.save()
    out = tmp_path / "out"
    summary = export_scene(scene_copy, "epose", out, only_verified=True, objects="box")
    assert summary.written == 3 + 1
    assert summary.review_marked == 3 + 3 + 1 + 1
    assert summary.review_unused_reasons == {REVIEW_PARTLY: 2, REVIEW_MIXED: 1, REVIEW_STALE: 1}
    text = summary_text(summary)
    assert "verified marks touch 8 window(s): 4 exported, 4 not used" in text and "partly covered" in text
    # --include-stale uses the stale mark (a different configuration: a new folder)
    s2 = export_scene(scene_copy, "epose", tmp_path / "out2", only_verified=True, objects="box", include_stale=True)
    assert s2.written == 5 and s2.review_unused_reasons == {REVIEW_PARTLY: 2, REVIEW_MIXED: 1}
    # ... and it cannot be mixed into the first folder (its fingerprint differs)
    from evpose.core.export import ExportError

    with pytest.raises(ExportError):
        export_scene(scene_copy, "epose", out, only_verified=True, objects="box", include_stale=True)


def test_marked_windows_without_labels_are_counted(scene_copy, tmp_path):
    s = Session.open(scene_copy)
    t0, t1 = s.time_range
    s.set_offset_correction_us(800_000)       # pushes the last windows' pose times past the trajectory
    s.set_time(t1)
    s.add_review("verified")
    s.set_time(t0 + 100_000)
    s.add_review("verified")
    s.save()
    summary = export_scene(scene_copy, "epose", tmp_path / "out", only_verified=True)
    assert summary.review_marked == 2 and summary.written == 1
    assert summary.review_unused_reasons == {REVIEW_NO_LABEL: 1}
    assert summary.unlabeled == 1
