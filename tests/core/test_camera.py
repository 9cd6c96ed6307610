import json

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from evpose.core.data.camera import DAVIS346_DIST, DAVIS346_K, CameraError, CameraModel
from evpose.core.data.geometry import apply_T, make_T


@pytest.fixture
def cam():
    return CameraModel.davis346()


def test_projection_matches_cv2_projectpoints(cam):
    rng = np.random.default_rng(0)
    pts_obj = rng.uniform(-0.1, 0.1, size=(2000, 3))
    rvec = np.array([0.3, -0.2, 0.1])
    tvec = np.array([0.02, -0.01, 0.5])
    T = make_T(Rotation.from_rotvec(rvec).as_matrix(), tvec)
    uv, valid = cam.project(apply_T(T, pts_obj))
    ref, _ = cv2.projectPoints(pts_obj, rvec, tvec, np.array(DAVIS346_K), np.array(DAVIS346_DIST))
    assert valid.all()
    assert np.abs(uv - ref.reshape(-1, 2)).max() < 1e-6


def test_points_behind_or_on_the_camera_plane_are_never_projected(cam):
    pts = np.array([[0.1, 0.1, -0.5], [0.0, 0.0, 0.0], [0.01, 0.0, 1e-4], [0.01, 0.0, 0.002]])
    uv, valid = cam.project(pts)
    assert valid.tolist() == [False, False, False, True]
    assert np.isnan(uv[:3]).all() and np.isfinite(uv[3]).all()


def test_distortion_foldback_is_rejected():
    # k1 alone: r_d = r (1 + k1 r^2) peaks at r = 1/sqrt(-3 k1); beyond it points fold back inward.
    cam = CameraModel(DAVIS346_K, [-0.6, 0, 0, 0], 346, 260)
    assert cam.r_max == pytest.approx(1 / np.sqrt(1.8), abs=2e-4)
    far = np.array([[1.2, 0.0, 1.0]])  # r = 1.2: cv2 would put it back near the image
    naive, _ = cv2.projectPoints(far, np.zeros(3), np.zeros(3), cam.K, cam.dist)
    assert cam.in_image(naive.reshape(-1, 2))[0]  # the trap: it lands on the sensor
    uv, valid = cam.project(far)
    assert not valid[0]
    near_axis = np.array([[0.5, 0.0, 1.0]])
    assert cam.project(near_axis)[1][0]


def test_davis346_has_no_foldback_and_all_rays_valid(cam):
    assert cam.r_max == np.inf
    xy, ok = cam.pixel_rays()
    assert ok.all() and xy.shape == (260, 346, 2)
    back = cam.distort_normalized(xy.reshape(-1, 2))
    vv, uu = np.mgrid[0:260, 0:346]
    assert np.abs(back - np.stack([uu.ravel(), vv.ravel()], 1)).max() < 1e-6
    assert not xy.flags.writeable


def test_undistort_points_is_accurate(cam):
    rng = np.random.default_rng(3)
    xy = rng.uniform(-0.6, 0.6, size=(500, 2))
    uv = cam.distort_normalized(xy)
    np.testing.assert_allclose(cam.undistort_points(uv), xy, atol=1e-9)
    # with a new camera matrix we get pixels of the ideal camera
    uv_ideal = cam.undistort_points(uv, K_new=cam.K)
    np.testing.assert_allclose(uv_ideal, xy * [cam.K[0, 0], cam.K[1, 1]] + cam.K[:2, 2], atol=1e-7)


def test_undistortion_maps_cached_and_consistent(cam):
    m1 = cam.undistortion_maps()
    assert cam.undistortion_maps() is m1
    img = np.zeros((260, 346), np.uint8)
    u, v = cam.distort_normalized(np.array([[0.2, 0.1]]))[0]
    img[int(round(v)), int(round(u))] = 255
    und = cam.undistort_image(img)
    vv, uu = np.nonzero(und)
    expect = np.array([0.2, 0.1]) * [cam.K[0, 0], cam.K[1, 1]] + cam.K[:2, 2]
    assert len(uu) >= 1
    assert np.hypot(uu.mean() - expect[0], vv.mean() - expect[1]) < 1.0


def test_no_distortion_is_kept_as_given_not_forced():
    cam = CameraModel(DAVIS346_K, [], 346, 260)
    assert not cam.has_distortion and cam.r_max == np.inf
    uv, _ = cam.project(np.array([[0.1, 0.05, 1.0]]))
    np.testing.assert_allclose(uv[0], [0.1 * 292.52 + 172.61, 0.05 * 293.19 + 130.125])
    cam5 = CameraModel.davis346()
    assert cam5.has_distortion and len(cam5.dist) == 5


@pytest.mark.parametrize("K,dist,w,h,match", [
    (np.eye(2), [], 10, 10, "K: expected a 3x3"),
    ([[1, 0, 0], [0, 1, 0], [0, 0, 2]], [], 10, 10, "K: expected \\[\\[fx"),
    ([[-1, 0, 0], [0, 1, 0], [0, 0, 1]], [], 10, 10, "focal lengths"),
    ([[1, 0, 0], [0, 1, 0], [0, 0, 1]], [0.1, 0.2, 0.3], 10, 10, "dist: OpenCV takes"),
    ([[1, 0, 0], [0, 1, 0], [0, 0, 1]], [np.nan, 0, 0, 0], 10, 10, "dist: contains NaN"),
    ([[1, 0, 0], [0, 1, 0], [0, 0, 1]], [], 0, 10, "width/height"),
])
def test_invalid_parameters_are_named(K, dist, w, h, match):
    with pytest.raises(CameraError, match=match):
        CameraModel(K, dist, w, h, source="cam.json")


def test_from_json_matches_published_calibration(assets_dir):
    cam = CameraModel.from_json(assets_dir / "camera_davis346.json")
    ref = json.loads((assets_dir / "camera_davis346.json").read_text())
    np.testing.assert_array_equal(cam.K, ref["K"])
    np.testing.assert_array_equal(cam.dist, ref["dist"])
    builtin = CameraModel.davis346()
    np.testing.assert_array_equal(cam.K, builtin.K)
    np.testing.assert_array_equal(cam.dist, builtin.dist)
