"""The timeline's score row follows the document (app/score_row.py): stale in the same event-loop turn as a
change of the clock or a pose, recomputed in the background, fresh again with the values a fresh computation
gives; a newer change cancels an older recompute and its late result is dropped."""
from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from evpose.app.score_row import RECOMPUTE_DELAY_MS
from evpose.core.align.score_table import score_windows


def fresh_scores(session):
    """What scoring the document as it is now gives (the reference for the row)."""
    snap = session.scene.with_corrections(session.scene.corrections.copy())
    tab = score_windows(snap, window_us=int(session.view.window_us))
    return ({n: np.ma.filled(tab.score[n].astype(np.float64), np.nan) for n in tab.objects},
            {n: tab.low_evidence[n] for n in tab.objects})


def assert_row_equals(tl, expected):
    scores, low = expected
    assert set(tl.scores) == set(scores)
    for n in scores:
        np.testing.assert_array_equal(tl.scores[n], scores[n])
        np.testing.assert_array_equal(tl.score_row.low_evidence[n], low[n])


@pytest.fixture
def scored(qtbot, window, scene_copy):
    s = window.controller.open_scene(scene_copy)
    window.actions_by_name["score_all"].trigger()
    qtbot.waitUntil(lambda: window.align.last_scores is not None and bool(window.timeline.scores), timeout=60_000)
    assert not window.timeline.scores_stale and not window.score_row.stale
    return s


def test_stale_at_once_after_a_nudge_or_an_offset_change_then_fresh(qtbot, window, scored):
    s, tl, row = scored, window.timeline, window.score_row
    before = {n: v.copy() for n, v in tl.scores.items()}
    # a review mark or a view change does not touch the scores
    s.add_review("verified")
    s.step_windows(3)
    assert not tl.scores_stale and row.job is None
    # a nudge: stale before control returns to the event loop, with its label
    s.nudge_object("box", "camera", trans_mm=(4.0, 0.0, 0.0))
    assert tl.scores_stale and row.stale
    assert tl.score_row.stale_label.item.isVisible() and tl.score_row.stale_label.text == "stale — recomputing"
    qtbot.waitUntil(lambda: not tl.scores_stale, timeout=60_000)
    assert not tl.score_row.stale_label.item.isVisible() and row.job is None
    assert_row_equals(tl, fresh_scores(s))
    assert window.align.last_scores is row.table
    assert not np.array_equal(tl.scores["box"], before["box"], equal_nan=True)     # the nudge moved the box
    np.testing.assert_array_equal(tl.scores["cylinder"], before["cylinder"])       # and nothing else
    # an offset change, then undo: each time stale at once, then the fresh values
    s.set_offset_correction_us(s.scene.corrections.offset_us + 3000)
    assert tl.scores_stale
    qtbot.waitUntil(lambda: not tl.scores_stale, timeout=60_000)
    assert_row_equals(tl, fresh_scores(s))
    window.actions_by_name["undo"].trigger()
    assert tl.scores_stale
    qtbot.waitUntil(lambda: not tl.scores_stale, timeout=60_000)
    assert_row_equals(tl, fresh_scores(s))
    assert row.jobs_started == 3 and row.results_dropped == 0
    # a change undone before the recompute started: fresh again at once, nothing computed
    s.nudge_object("cylinder", "object", rot_deg=(0.0, 0.0, 2.0), mergeable=False)
    assert tl.scores_stale
    window.actions_by_name["undo"].trigger()
    assert not tl.scores_stale and row.job is None
    qtbot.wait(RECOMPUTE_DELAY_MS + 200)
    assert row.jobs_started == 3 and not tl.scores_stale


def test_a_newer_change_cancels_and_supersedes_an_older_recompute(qtbot, window, scored):
    s, tl, row = scored, window.timeline, window.score_row
    gate, entered, offsets = threading.Event(), threading.Event(), []
    compute = row.compute

    def held_first(scene, window_us, progress, cancel):
        """The first recompute waits for the gate and ignores cancel: its result comes late."""
        offsets.append(scene.corrections.offset_us)
        if len(offsets) == 1:
            entered.set()
            assert gate.wait(60)
            return compute(scene, window_us, progress, lambda: False)
        return compute(scene, window_us, progress, cancel)

    row.compute = held_first
    try:
        s.set_offset_correction_us(1000, mergeable=False)
        qtbot.waitUntil(entered.is_set, timeout=10_000)
        first = row.job
        assert first is not None and tl.scores_stale
        t = time.perf_counter()
        s.set_offset_correction_us(2000, mergeable=False)           # a newer change while the first runs
        assert time.perf_counter() - t < 0.5                         # the GUI thread did not wait for it
        assert first.cancelled and row.job is None and tl.scores_stale
        qtbot.waitUntil(lambda: not tl.scores_stale, timeout=60_000)  # the second is shown ...
        assert offsets == [1000, 2000]
        expected = fresh_scores(s)
        assert_row_equals(tl, expected)
        with qtbot.waitSignal(first.signals.finished, timeout=60_000):   # ... then the first's late result
            gate.set()
    finally:
        gate.set()
    qtbot.wait(50)
    assert row.results_dropped == 1 and not tl.scores_stale                # ... is dropped
    assert_row_equals(tl, expected)


def test_a_score_all_table_supersedes_a_running_recompute(qtbot, window, scored):
    """A recompute still running when a fresh "Score all windows" table arrives (here of another window length)
    must not replace that table when it ends."""
    s, tl, row = scored, window.timeline, window.score_row
    gate, entered = threading.Event(), threading.Event()
    compute = row.compute

    def held(scene, window_us, progress, cancel):
        entered.set()
        assert gate.wait(60)
        return compute(scene, window_us, progress, lambda: False)

    row.compute = held
    try:
        s.set_offset_correction_us(1000, mergeable=False)
        qtbot.waitUntil(entered.is_set, timeout=10_000)
        late = row.job
        snap = s.scene.with_corrections(s.scene.corrections.copy())
        table = score_windows(snap, window_us=20_000)                 # "Score all" with 20 ms windows
        from evpose.app.score_row import document_key

        row.show(table, 20_000, document_key(snap))
        assert late.cancelled and not tl.scores_stale and row.window_us == 20_000
        with qtbot.waitSignal(late.signals.finished, timeout=60_000):
            gate.set()
    finally:
        gate.set()
    qtbot.wait(50)
    assert row.table is table and row.window_us == 20_000 and not tl.scores_stale


def test_a_cancelled_score_all_leaves_scores_of_another_window_length_marked(qtbot, window, scored):
    """Scores of 10 ms windows shown, the window set to 5 ms, Score all cancelled: the row says it is not current
    (it showed the old scores as if current); cancelling with the scores current leaves them as they are."""
    s, tl = scored, window.timeline
    job = window.align.score_all()
    job.cancel()
    qtbot.waitUntil(lambda: not window.align.jobs, timeout=60_000)
    assert not tl.scores_stale                                    # current scores: nothing to say
    s.set_window_us(5_000)
    job = window.align.score_all()
    job.cancel()
    qtbot.waitUntil(lambda: not window.align.jobs, timeout=60_000)
    assert tl.scores_stale and "Score all cancelled" in tl.score_row.stale_label.text
    assert "10 ms windows" in tl.score_row.stale_label.text
