"""The kymograph (issue 16, point 1; issue 23, part 8): events along a line against time, each object's projected
edge track, and the measured lag of the events behind the tracks with its 1σ: ~0 at the true clock, the clock
error when the clock is wrong (on a synthetic scene with a known clock and no pose error), within 2σ of the truth,
or "too weak to read" with the reason where the line's evidence cannot carry a reading; the default line across
the edge with the most evidence; plus the line geometry it rests on."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from kymograph_scene import (
    TRUE_OFFSET_US,
    edge_events,
    kymograph_scene,
    moves_us,
    moving_session,
    still_time_us,
    two_object_span,
)

from evpose.core.data.events import EventArray
from evpose.core.views import kymograph_confidence as conf
from evpose.core.views.kymograph import KymographComputer, KymographRequest, bin_events, link_segments
from evpose.core.views.kymograph_lag import estimate_lag
from evpose.core.views.kymograph_line import KymoLine, crossing_distances, default_line, labels_along
from evpose.core.views.kymograph_pick import pick_default_line
from evpose.core.views.kymograph_read import read_line


@pytest.fixture(scope="module")
def kymo_session(tmp_path_factory):
    s = moving_session(tmp_path_factory)
    yield s
    s.close()


def kymograph_at(session, kc, correction_us, line=None):
    session.set_offset_correction_us(correction_us)
    return kc.kymograph(KymographRequest(session.request(), line))


def test_lag_is_zero_at_the_true_clock_and_the_clock_error_when_wrong(kymo_session):
    kc = KymographComputer()
    true = kymograph_at(kymo_session, kc, TRUE_OFFSET_US)
    assert true.auto_line and true.tracks and true.n_events > 500
    line = true.line.as_tuple()               # the same line for every clock: the default one at the true clock
    assert true.lag_ms is not None and abs(true.lag_ms) <= 2.0, true.lag_ms
    for error_us in (-20_000, 20_000):
        d = kymograph_at(kymo_session, kc, TRUE_OFFSET_US + error_us, line)
        assert not d.auto_line and d.line.as_tuple() == pytest.approx(line)
        # the offset in effect is error_us too large: the poses are taken that much too late, the events lag
        assert d.lag_ms == pytest.approx(error_us / 1e3, abs=2.5), (error_us, d.lag_ms)
        assert d.lag.readable and abs(d.lag_ms - error_us / 1e3) <= 2 * d.lag.sigma_ms
    # the image covers the span, a row per ms, a column per px along the line
    n_t, n_s = true.image_rgb.shape[:2]
    assert n_t == 200 and n_s == int(np.floor(true.line.length + 0.5)) + 1
    assert true.t_first_ms == pytest.approx(-100.0)
    assert true.frame_rgb.shape == (130, 173, 3) and true.frame_contours


def test_tracks_are_the_silhouette_crossings_and_move_with_the_clock(kymo_session):
    kc = KymographComputer()
    true = kymograph_at(kymo_session, kc, TRUE_OFFSET_US)
    wrong = kymograph_at(kymo_session, kc, TRUE_OFFSET_US - 20_000, true.line.as_tuple())
    misses = kc.maps.misses
    again = kymograph_at(kymo_session, kc, TRUE_OFFSET_US - 20_000, true.line.as_tuple())
    assert kc.maps.misses == misses, "the label maps of unchanged poses were rendered again"
    assert [t.name for t in again.tracks] == [t.name for t in wrong.tracks]
    tr_true = {t.name: t for t in true.tracks}
    for tr in wrong.tracks:
        assert len(tr.segments) and np.all(tr.s_px >= 0) and np.all(tr.s_px <= true.line.length)
        # a clock 20 ms behind shows the poses of 20 ms earlier: the wrong track is the true one, 20 ms later
        ref = tr_true[tr.name]
        both = np.intersect1d(tr.t_ms, ref.t_ms + 20.0)
        assert len(both) > 10
        for t in both[::5]:
            s_wrong = np.sort(tr.s_px[tr.t_ms == t])
            s_ref = np.sort(ref.s_px[ref.t_ms == t - 20.0])
            if len(s_wrong) == len(s_ref):
                assert np.allclose(s_wrong, s_ref, atol=1.5)


def test_line_geometry_crossings_and_binning():
    line = KymoLine(10.0, 5.0, 30.0, 5.0)               # 20 px to the right along row 5
    s, n = line.project(np.array([15.0, 20.0]), np.array([5.0, 7.0]))
    assert s.tolist() == [5.0, 10.0] and n.tolist() == [0.0, 2.0]   # across: 90° clockwise, i.e. down
    assert KymoLine(-10, 5, 30, 5).clipped(20, 10).as_tuple() == (0.0, 5.0, 19.0, 5.0)
    assert KymoLine(-10, -5, -1, -5).clipped(20, 10) is None
    label_map = np.full((10, 40), -1, np.int16)
    label_map[:, 18:25] = 1                              # object 1 covers columns 18..24
    ss, uv = line.samples()
    cols = np.column_stack([10.0 + np.arange(21), np.full(21, 5.0)])
    labels, at_cols = labels_along(label_map[None], uv), labels_along(label_map[None], cols)
    cross0, d0 = crossing_distances(labels, ss, at_cols, 0)
    cross, d = crossing_distances(labels, ss, at_cols, 1)
    assert len(cross0[0]) == 0 and np.all(np.isinf(d0))
    assert cross[0] == pytest.approx([7.5, 14.5], abs=0.13)     # the pixel boundaries 17.5 and 24.5 px
    # signed distance to the nearest crossing, > 0 inside the silhouette (columns 8..14 of the line)
    assert d[0, [0, 7, 8, 11, 14, 15, 20]] == pytest.approx([-7.5, -0.5, 0.5, 3.5, 0.5, -0.5, -5.5], abs=0.13)
    ev = EventArray(np.array([12, 12, 12, 25, 25]), np.array([5, 6, 8, 5, 5]),
                    np.array([1_000, 1_500, 1_000, 3_999, 4_000]), np.array([1, 0, 1, 0, 1]))
    on, off = bin_events(ev, line, 0, 4, 1_000)
    assert on.shape == (4, 21)
    assert on[1, 2] == 1 and off[1, 2] == 1              # on the line and 1 px across; 3 px across left out
    assert off[3, 15] == 1 and on.sum() == 1             # t = 4000 is after the last bin


def test_lag_estimate_on_a_synthetic_moving_edge():
    """An edge moving at 0.5 px/ms, its events 7 ms after the track says: the lag is +7 ms within its σ; a still
    edge, one that moves for 24 ms of the 200, a line with few events near the track, or an edge so slow that half a
    pixel across it is 6 ms, is too weak to read, and says why."""
    events, track_t, dist, travel = edge_events(1, 0.5, 7.0)
    est = estimate_lag(events, track_t, dist, travel)
    assert est.readable and est.lag_ms == pytest.approx(7.0, abs=1.0) and 0.2 < est.sigma_ms < 3.0
    assert abs(est.lag_ms - 7.0) <= 2 * est.sigma_ms
    still = estimate_lag(events, track_t, np.repeat(dist[25:26], len(track_t), axis=0), 0.0)
    assert still.lag_ms is None and still.weak == conf.NO_MOTION
    brief = estimate_lag(*edge_events(1, 0.5, 7.0, moving_ms=(-12.0, 12.0)))   # moves over 6 track times only
    assert brief.lag_ms is None and brief.weak == conf.NO_MOTION and brief.n_moving < conf.MIN_MOVING_TIMES
    sparse = estimate_lag(*edge_events(1, 0.5, 7.0, rate=0.05, noise=0.0))
    assert sparse.lag_ms is None and sparse.weak == conf.FEW_EVENTS
    slow = estimate_lag(*edge_events(1, 0.08, 7.0))          # 0.5 px across the edge alone is 6 ms
    assert slow.lag_ms is None and slow.weak == conf.SLOW and slow.sigma_ms > conf.MAX_SIGMA_MS


def test_the_lag_is_read_finer_than_the_time_bins():
    """Dense events on a sharp edge whose true lag falls midway between two time bins' centres (the scores are
    linear between those): the reading is not locked to a bin centre, 0.5 ms off, but within 0.3 ms RMS over
    speeds, directions and seeds."""
    err = [estimate_lag(*edge_events(seed, v, lag, rate=3.0, noise=0.005), judge=False).peak_ms - lag
           for seed in range(3) for v in (0.5, 1.0, -0.7) for lag in (7.0, -31.0)]
    assert np.sqrt(np.mean(np.square(err))) < 0.3, err


def test_a_still_part_of_the_track_does_not_blur_the_reading():
    """An edge that stops 40 ms before the current time, its events 5 ms after its track while it moves (a still
    edge makes none): the track's still part says nothing about the lag and must not blur it (shifted back, it
    lies on the last events of the motion), so the moving part reads the lag to within 2σ, σ under 3 ms."""
    for seed in (3, 4):
        est = estimate_lag(*edge_events(seed, 0.3, 5.0, rate=2.0, moving_ms=(-np.inf, -40.0)))
        assert est.readable and abs(est.lag_ms - 5.0) <= 2 * est.sigma_ms and est.sigma_ms < 3.0, est


def test_sigma_covers_the_truth_on_synthetic_edges():
    """Edges at 0.4 to 1 px/ms either way with a known lag, sparse and dense events: (nearly) all readable, every
    reading within 2σ of the truth, and σ not padded (the errors fill it: their RMS is over a sixth of σ's)."""
    z = []
    for seed, speed, lag, rate in [(s, v, lag, r) for s in range(2) for v in (0.4, 0.7, -1.0)
                                   for lag, r in ((-31.0, 0.5), (12.5, 2.0))]:
        est = estimate_lag(*edge_events(10 + seed, speed, lag, rate=rate))
        if est.readable:
            z.append((est.lag_ms - lag) / est.sigma_ms)
    z = np.abs(z)
    assert len(z) >= 10 and z.max() <= 2.0 and np.sqrt(np.mean(z ** 2)) > 1 / 6, z


def test_a_parallel_streak_beside_the_edge_is_never_read_with_confidence():
    """A second streak as strong as the edge's, 8 or 15 px beside it and moving with it (a texture line): every
    track time agrees with either, so the reading is too weak (σ shows the doubt, or the other streak's peak
    nearly matches) or within 2σ of the truth, never confidently wrong; the rival check catches some that σ
    alone would let through."""
    reasons = []
    for speed, twin, seed in [(v, tw, sd) for v in (0.5, 1.0) for tw in (8.0, -15.0) for sd in range(4)]:
        est = estimate_lag(*edge_events(seed, speed, 7.0, twin_px=twin))
        assert not est.readable or abs(est.lag_ms - 7.0) <= 2 * est.sigma_ms, (speed, twin, seed, est)
        reasons.append(est.weak)
    assert reasons.count(conf.RIVAL) >= 2, reasons


def test_link_segments_join_nearby_crossings_only():
    segs = link_segments([0.0, 4.0, 8.0], [np.array([10.0, 50.0]), np.array([12.0]), np.array([30.0])])
    assert segs.tolist() == [[[10.0, 0.0], [12.0, 4.0]]]


def test_the_default_line_crosses_a_shown_object(kymo_session):
    kc = KymographComputer()
    d = kymograph_at(kymo_session, kc, TRUE_OFFSET_US)
    assert d.lines_tried > 1
    crossed = [t.name for t in d.tracks]
    try:
        for name in crossed:
            kymo_session.set_object_visible(name, False)
        d2 = kc.kymograph(KymographRequest(kymo_session.request()))
        assert d2.auto_line and d2.tracks                                 # across another object
        assert not {t.name for t in d2.tracks} & set(crossed)
    finally:
        for name in crossed:
            kymo_session.set_object_visible(name, True)


def test_the_default_line_takes_the_largest_silhouette_when_none_moves():
    now = np.full((100, 200), -1, np.int8)
    now[40:80, 100:180] = 1                   # object 1: 3200 px, still
    now[10:20, 10:20] = 0                     # object 0: 100 px
    after = now.copy()
    after[10:20, 20] = 0                      # object 0's centroid moves 0.5 px: not a motion
    line = default_line(now, now, after, 2)
    # along x through object 1's centroid (139.5, 59.5), reaching beyond it on both sides
    assert line.v0 == line.v1 == pytest.approx(59.5) and line.u0 < 100 and line.u1 > 179
    assert (line.u0 + line.u1) / 2 == pytest.approx(139.5)


def test_the_default_line_crosses_the_edge_with_evidence():
    """Of two moving objects, the faster one makes no events (no contrast against the background): the default
    line crosses the other one and reads its lag (0: the clock is right); a line across the faster one (the
    likeliest by motion alone) is too weak to read."""
    span = two_object_span()
    reading, tried = pick_default_line(span, SimpleNamespace(selected=None))
    assert tried > 2 and "lit" in [t.name for t in reading.tracks]
    assert reading.lag.readable and abs(reading.lag.lag_ms) <= 2 * reading.lag.sigma_ms, reading.lag
    now = span.nearest_map(span.tc_us)
    likeliest = default_line(now, span.nearest_map(span.tc_us - 10_000), span.nearest_map(span.tc_us + 10_000), 2)
    dark = read_line(span, likeliest)
    assert [t.name for t in dark.tracks] == ["dark"] and dark.lag.weak == conf.FEW_EVENTS
    # the selected object's lines come first while one of them has evidence
    selected, _ = pick_default_line(span, SimpleNamespace(selected="dark"))
    assert "lit" in [t.name for t in selected.tracks]


def test_the_default_line_is_too_weak_where_the_lines_across_the_objects_disagree():
    """One clock moves every track. When the dark object's edges fire too, 12 ms earlier than its track says (as
    a pose error would make them seem), the selected lit object's line reads ~0 and the dark object's lines
    -12 ms, each confidently: the default line does not read, and says why. With both right it reads ~0."""
    view = SimpleNamespace(selected="lit")
    reading, _ = pick_default_line(two_object_span(0, dark_lag_ms=-12.0), view)
    assert "lit" in [t.name for t in reading.tracks]
    assert reading.lag.lag_ms is None and reading.lag.weak == conf.DISAGREE, reading.lag
    reading, _ = pick_default_line(two_object_span(0, dark_lag_ms=0.0), view)
    assert reading.lag.readable and abs(reading.lag.lag_ms) <= 2 * reading.lag.sigma_ms, reading.lag


@pytest.fixture(scope="module")
def scene_windows(tmp_path_factory):
    """The kymograph scene's windows: in the middle of its two moves (and 40 ms later), and in a pause."""
    from evpose.core.session.model import Session

    path = kymograph_scene(tmp_path_factory)
    s = Session.open(path)
    moving = [t + dt for _, t in moves_us(path, *s.time_range)[:2] for dt in (0, 40_000)]
    yield s, moving, still_time_us(path, *s.time_range)
    s.close()


def test_sigma_covers_the_truth_in_the_scene_and_a_still_window_is_too_weak(scene_windows):
    """Default lines at four moving times, each read at the true clock and 20 ms either side: most are readable,
    all of those within 2σ of the clock error; in a pause between moves the reading is too weak (no motion)."""
    s, moving, still = scene_windows
    kc = KymographComputer()
    readable = 0
    for t in moving:
        s.set_time(t)
        line = None
        for error_us in (0, -20_000, 20_000):
            d = kymograph_at(s, kc, TRUE_OFFSET_US + error_us, line)
            line = d.line.as_tuple()
            if d.lag.readable:
                readable += 1
                assert abs(d.lag_ms - error_us / 1e3) <= 2 * d.lag.sigma_ms, (t, error_us, d.lag)
            else:
                assert d.lag.weak in (conf.NO_MOTION, conf.AMBIGUOUS, conf.FEW_EVENTS, conf.RIVAL, conf.DISAGREE)
    assert readable >= 6
    s.set_time(still)
    for error_us in (0, 20_000):
        d = kymograph_at(s, kc, TRUE_OFFSET_US + error_us)
        assert d.lag_ms is None and d.lag.weak == conf.NO_MOTION, d.lag
