"""SE(3) helpers on 4x4 float64 arrays.

Conventions (DESIGN section 3): ``T_a_b`` maps points from frame ``b`` into frame ``a``:
``p_a = T_a_b @ p_b``. Translations are in metres, rotation angles in radians. Every function
accepts a single transform ``(4, 4)`` or a stack ``(..., 4, 4)``.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from evpose.core.errors import InputError

#: Default tolerance on ``max|R R^T - I|`` above which a rotation read from a file is refused
#: (unless the user opts in to repairing it). Published E-POSE poses are rounded to 3-5 digits
#: and have residuals mostly below 0.012.
ROTATION_TOLERANCE = 0.02


class GeometryError(InputError):
    """A matrix that is not a valid rigid transform."""


def identity(n: int | None = None) -> np.ndarray:
    """Identity transform ``(4, 4)``, or a stack of ``n`` of them."""
    eye = np.eye(4)
    return eye if n is None else np.repeat(eye[None], n, axis=0)


def make_T(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Build ``T`` from rotation ``R (..., 3, 3)`` and translation ``t (..., 3)`` in metres."""
    R = np.asarray(R, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)
    T = np.zeros(R.shape[:-2] + (4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = t
    T[..., 3, 3] = 1.0
    return T


def inv_T(T: np.ndarray) -> np.ndarray:
    """Inverse of a rigid transform (uses ``R^T``, exact for orthonormal ``R``)."""
    T = np.asarray(T, dtype=np.float64)
    R_inv = np.swapaxes(T[..., :3, :3], -1, -2)
    t_inv = -np.einsum("...ij,...j->...i", R_inv, T[..., :3, 3])
    return make_T(R_inv, t_inv)


def apply_T(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Transform points ``(N, 3)`` with one ``T (4, 4)``; returns ``(N, 3)`` float64."""
    points = np.asarray(points, dtype=np.float64)
    return points @ T[:3, :3].T + T[:3, 3]


def T_from_rotvec(rotvec_rad, t_m=(0.0, 0.0, 0.0)) -> np.ndarray:
    """Transform from a rotation vector (axis * angle, radians) and a translation in metres."""
    return make_T(Rotation.from_rotvec(np.asarray(rotvec_rad, dtype=np.float64)).as_matrix(), t_m)


def rotation_angle(R: np.ndarray) -> np.ndarray:
    """Rotation angle in radians of ``R (..., 3, 3)``, robust near 0 and pi (via scipy)."""
    R = np.asarray(R, dtype=np.float64)
    mats = R.reshape(-1, 3, 3)
    ang = Rotation.from_matrix(mats).magnitude()
    return ang.reshape(R.shape[:-2]) if R.ndim > 2 else float(ang[0])


def pose_error(T_est: np.ndarray, T_true: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Translation error (metres) and rotation error (radians) between two poses.

    Both errors are measured on ``inv(T_true) @ T_est`` expressed in the parent frame:
    ``dt = |t_est - t_true|`` and ``dR = angle(R_true^T R_est)``.
    """
    T_est = np.asarray(T_est, dtype=np.float64)
    T_true = np.asarray(T_true, dtype=np.float64)
    dt = np.linalg.norm(T_est[..., :3, 3] - T_true[..., :3, 3], axis=-1)
    R_rel = np.swapaxes(T_true[..., :3, :3], -1, -2) @ T_est[..., :3, :3]
    return dt, rotation_angle(R_rel)


def rotation_error_about_symmetry(R_est: np.ndarray, R_true: np.ndarray, axis_obj: np.ndarray | None) -> np.ndarray:
    """Rotation error (radians) of an object with a continuous radial symmetry: the least rotation between the two
    poses over every spin about the unit ``axis_obj`` (object frame), which is the angle between the axis as each
    pose carries it into the parent frame. ``axis_obj=None`` (no symmetry) gives the plain ``angle(R_true^T R_est)``.
    """
    R_est = np.asarray(R_est, dtype=np.float64)
    R_true = np.asarray(R_true, dtype=np.float64)
    if axis_obj is None:
        return rotation_angle(np.swapaxes(R_true, -1, -2) @ R_est)
    a = np.asarray(axis_obj, dtype=np.float64)
    a = a / np.linalg.norm(a)
    c = np.clip(np.einsum("...i,...i->...", R_est @ a, R_true @ a), -1.0, 1.0)
    return np.arccos(c)


def rotation_residual(R: np.ndarray) -> float:
    """Orthonormality residual ``max|R R^T - I|`` (0 for a rotation)."""
    R = np.asarray(R, dtype=np.float64)
    return float(np.max(np.abs(R @ np.swapaxes(R, -1, -2) - np.eye(3))))


def orthonormalize(R: np.ndarray) -> tuple[np.ndarray, float]:
    """Project ``R (3, 3)`` onto SO(3) by SVD (nearest rotation in Frobenius norm).

    Returns the rotation and the residual ``max|R R^T - I|`` of the input. A reflection
    (``det < 0``) is turned into the nearest proper rotation by flipping the smallest singular
    direction; the residual then reflects how far the input was from a rotation.
    """
    R = np.asarray(R, dtype=np.float64)
    U, _, Vt = np.linalg.svd(R)
    d = np.sign(np.linalg.det(U @ Vt)) or 1.0
    R_proj = U @ np.diag([1.0, 1.0, d]) @ Vt
    return R_proj, rotation_residual(R)


def validate_T(
    value,
    field: str,
    *,
    tolerance: float = ROTATION_TOLERANCE,
    repair: bool = False,
) -> tuple[np.ndarray, float]:
    """Check a user-supplied 4x4 rigid transform and return ``(T, residual)``.

    The rotation block is projected onto SO(3). Raises :class:`GeometryError` naming ``field``
    when the shape is not 4x4, a value is not finite, the last row is not ``[0, 0, 0, 1]`` or the
    rotation residual exceeds ``tolerance`` (unless ``repair``).
    """
    try:
        T = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise GeometryError(f"{field}: not a numeric 4x4 matrix ({exc})") from None
    if T.shape != (4, 4):
        raise GeometryError(f"{field}: expected a 4x4 matrix, got shape {T.shape}")
    if not np.all(np.isfinite(T)):
        raise GeometryError(f"{field}: contains NaN or inf")
    if not np.allclose(T[3], [0.0, 0.0, 0.0, 1.0], atol=1e-9):
        raise GeometryError(f"{field}: last row must be [0, 0, 0, 1], got {T[3].tolist()}")
    R, residual = orthonormalize(T[:3, :3])
    if residual > tolerance and not repair:
        raise GeometryError(
            f"{field}: rotation is not orthonormal (max|R R^T - I| = {residual:.4g} > tolerance "
            f"{tolerance:g}); fix the value or allow repair to project it onto SO(3)"
        )
    return make_T(R, T[:3, 3]), residual
