"""Direct manipulation on the frame view (issue 16): a click on an object selects it (view state: no undo
step); a drag moves it parallel to the image, Shift+drag spins it, each drag one undo step; a drag off the
objects pans. Driven with real mouse events on the view's viewport."""
import numpy as np
import pytest
from PySide6 import QtCore, QtGui, QtWidgets

from evpose.core.data.geometry import apply_T, pose_error
from evpose.core.views.frame import FrameComputer
from evpose.widgets.frame.view import FrameView


@pytest.fixture
def view(qtbot, session):
    w = FrameView(session)
    qtbot.addWidget(w)
    w.resize(700, 560)
    w.show()
    qtbot.waitExposed(w)
    w.set_frame(FrameComputer().frame(session.request()))
    return w


def widget_point(view, u, v) -> QtCore.QPointF:
    return QtCore.QPointF(view.glw.mapFromScene(view.vb.mapViewToScene(QtCore.QPointF(u, v))))


def mouse(view, kind, pt, buttons=QtCore.Qt.LeftButton, modifiers=QtCore.Qt.NoModifier):
    vp = view.glw.viewport()
    button = QtCore.Qt.NoButton if kind == QtCore.QEvent.MouseMove else QtCore.Qt.LeftButton
    ev = QtGui.QMouseEvent(kind, pt, vp.mapToGlobal(pt), button, buttons, modifiers)
    QtWidgets.QApplication.sendEvent(vp, ev)


def drag(view, qtbot, uv_from, uv_to, modifiers=QtCore.Qt.NoModifier, steps=8):
    """Press at pixel ``uv_from``, move in ``steps`` (with pauses) to ``uv_to``, release."""
    mouse(view, QtCore.QEvent.MouseButtonPress, widget_point(view, *uv_from), modifiers=modifiers)
    for k in range(1, steps + 1):
        uv = np.asarray(uv_from, float) + k / steps * (np.asarray(uv_to, float) - uv_from)
        mouse(view, QtCore.QEvent.MouseMove, widget_point(view, *uv), modifiers=modifiers)
        qtbot.wait(5)
    mouse(view, QtCore.QEvent.MouseButtonRelease, widget_point(view, *uv_to), buttons=QtCore.Qt.NoButton,
          modifiers=modifiers)


def inner_pixel(view, name):
    """A pixel well inside the object's visible mask (the farthest from its border)."""
    import cv2

    k = view.session.object_names.index(name)
    mask = (view.frame.labels.label_map == k).astype(np.uint8)
    dist = cv2.distanceTransform(mask, cv2.DIST_L2, 3)
    v, u = np.unravel_index(np.argmax(dist), dist.shape)
    return int(u), int(v)


def centre_uv(session, name):
    T, _ = session.scene.T_cam_obj([session.view.window().t_label_us], [name])
    c = apply_T(T[0, 0], session.scene.model(name).bbox_center_m[None])
    return session.scene.camera.project(c)[0][0]


def test_a_click_on_an_object_selects_it_without_an_undo_step(view, session, qtbot):
    assert session.view.selected is None
    for name in ("cylinder", "box"):
        u, v = inner_pixel(view, name)
        qtbot.mouseClick(view.glw.viewport(), QtCore.Qt.LeftButton, pos=widget_point(view, u, v).toPoint())
        assert session.view.selected == name
        assert view.pick(u, v) == name
    assert len(session.history) == 0 and not session.dirty
    # the selected object's outline is drawn wider
    assert view._items["box"]["contour"].opts["pen"].widthF() > view._items["cylinder"]["contour"].opts["pen"].widthF()


def test_a_drag_moves_the_object_under_the_cursor_as_one_undo_step(view, session, qtbot):
    u, v = inner_pixel(view, "cylinder")
    c0 = centre_uv(session, "cylinder")
    T0 = session.scene.T_base_obj("cylinder")
    T_cam0, _ = session.scene.T_cam_obj([session.view.window().t_label_us], ["cylinder"])
    drag(view, qtbot, (u, v), (u + 12, v - 7))
    assert session.view.selected == "cylinder"
    assert len(session.history) == 1 and session.history.undo_text == "drag cylinder"
    assert session.dragging is None
    np.testing.assert_allclose(centre_uv(session, "cylinder") - c0, [12, -7], atol=0.3)   # followed the cursor
    T_cam1, _ = session.scene.T_cam_obj([session.view.window().t_label_us], ["cylinder"])
    assert abs(T_cam1[0, 0, 2, 3] - T_cam0[0, 0, 2, 3]) < 1e-9          # parallel to the image: same depth
    assert np.degrees(pose_error(session.scene.T_base_obj("cylinder"), T0)[1]) < 1e-9
    # a Shift+drag spins it about its centre: a second step
    view.set_frame(FrameComputer().frame(session.request()))
    u, v = inner_pixel(view, "cylinder")
    c1 = centre_uv(session, "cylinder")
    drag(view, qtbot, (u, v), (u + 10, v + 10), modifiers=QtCore.Qt.ShiftModifier)
    assert len(session.history) == 2
    np.testing.assert_allclose(centre_uv(session, "cylinder"), c1, atol=1e-6)
    assert np.degrees(pose_error(session.scene.T_base_obj("cylinder"), T0)[1]) > 1.0
    session.history.undo()
    session.history.undo()
    np.testing.assert_allclose(session.scene.T_base_obj("cylinder"), T0, atol=1e-12)


def test_a_drag_off_the_objects_pans_and_edits_nothing(view, session, qtbot):
    lm = view.frame.labels.label_map
    vs, us = np.nonzero(lm < 0)
    u, v = int(us[0]), int(vs[0])
    before = view.vb.viewRange()
    drag(view, qtbot, (u, v), (u + 20, v + 20))
    assert len(session.history) == 0 and session.view.selected is None
    assert view.vb.viewRange() != before
