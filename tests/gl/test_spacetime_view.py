"""SpaceTimeView (vispy) under Xvfb: assertions on rendered pixels.

Colour tests compare against a render of the same widget without the thing under test, so the
legend (which names ON / OFF and the objects in their colours) never decides a test by itself.
"""
from __future__ import annotations

import time

import numpy as np
import pytest

from evpose.core.views.spacetime import SpaceTimeComputer, SpaceTimeData

W_CANVAS, H_CANVAS = 640, 480


@pytest.fixture
def view(qtbot, session):
    from evpose.widgets.spacetime.view import SpaceTimeView

    w = SpaceTimeView(session)
    qtbot.addWidget(w)
    w.resize(W_CANVAS, H_CANVAS + 70)
    w.show()
    qtbot.waitExposed(w)
    yield w
    w.close()


def sheet(session, pol: int, n: int = 20_000, *, seed: int = 0, x_max: float | None = None,
          y_max: float | None = None, span_ms: float = 100.0) -> SpaceTimeData:
    """Uniform random events over the sensor (or its top-left part) and the span, all of one polarity."""
    cam = session.scene.camera
    rng = np.random.default_rng(seed)
    pts = np.empty((n, 3), np.float32)
    pts[:, 0] = rng.uniform(0, x_max if x_max is not None else cam.width - 1, n)
    pts[:, 1] = rng.uniform(0, y_max if y_max is not None else cam.height - 1, n)
    pts[:, 2] = rng.uniform(-0.45 * span_ms, 0.45 * span_ms, n)
    return SpaceTimeData(session.view.t_us, pts, np.full(n, pol, np.uint8), n, [], int(span_ms * 1000))


def empty(session, span_ms: float = 100.0) -> SpaceTimeData:
    return SpaceTimeData(session.view.t_us, np.zeros((0, 3), np.float32), np.zeros(0, np.uint8), 0, [],
                         int(span_ms * 1000))


def reddish(img):
    rgb = img[..., :3].astype(np.int16)
    return (rgb[..., 0] - np.maximum(rgb[..., 1], rgb[..., 2])) > 80


def bluish(img):
    rgb = img[..., :3].astype(np.int16)
    return (rgb[..., 2] - np.maximum(rgb[..., 0], rgb[..., 1])) > 80


def colour_mask(img, rgb, tol=25):
    return np.all(np.abs(img[..., :3].astype(np.int16) - np.asarray(rgb, np.int16)) <= tol, axis=-1)


def render(qtbot, view):
    qtbot.wait(10)
    img = view.render_image()
    assert img.dtype == np.uint8 and img.ndim == 3 and img.shape[2] == 4
    return img


def test_on_red_off_blue(qtbot, view, session):
    assert view.markers.lean, "the 16-byte-per-point upload should be in use with this vispy"
    view.set_data(empty(session))
    base = render(qtbot, view)
    view.set_data(sheet(session, 1))
    on = render(qtbot, view)
    view.set_data(sheet(session, 0))
    off = render(qtbot, view)
    n_red0, n_blue0 = reddish(base).sum(), bluish(base).sum()
    assert reddish(on).sum() > n_red0 + 5000, "ON events are not drawn red"
    assert bluish(on).sum() <= n_blue0 + 20, "ON-only data rendered blue pixels"
    assert bluish(off).sum() > n_blue0 + 5000, "OFF events are not drawn blue"
    assert reddish(off).sum() <= n_red0 + 20, "OFF-only data rendered red pixels"
    assert "20,000 of 20,000 events shown" in view.info_label.text()


def test_front_view_keeps_image_orientation(qtbot, view, session):
    """Events in the sensor's top-left quarter appear in the top-left of the front view (rows down)."""
    cam = session.scene.camera
    view.set_preset("front")
    view.set_data(empty(session))
    base = reddish(render(qtbot, view))
    view.set_data(sheet(session, 1, x_max=cam.width / 4, y_max=cam.height / 4))
    red = reddish(render(qtbot, view)) & ~base
    ys, xs = np.nonzero(red)
    assert len(xs) > 500
    assert np.median(xs) < W_CANVAS / 2 and np.median(ys) < H_CANVAS / 2


def test_time_scale_rescales_depth_without_set_data(qtbot, view, session, monkeypatch):
    view.set_data(sheet(session, 1))
    view.set_preset("side")                     # orthographic, t to the right
    img1 = render(qtbot, view)
    uploads = dict(view.upload_counts)

    def no_set_data(*a, **k):
        raise AssertionError("the time scale must not rebuild data")

    monkeypatch.setattr(view, "set_data", no_set_data)
    s1 = view.time_scale
    view.scale_slider.setValue(view.scale_slider.value() - 30)      # x 10**-0.3 ~ 0.5
    assert view.time_scale == pytest.approx(s1 * 10 ** -0.3, rel=0.02)
    img2 = render(qtbot, view)
    assert view.upload_counts == uploads, "rescaling time re-uploaded buffers"

    def t_extent(img):
        cols = np.nonzero(reddish(img)[60:].sum(axis=0) > 3)[0]     # skip the legend rows
        return cols.max() - cols.min()

    e1, e2 = t_extent(img1), t_extent(img2)
    assert not np.array_equal(img1, img2)
    assert 0.35 < e2 / e1 < 0.65, (e1, e2)


def test_tube_colours_and_hidden_objects(qtbot, view, session):
    session.set_view_option(spacetime_slices=6)          # real data, fewer silhouettes: a faster test
    fc = SpaceTimeComputer()
    data = fc.spacetime(session.request())
    assert len(data.points) > 0 and data.tubes, "fixture scene should have events and objects in view"
    names = [name for name, _, _ in data.tubes]
    no_tubes = SpaceTimeData(data.t_center_us, data.points, data.polarity, data.n_total, [], data.span_us)
    view.set_data(no_tubes)
    base = render(qtbot, view)
    view.set_data(data)
    img = render(qtbot, view)
    for name, rgb, _ in data.tubes:
        assert rgb == session.color(name)
        n0, n1 = colour_mask(base, rgb).sum(), colour_mask(img, rgb).sum()
        assert n1 > n0 + 150, f"tube of {name} {rgb} not visible ({n0} -> {n1} pixels)"

    hidden = names[0]
    rgb_h = session.color(hidden)
    session.set_object_visible(hidden, False)
    data2 = fc.spacetime(session.request())
    assert hidden not in [name for name, _, _ in data2.tubes]
    view.set_data(data2)
    img2 = render(qtbot, view)
    assert colour_mask(img2, rgb_h).sum() <= colour_mask(base, rgb_h).sum() + 20, "hidden object still drawn"
    for name in names[1:]:
        rgb = session.color(name)
        assert colour_mask(img2, rgb).sum() > colour_mask(base, rgb).sum() + 150

    # data computed before the object was hidden (a stale worker result): the view drops the tube itself
    view.set_data(data)
    assert colour_mask(render(qtbot, view), rgb_h).sum() <= colour_mask(base, rgb_h).sum() + 20


def test_spin_boxes_write_and_follow_view_state(qtbot, view, session):
    view.budget_spin.setValue(123_000)
    assert session.view.spacetime_budget == 123_000
    view.span_spin.setValue(250)
    assert session.view.spacetime_span_us == 250_000
    session.set_view_option(spacetime_budget=77_000, spacetime_span_us=40_000, spacetime_slices=4)
    assert view.budget_spin.value() == 77_000 and view.span_spin.value() == 40
    data = SpaceTimeComputer().spacetime(session.request())
    assert data.span_us == 40_000 and len(data.points) <= 77_000
    view.set_data(data)
    cam = session.scene.camera                       # untouched time scale follows the span
    assert view.time_scale == pytest.approx(max(cam.width, cam.height) / 40.0)
    render(qtbot, view)


def test_two_million_points_are_thinned_and_counted(qtbot, view, session):
    n = 2_000_000
    rng = np.random.default_rng(1)
    pts = np.column_stack([rng.uniform(0, 172, n), rng.uniform(0, 129, n), rng.uniform(-50, 50, n)])
    data = SpaceTimeData(session.view.t_us, pts.astype(np.float32), (rng.random(n) < 0.5).astype(np.uint8),
                         n, [], 100_000)
    t0 = time.perf_counter()
    view.set_data(data)
    img = render(qtbot, view)
    dt = time.perf_counter() - t0
    budget = session.view.spacetime_budget
    assert 0 < view.shown_count <= budget
    assert f"{view.shown_count:,} of 2,000,000 events shown" in view.info_label.text()
    assert reddish(img).sum() > 1000 and bluish(img).sum() > 1000
    assert dt < 10.0
    view.budget_spin.setValue(100_000)          # a lower budget re-thins the data at hand at once
    assert session.view.spacetime_budget == 100_000
    assert 0 < view.shown_count <= 100_000
    assert f"{view.shown_count:,} of 2,000,000 events shown" in view.info_label.text()
    render(qtbot, view)


def test_only_changed_buffers_are_uploaded(qtbot, view, session):
    d1 = sheet(session, 1, seed=1)
    view.set_data(d1)
    c1 = dict(view.upload_counts)
    view.set_data(d1)                                   # same arrays: nothing new
    assert view.upload_counts == c1
    d2 = sheet(session, 1, seed=2)                      # new positions, same polarity
    view.set_data(d2)
    assert view.upload_counts["points"] == c1["points"] + 1
    assert view.upload_counts["polarity"] == c1["polarity"]
    assert view.upload_counts["cage"] == c1["cage"] and view.upload_counts["slab"] == c1["slab"]
    session.set_window_us(20_000)                       # the slab follows the window length
    assert view.upload_counts["slab"] == c1["slab"] + 1
    render(qtbot, view)


def test_presets_and_reset_render(qtbot, view, session):
    view.set_data(sheet(session, 1, x_max=100))
    images = {}
    for name in ("front", "side", "top"):
        getattr(view, f"{name}_button").click()
        images[name] = render(qtbot, view)
    view.reset_button.click()
    images["reset"] = render(qtbot, view)
    keys = list(images)
    for i, a in enumerate(keys):
        for b in keys[i + 1:]:
            assert not np.array_equal(images[a], images[b]), (a, b)


def test_close_unsubscribes(qtbot, session):
    from evpose.widgets.spacetime.view import SpaceTimeView

    n0 = len(session.changed)
    w = SpaceTimeView(session)
    qtbot.addWidget(w)
    w.show()
    qtbot.waitExposed(w)
    assert len(session.changed) == n0 + 1
    w.close()
    assert len(session.changed) == n0
    session.set_view_option(spacetime_budget=50_000)     # no callback into the closed view


def test_lean_points_draw_the_same_pixels_as_stock_markers(qtbot, session, monkeypatch):
    """The lean point visual (own shaders, 16 B a point) renders exactly what vispy's ``Markers`` renders for
    the same data (2 px discs, no edge, no antialiasing), in the perspective and an orthographic preset,
    with and without silhouette tubes."""
    from evpose.widgets.spacetime.view import SpaceTimeView

    data = SpaceTimeComputer().spacetime(session.request())
    assert data.tubes and len(data.points) > 1000
    mixed = sheet(session, 1, n=30_000, seed=5)
    mixed.polarity[::2] = 0
    images = {}
    monkeypatch.setattr(SpaceTimeView, "step_coarse_s", 0.0)     # every set_data drawn in full (no stepping)
    for lean in (True, False):
        monkeypatch.setattr(SpaceTimeView, "lean_upload", lean)
        w = SpaceTimeView(session)
        qtbot.addWidget(w)
        w.resize(W_CANVAS, H_CANVAS + 70)
        w.show()
        qtbot.waitExposed(w)
        assert w.markers.lean == lean
        for d in (data, mixed):
            for preset in ("oblique", "side"):
                w.set_data(d)
                w.set_preset(preset)
                images[lean, id(d), preset] = render(qtbot, w)
        w.close()
    for d in (data, mixed):
        for preset in ("oblique", "side"):
            a, b = images[True, id(d), preset], images[False, id(d), preset]
            assert (reddish(a).sum() + bluish(a).sum()) > 2000
            assert np.array_equal(a, b), (preset, int((a != b).any(axis=-1).sum()))


def test_coarse_subset_while_the_camera_moves(qtbot, view, session):
    """Mouse press on the canvas draws a time-uniform prefix of the points; release draws all again."""
    from PySide6 import QtCore

    from evpose.widgets.spacetime.points import LOD_POINTS, draw_order

    d = sheet(session, 1, n=200_000, seed=3)
    view.set_data(d)
    full = render(qtbot, view)
    centre = view.canvas.native.rect().center()
    qtbot.mousePress(view.canvas.native, QtCore.Qt.LeftButton, pos=centre)
    assert view._interacting
    assert 0 < view.markers._index_buffer.size <= LOD_POINTS
    coarse = render(qtbot, view)
    qtbot.mouseRelease(view.canvas.native, QtCore.Qt.LeftButton, pos=centre)
    assert not view._interacting and view.markers._index_buffer is None
    again = render(qtbot, view)
    assert reddish(coarse).sum() < reddish(full).sum()
    assert np.array_equal(full, again)
    # the coarse prefix is uniform in time: it covers the whole span, not just its start
    idx, n_lod = draw_order(len(d.points), view.point_layer.stride)
    t_lod = d.points[idx[:n_lod], 2]
    assert n_lod <= LOD_POINTS and t_lod.min() < -40 and t_lod.max() > 40


def test_steps_in_quick_succession_draw_the_coarse_subset_then_all(qtbot, view, session):
    """Data arriving while the user steps (within ``step_coarse_s`` of the last) is drawn with the coarse,
    time-uniform subset; all points follow ``LOD_IDLE_MS`` after the last step. A step after a pause is drawn in
    full at once."""
    from evpose.widgets.spacetime.points import LOD_POINTS
    from evpose.widgets.spacetime.view import LOD_IDLE_MS

    a, b = sheet(session, 1, n=200_000, seed=3), sheet(session, 1, n=200_000, seed=4)
    view.step_coarse_s = 60.0                   # any two set_data calls of the test count as stepping
    view.set_data(a)
    assert not view._interacting and view.markers._index_buffer is None       # the first: in full
    view.set_data(b)
    assert view._interacting and 0 < view.markers._index_buffer.size <= LOD_POINTS
    coarse = render(qtbot, view)
    qtbot.waitUntil(lambda: not view._interacting, timeout=LOD_IDLE_MS * 20)
    assert view.markers._index_buffer is None
    assert reddish(coarse).sum() < reddish(render(qtbot, view)).sum()
    view.step_coarse_s = 0.0                    # a pause longer than the threshold: drawn in full at once
    view.set_data(a)
    assert not view._interacting and view.markers._index_buffer is None


def test_deleted_with_its_parent_ignores_late_data(qtbot, session):
    """Inside a dock deleted by the app: the session forgets the view and a late worker result is ignored."""
    from PySide6 import QtWidgets

    from evpose.widgets.spacetime.view import SpaceTimeView

    n0 = len(session.changed)
    parent = QtWidgets.QWidget()
    lay = QtWidgets.QVBoxLayout(parent)
    w = SpaceTimeView(session)
    lay.addWidget(w)
    parent.show()
    qtbot.waitExposed(parent)
    w.set_data(sheet(session, 1, n=1000))
    parent.deleteLater()
    qtbot.waitUntil(lambda: len(session.changed) == n0, timeout=5000)
    w.set_data(sheet(session, 0, n=1000))          # no exception
    session.set_view_option(spacetime_budget=60_000)
