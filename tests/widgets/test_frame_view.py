import numpy as np
import pytest
from PySide6 import QtCore

from evpose.core.session.frames import FrameComputer
from evpose.widgets.frame_view import FrameView


@pytest.fixture
def view(qtbot, session):
    w = FrameView(session)
    qtbot.addWidget(w)
    w.resize(700, 560)
    w.show()
    return w


def test_frame_and_overlays_are_displayed(view, session):
    data = FrameComputer().frame(session.request())
    view.set_frame(data)
    assert view.image_item.image.shape == (session.scene.camera.height, session.scene.camera.width, 3)
    assert data.labels.valid
    for name in session.object_names:
        x, y = view._items[name]["contour"].getData()
        assert len(x) > 10, name  # every object is in view mid-motion
        bx, _ = view._items[name]["box"].getData()
        assert len(bx) > 0
    # contours sit on the mask boundary (pixel coordinates = scene coordinates)
    lab = data.labels
    k = 0
    x, y = view._items[session.object_names[k]]["contour"].getData()
    ok = np.isfinite(x)
    np.testing.assert_array_equal(x[ok], np.round(x[ok]))      # pixel centres, not half a pixel off
    np.testing.assert_array_equal(y[ok], np.round(y[ok]))
    assert np.all(lab.label_map[y[ok].astype(int), x[ok].astype(int)] == k)


def test_hidden_object_and_overlay_toggles(view, session):
    session.set_object_visible("box", False)
    session.set_overlay("box", False)
    data = FrameComputer().frame(session.request())
    view.set_frame(data)
    assert len(view._items["box"]["contour"].getData()[0]) == 0
    assert len(view._items["cylinder"]["box"].getData()[0]) == 0
    assert len(view._items["cylinder"]["contour"].getData()[0]) > 0
    # the mask image leaves hidden objects transparent
    box_px = data.labels.label_map == 0
    assert data.mask_rgba[box_px][:, 3].max() == 0


def test_hover_readout_reports_object_events_and_depth(view, session, qtbot):
    data = FrameComputer().frame(session.request())
    view.set_frame(data)
    vs, us = np.nonzero(data.labels.label_map == 1)
    u, v = int(us[len(us) // 2]), int(vs[len(vs) // 2])
    info = view.hover_info(u, v)
    assert info["object"] == session.object_names[1]
    assert 0.2 < info["depth_m"] < 1.0
    assert info["events"] == int(data.counts[v, u])
    assert view.hover_info(-1, 0) is None
    # real mouse move over that pixel updates the readout
    scene_pt = view.vb.mapViewToScene(QtCore.QPointF(u, v))
    widget_pt = view.glw.mapFromScene(scene_pt)
    with qtbot.waitSignal(view.hoverText, timeout=2000) as sig:
        qtbot.mouseMove(view.glw.viewport(), widget_pt)
    assert session.object_names[1] in sig.args[0]


def test_unlabeled_window_shows_reason(view, session):
    session.set_offset_correction_us(10_000_000)
    view.set_frame(FrameComputer().frame(session.request()))
    assert "outside the trajectory" in view.message.toPlainText()


def _lit_block_centre(img: np.ndarray, rgb) -> np.ndarray:
    """Centre (x, y) in widget pixels of the screen pixels of colour ``rgb`` (a lit sensor pixel)."""
    ys, xs = np.nonzero(np.all(np.abs(img[..., :3].astype(int) - rgb) <= 8, axis=-1))
    assert len(xs) > 100, "the lit pixel is not on screen"
    return np.array([(xs.min() + xs.max() + 1) / 2, (ys.min() + ys.max() + 1) / 2])


def test_event_pixel_and_overlay_point_land_on_the_same_spot(view, session, qtbot):
    """An event at pixel (u, v) (in the event image and in the mask image) is drawn centred where
    an overlay point at (u, v) is drawn: the screen shows both at the same place, zoomed so that
    a sensor pixel is tens of screen pixels wide (half a pixel off is a large miss)."""
    from dataclasses import replace

    from PySide6 import QtGui

    data = FrameComputer().frame(session.request())
    H, W = data.image_rgb.shape[:2]
    u, v = 61, 47                                    # the event pixel
    um, vm = 64, 45                                  # a masked pixel (mask image)
    image = np.zeros((H, W, 3), np.uint8)
    image[v, u] = (255, 255, 255)
    mask = np.zeros((H, W, 4), np.uint8)
    mask[vm, um] = (255, 0, 0, 255)
    view.set_frame(replace(data, image_rgb=image, mask_rgba=mask, overlays=[]))   # nothing drawn over them
    view.vb.setRange(QtCore.QRectF(u - 5, v - 5, 10, 10), padding=0)
    qtbot.wait(50)
    grab = view.glw.grab().toImage().convertToFormat(QtGui.QImage.Format_RGBA8888)
    shot = np.frombuffer(grab.constBits(), np.uint8).reshape(grab.height(), grab.bytesPerLine() // 4, 4)
    shot = shot[:, :grab.width()]
    scale = grab.width() / view.glw.width()          # device pixels per widget pixel

    def on_screen(item, x, y):
        """Where ``item`` draws its own point (x, y): widget pixels of the grab."""
        p = view.glw.mapFromScene(item.mapToScene(QtCore.QPointF(x, y)))
        return np.array([p.x(), p.y()]) * scale

    px_size = (on_screen(view.axis_items[0], u + 1, v) - on_screen(view.axis_items[0], u, v))[0]
    assert px_size > 20
    # overlay items (contours, boxes, axes, centres) share the view's coordinates = OpenCV pixels
    for item in (view.axis_items[0], view.center_item, view._items["box"]["contour"]):
        np.testing.assert_allclose(on_screen(item, u, v), on_screen(view.axis_items[0], u, v), atol=1e-6)
    np.testing.assert_allclose(_lit_block_centre(shot, (255, 255, 255)), on_screen(view.center_item, u, v),
                               atol=0.1 * px_size)
    np.testing.assert_allclose(_lit_block_centre(shot, (255, 0, 0)), on_screen(view.center_item, um, vm),
                               atol=0.1 * px_size)
