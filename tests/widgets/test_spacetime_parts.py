"""The space-time view's display-free parts (no OpenGL): camera framing, time-scale slider mapping,
point thinning and draw order, tube packing, cage ticks and the legend's rows."""
from types import SimpleNamespace

import numpy as np
import pytest

from evpose.widgets.spacetime.cage import nice_step
from evpose.widgets.spacetime.camera import (
    LOG_SCALE_MAX,
    LOG_SCALE_MIN,
    SLIDER_STEPS,
    clip_scale,
    frame_preset,
    scene_matrix,
    slider_position,
    slider_scale,
)
from evpose.widgets.spacetime.legend import legend_entries, legend_html
from evpose.widgets.spacetime.points import LOD_POINTS, draw_order, stride_for
from evpose.widgets.spacetime.tubes import tube_segments


def framed(name, W=200.0, H=100.0, D=400.0, aspect=1.0):
    cam = SimpleNamespace()
    frame_preset(cam, name, (W, H, D), aspect)
    return cam


def test_presets_frame_the_faces_they_look_at():
    """Front frames width x height, side depth x height, top width x depth; only oblique has perspective."""
    assert framed("front").scale_factor == pytest.approx(1.2 * 200)
    assert framed("side").scale_factor == pytest.approx(1.2 * 400)
    assert framed("top").scale_factor == pytest.approx(1.2 * 400)
    assert framed("side", D=50).scale_factor == pytest.approx(1.2 * 100)      # height is then the larger
    assert framed("top", D=50).scale_factor == pytest.approx(1.2 * 200)
    assert framed("front", D=5000).scale_factor == framed("front").scale_factor
    assert [framed(n).fov for n in ("front", "side", "top")] == [0.0, 0.0, 0.0]
    assert framed("oblique").fov > 0
    # a wide viewport frames the height: the scale factor spans the viewport's shorter side
    assert framed("front", W=100, H=100, aspect=2.0).scale_factor == pytest.approx(1.2 * 100)
    with pytest.raises(KeyError):
        framed("bottom")


def test_scene_matrix_maps_data_to_scene():
    M = scene_matrix(11, 21, 3.0)
    x, y, t = 10.0, 0.0, 2.0                                   # right edge, top row, 2 ms later
    X, Y, Z, w = np.array([x, y, t, 1.0]) @ M
    assert (X, Y, Z, w) == pytest.approx((5.0, 6.0, 10.0, 1.0))   # x - cx, s * t, cy - y


def test_slider_maps_decades_and_round_trips():
    assert slider_scale(0) == pytest.approx(10 ** LOG_SCALE_MIN)
    assert slider_scale(SLIDER_STEPS) == pytest.approx(10 ** LOG_SCALE_MAX)
    for v in (0, 37, 200, SLIDER_STEPS):
        assert slider_position(slider_scale(v)) == v
    assert clip_scale(1e9) == pytest.approx(10 ** LOG_SCALE_MAX) and clip_scale(0.0) == 10 ** LOG_SCALE_MIN


def test_stride_and_draw_order():
    assert stride_for(100, 100) == 1 and stride_for(101, 100) == 2
    assert stride_for(10, 0) == 10 and stride_for(10, -5) == 10          # a budget below 1 counts as 1
    n, s = 300_001, 2
    idx, first = draw_order(n, s)
    assert sorted(idx.tolist()) == list(range(0, n, s))            # every stride-th point, each once
    assert 0 < first <= LOD_POINTS
    head = idx[:first]
    assert head.min() < n // 100 and head.max() > n - n // 100      # the prefix spans the whole time range
    idx, first = draw_order(1000, 1)
    assert first == 1000 and np.array_equal(idx, np.arange(1000))


def test_tube_segments_close_polylines_and_skip_hidden():
    square = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], np.float32)
    tubes = [("a", (255, 0, 0), [square, square[:1]]), ("b", (0, 0, 255), [square + 5])]
    v, c, s = tube_segments(tubes, hidden=set())
    assert v.shape == (8, 3) and c.shape == (8, 4) and s.dtype == np.uint32
    assert s[:4].tolist() == [[0, 1], [1, 2], [2, 3], [3, 0]]      # closed; the 1-vertex polyline dropped
    assert s[4:].tolist() == [[4, 5], [5, 6], [6, 7], [7, 4]]
    assert c[0].tolist() == [1.0, 0.0, 0.0, 1.0] and c[4].tolist() == [0.0, 0.0, 1.0, 1.0]
    v, c, s = tube_segments(tubes, hidden={"a"})
    assert np.array_equal(v, square + 5) and s.tolist() == [[0, 1], [1, 2], [2, 3], [3, 0]]
    assert tube_segments(tubes, hidden={"a", "b"}) is None


def test_cage_tick_steps():
    xs = (0.0, 0.7, 1.0, 1.5, 2.2, 3.0, 7.0, 25.0, 26.0)
    assert [nice_step(x) for x in xs] == [1.0, 1.0, 1.0, 2.0, 2.5, 5.0, 10.0, 25.0, 50.0]


def test_legend_lists_polarities_window_and_shown_objects():
    tubes = [("box", (255, 0, 0), []), ("cyl", (0, 128, 0), [])]
    rows = legend_entries(tubes, hidden={"box"})
    assert [text for text, _ in rows] == ["ON events", "OFF events", "current window", "cyl"]
    html = legend_html(rows)
    assert "color:#008000'>\u2014 cyl<" in html and "box" not in html
    assert "color:#ff0000'>\u00b7 ON events<" in html


def test_legend_in_band_mode_names_the_band_and_the_dimmed_rest():
    tubes = [("box", (255, 0, 0), []), ("cyl", (0, 128, 0), [])]
    rows = legend_entries(tubes, hidden=set(), band_px=2.5)
    assert [text for text, _ in rows][:3] == ["events \u2264 2.5 px from a silhouette: its colour",
                                              "other events (dimmed)", "current window"]
    assert [text for text, _ in rows][3:] == ["box", "cyl"]


def test_band_split_of_points():
    from types import SimpleNamespace

    from evpose.widgets.spacetime.band import BandSplitter, band_mask, band_palette

    edge = np.array([0.5, 2.0, 3.5, np.inf, 1.0], np.float32)
    nearest = np.array([0, 1, 1, -1, 2], np.int8)
    assert band_mask(edge, nearest, 3.0, set()).tolist() == [True, True, False, False, True]
    assert band_mask(edge, nearest, 3.0, {1}).tolist() == [True, False, False, False, True]
    pts = np.arange(15, dtype=np.float32).reshape(5, 3)
    data = SimpleNamespace(points=pts, polarity=np.array([1, 0, 1, 0, 1], np.uint8), edge_px=edge, nearest=nearest)
    sp = BandSplitter().split(data, 3.0, True, set())
    assert sp.band_points.tolist() == pts[[0, 1, 4]].tolist() and sp.band_colors.tolist() == [0, 1, 2]
    assert sp.rest_points.tolist() == pts[[2, 3]].tolist() and sp.rest_colors.tolist() == [1, 0]
    splitter = BandSplitter()
    assert splitter.split(data, 3.0, True, set()) is splitter.split(data, 3.0, True, set())   # cached
    off = splitter.split(data, 3.0, False, set())
    assert off.rest_points is pts and len(off.band_points) == 0 and off.in_band is None
    pal = band_palette([(255, 0, 0), (0, 255, 0)])
    assert pal[1][:3] == (0.0, 1.0, 0.0) and len(pal) == 16
