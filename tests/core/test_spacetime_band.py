"""The space-time view's band (issue 16, point 1): each event's distance to the nearest projected silhouette at its
own time and that object, and the tubes' surfaces."""
from __future__ import annotations

import numpy as np
import pytest
from kymograph_scene import TRUE_OFFSET_US, kymograph_scene, moving_time_us

from evpose.core.views.spacetime import SpaceTimeComputer
from evpose.core.views.spacetime_band import (
    FIELD_CLIP_PX,
    event_edge_distance,
    merged_field,
    signed_field,
    stacked_fields,
)
from evpose.core.views.spacetime_surface import RING_POINTS, resample_ring, tube_surface


def half_plane(width=60, height=20, edge=20):
    mask = np.zeros((height, width), bool)
    mask[:, :edge] = True
    return mask


def test_signed_field_is_half_a_pixel_either_side_of_the_edge_and_clipped():
    f = signed_field(half_plane())
    sd = f.sd.astype(float) / 4.0
    row = sd[10 - f.y0]
    u = np.arange(f.x0, f.x0 + f.sd.shape[1])
    assert row[u == 19][0] == -0.5 and row[u == 20][0] == 0.5     # inside / outside neighbours of the edge
    assert row[u == 25][0] == pytest.approx(5.5, abs=0.1) and row[u == 10][0] == pytest.approx(-9.5, abs=0.1)
    assert np.abs(sd).max() <= FIELD_CLIP_PX
    assert signed_field(np.zeros((5, 5), bool)) is None


def test_events_on_a_moving_edge_between_slices_are_on_it():
    """The edge moves from u = 19.5 to 29.5 px between two slices 10 ms apart: an event on the edge at any time
    between them is within half a pixel of it (the signed distances interpolate; unsigned ones would not)."""
    H, W = 20, 60
    fields = []
    for edge in (20, 30):
        sd, obj = merged_field([(2, signed_field(half_plane(W, H, edge)))], H, W)
        fields.append((sd, obj))
    stacked = stacked_fields(fields)
    t = np.array([1_000, 3_000, 5_000, 8_000], np.int64)
    u_edge = 19.5 + 10.0 * t / 10_000                   # where the edge is at each time
    x = np.rint(u_edge).astype(np.uint16)              # the pixel the edge crosses
    y = np.full(len(t), 10, np.uint16)
    d, k = event_edge_distance(x, y, t, np.array([0, 10_000], np.int64), stacked)
    assert np.all(d <= 0.6), d
    assert k.tolist() == [2, 2, 2, 2]
    d2, k2 = event_edge_distance(np.array([34, 55], np.uint16), np.array([10, 10], np.uint16), np.array([0, 0]),
                                 np.array([0, 10_000], np.int64), stacked)
    assert d2[0] == pytest.approx(14.5, abs=0.3) and k2[0] == 2
    assert np.isinf(d2[1]) and k2[1] == -1                           # beyond the fields' reach: nobody's
    none = np.zeros_like(stacked)
    none[..., 0], none[..., 1] = 127, -1
    d_none, k_none = event_edge_distance(x, y, t, np.array([0, 10_000], np.int64), none)
    assert np.all(np.isinf(d_none)) and np.all(k_none == -1)


def test_more_events_in_the_band_at_the_true_clock(tmp_path_factory):
    from evpose.core.session.model import Session

    path = kymograph_scene(tmp_path_factory)
    s = Session.open(path)
    try:
        s.set_time(moving_time_us(path, *s.time_range))
        s.set_view_option(spacetime_slices=8)
        fc = SpaceTimeComputer()
        share = {}
        for error_us in (0, -20_000):
            s.set_offset_correction_us(TRUE_OFFSET_US + error_us)
            d = fc.spacetime(s.request())
            assert d.edge_px.shape == d.nearest.shape == (len(d.points),)
            assert set(np.unique(d.nearest)) <= {-1, 0, 1, 2}
            assert len(d.object_colors) == 3 and d.surfaces
            share[error_us] = float((d.edge_px <= 3.0).mean())
        assert share[0] > 1.2 * share[-20_000], share
        s.set_object_visible(s.object_names[0], False)     # a hidden object's events are nobody's
        d = fc.spacetime(s.request())
        assert 0 not in set(np.unique(d.nearest)) and s.object_names[0] not in [n for n, *_ in d.surfaces]
    finally:
        s.close()


def test_surface_joins_consecutive_silhouettes():
    square = np.array([[0, 0], [10, 0], [10, 10], [0, 10], [0, 0]], float)
    ring = resample_ring(square)
    assert ring.shape == (RING_POINTS, 2)
    assert resample_ring(square[::-1]) is not None                  # either winding
    v, f = tube_surface([(-5.0, [square]), (0.0, [square + 2]), (5.0, [])])
    assert v.shape == (2 * RING_POINTS, 3) and f.shape == (2 * RING_POINTS, 3)
    assert set(np.unique(v[:, 2])) == {-5.0, 0.0}
    a, b = v[:RING_POINTS, :2], v[RING_POINTS:, :2]
    assert np.allclose(b - a, 2.0)                                   # the second ring starts where the first does
    v, f = tube_surface([(-5.0, [square]), (0.0, [square + 200])])   # too far apart: not the same silhouette
    assert len(f) == 0
