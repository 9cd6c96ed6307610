import numpy as np
import pytest
from PySide6 import QtCore, QtWidgets

from evpose.core.views.frame import FrameComputer
from evpose.widgets.frame.view import FrameView


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


# ---------------------------------------------------------------------- issue 16: the frame view's display
def _grab(view) -> np.ndarray:
    """The graphics view as an (H, W, 4) RGBA array of device pixels."""
    from PySide6 import QtGui

    img = view.glw.grab().toImage().convertToFormat(QtGui.QImage.Format_RGBA8888)
    arr = np.frombuffer(img.constBits(), np.uint8).reshape(img.height(), img.bytesPerLine() // 4, 4)
    return arr[:, :img.width()], img.width() / view.glw.width()


def _screen_px(view, scale, x, y) -> tuple[int, int]:
    p = view.glw.mapFromScene(view.vb.mapViewToScene(QtCore.QPointF(x, y)))
    return int(round(p.x() * scale)), int(round(p.y() * scale))


def test_sensor_border_is_drawn_and_overlays_outside_it_are_faded(view, session, qtbot):
    from dataclasses import replace

    from evpose.core.label.overlay import ObjectOverlay

    cam = session.scene.camera
    assert view.sensor_border.rect() == QtCore.QRectF(-0.5, -0.5, cam.width, cam.height)
    data = FrameComputer().frame(session.request())
    H, W = data.image_rgb.shape[:2]
    # one object's box: a horizontal line from 30 px left of the sensor to 30 px inside, on a blank image
    ov = ObjectOverlay("box", session.color("box"), box_segments=np.array([[[-30.0, 40.0], [30.0, 40.0]]]))
    view.set_frame(replace(data, image_rgb=np.full((H, W, 3), 255, np.uint8), mask_rgba=None, overlays=[ov]))
    view.vb.setRange(QtCore.QRectF(-40, 20, 80, 40), padding=0)
    qtbot.wait(50)
    shot, scale = _grab(view)
    inside = shot[_screen_px(view, scale, 15, 40)[::-1]][:3].astype(int)
    outside = shot[_screen_px(view, scale, -15, 40)[::-1]][:3].astype(int)
    colour = np.array(session.color("box"))
    assert np.abs(inside - colour).max() < 40                     # drawn as is on the sensor
    assert np.abs(outside - 255).max() < 60                      # faded towards white off the sensor
    assert np.abs(outside - colour).max() > 80
    x, y = _screen_px(view, scale, -0.5, 30)
    assert shot[y, x - 2:x + 3, :3].astype(int).sum(axis=1).min() < 3 * 160   # a dark line at the sensor's edge


def test_representation_indicator_and_legend_follow_the_session(view, session):
    from evpose.widgets.frame.legend import legend_text

    bar = view.toolbar
    assert bar.rep_combo.currentData() == "polarity"
    assert "ON" in bar.legend.text() and "OFF" in bar.legend.text()
    session.set_representation("counts")
    assert bar.rep_combo.currentData() == "counts" and "many events" in bar.legend.text()
    assert bar.rep_combo.toolTip().startswith(legend_text("counts"))
    bar.rep_combo.setCurrentIndex(bar.rep_combo.findData("time_surface"))    # the user picks one
    assert session.view.representation == "time_surface" and "recent" in bar.legend.text()
    bar.set_key_hints({"polarity": "1", "time_surface": "4"})
    assert bar.rep_combo.itemText(bar.rep_combo.findData("time_surface")).endswith("(4)")
    assert "keys 1 / 4 switch" in bar.rep_combo.toolTip()


def test_window_length_control_changes_the_computed_window(view, session):
    bar = view.toolbar
    assert bar.win_spin.value() == 10.0 and bar.unit == "ms"
    bar.win_spin.setValue(25.0)
    assert session.view.window_us == 25_000
    w = FrameComputer().frame(session.request()).window
    assert w.t1_us - w.t0_us == 25_000 and w.t0_us <= session.view.t_us < w.t1_us
    bar.win_unit.setCurrentIndex(1)                               # events: about the same window
    n = session.view.window_events
    data = FrameComputer().frame(session.request())
    store = session.scene.events

    def n_read(w):
        """Events the frame reads: [t0, t1) by time, so also those sharing the last event's µs time stamp."""
        i0, i1 = store.index_range(w.t0_us, w.t1_us)
        return i1 - i0

    assert n > 0 and data.window.n_events == n and bar.win_spin.value() == n
    assert data.n_events == n_read(data.window) and 0 <= data.n_events - n <= 5
    bar.win_spin.setValue(2000)
    data = FrameComputer().frame(session.request())
    assert session.view.window_events == 2000 and data.window.n_events == 2000
    assert data.n_events == n_read(data.window) and 0 <= data.n_events - 2000 <= 5
    bar.scale_window(2.0)                                         # the window shortcuts: same unit
    assert session.view.window_events == 4000
    bar.win_unit.setCurrentIndex(0)
    assert session.view.window_events == 0 and bar.win_spin.value() == pytest.approx(
        (data.window.t1_us - data.window.t0_us) * 2 / 1000, abs=0.6)


def test_contrast_and_event_opacity_change_the_event_image(view, session):
    from evpose.core.label.overlay import adjust_contrast

    session.set_representation("counts")
    data = FrameComputer().frame(session.request())
    view.set_frame(data)
    np.testing.assert_array_equal(view.image_item.image, data.image_rgb)
    view.toolbar.contrast_spin.setValue(3.0)
    shown = view.image_item.image
    np.testing.assert_array_equal(shown, adjust_contrast(data.image_rgb, 3.0))
    faint = (data.image_rgb[..., 0] > 128) & (data.image_rgb[..., 0] < 250)
    assert faint.sum() > 20 and np.all(shown[..., 0][faint] < data.image_rgb[..., 0][faint])   # faint ink darker
    view.toolbar.event_slider.setValue(40)
    assert session.view.event_opacity == 0.4 and view.image_item.opacity() == pytest.approx(0.4)
    assert "events at 40%" in view.toolbar.display_button.toolTip()


def _drawn_points(view, name, kind="contour") -> int:
    return int(np.isfinite(view._items[name][kind].getData()[0]).sum()) if view._items[name][kind].getData()[0] \
        is not None else 0


def test_mask_opacity_selected_only_and_outline_only_change_the_overlays(view, session):
    data = FrameComputer().frame(session.request())
    view.set_frame(data)
    lm = data.labels.label_map
    alpha = view.mask_item.image[..., 3]
    assert alpha[lm == 0].max() == round(255 * 0.35) and alpha[lm == 1].max() > 0
    view.toolbar.mask_slider.setValue(80)                           # at once, from the labels on screen
    assert view.mask_item.image[..., 3][lm == 0].max() == round(255 * 0.8)
    session.select("box")
    view.toolbar.selected_only_action.setChecked(True)
    assert session.view.selected_only
    assert view.mask_item.image[..., 3][lm == 1].max() == 0 and view.mask_item.image[..., 3][lm == 0].max() > 0
    assert _drawn_points(view, "box") > 10 and _drawn_points(view, "cylinder") == 0
    assert _drawn_points(view, "cylinder", "box") == 0
    assert view.pick(*np.argwhere(lm == 1)[0][::-1]) is None        # what is not drawn is not picked
    view.set_frame(data)                                            # the next frame keeps the mode
    assert _drawn_points(view, "cylinder") == 0 and view.mask_item.image[..., 3][lm == 1].max() == 0
    view.toolbar.selected_only_action.setChecked(False)
    view.toolbar.outline_only_action.setChecked(True)
    assert not view.mask_item.isVisible()
    assert all(_drawn_points(view, n) > 10 and _drawn_points(view, n, "box") == 0 for n in session.object_names)
    assert len(view.center_item.data) == 0
    session.set_overlay("contour", False)                           # outlines even with contours off
    view.set_frame(FrameComputer().frame(session.request()))
    assert all(_drawn_points(view, n) > 10 for n in session.object_names)
    assert "outlines only" in view.toolbar.display_button.toolTip() and view.toolbar.display_button.text() != "Display"


def test_hover_readout_is_cleared_when_the_mouse_leaves(view, session, qtbot):
    data = FrameComputer().frame(session.request())
    view.set_frame(data)
    vs, us = np.nonzero(data.labels.label_map == 1)
    u, v = int(us[len(us) // 2]), int(vs[len(vs) // 2])
    widget_pt = view.glw.mapFromScene(view.vb.mapViewToScene(QtCore.QPointF(u, v)))
    qtbot.mouseMove(view.glw.viewport(), QtCore.QPoint(3, 3))
    qtbot.wait(100)                                                  # the readout is rate-limited (30 Hz)
    with qtbot.waitSignal(view.hoverText, timeout=2000, check_params_cb=lambda t: t.startswith(f"u {u}, v {v}")):
        qtbot.mouseMove(view.glw.viewport(), widget_pt)
    assert view.info.rightText().startswith(f"u {u}, v {v}")
    with qtbot.waitSignal(view.hoverText, timeout=2000, check_params_cb=lambda t: t == ""):
        QtWidgets.QApplication.sendEvent(view.glw.viewport(), QtCore.QEvent(QtCore.QEvent.Leave))
    assert view.info.rightText() == ""
    qtbot.wait(60)                                                   # no late rate-limited move brings it back
    assert view.info.rightText() == ""
