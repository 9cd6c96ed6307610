"""Overlays computed ahead of the user (core/views/overlay_cache.py, FrameComputer.prefetch_overlays).

While the overlay worker is idle it computes the next window in the user's direction and step; the next
request takes that result only when it would compute exactly the same thing (same corrections, window,
overlay settings), and the store is bounded in bytes.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from evpose.core.views.frame import FrameComputer, run_stages
from evpose.core.session.model import Session
from evpose.core.views.overlay_cache import OverlayCache


@pytest.fixture
def session(tiny_scene_dir):
    s = Session.open(tiny_scene_dir)
    yield s
    s.close()


def at(session, t_us):
    session.set_time(t_us)
    return session.request()


def same_frame(a, b) -> None:
    assert a.window == b.window
    assert np.array_equal(a.labels.label_map, b.labels.label_map)
    assert np.array_equal(a.mask_rgba, b.mask_rgba)
    assert [o.name for o in a.overlays] == [o.name for o in b.overlays]
    for oa, ob in zip(a.overlays, b.overlays):
        assert len(oa.contours) == len(ob.contours) and all(np.array_equal(x, y) for x, y in zip(oa.contours, ob.contours))
        assert np.array_equal(oa.box_segments, ob.box_segments)
    assert a.scores == b.scores


def test_next_step_is_computed_ahead_and_equals_a_fresh_computation(session):
    fc = FrameComputer()
    t0 = session.time_range[0] + 200_000
    w = session.view.window_us
    run_stages(fc.overlay_stages(at(session, t0)))
    assert not fc.prefetch_overlays()                # no motion yet: nothing to predict
    run_stages(fc.overlay_stages(at(session, t0 + w)))
    assert fc.prefetch_overlays()                    # stepping forward by one window
    req = at(session, t0 + 2 * w)
    hits = fc.overlays_ahead.hits
    with pytest.MonkeyPatch.context() as mp:          # served from ahead: nothing is computed
        mp.setattr(fc, "_overlays", lambda r: pytest.fail("computed again"))
        got = run_stages(fc.overlay_stages(req))
    assert fc.overlays_ahead.hits == hits + 1
    same_frame(got, run_stages(FrameComputer().overlay_stages(req)))
    # backwards by two windows: the prediction follows the step
    run_stages(fc.overlay_stages(at(session, t0)))
    assert fc.prefetch_overlays()
    hits = fc.overlays_ahead.hits
    run_stages(fc.overlay_stages(at(session, t0 - 2 * w)))
    assert fc.overlays_ahead.hits == hits + 1


def test_a_changed_pose_or_setting_is_never_served_from_ahead(session):
    fc = FrameComputer()
    t0 = session.time_range[0] + 200_000
    w = session.view.window_us
    run_stages(fc.overlay_stages(at(session, t0)))
    run_stages(fc.overlay_stages(at(session, t0 + w)))
    assert fc.prefetch_overlays()
    name = session.scene.object_names[0]
    session.nudge_object(name, "camera", trans_mm=(8, 0, 0))       # the user moved an object
    req = at(session, t0 + 2 * w)
    hits = fc.overlays_ahead.hits
    got = run_stages(fc.overlay_stages(req))
    assert fc.overlays_ahead.hits == hits                          # recomputed with the new pose
    same_frame(got, run_stages(FrameComputer().overlay_stages(req)))
    hidden = replace(req, view=replace(req.view, hidden=frozenset({name})))
    fc.prefetch_overlays()
    hits = fc.overlays_ahead.hits
    run_stages(fc.overlay_stages(hidden))
    assert fc.overlays_ahead.hits == hits


def test_prefetch_stops_when_asked_and_large_jumps_are_not_predicted(session):
    fc = FrameComputer()
    t0 = session.time_range[0] + 200_000
    w = session.view.window_us
    run_stages(fc.overlay_stages(at(session, t0)))
    run_stages(fc.overlay_stages(at(session, t0 + w)))
    assert not fc.prefetch_overlays(lambda: True) and len(fc.overlays_ahead) == 0
    run_stages(fc.overlay_stages(at(session, t0 + 50 * w)))       # a drag of the timeline
    assert not fc.prefetch_overlays()


def test_overlay_cache_is_bounded_in_bytes():
    class Data:
        def __init__(self, n):
            self.a = np.zeros(n, np.uint8)
            self.parts = [np.zeros(n, np.uint8)]

    cache = OverlayCache(max_bytes=10_000)
    for k in range(10):
        cache.put(k, Data(2_000))                      # 4 kB each
    assert cache.nbytes <= 10_000 and len(cache) == 2 and 9 in cache and 8 in cache
    cache.get(8)
    cache.put(10, Data(2_000))                          # 9 was least recently used
    assert 8 in cache and 9 not in cache
    cache.put(11, Data(20_000))                         # larger than the budget: not stored
    assert 11 not in cache and cache.nbytes <= 10_000
