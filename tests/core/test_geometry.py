import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from evpose.core.data.geometry import (
    GeometryError,
    T_from_rotvec,
    apply_T,
    inv_T,
    make_T,
    orthonormalize,
    pose_error,
    rotation_angle,
    rotation_residual,
    validate_T,
)


def random_T(rng, n=None):
    R = Rotation.random(n, random_state=rng).as_matrix()
    t = rng.normal(size=(3,) if n is None else (n, 3))
    return make_T(R, t)


def test_inverse_and_apply_roundtrip():
    rng = np.random.default_rng(0)
    T = random_T(rng)
    p = rng.normal(size=(100, 3))
    np.testing.assert_allclose(apply_T(inv_T(T), apply_T(T, p)), p, atol=1e-12)
    np.testing.assert_allclose(T @ inv_T(T), np.eye(4), atol=1e-12)
    Ts = random_T(rng, 5)
    np.testing.assert_allclose(np.einsum("nij,njk->nik", Ts, inv_T(Ts)), np.broadcast_to(np.eye(4), (5, 4, 4)), atol=1e-12)


def test_rotation_angle_near_zero_and_pi():
    assert rotation_angle(np.eye(3)) == pytest.approx(0.0, abs=1e-12)
    R = Rotation.from_rotvec([0, 0, np.pi]).as_matrix()
    assert rotation_angle(R) == pytest.approx(np.pi, abs=1e-9)
    R = Rotation.from_rotvec([1e-9, 0, 0]).as_matrix()
    assert rotation_angle(R) == pytest.approx(1e-9, rel=1e-3)


def test_pose_error_units():
    T1 = T_from_rotvec([0, 0, np.radians(3)], [0.005, 0, 0])
    dt, dR = pose_error(T1, np.eye(4))
    assert dt == pytest.approx(0.005)
    assert np.degrees(dR) == pytest.approx(3.0)


def test_orthonormalize_reports_residual_and_fixes_reflection():
    R = Rotation.from_rotvec([0.2, -0.4, 0.9]).as_matrix()
    noisy = R + 1e-3 * np.arange(9).reshape(3, 3)
    Rp, res = orthonormalize(noisy)
    assert res > 1e-3
    assert rotation_residual(Rp) < 1e-12 and np.linalg.det(Rp) == pytest.approx(1.0)
    assert rotation_angle(Rp.T @ R) < 1e-2
    Rp, _ = orthonormalize(np.diag([1.0, 1.0, -1.0]))
    assert np.linalg.det(Rp) == pytest.approx(1.0)


def test_validate_T_errors_name_the_field():
    with pytest.raises(GeometryError, match="objects\\[0\\].T: expected a 4x4"):
        validate_T(np.eye(3), "objects[0].T")
    bad = np.eye(4)
    bad[0, 1] = np.nan
    with pytest.raises(GeometryError, match="NaN"):
        validate_T(bad, "T")
    skew = np.eye(4)
    skew[2, 0] = 0.5  # residual 0.5, like E-POSE's three_obj/potted_meat_can
    with pytest.raises(GeometryError, match="not orthonormal.*0.5"):
        validate_T(skew, "T")
    T, res = validate_T(skew, "T", repair=True)
    assert res == pytest.approx(0.5)
    assert rotation_residual(T[:3, :3]) < 1e-12
    row = np.eye(4)
    row[3, 0] = 1
    with pytest.raises(GeometryError, match="last row"):
        validate_T(row, "T")
