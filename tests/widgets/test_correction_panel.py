import numpy as np
import pytest
from PySide6 import QtCore, QtWidgets
from scipy.spatial.transform import Rotation

from evpose.core.data.geometry import make_T, pose_error
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
    # the panel shows the move in the chosen axes: the box centre moved 3 mm along camera x
    assert panel.object_delta.text() == ("centre moved 3.00 mm  [+3.00, +0.00, +0.00] mm\n"
                                         "rotated 0.000°  [+0.000, +0.000, +0.000]°")
    rb = panel.findChild(QtWidgets.QToolButton, "rotate_z_plus")
    panel.rot_step.setCurrentIndex(3)  # 1 degree
    qtbot.mouseClick(rb, QtCore.Qt.LeftButton)
    T2, _ = session.scene.T_cam_obj([session.view.t_us], ["box"])
    _, dR = pose_error(T2[0, 0], T1[0, 0])
    assert np.degrees(dR) == pytest.approx(1.0, abs=1e-9)
    # 1 degree about camera z through the box centre: the centre stays, the readout says so
    assert panel.object_delta.text() == ("centre moved 3.00 mm  [+3.00, +0.00, +0.00] mm\n"
                                         "rotated 1.000°  [+0.000, +0.000, +1.000]°")
    # the same correction in the robot base's axes: the camera's x and z axes seen from the base
    panel.frame_combo.setCurrentIndex(2)
    R_bc = session.current_T_base_cam()[:3, :3]
    t_mm, r_deg = np.round(3.0 * R_bc[:, 0], 2) + 0.0, np.round(R_bc[:, 2], 3) + 0.0
    assert panel.object_delta.text() == (f"centre moved 3.00 mm  [{t_mm[0]:+.2f}, {t_mm[1]:+.2f}, {t_mm[2]:+.2f}] mm"
                                         f"\nrotated 1.000°  [{r_deg[0]:+.3f}, {r_deg[1]:+.3f}, "
                                         f"{r_deg[2]:+.3f}]°")
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


def _readout_numbers(text: str) -> tuple[float, float]:
    """(centre displacement mm, rotation degrees) from the panel's pose readout."""
    first, second = text.split("\n")
    return float(first.split()[2]), float(second.split()[1].rstrip("°"))


def test_readout_of_a_rotation_about_the_centre_is_0_mm(panel, session):
    """Issue 16: after a 10 mm move, a 5 degree rotation about the object's centre changed "Δ t" from 8.00 to
    28.65 mm (the lever arm of the base-frame delta). The readout is the displacement of the centre."""
    panel.object_combo.setCurrentText("box")
    session.nudge_object("box", "camera", rot_deg=(0, 5, 0), mergeable=False)
    assert _readout_numbers(panel.object_delta.text()) == (0.0, 5.0)
    session.nudge_object("box", "object", trans_mm=(10, 0, 0), mergeable=False)
    assert _readout_numbers(panel.object_delta.text()) == (10.0, 5.0)
    session.nudge_object("box", "camera", rot_deg=(5, 0, 0), mergeable=False)      # about the centre again
    moved, angle = _readout_numbers(panel.object_delta.text())
    assert moved == 10.0 and 5.0 < angle <= 10.0
    # an accepted estimate reads as the Refine dialog reports it: 7.62 mm of the centre, 5.19 degrees
    box = session.scene.model("box")
    T0 = session.scene.manifest.object("box").T_base_obj
    c = T0[:3, :3] @ box.bbox_center_m + T0[:3, 3]
    R = Rotation.from_rotvec(np.radians(5.19) * np.array([0.6, 0.0, 0.8])).as_matrix()
    shift = np.array([0.00762, 0.0, 0.0])
    session.apply_pose_estimate("box", make_T(R, c - R @ c + shift))
    assert _readout_numbers(panel.object_delta.text()) == (7.62, 5.19)


def test_camera_axes_where_the_trajectory_has_no_camera_pose(panel, session, qtbot):
    """Outside the trajectory the camera's axes are unknown: a nudge in camera axes is refused with the reason (it
    used to move the object along the base axes under the camera's name), the readout says why it has no numbers,
    and object or base axes still work."""
    session.set_offset_correction_us(10**9)                 # every event time maps beyond the trajectory
    assert session.current_T_base_cam() is None
    panel.object_combo.setCurrentText("box")
    panel.frame_combo.setCurrentIndex(0)                     # camera
    assert "no camera pose" in panel.object_delta.text()
    n = len(session.history)
    qtbot.mouseClick(panel.findChild(QtWidgets.QToolButton, "translate_x_plus"), QtCore.Qt.LeftButton)
    assert len(session.history) == n and "box" not in session.scene.corrections.object_deltas
    assert "no camera pose" in panel.object_delta.text()
    panel.frame_combo.setCurrentIndex(2)                     # robot base
    qtbot.mouseClick(panel.findChild(QtWidgets.QToolButton, "translate_x_plus"), QtCore.Qt.LeftButton)
    d = session.scene.corrections.object_delta("box")
    np.testing.assert_allclose(d[:3, 3], [0.001 * panel.trans_step.currentData(), 0, 0], atol=1e-12)
    assert panel.object_delta.text().startswith("centre moved")


def test_typed_move_and_typed_pose_are_one_undo_step_each(panel, session):
    """Type…: "Move by" does what that many nudges do (mm / degrees in the panel's axes, about the box centre);
    "Set pose" sets T_base_obj exactly (position mm, rotation vector degrees, base frame); an unchanged dialog
    applies nothing."""
    from scipy.spatial.transform import Rotation

    from evpose.core.document.pose_edit import nudge_step
    from evpose.widgets.pose_entry import PoseEntryDialog

    name = panel.current_object()
    T0 = session.scene.T_base_obj(name)
    dlg = PoseEntryDialog(name, "base", T0)
    assert dlg.result_values() is None                          # nothing typed: nothing to apply
    dlg.tabs.setCurrentIndex(1)
    assert dlg.result_values() is None                          # the pose as shown: nothing to apply
    panel.frame_combo.setCurrentIndex(panel.frame_combo.findData("base"))
    dlg.tabs.setCurrentIndex(0)
    for b, v in zip(dlg.move_t + dlg.move_r, (1.5, 0.0, -2.0, 0.0, 3.0, 0.0)):
        b.setValue(v)
    n = len(session.history)
    assert panel.type_pose(dlg)
    expected = nudge_step("base", (0, 3.0, 0), (1.5, 0, -2.0), T0, np.eye(4),
                          pivot_obj_m=session.scene.model(name).bbox_center_m) @ T0
    np.testing.assert_allclose(session.scene.T_base_obj(name), expected, atol=1e-12)
    assert len(session.history) == n + 1
    # an exact pose: 10 mm up from the start, turned 5 degrees about base z
    target = T0.copy()
    target[:3, 3] += [0.0, 0.0, 0.010]
    target[:3, :3] = Rotation.from_euler("z", 5, degrees=True).as_matrix() @ T0[:3, :3]
    dlg = PoseEntryDialog(name, "base", session.scene.T_base_obj(name))
    dlg.tabs.setCurrentIndex(1)
    for b, v in zip(dlg.set_t, target[:3, 3] * 1e3):
        b.setValue(v)
    for b, v in zip(dlg.set_r, np.degrees(Rotation.from_matrix(target[:3, :3]).as_rotvec())):
        b.setValue(v)
    assert panel.type_pose(dlg)
    got = session.scene.T_base_obj(name)
    assert np.abs(got[:3, 3] - target[:3, 3]).max() < 1e-6                       # mm spin boxes: 3 decimals
    assert np.degrees(Rotation.from_matrix(got[:3, :3] @ target[:3, :3].T).magnitude()) < 1e-3
    assert len(session.history) == n + 2
    session.history.undo()
    np.testing.assert_allclose(session.scene.T_base_obj(name), expected, atol=1e-12)
