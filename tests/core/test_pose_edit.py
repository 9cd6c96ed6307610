"""Pose nudges (evpose.core.document.pose_edit) and the session's object nudge.

A nudge in frame F (base, camera or object) by ``rot_deg`` about F's axes, pivoting about the
object's box centre, and ``trans_mm`` along F's axes, is a base-frame step ``S``: the new pose is
``S @ T_base_obj``. The poses below are chosen so that the three frames' axes all differ, so a
nudge that uses the wrong frame moves the object in a different direction.
"""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from evpose.core.data.geometry import apply_T, make_T, pose_error
from evpose.core.data.camera import CameraModel
from evpose.core.document.pose_edit import (
    FRAMES,
    delta_components,
    drag_step,
    frame_rotation,
    hand_eye_step,
    image_plane_shift,
    nudge_step,
    pose_change,
    swept_angle_deg,
)

R_BASE_OBJ = Rotation.from_rotvec([0.5, -0.9, 0.4]).as_matrix()
R_BASE_CAM = Rotation.from_rotvec([-1.1, 0.3, 0.8]).as_matrix()
T_BASE_OBJ = make_T(R_BASE_OBJ, [0.31, -0.62, 0.07])
T_BASE_CAM = make_T(R_BASE_CAM, [0.05, -0.2, 0.45])
PIVOT_OBJ_M = np.array([0.02, -0.035, 0.05])           # box centre off the object origin
AXES_IN_BASE = {"base": np.eye(3), "camera": R_BASE_CAM, "object": R_BASE_OBJ}


def test_the_three_frames_have_different_axes():
    for a in FRAMES:
        for b in FRAMES:
            if a != b:
                for k in range(3):
                    assert np.linalg.norm(AXES_IN_BASE[a][:, k] - AXES_IN_BASE[b][:, k]) > 0.3, (a, b, k)
    for f in FRAMES:
        np.testing.assert_array_equal(frame_rotation(f, T_BASE_OBJ, T_BASE_CAM), AXES_IN_BASE[f])
    with pytest.raises(ValueError, match="frame must be one of"):
        frame_rotation("world", T_BASE_OBJ, T_BASE_CAM)


@pytest.mark.parametrize("frame", FRAMES)
@pytest.mark.parametrize("axis", [0, 1, 2])
def test_translation_nudge_moves_along_the_frame_axis(frame, axis):
    trans_mm = np.zeros(3)
    trans_mm[axis] = -2.5
    S = nudge_step(frame, (0, 0, 0), trans_mm, T_BASE_OBJ, T_BASE_CAM, PIVOT_OBJ_M)
    new = S @ T_BASE_OBJ
    np.testing.assert_allclose(new[:3, :3], R_BASE_OBJ, atol=1e-12)     # no rotation
    expected_m = -2.5e-3 * AXES_IN_BASE[frame][:, axis]                   # base-frame displacement
    np.testing.assert_allclose(new[:3, 3] - T_BASE_OBJ[:3, 3], expected_m, atol=1e-12)


@pytest.mark.parametrize("frame", FRAMES)
@pytest.mark.parametrize("axis", [0, 1, 2])
def test_rotation_nudge_pivots_about_the_box_centre_by_the_requested_degrees(frame, axis):
    rot_deg = np.zeros(3)
    rot_deg[axis] = 7.0
    S = nudge_step(frame, rot_deg, (0, 0, 0), T_BASE_OBJ, T_BASE_CAM, PIVOT_OBJ_M)
    new = S @ T_BASE_OBJ
    # the box centre stays where it was (in the base frame)
    np.testing.assert_allclose(apply_T(new, PIVOT_OBJ_M[None]), apply_T(T_BASE_OBJ, PIVOT_OBJ_M[None]), atol=1e-12)
    # the object turned by 7 degrees ...
    _, angle_rad = pose_error(new, T_BASE_OBJ)
    assert np.degrees(angle_rad) == pytest.approx(7.0, abs=1e-9)
    # ... right-handed about the frame's axis (in the base frame)
    R_expected = Rotation.from_rotvec(np.radians(7.0) * AXES_IN_BASE[frame][:, axis]).as_matrix()
    np.testing.assert_allclose(new[:3, :3], R_expected @ R_BASE_OBJ, atol=1e-12)
    # and any other point of the object moved (it is not a translation in disguise)
    far = apply_T(new, np.array([[0.1, 0.1, 0.1]])) - apply_T(T_BASE_OBJ, np.array([[0.1, 0.1, 0.1]]))
    assert np.linalg.norm(far) > 1e-3


def test_object_frame_rotation_is_about_the_objects_own_axis():
    """About the object's x: the new object axes are the old ones turned about object x, so x stays."""
    S = nudge_step("object", (30.0, 0, 0), (0, 0, 0), T_BASE_OBJ, T_BASE_CAM)
    new = S @ T_BASE_OBJ
    np.testing.assert_allclose(new[:3, :3], R_BASE_OBJ @ Rotation.from_euler("x", 30, degrees=True).as_matrix(),
                               atol=1e-12)
    np.testing.assert_allclose(new[:3, 3], T_BASE_OBJ[:3, 3], atol=1e-12)      # default pivot: the origin


def test_rotation_then_translation_moves_the_centre_along_the_frame_axes():
    S = nudge_step("camera", (0, 0, 12.0), (1.0, -3.0, 4.0), T_BASE_OBJ, T_BASE_CAM, PIVOT_OBJ_M)
    new = S @ T_BASE_OBJ
    moved = apply_T(new, PIVOT_OBJ_M[None])[0] - apply_T(T_BASE_OBJ, PIVOT_OBJ_M[None])[0]
    np.testing.assert_allclose(moved, R_BASE_CAM @ np.array([1.0, -3.0, 4.0]) * 1e-3, atol=1e-12)
    assert np.degrees(pose_error(new, T_BASE_OBJ)[1]) == pytest.approx(12.0, abs=1e-9)


def test_hand_eye_step_and_delta_components():
    S = hand_eye_step((0, 0, 90.0), (1.0, 2.0, -3.0))
    np.testing.assert_allclose(S[:3, :3], [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-12)
    np.testing.assert_allclose(S[:3, 3], [0.001, 0.002, -0.003], atol=1e-15)
    rv_deg, t_mm = delta_components(make_T(Rotation.from_rotvec([0, np.radians(-4.0), 0]).as_matrix(),
                                           [0.0015, 0, -0.002]))
    np.testing.assert_allclose(rv_deg, [0, -4.0, 0], atol=1e-12)
    np.testing.assert_allclose(t_mm, [1.5, 0, -2.0], atol=1e-12)


# ---------------------------------------------------------------------- through the session
OFFSET_M = np.array([0.04, -0.03, 0.05])


@pytest.fixture
def offcentre_session(scene_copy):
    """The tiny scene with the box mesh moved off its origin (box centre at OFFSET_M in the
    object frame), so pivoting about the origin and about the centre differ."""
    import trimesh

    from evpose.core.session.model import Session

    path = scene_copy / "models" / "box.ply"
    mesh = trimesh.load(path, force="mesh")
    mesh.apply_translation(OFFSET_M)
    mesh.export(path)
    s = Session.open(scene_copy)
    s.set_time(s.time_range[0] + 300_000)
    yield s
    s.close()


def test_session_nudge_rotates_about_the_box_centre(offcentre_session):
    s = offcentre_session
    np.testing.assert_allclose(s.scene.model("box").bbox_center_m, OFFSET_M, atol=1e-9)
    T0 = s.scene.T_base_obj("box")
    c0 = apply_T(T0, OFFSET_M[None])[0]
    s.nudge_object("box", "camera", rot_deg=(0, 5.0, 0))
    T1 = s.scene.T_base_obj("box")
    np.testing.assert_allclose(apply_T(T1, OFFSET_M[None])[0], c0, atol=1e-12)
    assert np.degrees(pose_error(T1, T0)[1]) == pytest.approx(5.0, abs=1e-9)
    R_bc = s.current_T_base_cam()[:3, :3]
    np.testing.assert_allclose(T1[:3, :3], Rotation.from_rotvec(np.radians(5.0) * R_bc[:, 1]).as_matrix() @ T0[:3, :3],
                               atol=1e-12)


@pytest.mark.parametrize("frame", FRAMES)
def test_session_translation_nudge_in_each_frame(offcentre_session, frame):
    s = offcentre_session
    T0 = s.scene.T_base_obj("box")
    R = {"base": np.eye(3), "camera": s.current_T_base_cam()[:3, :3], "object": T0[:3, :3]}
    # the three frames' z axes differ for this pose and time, so the test tells them apart
    assert all(np.linalg.norm(R[o][:, 2] - R[frame][:, 2]) > 0.1 for o in FRAMES if o != frame)
    s.nudge_object("box", frame, trans_mm=(0, 0, 4.0))
    T1 = s.scene.T_base_obj("box")
    np.testing.assert_allclose(T1[:3, 3] - T0[:3, 3], 4e-3 * R[frame][:, 2], atol=1e-12)
    np.testing.assert_allclose(T1[:3, :3], T0[:3, :3], atol=1e-12)


# ---------------------------------------------------------------------- the pose readout (issue 16)
@pytest.mark.parametrize("frame", FRAMES)
def test_pose_change_of_a_rotation_about_the_centre_is_0_mm(frame):
    """The readout is the displacement of the box centre and the rotation angle (what the Refine dialog
    reports): a rotation about the centre reads 0 mm, where the delta's own translation holds a lever arm."""
    dT = nudge_step("camera", (3.0, -4.0, 0.0), (0, 0, 0), T_BASE_OBJ, T_BASE_CAM, PIVOT_OBJ_M)
    assert np.linalg.norm(dT[:3, 3]) > 5e-3                     # the lever arm the old readout showed
    angle, rv, moved = pose_change(dT, T_BASE_OBJ, PIVOT_OBJ_M, frame, T_BASE_CAM)
    assert angle == pytest.approx(5.0, abs=1e-9)
    np.testing.assert_allclose(moved, 0.0, atol=1e-9)
    R_f = AXES_IN_BASE[frame]
    np.testing.assert_allclose(rv, R_f.T @ R_BASE_CAM @ np.array([3.0, -4.0, 0.0]), atol=1e-9)


@pytest.mark.parametrize("frame", FRAMES)
def test_pose_change_gives_the_centre_displacement_in_the_chosen_axes(frame):
    """A 10 mm move then a 5 degree turn about the centre still reads 10 mm, with components along the chosen
    frame's axes (object: the corrected pose's axes)."""
    move = nudge_step(frame, (0, 0, 0), (6.0, 0.0, -8.0), T_BASE_OBJ, T_BASE_CAM, PIVOT_OBJ_M)
    T1 = move @ T_BASE_OBJ
    turn = nudge_step("camera", (0, 5.0, 0), (0, 0, 0), T1, T_BASE_CAM, PIVOT_OBJ_M)
    dT = turn @ move
    angle, _, moved = pose_change(dT, T_BASE_OBJ, PIVOT_OBJ_M, frame, T_BASE_CAM)
    assert angle == pytest.approx(5.0, abs=1e-9)
    assert np.linalg.norm(moved) == pytest.approx(10.0, abs=1e-9)
    if frame != "object":            # object axes turned with the object: the components turned too
        np.testing.assert_allclose(moved, [6.0, 0.0, -8.0], atol=1e-9)


# ---------------------------------------------------------------------- drags on the image
CAMERA = CameraModel([[292.52, 0.0, 172.61], [0.0, 293.19, 130.125], [0.0, 0.0, 1.0]],
                     [-0.362, 0.115, 0.0009576, 0.00000455, 0.130])


def _centre_cam(T_base_obj):
    return apply_T(np.linalg.inv(T_BASE_CAM) @ T_base_obj, PIVOT_OBJ_M[None])[0]


def _object_in_front():
    """T_base_obj with the box centre 0.5 m in front of the camera, left of and above the image centre."""
    T_cam_obj = make_T(R_BASE_OBJ, np.array([-0.08, -0.05, 0.5]) - R_BASE_OBJ @ PIVOT_OBJ_M)
    return T_BASE_CAM @ T_cam_obj


def test_a_move_drag_carries_the_centre_under_the_cursor_at_its_depth():
    T = _object_in_front()
    c0 = _centre_cam(T)
    uv0, _ = CAMERA.project(c0[None])
    uv1 = uv0[0] + [23.0, -11.0]
    S = drag_step("move", uv0[0], uv1, CAMERA, T, T_BASE_CAM, PIVOT_OBJ_M)
    c1 = _centre_cam(S @ T)
    assert c1[2] == pytest.approx(c0[2], abs=1e-12)               # parallel to the image: same depth
    np.testing.assert_allclose(CAMERA.project(c1[None])[0][0], uv1, atol=1e-6)   # under the cursor (distorted)
    np.testing.assert_allclose((S @ T)[:3, :3], T[:3, :3], atol=1e-12)
    # a shift is a shift wherever it starts: through the lens, 10 px near the border is not 10 px at the centre
    d = image_plane_shift(CAMERA, c0, (20.0, 20.0), (30.0, 20.0))
    assert d[2] == 0 and d[0] > 0 and abs(d[1]) < abs(d[0])


def test_spin_and_tilt_drags_turn_about_the_centre():
    T = _object_in_front()
    c0 = _centre_cam(T)
    uvc = CAMERA.project(c0[None])[0][0]
    # a quarter turn clockwise on screen (x right, y down) about the centre's image: +90 degrees about camera z
    assert swept_angle_deg(uvc, uvc + [10, 0], uvc + [0, 10]) == pytest.approx(90.0)
    S = drag_step("spin", uvc + [10, 0], uvc + [0, 10], CAMERA, T, T_BASE_CAM, PIVOT_OBJ_M)
    np.testing.assert_allclose(_centre_cam(S @ T), c0, atol=1e-12)
    R_cam = T_BASE_CAM[:3, :3].T @ S[:3, :3] @ T_BASE_CAM[:3, :3]       # the step in camera axes
    np.testing.assert_allclose(R_cam, Rotation.from_euler("z", 90, degrees=True).as_matrix(), atol=1e-9)
    # tilt: a drag to the right turns the side facing the camera to the right (about camera -y)
    S = drag_step("tilt", (100, 100), (110, 100), CAMERA, T, T_BASE_CAM, PIVOT_OBJ_M)
    np.testing.assert_allclose(_centre_cam(S @ T), c0, atol=1e-12)
    R_cam = T_BASE_CAM[:3, :3].T @ S[:3, :3] @ T_BASE_CAM[:3, :3]
    front = R_cam @ np.array([0, 0, -0.05])                               # the point facing the camera
    assert front[0] > 0.003
    with pytest.raises(ValueError, match="drag mode"):
        drag_step("zoom", (0, 0), (1, 1), CAMERA, T, T_BASE_CAM, PIVOT_OBJ_M)
