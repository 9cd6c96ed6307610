"""Overlay geometry (evpose.core.label.overlay) pinned against independent references.

Pixel convention: OpenCV's, pixel centres at integers. Contours are polylines through the
centres of the mask's boundary pixels; axes and box edges are the projections of 3D points as
``cv2.projectPoints`` computes them (distortion included). The last test checks the same
through :class:`~evpose.core.views.frame.FrameComputer` on the tiny synthetic scene.
"""
from __future__ import annotations

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from evpose.core.data.camera import CameraModel
from evpose.core.data.geometry import apply_T, inv_T, make_T
from evpose.core.data.objects import BBOX_EDGES, box_model
from evpose.core.label.overlay import (
    EVENT_COLORS,
    PALETTE,
    adjust_contrast,
    axes_segments,
    box_segments,
    compose_masks_rgba,
    drawn_objects,
    mask_contours,
    object_color,
)
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

    from evpose.core.views.frame import FrameComputer, FrameRequest
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


# ---------------------------------------------------------------------- display (issue 16)
def _lab(rgb) -> np.ndarray:
    """CIE L*a*b* of an sRGB colour (OpenCV's 8-bit Lab rescaled to L 0..100, a and b centred)."""
    lab = cv2.cvtColor(np.uint8([[rgb]]), cv2.COLOR_RGB2LAB)[0, 0].astype(float)
    return lab * [100 / 255, 1, 1] - [0, 128, 128]


def _hue_deg(rgb) -> float:
    import colorsys

    return 360.0 * colorsys.rgb_to_hsv(*(c / 255 for c in rgb))[0]


def test_object_colours_are_distinct_from_the_event_colours():
    """Red and blue objects blended into the ON / OFF events (issue 16): no object colour is near red, blue or
    magenta in hue, nor within a large colour difference of them, including their pale tints on white."""
    events = list(EVENT_COLORS.values())
    assert (255, 0, 0) in events and (0, 0, 255) in events
    tints = [tuple(int(255 - 0.4 * (255 - c)) for c in e) for e in events]     # 40 % ink on white
    for k in range(len(PALETTE)):
        c = object_color(k)
        for e in events:
            d = abs(_hue_deg(c) - _hue_deg(e)) % 360
            assert min(d, 360 - d) >= 25, (c, e)
            assert np.linalg.norm(_lab(c) - _lab(e)) > 50, (c, e)
        for t in tints:
            assert np.linalg.norm(_lab(c) - _lab(t)) > 40, (c, t)
    # and from each other (the first five: a 5-object scene)
    for a in range(5):
        for b in range(a):
            assert np.linalg.norm(_lab(object_color(a)) - _lab(object_color(b))) > 25


def test_contrast_strengthens_faint_ink_and_keeps_background_and_saturation():
    img = np.array([[[255, 255, 255], [230, 230, 230], [255, 200, 200], [0, 0, 0], [255, 0, 0]]], np.uint8)
    assert adjust_contrast(img, 1.0) is img
    out = adjust_contrast(img, 3.0)
    np.testing.assert_array_equal(out[0, [0, 3, 4]], img[0, [0, 3, 4]])     # white, black, pure red stay
    assert out[0, 1, 0] < 200                                                # faint grey darkens a lot
    assert out[0, 2, 0] == 255 and out[0, 2, 1] < 150                        # pale red turns redder
    dark = adjust_contrast(np.array([[[20, 0, 255]]], np.uint8), 3.0, background="black")
    assert dark[0, 0, 0] > 100 and dark[0, 0, 1] == 0 and dark[0, 0, 2] == 255
    with pytest.raises(ValueError):
        adjust_contrast(img, 0.0)


def test_drawn_objects_for_hidden_and_selected_only():
    names = ["a", "b", "c"]
    assert drawn_objects(names, frozenset({"b"}), "a", False) == [True, False, True]
    assert drawn_objects(names, frozenset(), "c", True) == [False, False, True]
    assert drawn_objects(names, frozenset({"c"}), "c", True) == [False, False, False]
    assert drawn_objects(names, frozenset(), None, True) == [True, True, True]      # nothing selected: all
