"""The view feeds (app/view_feed.py, app/feeds.py): results in order, nothing computed out of sight, coalesced
bursts, nothing delivered from a closed session, the timeline's curves computed on a worker."""
from __future__ import annotations

import threading

import pytest
from evpose.app.view_feed import ViewFeed


class _Req:
    def __init__(self, serial):
        self.serial = serial


@pytest.fixture
def feed_parts(qtbot):
    gate = threading.Event()
    computed, delivered, failed = [], [], []

    def compute(req):
        computed.append((req.serial, threading.current_thread() is threading.main_thread()))
        gate.wait(10)
        if req.serial < 0:
            raise ValueError("bad request")
        return f"result {req.serial}"

    serials = iter(range(1, 1000))
    state = {"in_sight": True}
    feed = ViewFeed(None, "test-feed", compute, lambda r, s: delivered.append((r, s)),
                    make_request=lambda: _Req(next(serials)), in_sight=lambda: state["in_sight"],
                    on_failed=lambda m, s: failed.append((m, s)))
    yield feed, gate, computed, delivered, failed, state
    gate.set()
    feed.stop()


def test_a_burst_computes_the_latest_off_the_gui_thread_and_delivers_it_once(qtbot, feed_parts):
    feed, gate, computed, delivered, _, _ = feed_parts
    feed.request()                                   # 1 starts and waits at the gate
    qtbot.waitUntil(lambda: len(computed) == 1, timeout=5000)
    for _ in range(5):
        feed.request()                               # 2..6: each replaces the pending one
    gate.set()
    qtbot.waitUntil(feed.up_to_date, timeout=5000)
    assert [s for s, _ in computed] == [1, 6] and not any(main for _, main in computed)
    assert delivered == [("result 1", 1), ("result 6", 6)]


def test_an_older_result_after_a_newer_one_is_dropped(qtbot, feed_parts):
    feed, gate, _, delivered, _, _ = feed_parts
    gate.set()
    feed.submit(_Req(10))
    qtbot.waitUntil(lambda: feed.shown == 10, timeout=5000)
    feed._done("late", 7)                            # a result of an older request arriving late
    assert delivered == [("result 10", 10)]


def test_out_of_sight_nothing_is_computed_until_it_comes_into_sight(qtbot, feed_parts):
    feed, gate, computed, delivered, _, state = feed_parts
    gate.set()
    state["in_sight"] = False
    feed.request()
    qtbot.wait(100)
    assert computed == [] and feed.stale
    state["in_sight"] = True
    feed.visibility_changed(True)
    qtbot.waitUntil(lambda: len(delivered) == 1, timeout=5000)
    assert not feed.stale


def test_coalesced_requests_make_one_when_the_burst_ends(qtbot):
    calls = []
    serials = iter(range(1, 100))
    feed = ViewFeed(None, "coalesced", lambda req: req.serial, lambda r, s: calls.append(s),
                    make_request=lambda: _Req(next(serials)), coalesce_ms=50)
    try:
        for _ in range(10):
            feed.request()
            qtbot.wait(5)
        qtbot.waitUntil(lambda: bool(calls), timeout=5000)
        qtbot.wait(150)
        assert calls == [1]
    finally:
        feed.stop()


def test_results_of_a_closed_session_are_dropped_and_failures_reported(qtbot, feed_parts):
    feed, gate, computed, delivered, failed, _ = feed_parts
    feed.request()
    qtbot.waitUntil(lambda: len(computed) == 1, timeout=5000)
    feed.drop_pending()                              # the session closes while its request computes
    gate.set()
    qtbot.wait(200)
    assert delivered == []
    feed.submit(_Req(feed.submitted + 1))
    qtbot.waitUntil(lambda: len(delivered) == 1, timeout=5000)
    bad = _Req(-5)
    feed.submitted = -6                              # a failure of the latest request reaches the view
    feed.worker.submit(bad)
    qtbot.waitUntil(lambda: bool(failed), timeout=5000)
    assert "bad request" in failed[0][0]


@pytest.mark.gl
def test_the_timeline_follows_a_clock_change_from_a_worker(qtbot, window, scene_copy, monkeypatch):
    s = window.controller.open_scene(scene_copy)
    tl = window.timeline
    qtbot.waitUntil(window.frame_up_to_date, timeout=30_000)
    monkeypatch.setattr(tl, "refresh_data", lambda: pytest.fail("the timeline computed on the GUI thread"))
    before = tl.data.speed_mps.copy()
    n = window.feeds.timeline.submitted
    s.set_offset_correction_us(s.scene.corrections.offset_us + 30_000)
    qtbot.waitUntil(lambda: tl.clock_key() == tl._data_key and window.feeds.timeline.up_to_date(), timeout=10_000)
    assert window.feeds.timeline.submitted > n
    assert tl.data.speed_mps.shape == before.shape and not (tl.data.speed_mps == before).all()
