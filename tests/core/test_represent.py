"""Event frames (core/represent.py) against independent oracles: np.add.at, explicit loops, cv2."""
from __future__ import annotations

import warnings

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from evpose.core.data.camera import CameraModel
from evpose.core.data.events import EventArray
from evpose.core.label import represent as R
from evpose.core.label.event_frames import accumulate
from evpose.core.label.event_frames.counts import polarity_counts, spike
from evpose.core.label.event_frames.display import gray_rgb, polarity_rgb, three_channel_rgb
from evpose.core.label.event_frames.three_channel import three_channel
from evpose.core.label.event_frames.time_surface import time_surface
from evpose.core.label.event_frames.undistort import EventUndistorter, clear_undistorter_cache, undistorter_for
from evpose.core.label.event_frames.voxel_grid import voxel_grid

W, H = 346, 260          # DAVIS346; W != H so that an x/y swap cannot pass


def rand_events(n, seed=0, t0=0, t1=10_000, width=W, height=H, sort=True):
    rng = np.random.default_rng(seed)
    t = rng.integers(t0, t1, n)
    if sort:
        t = np.sort(t)
    return EventArray(rng.integers(0, width, n), rng.integers(0, height, n), t, rng.integers(0, 2, n))


def oracle_counts(ev, width=W, height=H):
    pos = np.zeros((height, width), np.int64)
    neg = np.zeros((height, width), np.int64)
    on = ev.p == 1
    np.add.at(pos, (ev.y[on].astype(int), ev.x[on].astype(int)), 1)
    np.add.at(neg, (ev.y[~on].astype(int), ev.x[~on].astype(int)), 1)
    return pos, neg


# ------------------------------------------------------------------------------------------------ counts
def test_polarity_counts_match_add_at_with_duplicates_and_edge_pixels():
    ev = rand_events(20_000, seed=1)
    edges = [(0, 0), (W - 1, H - 1), (0, H - 1), (W - 1, 0), (0, 0), (0, 0)]
    ex = np.array([e[0] for e in edges] * 3)
    ey = np.array([e[1] for e in edges] * 3)
    ep = np.array([1] * len(edges) + [0] * len(edges) + [1] * len(edges))
    ev = EventArray(np.r_[ev.x, ex], np.r_[ev.y, ey], np.r_[ev.t, np.full(len(ex), 9_999)], np.r_[ev.p, ep])
    pos, neg = polarity_counts(ev, W, H)
    opos, oneg = oracle_counts(ev)
    assert pos.shape == neg.shape == (H, W)
    assert np.array_equal(pos, opos) and np.array_equal(neg, oneg)
    assert pos.sum() + neg.sum() == len(ev)
    assert pos[0, 0] >= 6 and pos[H - 1, W - 1] >= 2 and neg[H - 1, 0] >= 1 and neg[0, W - 1] >= 1


def test_events_on_row_zero_and_column_zero_are_counted():
    # The original E-POSE scripts dropped x=0 / y=0 events; each must land exactly at [v, u].
    ev = EventArray([0, 5, 0, 300], [7, 0, 0, 10], [0, 1, 2, 3], [1, 1, 0, 1])
    pos, neg = polarity_counts(ev, W, H)
    assert pos[7, 0] == 1 and pos[0, 5] == 1 and neg[0, 0] == 1 and pos[10, 300] == 1
    assert pos.sum() == 3 and neg.sum() == 1
    assert spike(ev, W, H).sum() == 4 and spike(ev, W, H)[0, 0]


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 6), st.integers(0, 4), st.integers(0, 1)), max_size=60))
def test_polarity_counts_property_small_sensor(evs):
    w, h = 7, 5
    a = np.array(evs, dtype=np.int64).reshape(-1, 3)
    ev = EventArray(a[:, 0], a[:, 1], np.arange(len(a)), a[:, 2])
    pos, neg = polarity_counts(ev, w, h)
    opos, oneg = oracle_counts(ev, w, h)
    assert np.array_equal(pos, opos) and np.array_equal(neg, oneg)
    assert np.array_equal(spike(ev, w, h), (opos + oneg) > 0)


def test_ten_million_events_in_one_millisecond_on_a_few_pixels_no_overflow():
    n_a, n_b, n_c = 6_000_000, 3_999_990, 10        # 10**7 in total, pixel A far beyond int16/uint16
    x = np.repeat(np.array([0, W - 1, 100], np.uint16), [n_a, n_b, n_c])
    y = np.repeat(np.array([0, H - 1, 50], np.uint16), [n_a, n_b, n_c])
    p = np.repeat(np.array([1, 0, 1], np.uint8), [n_a, n_b, n_c])
    t = np.sort(np.random.default_rng(0).integers(5_000_000, 5_001_000, len(x)))   # 1 ms window
    ev = EventArray(x, y, t, p)
    assert len(ev) == 10**7
    pos, neg = polarity_counts(ev, W, H)
    assert pos.dtype == np.int64 and neg.dtype == np.int64
    assert pos[0, 0] == n_a and neg[H - 1, W - 1] == n_b and pos[50, 100] == n_c
    assert pos.sum() + neg.sum() == 10**7
    img = three_channel(ev, W, H, 5_000_000, 5_001_000)
    assert img[0, 0, 0] == 1.0 and img[H - 1, W - 1, 1] == 1.0
    assert img[50, 100, 0] == pytest.approx(n_c / n_a, rel=1e-6)


@pytest.mark.parametrize("field, ev", [
    ("x", EventArray([W], [0], [0], [1])),
    ("y", EventArray([0], [H], [0], [1])),
    ("p", EventArray(np.array([0], np.uint16), np.array([0], np.uint16), np.array([0]), np.array([2], np.uint8))),
])
def test_out_of_sensor_events_raise_naming_the_field(field, ev):
    for f in (lambda: polarity_counts(ev, W, H), lambda: spike(ev, W, H),
              lambda: time_surface(ev, W, H, 10), lambda: voxel_grid(ev, W, H, 0, 10),
              lambda: three_channel(ev, W, H, 0, 10)):
        with pytest.raises(ValueError, match=rf"^{field}: "):
            f()


# ------------------------------------------------------------------------------------------------ 3-channel
def oracle_three_channel(ev, t0, width=W, height=H):
    img = np.zeros((height, width, 3), np.float64)
    for x, y, t, p in zip(ev.x.tolist(), ev.y.tolist(), ev.t.tolist(), ev.p.tolist()):
        img[y, x, 0 if p else 1] += 1
        img[y, x, 2] = max(img[y, x, 2], t - t0 + 1)
    for c in range(3):
        if img[..., c].max() > 0:
            img[..., c] /= img[..., c].max()
    return img


def test_three_channel_matches_loop_oracle_and_is_normalised():
    t0, t1 = 1_000_000, 1_010_000
    ev = rand_events(3_000, seed=2, t0=t0, t1=t1, width=40, height=30)
    img = three_channel(ev, 40, 30, t0, t1)
    assert img.dtype == np.float32 and img.shape == (30, 40, 3)
    assert np.allclose(img, oracle_three_channel(ev, t0, 40, 30), atol=1e-6)
    assert [float(img[..., c].max()) for c in range(3)] == [1.0, 1.0, 1.0]
    assert img.min() >= 0


def test_three_channel_time_channel_orders_events_and_marks_an_event_at_t0():
    t0, t1 = 500, 1_500
    ev = EventArray([1, 2, 3, 3], [0, 0, 0, 0], [t0, t0 + 10, t0 + 400, t1 - 1], [1, 0, 1, 0])
    img = three_channel(ev, 5, 2, t0, t1)
    c2 = img[..., 2]
    assert 0 < c2[0, 1] < c2[0, 2] < c2[0, 3] == 1.0        # later event -> larger value
    assert c2[0, 1] == pytest.approx(1 / 1000) and c2[0, 0] == 0 and c2[1].max() == 0
    # the pixel at (3, 0) has an ON at +400 and an OFF at t1-1: channel 2 takes the latest of either polarity
    assert img[0, 3, 0] == 1.0 and img[0, 3, 1] == 1.0
    win = three_channel(ev, 5, 2, t0, t1, time_norm="window")[..., 2]
    assert win[0, 1] == pytest.approx(1 / 1000) and win[0, 3] == 1.0 and win[0, 2] == pytest.approx(11 / 1000)
    # events in the first half only: "max" stretches to 1, "window" keeps the absolute scale
    early = ev[np.array([True, True, True, False])]
    assert three_channel(early, 5, 2, t0, t1)[..., 2].max() == 1.0
    assert three_channel(early, 5, 2, t0, t1, time_norm="window")[..., 2].max() == pytest.approx(401 / 1000)


def test_three_channel_second_window_depends_only_on_its_own_events():
    # E-POSE never reset its accumulators: window 2 also showed window 1. Ours must not.
    ev1 = rand_events(5_000, seed=3, t0=0, t1=10_000, width=60, height=40)
    ev2 = rand_events(500, seed=4, t0=10_000, t1=20_000, width=30, height=20)   # a sub-region only
    alone = three_channel(ev2, 60, 40, 10_000, 20_000)
    three_channel(ev1, 60, 40, 0, 10_000)
    after = three_channel(ev2, 60, 40, 10_000, 20_000)
    assert np.array_equal(alone, after)
    assert alone[25:, :].max() == 0 and alone[:, 35:].max() == 0                  # nothing of window 1
    leaky = oracle_three_channel(EventArray.concatenate([ev1, ev2]), 0, 60, 40)  # the E-POSE defect
    assert not np.allclose(leaky, alone, atol=1e-3)                                 # the test can tell
    rgb_alone = R.to_rgb("three_channel", ev2, 60, 40, 10_000, 20_000)
    R.to_rgb("three_channel", ev1, 60, 40, 0, 10_000)
    assert np.array_equal(rgb_alone, R.to_rgb("three_channel", ev2, 60, 40, 10_000, 20_000))


def test_empty_and_zero_length_windows_give_zeros_without_warnings():
    e = EventArray.empty()
    with warnings.catch_warnings():
        warnings.simplefilter("error")          # any warning (numpy divide/invalid included) fails
        with np.errstate(all="raise"):
            pos, neg = polarity_counts(e, W, H)
            assert pos.shape == (H, W) and pos.sum() == 0 and neg.sum() == 0
            assert not spike(e, W, H).any()
            for t0, t1 in ((0, 10_000), (7, 7)):
                img = three_channel(e, W, H, t0, t1)
                assert img.shape == (H, W, 3) and not img.any() and np.isfinite(img).all()
                vg = voxel_grid(e, W, H, t0, t1, bins=5)
                assert vg.shape == (5, H, W) and not vg.any()
                for name in R.REPRESENTATIONS:
                    rgb = R.to_rgb(name, e, W, H, t0, t1)
                    assert rgb.dtype == np.uint8 and rgb.shape == (H, W, 3)
            ts = time_surface(e, W, H, 100)
            assert ts.shape == (2, H, W) and not ts.any()


def test_window_bounds_are_half_open_and_checked():
    ev = EventArray([1, 2], [1, 1], [100, 199], [1, 0])
    assert three_channel(ev, 5, 5, 100, 200).any()                # t0 inside, t1 - 1 inside
    with pytest.raises(ValueError, match="^t: "):
        three_channel(ev, 5, 5, 100, 199)                         # an event at t1 belongs to the next window
    with pytest.raises(ValueError, match="^t: "):
        voxel_grid(ev, 5, 5, 101, 300)
    with pytest.raises(ValueError, match="reversed"):
        three_channel(EventArray.empty(), 5, 5, 10, 9)
    with pytest.raises(ValueError, match="^t: "):
        R.to_rgb("polarity", ev, 5, 5, 100, 199)


# ------------------------------------------------------------------------------------------------ time surface
def oracle_time_surface(ev, t_ref, tau, split, width, height):
    last = {}
    for x, y, t, p in zip(ev.x.tolist(), ev.y.tolist(), ev.t.tolist(), ev.p.tolist()):
        if t > t_ref:
            continue
        key = (0 if p else 1, y, x) if split else (y, x)
        last[key] = max(last.get(key, -np.inf), t)
    out = np.zeros((2, height, width) if split else (height, width))
    for key, t in last.items():
        out[key] = np.exp(-(t_ref - t) / tau)
    return out


@pytest.mark.parametrize("polarity", ["split", "merged"])
def test_time_surface_matches_formula_and_ignores_later_events(polarity):
    ev = rand_events(4_000, seed=5, t0=0, t1=100_000, width=30, height=20, sort=False)   # order must not matter
    t_ref, tau = 60_000, 15_000.0
    ts = time_surface(ev, 30, 20, t_ref, tau_us=tau, polarity=polarity)
    ref = oracle_time_surface(ev, t_ref, tau, polarity == "split", 30, 20)
    assert ts.dtype == np.float32 and ts.shape == ref.shape
    assert np.allclose(ts, ref, rtol=1e-6, atol=1e-7)
    assert ts.max() <= 1.0


def test_time_surface_event_at_reference_is_one_and_after_is_ignored():
    ev = EventArray([0, 1, 1, 2], [0, 0, 0, 0], [1_000, 1_000, 1_001, 1_001], [1, 0, 0, 1])
    ts = time_surface(ev, 3, 1, 1_000, tau_us=100, polarity="split")
    assert ts[0, 0, 0] == 1.0 and ts[1, 0, 1] == 1.0          # ON first, OFF second
    assert ts[:, 0, 2].max() == 0                              # only event after t_ref
    assert ts[0, 0, 1] == 0 and ts[1, 0, 0] == 0
    merged = time_surface(ev, 3, 1, 1_100, tau_us=100, polarity="merged")
    assert merged[0, 1] == pytest.approx(np.exp(-99 / 100)) and merged[0, 2] == pytest.approx(np.exp(-99 / 100))


# ------------------------------------------------------------------------------------------------ voxel grid
def oracle_voxel(ev, t0, t1, bins, width, height):
    g = np.zeros((bins, height, width))
    for x, y, t, p in zip(ev.x.tolist(), ev.y.tolist(), ev.t.tolist(), ev.p.tolist()):
        s = 1.0 if p else -1.0
        tau = (bins - 1) * (t - t0) / (t1 - t0)
        lo = int(np.floor(tau))
        fr = tau - lo
        g[lo, y, x] += s * (1 - fr)
        if fr > 0:
            g[lo + 1, y, x] += s * fr
    return g


@pytest.mark.parametrize("bins", [1, 2, 5, 9])
def test_voxel_grid_matches_bilinear_oracle_and_sums_to_signed_counts(bins):
    t0, t1 = 3_000_000, 3_010_000
    ev = rand_events(3_000, seed=6, t0=t0, t1=t1, width=25, height=15)
    vg = voxel_grid(ev, 25, 15, t0, t1, bins=bins)
    assert vg.dtype == np.float32 and vg.shape == (bins, 15, 25)
    assert np.allclose(vg, oracle_voxel(ev, t0, t1, bins, 25, 15), atol=1e-5)
    pos, neg = polarity_counts(ev, 25, 15)
    assert np.allclose(vg.sum(axis=0), pos - neg, atol=1e-4)


def test_voxel_event_at_bin_centre_goes_to_one_bin_and_bilinear_split():
    t0, t1, B = 0, 8_000, 5                  # centres every 2000 µs: 0, 2000, 4000, 6000, 8000
    on_centre = EventArray([1], [1], [4_000], [1])
    vg = voxel_grid(on_centre, 4, 3, t0, t1, B)
    assert vg[2, 1, 1] == 1.0 and np.count_nonzero(vg) == 1
    quarter = EventArray([2], [0], [2_500], [0])                 # 1/4 of the way from bin 1 to bin 2
    vg = voxel_grid(quarter, 4, 3, t0, t1, B)
    assert vg[1, 0, 2] == -0.75 and vg[2, 0, 2] == -0.25 and np.count_nonzero(vg) == 2
    first = voxel_grid(EventArray([0], [0], [0], [1]), 4, 3, t0, t1, B)
    assert first[0, 0, 0] == 1.0 and np.count_nonzero(first) == 1
    last = voxel_grid(EventArray([0], [0], [t1 - 1], [1]), 4, 3, t0, t1, B)
    assert last[4, 0, 0] == pytest.approx(1 - 1 / 2000) and last[3, 0, 0] == pytest.approx(1 / 2000)


# ------------------------------------------------------------------------------------------------ undistortion
@pytest.fixture
def davis():
    return CameraModel.davis346()


def test_straight_3d_line_becomes_straight_after_undistortion(davis):
    # A 3D line at normalised height y = -0.35 spanning x in [-0.5, 0.5]: barrel distortion bends it by ~7 px.
    s = np.linspace(-0.5, 0.5, 4000)
    P = np.stack([s, np.full_like(s, -0.35), np.ones_like(s)], axis=1) * 0.8          # z = 0.8 m
    uv, valid = davis.project(P)
    assert valid.all()
    pix = np.unique(np.rint(uv).astype(int), axis=0)
    ev = EventArray(pix[:, 0], pix[:, 1], np.arange(len(pix)), np.ones(len(pix), np.uint8))
    und = EventUndistorter(davis).apply(ev)
    assert len(und) == len(ev)
    v_line = davis.K[1, 1] * -0.35 + davis.K[1, 2]                                  # the ideal pinhole image
    err_und = np.abs(und.y.astype(float) - v_line)
    err_dist = np.abs(ev.y.astype(float) - v_line)

    def tls_residual(x, y):
        A = np.stack([x - x.mean(), y - y.mean()], axis=1).astype(float)
        n = np.linalg.svd(A, full_matrices=False)[2][-1]
        return np.abs(A @ n).max()

    assert err_dist.max() > 5.0 and tls_residual(ev.x, ev.y) > 3.0                 # curved before
    assert err_und.max() <= 1.0 and tls_residual(und.x, und.y) <= 1.0              # straight after
    u_ideal = davis.K[0, 0] * np.array([-0.5, 0.5]) + davis.K[0, 2]
    assert abs(int(und.x.min()) - u_ideal[0]) <= 1.5 and abs(int(und.x.max()) - u_ideal[1]) <= 1.5


def test_undistorted_counts_are_conserved_against_per_event_cv2_oracle(davis):
    ev = rand_events(50_000, seed=7)
    und = EventUndistorter(davis).apply(ev)
    # oracle: undistort every event on its own with cv2, round, keep those inside the image
    pts = np.stack([ev.x, ev.y], axis=1).astype(np.float64).reshape(-1, 1, 2)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    uvn = np.rint(cv2.undistortPoints(pts, davis.K, davis.dist, P=davis.K, criteria=crit).reshape(-1, 2))
    assert davis.pixel_rays()[1].all()               # DAVIS346: undistortion converges on every pixel
    keep = (uvn[:, 0] >= 0) & (uvn[:, 0] < W) & (uvn[:, 1] >= 0) & (uvn[:, 1] < H)
    assert 0.5 * len(ev) < keep.sum() < len(ev)      # corners leave the image with K_new = K
    assert len(und) == keep.sum()
    assert np.array_equal(und.x, uvn[keep, 0].astype(np.uint16))
    assert np.array_equal(und.y, uvn[keep, 1].astype(np.uint16))
    assert np.array_equal(und.t, ev.t[keep]) and np.array_equal(und.p, ev.p[keep])   # order and times kept
    pos, neg = polarity_counts(und, W, H)
    assert pos.sum() + neg.sum() == keep.sum()                                        # counts conserved


def test_undistortion_table_reprojects_within_rounding(davis):
    u = EventUndistorter(davis)
    vv, uu = np.nonzero(u.lut[..., 0] >= 0)
    und = u.lut[vv, uu].astype(np.float64)
    xy = (und - davis.K[:2, 2]) / np.diag(davis.K)[:2]
    back = davis.distort_normalized(xy)                     # cv2.projectPoints
    err = np.hypot(back[:, 0] - uu, back[:, 1] - vv)
    assert err.max() <= 0.75 and len(vv) == u.n_valid
    assert (u.lut[u.lut[..., 0] < 0] == -1).all()
    # a wider-angle K_new keeps every pixel in the image
    K_wide = davis.K.copy()
    K_wide[0, 0] *= 0.6
    K_wide[1, 1] *= 0.6
    assert EventUndistorter(davis, K_wide).n_valid == W * H


def test_pinhole_camera_undistorter_is_identity():
    cam = CameraModel(CameraModel.davis346().K, [], W, H)
    u = EventUndistorter(cam)
    assert u.identity and u.n_valid == W * H
    vv, uu = np.mgrid[0:H, 0:W]
    assert np.array_equal(u.lut[..., 0], uu) and np.array_equal(u.lut[..., 1], vv)
    ev = rand_events(1_000, seed=8)
    out = u.apply(ev)
    for f in "xytp":
        assert np.array_equal(getattr(out, f), getattr(ev, f))
    # zero coefficients given explicitly: computed through cv2, still the identity
    u0 = EventUndistorter(CameraModel(cam.K, [0, 0, 0, 0, 0], W, H))
    assert np.array_equal(u0.lut, u.lut)


def test_undistorter_cache_is_keyed_by_value(davis):
    clear_undistorter_cache()
    a = undistorter_for(davis)
    assert undistorter_for(CameraModel.davis346()) is a           # another object, same parameters
    K2 = davis.K * np.array([[0.9], [0.9], [1]])
    b = undistorter_for(davis, K2)
    assert b is not a and undistorter_for(davis, K2) is b
    assert undistorter_for(CameraModel(davis.K, [], W, H)) is not a
    ev = rand_events(2_000, seed=9)
    with pytest.raises(ValueError, match="^x: "):
        a.apply(EventArray([W], [0], [0], [0]))
    ref = a.apply(ev)
    rgb = R.to_rgb("polarity", ev, W, H, 0, 10_000, camera=davis)
    assert np.array_equal(rgb, polarity_rgb(*polarity_counts(ref, W, H)))


def test_undistorter_cache_is_bounded_in_bytes(monkeypatch):
    """The cache keeps the most recently used tables up to UNDISTORTER_CACHE_BYTES; a table larger than the
    bound is returned but not kept (nor does it push the others out)."""
    from evpose.core.label.event_frames import undistort

    def cam(f, w=40, h=30):
        return CameraModel(np.array([[f, 0, w / 2], [0, f, h / 2], [0, 0, 1]]), [0.1, 0, 0, 0, 0], w, h)

    clear_undistorter_cache()
    one = undistorter_for(cam(30.0)).nbytes
    assert one == 13 * 40 * 30                        # int32 (u, v) + ok + uint16 x, y per pixel
    monkeypatch.setattr(undistort, "UNDISTORTER_CACHE_BYTES", int(2.5 * one))
    clear_undistorter_cache()
    tables = [undistorter_for(cam(f)) for f in (30.0, 31.0, 32.0, 33.0)]
    assert undistort.undistorter_cache_nbytes() == 2 * one <= undistort.UNDISTORTER_CACHE_BYTES
    assert undistorter_for(cam(33.0)) is tables[3] and undistorter_for(cam(32.0)) is tables[2]
    assert undistorter_for(cam(30.0)) is not tables[0]          # the least recently used went first
    big = undistorter_for(cam(30.0, 80, 60))                      # 4 tables' worth: returned, not kept
    assert big.nbytes > undistort.UNDISTORTER_CACHE_BYTES and undistorter_for(cam(30.0, 80, 60)) is not big
    assert undistort.undistorter_cache_nbytes() == 2 * one
    clear_undistorter_cache()


# ------------------------------------------------------------------------------------------------ display
@pytest.mark.parametrize("background, empty", [("white", (255, 255, 255)), ("black", (0, 0, 0))])
def test_polarity_rgb_colours(background, empty):
    pos = np.zeros((4, 5), np.int64)
    neg = np.zeros((4, 5), np.int64)
    pos[1, 2] = 3
    neg[3, 0] = 3
    pos[0, 4] = neg[0, 4] = 3
    rgb = polarity_rgb(pos, neg, background=background)
    assert rgb.dtype == np.uint8 and rgb.shape == (4, 5, 3)
    assert tuple(rgb[1, 2]) == (255, 0, 0)           # ON red
    assert tuple(rgb[3, 0]) == (0, 0, 255)           # OFF blue
    assert tuple(rgb[0, 4]) == (255, 0, 255)         # both: magenta
    assert tuple(rgb[2, 2]) == empty
    pos[2, 4] = 1                                    # a third of the scale (the 99th percentile is 3)
    rgb = polarity_rgb(pos, neg, background=background)
    assert tuple(rgb[2, 4]) == ((85, 0, 0) if background == "black" else (255, 170, 170))


def test_hot_pixel_does_not_wash_out_the_frame():
    rng = np.random.default_rng(10)
    pos = np.zeros((H, W), np.int64)
    idx = rng.choice(H * W, 2_000, replace=False)
    pos.flat[idx] = rng.integers(1, 4, idx.size)       # ordinary pixels: 1..3 events
    pos[5, 5] = 10**6                                    # hot pixel
    rgb = polarity_rgb(pos, np.zeros_like(pos), background="black")
    ordinary = pos.flat[idx]
    red = rgb[..., 0].reshape(-1)[idx]
    assert rgb[5, 5, 0] == 255
    assert (red[ordinary == 3] == 255).all() and (red[ordinary == 1] >= 80).all()
    naive = np.rint(255 * pos / pos.max()).reshape(-1)[idx]       # plain max scaling: all black
    assert naive.max() == 0
    g = gray_rgb(pos, percentile=99)
    assert (g[..., 0].reshape(-1)[idx][ordinary == 3] == 255).all()


def test_gray_and_three_channel_rgb():
    b = np.zeros((3, 4), bool)
    b[1, 2] = True
    g = gray_rgb(b)
    assert g.dtype == np.uint8 and g.shape == (3, 4, 3)
    assert tuple(g[1, 2]) == (255, 255, 255) and g.sum() == 3 * 255
    gi = gray_rgb(b, invert=True)
    assert tuple(gi[1, 2]) == (0, 0, 0) and tuple(gi[0, 0]) == (255, 255, 255)
    f = np.array([[0.0, 0.5, 1.0, -1.0]])
    assert gray_rgb(f)[0, :, 0].tolist() == [0, 128, 255, 0]
    img3 = np.zeros((2, 2, 3), np.float32)
    img3[0, 0] = (1.0, 0.0, 0.5)
    rgb = three_channel_rgb(img3)
    assert rgb.dtype == np.uint8 and tuple(rgb[0, 0]) == (255, 0, 128) and rgb[1].max() == 0


def test_registry_renders_every_representation():
    assert {"polarity", "spike", "three_channel", "time_surface", "counts", "voxel"} <= set(R.REPRESENTATIONS)
    ev = rand_events(20_000, seed=11)
    for name in R.REPRESENTATIONS:
        for bg in ("white", "black"):
            rgb = R.to_rgb(name, ev, W, H, 0, 10_000, background=bg)
            assert rgb.dtype == np.uint8 and rgb.shape == (H, W, 3) and rgb.flags.c_contiguous
            assert len(np.unique(rgb.reshape(-1, 3), axis=0)) > 1, name
    on = EventArray([10], [20], [9_999], [1])
    assert tuple(R.to_rgb("polarity", on, W, H, 0, 10_000)[20, 10]) == (255, 0, 0)
    assert tuple(R.to_rgb("spike", on, W, H, 0, 10_000)[20, 10]) == (0, 0, 0)
    assert tuple(R.to_rgb("time_surface", on, W, H, 0, 10_000, polarity="split")[20, 10]) == (255, 0, 0)
    assert tuple(R.to_rgb("voxel", on, W, H, 0, 10_000, show="latest")[20, 10]) == (255, 0, 0)
    with pytest.raises(ValueError, match="unknown representation"):
        R.to_rgb("nope", ev, W, H, 0, 10_000)
    with pytest.raises(TypeError):
        R.to_rgb("spike", ev, W, H, 0, 10_000, bins=3)
    with pytest.raises(ValueError, match="background"):
        R.to_rgb("polarity", ev, W, H, 0, 10_000, background="grey")


def test_chunked_accumulation_equals_one_pass(monkeypatch):
    # Windows larger than accumulate.CHUNK_EVENTS are accumulated piecewise; a tiny chunk must give identical frames.
    t0, t1 = 0, 10_000
    ev = rand_events(5_003, seed=12, t0=t0, t1=t1, width=30, height=20)
    ref = {
        "counts": polarity_counts(ev, 30, 20), "spike": spike(ev, 30, 20),
        "3ch": three_channel(ev, 30, 20, t0, t1), "voxel": voxel_grid(ev, 30, 20, t0, t1, 5),
        "voxel1": voxel_grid(ev, 30, 20, t0, t1, 1), "ts": time_surface(ev, 30, 20, 8_000, 2_000),
    }
    monkeypatch.setattr(accumulate, "CHUNK_EVENTS", 97)
    got = {
        "counts": polarity_counts(ev, 30, 20), "spike": spike(ev, 30, 20),
        "3ch": three_channel(ev, 30, 20, t0, t1), "voxel": voxel_grid(ev, 30, 20, t0, t1, 5),
        "voxel1": voxel_grid(ev, 30, 20, t0, t1, 1), "ts": time_surface(ev, 30, 20, 8_000, 2_000),
    }
    assert np.array_equal(got["counts"][0], ref["counts"][0]) and np.array_equal(got["counts"][1], ref["counts"][1])
    for k in ("spike", "3ch", "ts"):
        assert np.array_equal(got[k], ref[k]), k
    for k in ("voxel", "voxel1"):
        assert np.allclose(got[k], ref[k], atol=1e-5), k
    assert np.allclose(got["voxel"], oracle_voxel(ev, t0, t1, 5, 30, 20), atol=1e-5)
