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
