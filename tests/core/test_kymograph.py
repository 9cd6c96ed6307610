"""The kymograph (issue 16, point 1): events along a line against time, each object's projected edge track, and the
measured lag of the events behind the tracks: ~0 at the true clock, the clock error when the clock is wrong
(on a synthetic scene with a known clock and no pose error), plus the line geometry it rests on."""
from __future__ import annotations

import numpy as np
import pytest
from kymograph_scene import TRUE_OFFSET_US, moving_session

from evpose.core.data.events import EventArray
from evpose.core.session.kymograph import KymographComputer, KymographRequest, bin_events, link_segments
from evpose.core.session.kymograph_lag import contrast_density, estimate_lag, signed_edge_distance
from evpose.core.session.kymograph_line import KymoLine, edge_crossings, labels_along


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
        assert d.lag.clear
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
    cross = edge_crossings(labels_along(label_map, uv), ss, 2)
    assert len(cross[0]) == 0
    assert cross[1] == pytest.approx([7.5, 14.5], abs=0.13)     # the pixel boundaries 17.5 and 24.5 px
    ev = EventArray(np.array([12, 12, 12, 25, 25]), np.array([5, 6, 8, 5, 5]),
                    np.array([1_000, 1_500, 1_000, 3_999, 4_000]), np.array([1, 0, 1, 0, 1]))
    on, off = bin_events(ev, line, 0, 4, 1_000)
    assert on.shape == (4, 21)
    assert on[1, 2] == 1 and off[1, 2] == 1              # on the line and 1 px across; 3 px across left out
    assert off[3, 15] == 1 and on.sum() == 1             # t = 4000 is after the last bin


def test_lag_estimate_on_a_synthetic_moving_edge():
    """An edge moving at 0.5 px/ms, its events 7 ms after the track says: the lag is +7 ms; a still edge, or a line
    with too few events, has none."""
    n_t, n_s, t_first = 300, 80, -150.0
    t = t_first + np.arange(n_t) + 0.5
    counts = np.zeros((n_t, n_s))
    edge_events = 40 + 0.5 * (t - 7.0)
    for i, s_e in enumerate(edge_events):
        c = int(round(s_e))
        if 0 <= c < n_s:
            counts[i, c] += 3
    dens = contrast_density(counts)
    track_t = np.arange(-100.0, 100.0, 4.0)
    edge_track = 40 + 0.5 * track_t
    dist = np.array([signed_edge_distance(np.arange(n_s) > s_e, np.array([s_e]), n_s) for s_e in edge_track])
    est = estimate_lag(dens, t_first, 1.0, track_t, dist, n_events=1000, travel_px=100.0)
    assert est.lag_ms == pytest.approx(7.0, abs=0.6)
    still = estimate_lag(dens, t_first, 1.0, track_t, dist, n_events=1000, travel_px=1.0)
    assert still.lag_ms is None
    assert estimate_lag(dens, t_first, 1.0, track_t, dist, n_events=10, travel_px=100.0).lag_ms is None


def test_link_segments_join_nearby_crossings_only():
    segs = link_segments([0.0, 4.0, 8.0], [np.array([10.0, 50.0]), np.array([12.0]), np.array([30.0])])
    assert segs.tolist() == [[[10.0, 0.0], [12.0, 4.0]]]


def test_the_default_line_crosses_a_shown_object(kymo_session):
    kc = KymographComputer()
    d = kymograph_at(kymo_session, kc, TRUE_OFFSET_US)
    crossed = [t.name for t in d.tracks]
    try:
        for name in crossed:
            kymo_session.set_object_visible(name, False)
        d2 = kc.kymograph(KymographRequest(kymo_session.request()))
        assert d2.auto_line and d2.tracks and d2.lag_ms is not None      # across another object, with its lag
        assert not {t.name for t in d2.tracks} & set(crossed)
    finally:
        for name in crossed:
            kymo_session.set_object_visible(name, True)


def test_the_default_line_takes_the_largest_silhouette_when_none_moves():
    from evpose.core.session.kymograph_line import default_line

    now = np.full((100, 200), -1, np.int8)
    now[40:80, 100:180] = 1                   # object 1: 3200 px, still
    now[10:20, 10:20] = 0                     # object 0: 100 px
    after = now.copy()
    after[10:20, 20] = 0                      # object 0's centroid moves 0.5 px: not a motion
    line = default_line(now, now, after, 2)
    # along x through object 1's centroid (139.5, 59.5), reaching beyond it on both sides
    assert line.v0 == line.v1 == pytest.approx(59.5) and line.u0 < 100 and line.u1 > 179
    assert (line.u0 + line.u1) / 2 == pytest.approx(139.5)
