"""Overlay geometry (evpose.core.label.overlay) pinned against independent references.

Pixel convention: OpenCV's, pixel centres at integers. Contours are polylines through the
centres of the mask's boundary pixels; axes and box edges are the projections of 3D points as
``cv2.projectPoints`` computes them (distortion included). The last test checks the same
through :class:`~evpose.core.session.frames.FrameComputer` on the tiny synthetic scene.
"""
from __future__ import annotations

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from evpose.core.data.camera import CameraModel
from evpose.core.data.geometry import apply_T, inv_T, make_T
from evpose.core.data.objects import BBOX_EDGES, box_model
from evpose.core.label.overlay import axes_segments, box_segments, compose_masks_rgba, mask_contours
from evpose.core.label.raster import Rasterizer

#: a rotation whose columns are all different from +-e_x, +-e_y, +-e_z and from each other's
#: permutations: a reversed axis or swapped columns moves every projected tip
R_GENERIC = Rotation.from_rotvec([0.4, -0.7, 0.3]).as_matrix()


def pinhole_camera() -> CameraModel:
    K = [[150.0, 0.0, 80.3], [0.0, 150.0, 59.7], [0.0, 0.0, 1.0]]
    return CameraModel(K, (), 160, 120)


def distorted_camera() -> CameraModel:
    cam = CameraModel.davis346()
    return CameraModel(cam.K, cam.dist, cam.width, cam.height)


def cv_project(camera: CameraModel, T_cam_obj: np.ndarray, pts_obj: np.ndarray) -> np.ndarray:
    """Reference projection: ``cv2.projectPoints`` of object-frame points (N, 3) -> (N, 2)."""
    rvec, _ = cv2.Rodrigues(T_cam_obj[:3, :3])
    dist = camera.dist if len(camera.dist) else np.zeros(0)
    uv, _ = cv2.projectPoints(np.asarray(pts_obj, np.float64).reshape(-1, 1, 3), rvec, T_cam_obj[:3, 3], camera.K,
                              dist)
    return uv.reshape(-1, 2)


def polygon_centroid(poly: np.ndarray) -> np.ndarray:
    m = cv2.moments(np.asarray(poly, np.float32))
    return np.array([m["m10"] / m["m00"], m["m01"] / m["m00"]])


# ---------------------------------------------------------------------- contours
def test_contour_vertices_are_the_boundary_pixel_centres():
    mask = np.zeros((20, 30), bool)
    mask[4:11, 7:19] = True                       # rows 4..10, columns 7..18
    (c,) = mask_contours(mask)
    assert c.dtype == np.float64
    np.testing.assert_array_equal(c[0], c[-1])    # closed
    assert {tuple(p) for p in c[:-1]} == {(7.0, 4.0), (18.0, 4.0), (18.0, 10.0), (7.0, 10.0)}
    # a ring: outer and inner boundary, every vertex an integer pixel of the mask on its border
    ring = np.zeros((20, 30), bool)
    ring[2:15, 3:25] = True
    ring[6:10, 9:17] = False
    cs = mask_contours(ring)
    assert len(cs) == 2
    inner = min(cs, key=lambda p: np.ptp(p[:, 0]))
    # the hole (rows 6..9, columns 9..16) is bounded by the 8-connected ring pixels around it
    assert {tuple(p) for p in inner[:-1]} == {(8.0, 6.0), (9.0, 5.0), (16.0, 5.0), (17.0, 6.0),
                                              (17.0, 9.0), (16.0, 10.0), (9.0, 10.0), (8.0, 9.0)}
    for p in np.concatenate(cs):
        u, v = p
        assert u == int(u) and v == int(v) and ring[int(v), int(u)]
    assert mask_contours(np.zeros((5, 5), bool)) == []


@pytest.mark.parametrize("rotvec", [(0.3, -0.5, 0.2), (-0.6, 0.9, 1.3), (1.0, 0.1, 0.5)])
def test_projected_contour_matches_the_projected_silhouette(rotvec):
    """The outline of a rendered box lies on cv2.projectPoints' silhouette (the convex hull of the
    projected corners under a pinhole camera): same centroid to 0.2 px (measured: at most 0.05), every
    vertex a pixel centre inside it and within a pixel of its border."""
    cam = pinhole_camera()
    model = box_model("b", (0.10, 0.06, 0.14))
    T_cam_obj = make_T(Rotation.from_rotvec(rotvec).as_matrix(), [0.013, -0.021, 0.4])
    mask = Rasterizer(cam).render_objects([model], [T_cam_obj]).mask(0)
    hull = cv2.convexHull(cv_project(cam, T_cam_obj, model.bbox_corners()).astype(np.float32)).reshape(-1, 2)
    (c,) = mask_contours(mask)
    assert np.abs(polygon_centroid(c) - polygon_centroid(hull)).max() < 0.2
    d = np.array([cv2.pointPolygonTest(hull.reshape(-1, 1, 2), (float(u), float(v)), True) for u, v in c])
    assert d.min() > -1e-3 and d.max() < 1.0     # inside (positive), less than a pixel from the border


# ---------------------------------------------------------------------- axes and box
@pytest.mark.parametrize("camera", [pinhole_camera(), distorted_camera()], ids=["pinhole", "distorted"])
def test_axes_are_the_projected_object_axes(camera):
    origin_obj = np.array([0.01, -0.02, 0.015])
    L = 0.05
    T_cam_obj = make_T(R_GENERIC, [0.02, -0.01, 0.45])
    axes = axes_segments(camera, T_cam_obj, L, origin_obj, samples=8)
    assert len(axes) == 3
    o_uv = cv_project(camera, T_cam_obj, origin_obj[None])[0]
    for k, segs in enumerate(axes):
        assert segs.shape == (8, 2, 2)
        tip_obj = origin_obj + L * np.eye(3)[k]
        np.testing.assert_allclose(segs[0, 0], o_uv, atol=1e-6)
        np.testing.assert_allclose(segs[-1, 1], cv_project(camera, T_cam_obj, tip_obj[None])[0], atol=1e-6,
                                   err_msg=f"tip of axis {'xyz'[k]}")
        # the whole polyline follows the lens: every sample is the projection of the 3D segment
        s = np.linspace(0.0, 1.0, 9)[:, None]
        ref = cv_project(camera, T_cam_obj, origin_obj + s * (tip_obj - origin_obj))
        np.testing.assert_allclose(segs[:, 0], ref[:-1], atol=1e-6)
        np.testing.assert_allclose(segs[:, 1], ref[1:], atol=1e-6)


def test_box_wireframe_is_the_projected_box():
    cam = distorted_camera()
    model = box_model("b", (0.10, 0.06, 0.14), max_edge_m=None)
    T_cam_obj = make_T(R_GENERIC, [0.0, 0.01, 0.5])
    corners_obj = model.bbox_corners()
    segs = box_segments(cam, apply_T(T_cam_obj, corners_obj), samples_per_edge=4)
    assert segs.shape == (len(BBOX_EDGES) * 4, 2, 2)
    ref = cv_project(cam, T_cam_obj, corners_obj)
    for e, (i, j) in enumerate(BBOX_EDGES):
        np.testing.assert_allclose(segs[4 * e, 0], ref[i], atol=1e-6)
        np.testing.assert_allclose(segs[4 * e + 3, 1], ref[j], atol=1e-6)


def test_compose_masks_colours_each_object_and_leaves_the_rest_transparent():
    label_map = np.array([[-1, 0, 1], [1, 1, -1]], np.int16)
    rgba = compose_masks_rgba(label_map, [(10, 20, 30), (40, 50, 60)], alpha=0.5, visible=[True, False])
    assert rgba.shape == (2, 3, 4) and rgba.dtype == np.uint8
    assert rgba[0, 1].tolist() == [10, 20, 30, 128]
    assert rgba[0, 0, 3] == 0 and rgba[1, 0, 3] == 0 and rgba[1, 2, 3] == 0    # background, hidden object


# ---------------------------------------------------------------------- through the frame computer
@pytest.fixture(scope="module")
def tiny_frame(tiny_scene_dir):
    from dataclasses import replace

    from evpose.core.session.frames import FrameComputer, FrameRequest
    from evpose.core.session.model import Session

    s = Session.open(tiny_scene_dir)
    s.set_time(s.time_range[0] + 300_000)          # mid-motion: every object in view
    req = s.request()
    data = FrameComputer().frame(FrameRequest(req.scene, replace(req.view, overlays=("contour", "axes"))))
    yield s.scene, data
    s.close()


def test_frame_overlays_line_up_with_the_projection(tiny_frame):
    """FrameData's axes are cv2.projectPoints of inv(T_base_cam) @ T_base_obj at the label time
    (from the box centre, half a diameter long), and its contours run through the centres of the
    object's own boundary pixels in the label map (not half a pixel off)."""
    scene, data = tiny_frame
    assert data.labels.valid and len(data.overlays) == len(scene.object_names)
    t = np.array([data.window.t_label_us])
    T_bc, ok = scene.T_base_cam(t)
    assert ok[0]
    lab = data.labels.label_map
    for k, ov in enumerate(data.overlays):
        name = scene.object_names[k]
        assert ov.name == name
        model = scene.model(name)
        T_cam_obj = inv_T(T_bc[0]) @ scene.T_base_obj(name)
        o = model.bbox_center_m
        o_uv = cv_project(scene.camera, T_cam_obj, o[None])[0]
        for a in range(3):
            tip = o + 0.5 * model.diameter_m * np.eye(3)[a]
            np.testing.assert_allclose(ov.axes[a][0, 0], o_uv, atol=1e-6)
            np.testing.assert_allclose(ov.axes[a][-1, 1], cv_project(scene.camera, T_cam_obj, tip[None])[0],
                                       atol=1e-6, err_msg=f"{name} axis {'xyz'[a]}")
        assert ov.contours, name
        pts = np.concatenate(ov.contours)
        np.testing.assert_array_equal(pts, np.round(pts))          # pixel centres
        u, v = pts[:, 0].astype(int), pts[:, 1].astype(int)
        assert np.all(lab[v, u] == k), name                        # on the object
        padded = np.pad(lab, 1, constant_values=-1)
        border = ((padded[v, u + 1] != k) | (padded[v + 2, u + 1] != k) | (padded[v + 1, u] != k)
                  | (padded[v + 1, u + 2] != k))
        assert border.all(), name                                  # on its border
