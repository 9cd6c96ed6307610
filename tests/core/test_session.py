"""The app model without Qt (evpose.core.session.model.Session): view state is neither undoable nor
saved nor dirtying; every edit goes through the history (merge, undo, redo) and emits exactly one
Change per signal; accepted estimates are applied on top of the manifest's prior; the autosave
journal and another program's saves come in as one labelled undo step each."""
import gc
import re
import weakref

import numpy as np
import pytest

from evpose.core.data.geometry import T_from_rotvec
from evpose.core.document.corrections import Corrections
from evpose.core.document.corrections_merge import CorrectionsConflict
from evpose.core.session.model import Session
from evpose.core.signals import Change


class Recorder:
    """Every payload of the session's and its history's signals (bound methods: held weakly)."""

    def __init__(self, session: Session):
        self.session, self.history = [], []
        session.changed.connect(self.on_session)
        session.history.changed.connect(self.on_history)

    def on_session(self, change):
        self.session.append(change)

    def on_history(self, change):
        self.history.append(change)

    def take(self):
        out = (self.session, self.history)
        self.session, self.history = [], []
        return out


def doc(*fields):
    return Change("document", frozenset(fields))


@pytest.fixture
def session(scene_copy):
    s = Session.open(scene_copy)
    yield s
    s.close()


def set_prior(scene_dir, offset_us: int, skew_ppm: float) -> None:
    p = scene_dir / "scene.toml"
    text = p.read_text()
    text = re.sub(r"(?m)^offset_us = .*$", f"offset_us = {offset_us}", text, count=1)
    text = re.sub(r"(?m)^skew_ppm = .*$", f"skew_ppm = {skew_ppm!r}", text, count=1)
    p.write_text(text)


# ---------------------------------------------------------------------------- view state
VIEW_EDITS = [
    ("set_time", lambda s: s.set_time(s.time_range[0] + 123_456), Change("time", frozenset({"t_us"}))),
    ("go_end", lambda s: s.set_time(s.time_range[1]), Change("time", frozenset({"t_us"}))),
    ("set_window_us", lambda s: s.set_window_us(20_000), Change("view", frozenset({"window_us"}))),
    ("set_representation", lambda s: s.set_representation("counts"), Change("view", frozenset({"representation"}))),
    ("set_overlay", lambda s: s.set_overlay("axes", True), Change("view", frozenset({"overlays"}))),
    ("set_view_option", lambda s: s.set_view_option(spacetime_budget=1000, mask_alpha=0.5),
     Change("view", frozenset({"spacetime_budget", "mask_alpha"}))),
    ("select", lambda s: s.select("box"), Change("objects", frozenset({"selected"}))),
    ("set_object_visible", lambda s: s.set_object_visible("cylinder", False), Change("objects", frozenset({"hidden"}))),
]


@pytest.mark.parametrize("name,edit,expected", VIEW_EDITS, ids=[v[0] for v in VIEW_EDITS])
def test_view_state_emits_once_and_is_not_undoable_dirty_or_saved(session, name, edit, expected):
    rec = Recorder(session)
    before = session.view
    edit(session)
    assert session.view != before
    assert rec.take() == ([expected], [])                 # once, on the session only
    assert len(session.history) == 0 and not session.history.can_undo and not session.dirty
    assert session.write_journal() is None                # nothing to autosave
    edit(session)                                         # the same value again: no change, no signal
    assert rec.take() == ([], [])
    session.save()
    saved = Corrections.load(session.scene.corrections_path)
    assert saved.canonical() == Corrections().canonical()  # the view is not in the document
    assert session.view != before                         # a save leaves the view alone


def test_view_setters_refuse_bad_values_without_a_signal(session):
    rec = Recorder(session)
    with pytest.raises(ValueError):
        session.set_window_us(0)
    with pytest.raises(ValueError):
        session.set_representation("nope")
    with pytest.raises(ValueError):
        session.set_overlay("nope", True)
    with pytest.raises(KeyError):
        session.select("no such object")
    with pytest.raises(TypeError):
        session.set_view_option(no_such_field=1)
    assert rec.take() == ([], [])


def test_time_is_clamped_to_the_events(session):
    t0, t1 = session.time_range
    session.set_time(t1 + 10**9)
    assert session.view.t_us == t1
    session.set_time(t0 - 10**9)
    assert session.view.t_us == t0


# ---------------------------------------------------------------------------- document edits
DOC_EDITS = [
    ("offset", lambda s: s.set_offset_correction_us(1500), doc("clock")),
    ("skew", lambda s: s.set_skew_correction_ppm(12.5), doc("clock")),
    ("nudge_object", lambda s: s.nudge_object("box", "camera", trans_mm=(1, 0, 0)), doc("object:box")),
    ("nudge_hand_eye", lambda s: s.nudge_hand_eye(rot_deg=(0, 0.5, 0)), doc("hand_eye")),
    ("add_review", lambda s: s.add_review("verified"), doc("reviews")),
    ("clock_estimate", lambda s: s.apply_clock_estimate(2500, 3.0, "sync"), doc("clock")),
    ("pose_estimate", lambda s: s.apply_pose_estimate("cylinder", T_from_rotvec([0, 0, 0.01], [0.001, 0, 0])),
     doc("object:cylinder")),
]


@pytest.mark.parametrize("name,edit,expected", DOC_EDITS, ids=[d[0] for d in DOC_EDITS])
def test_each_edit_is_one_step_and_one_change_per_signal(session, name, edit, expected):
    rec = Recorder(session)
    before = session.scene.corrections.canonical()
    edit(session)
    after = session.scene.corrections.canonical()
    assert after != before
    assert rec.take() == ([expected], [expected])        # exactly once on each signal, naming the field
    assert len(session.history) == 1 and session.dirty
    assert session.history.undo()
    assert session.scene.corrections.canonical() == before and not session.dirty
    assert rec.take() == ([expected], [expected])        # undo: the same fields, once
    assert session.history.redo()
    assert session.scene.corrections.canonical() == after
    assert rec.take() == ([expected], [expected])


def test_no_op_edits_emit_nothing_and_record_nothing(session):
    rec = Recorder(session)
    session.set_offset_correction_us(0)
    session.reset("box")
    session.reset("hand_eye")
    session.apply_clock_estimate(int(session.scene.clock.offset_us), None)
    assert rec.take() == ([], []) and len(session.history) == 0 and not session.dirty


def test_remove_review_and_reset_are_steps_too(session):
    mark = session.add_review("rejected", obj="box")
    session.nudge_object("box", "object", rot_deg=(1, 0, 0), mergeable=False)
    rec = Recorder(session)
    session.remove_review(mark)
    session.reset("box")
    assert rec.take() == ([doc("reviews"), doc("object:box")], [doc("reviews"), doc("object:box")])
    assert session.scene.corrections.reviews == [] and "box" not in session.scene.corrections.object_deltas
    assert len(session.history) == 4


def test_nudges_merge_into_one_step_but_signal_each_time(session):
    rec = Recorder(session)
    for _ in range(5):
        session.nudge_object("box", "camera", trans_mm=(1, 0, 0))
    assert len(session.history) == 1 and session.history.undo_text == "move box"
    assert rec.take() == ([doc("object:box")] * 5, [doc("object:box")] * 5)
    dT = session.scene.corrections.object_delta("box")
    assert np.linalg.norm(dT[:3, 3]) == pytest.approx(5e-3, rel=1e-9)   # five 1 mm steps
    session.history.undo()
    assert "box" not in session.scene.corrections.object_deltas
    assert rec.take() == ([doc("object:box")], [doc("object:box")])


def test_a_group_is_one_change_with_all_its_fields_and_a_failed_group_none(session):
    rec = Recorder(session)
    with session.history.group("several"):
        session.set_offset_correction_us(10, mergeable=False)
        session.add_review("flagged")
        session.nudge_hand_eye(trans_mm=(0, 1, 0), mergeable=False)
    assert rec.take() == ([doc("clock", "reviews", "hand_eye")],) * 2
    with session.history.group("one field changes"):
        session.set_offset_correction_us(20, mergeable=False)
        session.reset("box")                               # already the identity: not a field of the step
    assert rec.take() == ([doc("clock")],) * 2
    with pytest.raises(RuntimeError):
        with session.history.group("fails"):
            session.set_offset_correction_us(99, mergeable=False)
            raise RuntimeError("boom")
    assert session.scene.corrections.offset_us == 20       # rolled back
    assert rec.take() == ([], []) and len(session.history) == 2


def test_save_emits_only_the_history_state(session):
    session.set_offset_correction_us(777)
    rec = Recorder(session)
    session.save()
    assert rec.take() == ([], [Change("history")]) and not session.dirty
    session.save()                                         # already clean: nothing moves
    assert rec.take() == ([], [])


def test_a_subscriber_is_not_kept_alive_and_the_session_is_freed(scene_copy):
    s = Session.open(scene_copy)
    rec = Recorder(s)
    ref_rec = weakref.ref(rec)
    del rec
    gc.collect()
    assert ref_rec() is None and len(s.changed) == 0
    assert len(s.history.changed) == 1                     # the session's own subscription only
    s.set_offset_correction_us(5)                          # no call into the dead recorder
    s.close()
    ref_s = weakref.ref(s)
    del s
    gc.collect()
    assert ref_s() is None                                 # the history does not hold its session


# ---------------------------------------------------------------------------- accepted estimates
def test_a_clock_estimate_is_stored_on_top_of_the_prior(scene_copy):
    set_prior(scene_copy, 40_000, 7.5)
    s = Session.open(scene_copy)
    assert (s.scene.clock.offset_us, s.scene.clock.skew_ppm) == (40_000, 7.5)
    s.set_skew_correction_ppm(2.25, mergeable=False)
    s.apply_clock_estimate(46_500, None, "clock from edges")   # skew not estimated: kept
    c = s.scene.corrections
    assert (c.offset_us, c.skew_ppm) == (6_500, 2.25)
    assert s.scene.clock.offset_us == 46_500 and s.scene.clock.skew_ppm == 9.75
    s.apply_clock_estimate(31_000, -2.5, "automatic clock sync")
    assert (c.offset_us, c.skew_ppm) == (-9_000, -10.0) and s.history.undo_text == "automatic clock sync"
    assert s.scene.clock.offset_us == 31_000 and s.scene.clock.skew_ppm == -2.5
    s.history.undo()                                        # one step each
    assert (c.offset_us, c.skew_ppm) == (6_500, 2.25)
    s.close()


def test_a_pose_estimate_replaces_the_correction_of_its_object_only(session):
    dT = T_from_rotvec([0.0, 0.02, 0.0], [0.003, 0.0, -0.001])
    session.apply_pose_estimate("box", dT, "refine box")
    assert np.array_equal(session.scene.corrections.object_delta("box"), dT)
    assert session.history.undo_text == "refine box" and list(session.scene.corrections.object_deltas) == ["box"]
    with pytest.raises(KeyError):
        session.apply_pose_estimate("no such object", dT)


# ---------------------------------------------------------------------------- journal
def test_journal_holds_unsaved_edits_and_restores_as_one_step(scene_copy):
    s = Session.open(scene_copy)
    assert s.write_journal() is None                       # clean: nothing written
    s.set_offset_correction_us(4321, mergeable=False)
    s.add_review("verified")
    s.select("box")                                        # view state: not in the journal
    path = s.write_journal()
    assert path == s.journal_path and path.exists()
    expected = s.scene.corrections.canonical()
    s.close()                                              # the app dies without saving
    s2 = Session.open(scene_copy)
    rec = Recorder(s2)
    j = s2.pending_journal()
    assert j is not None and s2.journal_problem is None
    assert s2.restore_journal(j) == []
    assert s2.scene.corrections.canonical() == expected and s2.view.selected is None
    assert rec.take() == ([doc("clock", "reviews")],) * 2 and len(s2.history) == 1 and s2.dirty
    s2.save()
    assert not s2.journal_path.exists()                    # a save removes the journal
    assert Session.open(scene_copy).pending_journal() is None
    s2.close()


def test_the_journal_lives_only_while_there_is_unsaved_work(session):
    session.set_offset_correction_us(1, mergeable=False)
    assert session.write_journal() is not None
    session.save()
    assert not session.journal_path.exists()               # a save removes it
    session.set_offset_correction_us(2, mergeable=False)
    mark = session.add_review("verified")
    session.write_journal()
    session.history.undo()
    assert session.journal_path.exists()                   # still unsaved work (the offset)
    session.history.undo()                                 # back to the saved content
    assert not session.journal_path.exists()
    session.history.redo()
    session.history.redo()
    assert session.write_journal() is not None
    session.set_offset_correction_us(1, mergeable=False)   # edits that cancel out: off the history's clean mark ...
    session.remove_review(mark)                            # ... but equal to the file again: nothing to save
    assert not session.history.is_clean and not session.dirty
    assert not session.unsaved and not session.journal_path.exists()
    assert session.write_journal() is None                 # nothing to keep
    session.set_offset_correction_us(3, mergeable=False)
    session.write_journal()
    session.discard_journal()
    assert not session.journal_path.exists()
    session.discard_journal()                              # idempotent


def test_closing_removes_the_journal_unless_work_is_unsaved(scene_copy):
    s = Session.open(scene_copy)
    s.set_offset_correction_us(5, mergeable=False)
    s.write_journal()
    s.close()                                              # unsaved work (a crash, or closed without a choice)
    assert s.journal_path.exists()
    s2 = Session.open(scene_copy)
    s2.restore_journal(s2.pending_journal())
    s2.save()
    s2.set_offset_correction_us(6, mergeable=False)
    s2.write_journal()
    s2.set_offset_correction_us(5, mergeable=False)        # back to what is saved, not by undo
    s2.close()
    assert not s2.journal_path.exists()
    s2.journal_path.write_text('{"format": "evpose-corrections/1", "clock": ')      # a damaged journal ...
    s3 = Session.open(scene_copy)
    assert s3.pending_journal() is None and s3.journal_problem
    assert s3.journal_path.exists()                        # ... reported and kept while the session runs
    s3.close()                                             # a clean quit ends it
    assert not s3.journal_path.exists()


# ---------------------------------------------------------------------------- another program's saves
def other_program_sets(scene_dir, key, value):
    path = scene_dir / "corrections.json"
    other = Corrections.load(path) if path.exists() else Corrections()
    other.set(key, value)
    other.save(path)


def test_external_change_reloads_as_one_labelled_step(session, scene_copy):
    assert session.check_disk() is None
    other_program_sets(scene_copy, ("skew_ppm",), 3.5)
    change = session.check_disk()
    assert change is not None and change.revision == 1 and change.fields == ["clock.skew_ppm"]
    rec = Recorder(session)
    assert session.reload_from_disk(change) == [("skew_ppm",)]
    assert session.scene.corrections.skew_ppm == 3.5 and not session.dirty
    assert rec.take() == ([doc("clock")], [doc("clock")])
    assert "reload corrections.json (revision 1" in session.history.undo_text
    assert session.check_disk() is None                    # taken over: no longer a change
    session.history.undo()
    assert session.scene.corrections.skew_ppm == 0.0 and session.dirty   # differs from the file now


def test_external_change_merges_under_local_edits_or_names_the_conflict(session, scene_copy):
    session.set_offset_correction_us(100, mergeable=False)
    other_program_sets(scene_copy, ("skew_ppm",), -1.5)
    rec = Recorder(session)
    res = session.merge_from_disk(session.check_disk())
    assert res.conflicts == []
    c = session.scene.corrections
    assert (c.offset_us, c.skew_ppm) == (100, -1.5) and session.dirty
    assert rec.take() == ([doc("clock")], [doc("clock")])
    # both change the offset: a real conflict changes nothing unless a side is preferred
    other_program_sets(scene_copy, ("offset_us",), 900)
    change = session.check_disk()
    with pytest.raises(CorrectionsConflict, match="offset"):
        session.merge_from_disk(change)
    assert c.offset_us == 100 and rec.take() == ([], [])
    session.merge_from_disk(change, prefer="disk")
    assert c.offset_us == 900 and not session.dirty       # equals the file now


def test_own_save_is_not_an_external_change_and_save_merges_others(session, scene_copy):
    session.set_offset_correction_us(250, mergeable=False)
    session.save()
    assert session.check_disk() is None
    session.set_skew_correction_ppm(1.0, mergeable=False)
    other_program_sets(scene_copy, ("hand_eye",), T_from_rotvec([0.001, 0, 0], [0, 0, 0]))
    rec = Recorder(session)
    session.save()                                         # merges the other program's hand-eye
    assert rec.take() == ([doc("hand_eye")], [doc("hand_eye")])
    assert not session.dirty and "merge another program's change" in session.history.undo_text
    disk = Corrections.load(scene_copy / "corrections.json")
    assert disk.skew_ppm == 1.0 and disk.offset_us == 250 and not np.array_equal(disk.hand_eye_delta, np.eye(4))


# ---------------------------------------------------------------------------- direct manipulation (issue 16)
def _centre_uv(session, name):
    """The image point of an object's box centre in the current window (raw pixels)."""
    from evpose.core.data.geometry import apply_T

    T, _ = session.scene.T_cam_obj([session.view.window().t_label_us], [name])
    c = apply_T(T[0, 0], session.scene.model(name).bbox_center_m[None])
    return session.scene.camera.project(c)[0][0]


def test_an_edit_ends_a_drag_whose_release_never_came(session):
    """A drag whose mouse release was lost (a dialog took the mouse) must not absorb later edits: a nudge, an
    offset change after it are undo steps of their own, with the normal merge timeout."""
    session.set_time(session.time_range[0] + 300_000)
    uv = _centre_uv(session, "box")
    assert session.begin_drag("box")
    session.drag_object(uv, uv + [6.0, 0.0], "move")               # ... and no end_drag
    session.nudge_object("box", "camera", trans_mm=(0, 1, 0))
    assert session.dragging is None and session.history.merge_timeout_s == 1.5
    assert len(session.history) == 2 and session.history.undo_text == "move box"
    session.history.undo()
    np.testing.assert_allclose(_centre_uv(session, "box"), uv + [6.0, 0.0], atol=1e-6)   # the drag stays


def test_a_drag_is_one_undo_step_however_long_it_pauses(session):
    session.set_time(session.time_range[0] + 300_000)
    now = [0.0]
    session.history._clock = lambda: now[0]
    session.nudge_object("box", "camera", trans_mm=(1, 0, 0))      # an earlier nudge: its own step
    rec = Recorder(session)
    assert session.begin_drag("box") and session.dragging == "box"
    assert session.view.selected == "box"
    uv = _centre_uv(session, "box")
    for k in range(1, 6):
        now[0] += 5.0                                                # far beyond the merge timeout
        session.drag_object(uv, uv + [4.0 * k, -2.0 * k], "move")
    session.end_drag()
    assert session.dragging is None and session.history.merge_timeout_s == 1.5
    assert len(session.history) == 2 and session.history.undo_text == "drag box"
    assert rec.take()[1] == [doc("object:box")] * 5                  # the views follow every move
    np.testing.assert_allclose(_centre_uv(session, "box"), uv + [20.0, -10.0], atol=1e-6)   # under the cursor
    session.nudge_object("box", "camera", trans_mm=(0, 1, 0))      # after the drag: a new step
    assert len(session.history) == 3
    session.history.undo()
    session.history.undo()
    np.testing.assert_allclose(_centre_uv(session, "box"), uv, atol=1e-9)
    # a drag back to where it started records nothing
    session.begin_drag("box")
    session.drag_object(uv, uv + [5.0, 0.0])
    session.drag_object(uv, uv)
    session.end_drag()
    assert len(session.history) == 2 and session.history.can_redo is False


def test_windows_of_n_events_are_the_exports_tiling(session):
    from evpose.core.label.windows import count_windows

    store = session.scene.events
    n = 5000
    tiling = count_windows(store, n)
    session.set_time(session.time_range[0] + 300_000)
    rec = Recorder(session)
    session.set_window_events(n)
    assert rec.take()[0][0].fields >= {"count_grid"} and session.view.window_events == n
    w = session.view.window()
    k = w.index
    assert (w.t0_us, w.t1_us, w.i0, w.i1) == (tiling[k].t0_us, tiling[k].t1_us, tiling[k].i0, tiling[k].i1)
    assert w.t0_us <= session.view.t_us < w.t1_us and w.n_events == n
    session.step_windows(1)
    assert session.view.window().index == k + 1 and session.view.t_us == tiling[k + 1].t_label_us
    session.step_windows(-3)
    assert session.view.window().index == k - 2
    session.step_windows(10**6)
    assert session.view.window().index == len(tiling) - 1
    # the average length stands for the window where one number is needed
    assert session.view.window_us == pytest.approx((store.t_last_us - store.t_first_us) * n / store.n_events, rel=1e-3)
    session.set_window_us(4000)
    assert session.view.window_events == 0 and session.view.window().t1_us - session.view.window().t0_us == 4000
    session.set_window_events(n)
    session.set_window_events(0)
    assert session.view.count_grid is None
    with pytest.raises(ValueError):
        session.set_window_events(-1)


@pytest.mark.parametrize("times, n", [
    (list(range(10)) + [10] * 6 + list(range(11, 20)), 3),     # a burst of equal times inside the tiling
    ([0, 5, 10, 10, 10, 10, 10, 10, 11, 12, 13, 14], 4),      # a window at the time the one before ends
])
def test_stepping_windows_of_n_events_never_stalls_on_equal_timestamps(times, n):
    """Windows whose events all share one timestamp (a burst of 10^5 events in 1 µs on a dense recording): their
    label time is that timestamp, where the window before also ends; every step must still change the window shown
    (the view is placed by time: the window shown is the one at the label time)."""
    from evpose.core.session.view_state import CountGrid

    class Store:
        t = np.array(times, dtype=np.int64)
        n_events = len(t)
        t_first_us, t_last_us = int(t[0]), int(t[-1])

        def index_of(self, t_us):
            return int(np.searchsorted(self.t, t_us))

        def read(self, i0, i1):
            return type("Ev", (), {"t": self.t[i0:i1]})()

    grid = CountGrid(Store(), n)
    last = grid.n_windows - 1
    t = int(grid.window(0).t_label_us)
    shown = [grid.index_at(t)]
    while shown[-1] < last:
        t = grid.step(t, 1)
        shown.append(grid.index_at(t))
        assert shown[-1] > shown[-2], shown                  # every step forward shows a later window
    assert grid.step(t, 1) == t                               # the end of the tiling
    while shown[-1] > 0:
        t = grid.step(t, -1)
        shown.append(grid.index_at(t))
        assert shown[-1] < shown[-2], shown                  # and back


def test_a_journal_restores_the_sigmas_of_its_estimates(scene_copy):
    """Issue 28.3: an applied estimate's value and its sigma come back together from the autosave journal (a value
    set through History.set would have dropped the sigma the journal holds)."""
    s = Session.open(scene_copy)
    step = np.array([[1, 0, 0, 0.002], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])
    s.apply_pose_estimate("box", s.scene.corrections.object_delta("box") @ step, "refine box", std_mm=0.4,
                          std_deg=0.2)
    s.save()                                    # saved: the first estimate; the journal: a second, same sigma
    s.apply_pose_estimate("box", s.scene.corrections.object_delta("box") @ step, "refine box", std_mm=0.4,
                          std_deg=0.2)
    expected = s.scene.corrections.canonical()
    assert expected["sigmas"] == {"object:box": {"deg": 0.2, "mm": 0.4}}
    s.write_journal()
    s.close()
    s2 = Session.open(scene_copy)
    assert s2.restore_journal(s2.pending_journal()) == []
    assert s2.scene.corrections.canonical() == expected and len(s2.history) == 1
    s2.history.undo()
    assert s2.scene.corrections.sigma("object:box") == {"mm": 0.4, "deg": 0.2}
    s2.close()
