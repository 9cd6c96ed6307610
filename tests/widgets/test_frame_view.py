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
    assert (lab.label_map[y[ok].astype(int), x[ok].astype(int)] == k).mean() > 0.9


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
