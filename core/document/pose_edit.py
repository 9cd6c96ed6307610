"""Pose nudges expressed in a chosen frame, converted to the corrections' base-frame deltas.

A user nudges an object by a rotation (degrees, about the axes of a chosen frame, pivoting about
the object's box centre) and a translation (millimetres, along the axes of that frame):

* ``"camera"``: the event camera's axes at the current time (x right, y down, z forward);
* ``"object"``: the object's own axes (its current, corrected pose);
* ``"base"``: the robot base axes.

The result is a step ``S`` in the base frame such that the new object pose is
``S @ T_base_obj`` and the new correction ``S @ dT_base`` (see :mod:`core.corrections`).
"""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from evpose.core.data.geometry import make_T

FRAMES = ("camera", "object", "base")


def frame_rotation(frame: str, T_base_obj: np.ndarray, T_base_cam: np.ndarray) -> np.ndarray:
    """``R_base_frame``: the axes of ``frame`` expressed in the base frame."""
    if frame == "camera":
        return T_base_cam[:3, :3]
    if frame == "object":
        return T_base_obj[:3, :3]
    if frame == "base":
        return np.eye(3)
    raise ValueError(f"frame must be one of {FRAMES}, got {frame!r}")


def nudge_step(frame: str, rot_deg, trans_mm, T_base_obj: np.ndarray, T_base_cam: np.ndarray,
               pivot_obj_m=(0.0, 0.0, 0.0)) -> np.ndarray:
    """Base-frame step ``S`` for a nudge in ``frame``.

    Parameters
    ----------
    rot_deg : (3,) rotation vector in degrees about the frame's x, y, z axes
    trans_mm : (3,) translation in millimetres along the frame's axes
    T_base_obj : current (corrected) object pose
    T_base_cam : camera pose at the current time (used by ``"camera"``)
    pivot_obj_m : rotation centre in the object frame (e.g. the box centre), metres
    """
    R_bf = frame_rotation(frame, T_base_obj, T_base_cam)
    R_f = Rotation.from_rotvec(np.radians(np.asarray(rot_deg, dtype=np.float64))).as_matrix()
    R_b = R_bf @ R_f @ R_bf.T
    pivot_base = T_base_obj[:3, :3] @ np.asarray(pivot_obj_m, dtype=np.float64) + T_base_obj[:3, 3]
    t_b = R_bf @ (np.asarray(trans_mm, dtype=np.float64) * 1e-3)
    # rotate about the pivot, then translate
    return make_T(R_b, pivot_base - R_b @ pivot_base + t_b)


def hand_eye_step(rot_deg, trans_mm) -> np.ndarray:
    """Camera-frame step ``S`` for the hand-eye correction: ``dT_cam' = dT_cam @ S``."""
    R = Rotation.from_rotvec(np.radians(np.asarray(rot_deg, dtype=np.float64))).as_matrix()
    return make_T(R, np.asarray(trans_mm, dtype=np.float64) * 1e-3)


def delta_components(dT: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A delta as (rotation vector in degrees, translation in mm) for display."""
    return np.degrees(Rotation.from_matrix(dT[:3, :3]).as_rotvec()), dT[:3, 3] * 1e3


def pose_change(dT_base: np.ndarray, T_base_obj_prior: np.ndarray, pivot_obj_m, frame: str,
                T_base_cam: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """An object correction as the user reads it: how far its box centre moved and by how much it turned.

    The same quantities as the Refine dialog (:func:`evpose.core.align.pose_refine._pose_change`): the
    rotation angle of the base-frame delta and the displacement of the centre, which a rotation about the
    centre leaves at 0 (unlike the delta's own translation, which holds the lever arm ``c - R c``).

    Parameters
    ----------
    dT_base : (4, 4) the correction: corrected pose ``dT_base @ T_base_obj_prior``
    T_base_obj_prior : (4, 4) the object's pose before the correction (the manifest's)
    pivot_obj_m : (3,) the centre in the object frame (the box centre), metres
    frame : "camera", "object" (the corrected pose's axes) or "base": the axes of the components
    T_base_cam : (4, 4) the camera pose at the current time (used by ``"camera"``)

    Returns
    -------
    angle_deg : float
        Rotation angle of the correction, degrees (>= 0).
    rotvec_deg : (3,)
        Its rotation vector in ``frame`` axes, degrees.
    moved_mm : (3,)
        Displacement of the centre in ``frame`` axes, millimetres.
    """
    dT_base = np.asarray(dT_base, dtype=np.float64)
    R = dT_base[:3, :3]
    c0 = T_base_obj_prior[:3, :3] @ np.asarray(pivot_obj_m, dtype=np.float64) + T_base_obj_prior[:3, 3]
    moved_base = R @ c0 + dT_base[:3, 3] - c0
    rotvec_base = Rotation.from_matrix(R).as_rotvec()
    R_bf = frame_rotation(frame, dT_base @ T_base_obj_prior, T_base_cam)
    return (float(np.degrees(np.linalg.norm(rotvec_base))), np.degrees(R_bf.T @ rotvec_base),
            R_bf.T @ moved_base * 1e3)


def image_plane_shift(camera, centre_cam: np.ndarray, uv_from, uv_to) -> np.ndarray:
    """Camera-frame translation (metres, z = 0) that carries a point at the depth of ``centre_cam`` from
    under pixel ``uv_from`` to under pixel ``uv_to``: a move parallel to the image, at the object's depth.

    Pixels are of the raw (distorted) image, as on screen; they are undistorted to rays first, so the
    shift follows the cursor also where the lens bends the image. A pixel the lens gives no ray (beyond the
    distortion's turning radius) moves nothing: zeros, never NaN into a pose."""
    z = float(np.asarray(centre_cam, dtype=np.float64)[2])
    xy = camera.undistort_points(np.array([uv_from, uv_to], dtype=np.float64))
    d = (xy[1] - xy[0]) * z
    if not np.all(np.isfinite(d)):
        return np.zeros(3)
    return np.array([d[0], d[1], 0.0])


def swept_angle_deg(centre_uv, uv_from, uv_to) -> float:
    """Signed angle (degrees) swept by the cursor about ``centre_uv`` on the image.

    Image axes are x right, y down, so a clockwise sweep on screen is positive: a rotation about the
    camera's +z (forward) axis by this angle turns the object the way the cursor went."""
    a = np.asarray(uv_from, dtype=np.float64) - np.asarray(centre_uv, dtype=np.float64)
    b = np.asarray(uv_to, dtype=np.float64) - np.asarray(centre_uv, dtype=np.float64)
    return float(np.degrees(np.arctan2(a[0] * b[1] - a[1] * b[0], a @ b)))


#: Degrees of tilt per image pixel of a tilt drag (:func:`tilt_rotation_deg`).
TILT_DEG_PER_PX = 0.5


def tilt_rotation_deg(uv_from, uv_to, deg_per_px: float = TILT_DEG_PER_PX) -> np.ndarray:
    """Camera-axes rotation vector (degrees) of a tilt drag, like a trackball: the side of the object that
    faces the camera follows the cursor (right: about camera -y; down: about camera +x)."""
    du, dv = np.asarray(uv_to, dtype=np.float64) - np.asarray(uv_from, dtype=np.float64)
    return np.array([dv, -du, 0.0]) * deg_per_px


#: Kinds of a drag in the frame view (:func:`drag_step`).
DRAG_MODES = ("move", "spin", "tilt")


def drag_step(mode: str, uv_from, uv_to, camera, T_base_obj: np.ndarray, T_base_cam: np.ndarray,
              pivot_obj_m) -> np.ndarray:
    """Base-frame step ``S`` of a drag on the image from pixel ``uv_from`` to ``uv_to`` (the new pose is
    ``S @ T_base_obj``), all about the object's centre ``pivot_obj_m``:

    * ``"move"``: a translation parallel to the image at the centre's depth (:func:`image_plane_shift`);
    * ``"spin"``: a rotation about the camera's z axis (the optical axis direction) through the centre by the
      angle the cursor swept about the centre's image (:func:`swept_angle_deg`);
    * ``"tilt"``: a rotation about the camera's x and y axes through the centre (:func:`tilt_rotation_deg`).

    ``T_base_cam``: the camera pose of the frame on screen (its label time).
    """
    T_cam_obj = np.linalg.inv(T_base_cam) @ T_base_obj
    centre_cam = T_cam_obj[:3, :3] @ np.asarray(pivot_obj_m, dtype=np.float64) + T_cam_obj[:3, 3]
    rot_deg, trans_mm = np.zeros(3), np.zeros(3)
    if mode == "move":
        trans_mm = image_plane_shift(camera, centre_cam, uv_from, uv_to) * 1e3
    elif mode == "spin":
        uv_c, ok = camera.project(centre_cam[None])
        if ok[0]:
            rot_deg[2] = swept_angle_deg(uv_c[0], uv_from, uv_to)
    elif mode == "tilt":
        rot_deg = tilt_rotation_deg(uv_from, uv_to)
    else:
        raise ValueError(f"drag mode must be one of {DRAG_MODES}, got {mode!r}")
    return nudge_step("camera", rot_deg, trans_mm, T_base_obj, T_base_cam, pivot_obj_m)
