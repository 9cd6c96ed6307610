import numpy as np
import pytest
from PySide6 import QtCore, QtWidgets
from scipy.spatial.transform import Rotation

from evpose.core.data.geometry import pose_error
from evpose.widgets.correction_panel import CorrectionPanel


@pytest.fixture
def panel(qtbot, session):
    w = CorrectionPanel(session)
    qtbot.addWidget(w)
    w.show()
    return w


def test_model_changes_show_in_the_panel(panel, session):
    session.set_offset_correction_us(12_345)
    assert panel.offset_spin.value() == 12_345
    assert "+12.345 ms" in panel.offset_total.text()
    session.set_skew_correction_ppm(-3.5)
    assert panel.skew_spin.value() == pytest.approx(-3.5)
    session.history.undo()
    assert panel.skew_spin.value() == 0.0


def test_spinbox_and_slider_edit_the_model_as_one_undo_step(panel, session):
    panel.offset_spin.setValue(500)
    panel.offset_spin.setValue(700)
    assert session.scene.corrections.offset_us == 700 and len(session.history) == 1
    session.history.break_merge()
    panel.offset_slider.setValue(10)  # coarse: 100 us per tick
    assert session.scene.corrections.offset_us == 1000
    panel.offset_slider.setValue(25)
    assert session.scene.corrections.offset_us == 2500 and len(session.history) == 2
    session.history.undo()
    assert session.scene.corrections.offset_us == 700


def test_fine_slider_steps_around_the_current_value(panel, session):
    session.set_offset_correction_us(20_000)
    panel.offset_fine.setChecked(True)
    panel.offset_slider.setValue(5)
    assert session.scene.corrections.offset_us == 20_010


def test_nudge_buttons_move_the_object_in_camera_axes(panel, session, qtbot):
    panel.object_combo.setCurrentText("box")
    panel.frame_combo.setCurrentIndex(0)  # camera
    panel.trans_step.setCurrentIndex(2)  # 1 mm
    T0, _ = session.scene.T_cam_obj([session.view.t_us], ["box"])
    b = panel.findChild(QtWidgets.QToolButton, "translate_x_plus")
    for _ in range(3):
        qtbot.mouseClick(b, QtCore.Qt.LeftButton)
    T1, _ = session.scene.T_cam_obj([session.view.t_us], ["box"])
    d = T1[0, 0, :3, 3] - T0[0, 0, :3, 3]
    np.testing.assert_allclose(d, [0.003, 0, 0], atol=1e-9)  # 3 mm along camera x
    assert len(session.history) == 1  # merged into one undo step
    # the panel shows the correction in the base frame: 3 mm along the camera's x axis there
    R_bc = session.current_T_base_cam()[:3, :3]
    t_mm = 3.0 * R_bc[:, 0]
    assert panel.object_delta.text() == ("correction (base frame): Δ rot 0.000°, Δ t 3.00 mm "
                                         f"[{t_mm[0]:+.2f}, {t_mm[1]:+.2f}, {t_mm[2]:+.2f}] mm")
    box = session.scene.model("box")
    c_base = session.scene.T_base_obj("box") @ np.append(box.bbox_center_m, 1.0)   # box centre, base frame
    rb = panel.findChild(QtWidgets.QToolButton, "rotate_z_plus")
    panel.rot_step.setCurrentIndex(3)  # 1 degree
    qtbot.mouseClick(rb, QtCore.Qt.LeftButton)
    T2, _ = session.scene.T_cam_obj([session.view.t_us], ["box"])
    _, dR = pose_error(T2[0, 0], T1[0, 0])
    assert np.degrees(dR) == pytest.approx(1.0, abs=1e-9)
    # 1 degree about camera z through the box centre: the base-frame correction turns by 1 degree
    # and its translation swings about that centre
    R_step = Rotation.from_rotvec(np.radians(1.0) * R_bc[:, 2]).as_matrix()
    t_mm = (R_step @ (t_mm * 1e-3) + c_base[:3] - R_step @ c_base[:3]) * 1e3
    assert abs(np.linalg.norm(t_mm) - 3.0) > 0.05       # distinguishable from the 3.00 mm before
    assert panel.object_delta.text() == (f"correction (base frame): Δ rot 1.000°, Δ t {np.linalg.norm(t_mm):.2f} mm "
                                         f"[{t_mm[0]:+.2f}, {t_mm[1]:+.2f}, {t_mm[2]:+.2f}] mm")
    session.history.undo()
    session.history.undo()
    T3, _ = session.scene.T_cam_obj([session.view.t_us], ["box"])
    np.testing.assert_allclose(T3, T0, atol=1e-12)


def test_reset_and_selection_sync(panel, session):
    session.select("cylinder")
    assert panel.object_combo.currentText() == "cylinder"
    panel.nudge_object("translate", 2, 1, big=True)  # 10 mm along z
    assert "cylinder" in session.scene.corrections.object_deltas
    panel.object_combo.setCurrentText("cylinder")
    session.reset("cylinder")
    assert "cylinder" not in session.scene.corrections.object_deltas


def test_nudge_offset_shortcut_steps(panel, session):
    panel.offset_step.setCurrentIndex(2)  # 1 ms
    panel.nudge_offset(+1)
    panel.nudge_offset(+1, big=True)
    assert session.scene.corrections.offset_us == 11_000
