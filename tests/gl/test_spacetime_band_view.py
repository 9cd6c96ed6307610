"""The space-time view's band and front view (issue 16, point 1): events within the band of a silhouette are drawn
in their object's colour, the others dimmed (or all by polarity when asked); the legend sits above the canvas,
the front view hides the t ticks and keeps the axis names inside the canvas."""
from __future__ import annotations

import numpy as np
import pytest
from test_spacetime_view import H_CANVAS, W_CANVAS, colour_mask, reddish, render

from evpose.core.views.spacetime import SpaceTimeData
from evpose.widgets.spacetime.style import BAND_ALPHA


@pytest.fixture
def view(qtbot, session):
    from evpose.widgets.spacetime.view import SpaceTimeView

    w = SpaceTimeView(session)
    qtbot.addWidget(w)
    w.resize(W_CANVAS, H_CANVAS + 120)
    w.show()
    qtbot.waitExposed(w)
    yield w
    w.close()


def banded(session, n=4_000, seed=0) -> SpaceTimeData:
    """ON events in two blocks: the left one within 1 px of object 1's silhouette, the right one 10 px from it."""
    cam = session.scene.camera
    rng = np.random.default_rng(seed)
    pts = np.empty((2 * n, 3), np.float32)
    pts[:, 0] = np.r_[rng.uniform(0, cam.width * 0.4, n), rng.uniform(cam.width * 0.6, cam.width - 1, n)]
    pts[:, 1] = rng.uniform(0, cam.height - 1, 2 * n)
    pts[:, 2] = rng.uniform(-45, 45, 2 * n)
    edge = np.r_[np.full(n, 1.0), np.full(n, 10.0)].astype(np.float32)
    nearest = np.full(2 * n, 1, np.int8)
    colors = tuple(session.color(name) for name in session.object_names)
    return SpaceTimeData(session.view.t_us, pts, np.ones(2 * n, np.uint8), 2 * n, [], 100_000, edge, nearest, colors)


def on_white(rgb, alpha):
    return tuple(int(round(alpha * c + (1 - alpha) * 255)) for c in rgb)


def test_band_events_in_their_objects_colour_and_the_rest_dimmed(qtbot, view, session):
    view.set_preset("front")
    data = banded(session)
    name = session.object_names[1]
    rgb = on_white(session.color(name), BAND_ALPHA)
    view.set_data(data)
    img = render(qtbot, view)
    assert view.split.by_object and view.split.in_band.sum() == len(data.points) // 2
    assert len(view.band_layer.markers._pos) and view.band_layer.shown + view.point_layer.shown == len(data.points)
    obj = colour_mask(img, rgb, tol=30)
    ys, xs = np.nonzero(obj)
    assert len(xs) > 1000, "events in the band are not drawn in their object's colour"
    assert np.percentile(xs, 95) < 0.5 * img.shape[1], "events outside the band drawn in the object's colour"
    right = img[:, int(0.62 * img.shape[1]):]
    assert reddish(right).sum() < 50, "events outside the band are not dimmed"
    assert (right[..., :3] < 250).any(axis=-1).sum() > 1000, "events outside the band not drawn at all"
    assert "within 3 px" in view.controls.band_label.text() and "50%" in view.controls.band_label.text()
    # a narrower band takes effect on the data at hand; so does hiding the object; by polarity again on request
    session.set_view_option(spacetime_band_px=0.5)
    assert view.split.in_band.sum() == 0
    session.set_view_option(spacetime_band_px=3.0)
    session.set_object_visible(name, False)
    assert view.split.in_band.sum() == 0
    session.set_object_visible(name, True)
    session.set_view_option(spacetime_by_object=False)
    img = render(qtbot, view)
    assert not view.split.by_object and view.band_layer.shown == 0
    assert reddish(img[:, int(0.62 * img.shape[1]):]).sum() > 1000, "by polarity: ON events are red"
    assert view.by_object_check.isChecked() is False


def test_front_view_legend_ticks_and_axis_names(qtbot, view, session):
    view.set_data(banded(session))
    canvas = view.canvas.native
    legend = view.legend.label
    assert not canvas.isAncestorOf(legend)
    lg = legend.geometry()
    cg = canvas.geometry()
    assert not lg.intersects(cg), (lg, cg)          # the legend never covers the points
    view.set_preset("front")
    render(qtbot, view)
    assert not view.cage.tick_text.visible, "t ticks would all land on one spot in the front view"
    assert "t (ms)" not in list(view.cage.axis_text.text)
    w, h = view.canvas.size
    tr = view.cage.axis_text.get_transform("visual", "canvas")
    for text, pos in zip(view.cage.axis_text.text, view.cage.axis_text.pos):
        x, y = tr.map(np.r_[pos, 1.0])[:2]
        assert 8 <= x <= w - 8 and 8 <= y <= h - 8, (text, x, y, w, h)
    view.set_preset("side")
    assert view.cage.tick_text.visible and "x" not in list(view.cage.axis_text.text)
