"""Z-buffer rasteriser (core/raster.py) against open3d's ray caster with the same pixel rays.

The oracle casts, for every pixel centre, the ray ``(x_n, y_n, 1)`` of ``camera.pixel_rays()``
from the camera centre with ``o3d.t.geometry.RaycastingScene``; ``t_hit`` is then the
camera-frame depth ``z``. Hits closer than the near plane are not counted (the rasteriser clips
there by design).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from evpose.core.data.camera import CameraModel
from evpose.core.data.geometry import T_from_rotvec, apply_T, make_T
from evpose.core.data.objects import ObjectModel, box_model, cylinder_model
from evpose.core.label.raster import Rasterizer, RasterResult, _distort32_fn, _distort_fn

o3d = pytest.importorskip("open3d")

MODELS = Path(__file__).resolve().parents[2].parent / "shared/assets/epose/models"
H_DAVIS, W_DAVIS = 260, 346


# ---------------------------------------------------------------------------- helpers
def o3d_cast(camera: CameraModel, meshes):
    """open3d ray casting through every pixel centre: depth (inf), mesh index (-1), face index."""
    xy, valid = camera.pixel_rays()
    scene = o3d.t.geometry.RaycastingScene()
    for V, F in meshes:
        scene.add_triangles(o3d.core.Tensor(np.asarray(V, np.float32)), o3d.core.Tensor(np.asarray(F, np.uint32)))
    d = np.concatenate([np.nan_to_num(xy), np.ones(xy.shape[:2] + (1,))], axis=2)
    rays = np.concatenate([np.zeros_like(d), d], axis=2).astype(np.float32)
    ans = scene.cast_rays(o3d.core.Tensor(rays))
    t = ans["t_hit"].numpy()
    hit = np.isfinite(t) & valid & (t > camera.near_m)
    depth = np.where(hit, t, np.inf)
    obj = np.where(hit, ans["geometry_ids"].numpy().astype(np.int64), -1)
    face = np.where(hit, ans["primitive_ids"].numpy().astype(np.int64), -1)
    return depth, obj, face


def iou(a: np.ndarray, b: np.ndarray) -> float:
    union = np.count_nonzero(a | b)
    return 1.0 if union == 0 else np.count_nonzero(a & b) / union


def compare(res: RasterResult, camera: CameraModel, meshes, n: int, *, min_iou=0.99, min_agree=0.99,
            depth_tol=1e-5):
    """Assert the measured agreement with open3d; return (depth, obj) of the oracle."""
    depth, obj, face = o3d_cast(camera, meshes)
    for k in range(n):
        a, b = res.obj_index == k, obj == k
        assert iou(a, b) >= min_iou, f"mesh {k}: IoU {iou(a, b):.5f} ({a.sum()} vs {b.sum()} px)"
    covered = (res.obj_index >= 0) | (obj >= 0)
    agree = np.mean(res.obj_index[covered] == obj[covered]) if covered.any() else 1.0
    assert agree >= min_agree, f"object index agrees on {agree:.5f} of covered pixels"
    same = (res.obj_index == obj) & (obj >= 0)
    if same.any():
        err = np.abs(res.depth_m[same].astype(np.float64) - depth[same])
        assert err.max() <= depth_tol, f"depth differs by up to {err.max():.3g} m"
    return depth, obj, face


@pytest.fixture(scope="module")
def davis() -> CameraModel:
    return CameraModel.davis346()


@pytest.fixture(scope="module")
def raster(davis) -> Rasterizer:
    return Rasterizer(davis)


def fronto_box(size_xy, z_front, z_back, centre_xy=(0.0, 0.0)):
    """Axis-aligned box (camera frame) between depths z_front and z_back (metres)."""
    m = box_model("b", (size_xy[0], size_xy[1], z_back - z_front))
    return apply_T(make_T(np.eye(3), [centre_xy[0], centre_xy[1], (z_front + z_back) / 2]), m.vertices_m), m.faces


def posed(model: ObjectModel, T: np.ndarray):
    return apply_T(T, model.vertices_m), model.faces


# ---------------------------------------------------------------------------- agreement with open3d
def test_real_meshes_with_occlusion_match_open3d(raster, davis):
    if not MODELS.is_dir():
        pytest.skip(f"E-POSE meshes not found at {MODELS}")
    names = ["drill.obj", "cracker_box.obj", "mustard_bottle.stl"]
    models = [ObjectModel.from_file(MODELS / n) for n in names]
    # bbox-centred poses at 0.36-0.55 m, laterally close so that they occlude each other
    poses = [T_from_rotvec([0.3, 0.5, 0.1], [-0.03, 0.0, 0.45]) @ make_T(np.eye(3), -models[0].bbox_center_m),
             T_from_rotvec([1.2, -0.3, 0.4], [0.06, 0.02, 0.55]) @ make_T(np.eye(3), -models[1].bbox_center_m),
             T_from_rotvec([-1.3, 0.2, 0.0], [0.02, -0.01, 0.36]) @ make_T(np.eye(3), -models[2].bbox_center_m)]
    res = raster.render_objects(models, poses, want_faces=True)
    meshes = [posed(m, T) for m, T in zip(models, poses)]
    _, obj, face = compare(res, davis, meshes, 3)
    # the scene really has mutual occlusion: amodal masks overlap by hundreds of pixels
    full = raster.full_masks(models, poses)
    assert np.count_nonzero(full[0] & full[2]) > 500 and np.count_nonzero(full[0] & full[1]) > 500
    vis = res.visible_pixel_counts(3)
    assert all(vis[k] < np.count_nonzero(full[k]) for k in (0, 1))
    # the amodal masks equal single-object renders, and contain the modal masks
    for k in range(3):
        alone = raster.render_objects([models[k]], [poses[k]])
        assert np.array_equal(full[k], alone.obj_index == 0)
        assert not np.any(res.mask(k) & ~full[k])
    # face indices agree with open3d's primitive ids where both see the same mesh
    same = (res.obj_index == obj) & (obj >= 0)
    assert np.mean(res.face_index[same] == face[same]) >= 0.99


def test_procedural_meshes_with_occlusion_match_open3d(raster, davis):
    box, cyl = box_model("box", (0.12, 0.08, 0.1)), cylinder_model("cyl", 0.04, 0.15)
    box2 = box_model("b2", (0.3, 0.04, 0.05))
    poses = [T_from_rotvec([0.4, 0.6, 0.2], [-0.03, 0.01, 0.5]),
             T_from_rotvec([1.1, 0.0, 0.3], [0.04, -0.02, 0.38]),
             T_from_rotvec([0.0, 0.2, 0.9], [0.0, 0.03, 0.3])]
    models = [box, cyl, box2]
    res = raster.render_objects(models, poses, want_faces=True)
    meshes = [posed(m, T) for m, T in zip(models, poses)]
    _, obj, face = compare(res, davis, meshes, 3)
    full = raster.full_masks(models, poses)
    assert np.count_nonzero(full[0] & full[1]) > 300 and np.count_nonzero(full[1] & full[2]) > 300
    # same result through render() with float64 camera-frame vertices (render_objects poses
    # the models in float32: at most a pixel centre within ~1e-5 px of an edge may differ)
    res2 = raster.render(meshes, want_faces=True)
    assert np.count_nonzero(res2.obj_index != res.obj_index) <= 2
    hit = np.isfinite(res.depth_m) & (res2.obj_index == res.obj_index)
    assert np.abs(res2.depth_m[hit] - res.depth_m[hit]).max() < 1e-6
    same = (res.obj_index == obj) & (obj >= 0)
    assert np.mean(res.face_index[same] == face[same]) >= 0.99


def test_depth_is_exact_on_fronto_parallel_faces(raster, davis):
    V, F = fronto_box((0.2, 0.15), 0.4, 0.5)
    res = raster.render([(V, F)])
    m = res.obj_index == 0
    assert m.sum() > 10000
    assert np.abs(res.depth_m[m] - 0.4).max() < 2e-7          # float32 of 0.4 m
    assert np.all(np.isinf(res.depth_m[~m]))


# ---------------------------------------------------------------------------- occlusion
def test_exact_occlusion_two_boxes_and_swap(raster, davis):
    a_near = fronto_box((0.12, 0.1), 0.40, 0.45, (-0.03, 0.0))
    b_far = fronto_box((0.12, 0.1), 0.50, 0.55, (0.03, 0.01))
    res = raster.render([a_near, b_far])
    fa = raster.render([a_near]).obj_index == 0
    fb = raster.render([b_far]).obj_index == 0
    overlap = fa & fb
    assert overlap.sum() > 2000
    assert np.all(res.obj_index[overlap] == 0)                 # nearer box wins everywhere
    assert np.all(res.obj_index[fb & ~fa] == 1)
    assert np.allclose(res.depth_m[overlap], 0.40, atol=1e-6)
    # swap the depths: the other box wins on the same overlap
    a_far = (a_near[0] + [0, 0, 0.10], a_near[1])
    b_near = (b_far[0] - [0, 0, 0.10], b_far[1])
    res2 = raster.render([a_far, b_near])
    fa2 = raster.render([a_far]).obj_index == 0
    fb2 = raster.render([b_near]).obj_index == 0
    ov2 = fa2 & fb2
    assert ov2.sum() > 2000 and np.all(res2.obj_index[ov2] == 1)
    assert np.allclose(res2.depth_m[ov2], 0.40, atol=1e-6)
    counts = res2.visible_pixel_counts(2)
    assert counts.tolist() == [np.count_nonzero(res2.mask(0)), np.count_nonzero(res2.mask(1))]
    assert counts[1] == fb2.sum() and counts[0] == (fa2 & ~fb2).sum()


# ---------------------------------------------------------------------------- near plane
def test_table_plane_through_camera_plane(raster, davis):
    # 2 triangles, 4 m square, 8 cm below the camera (y down), from 1 m behind to 3 m ahead
    V = np.array([[-2.0, 0.08, -1.0], [2.0, 0.08, -1.0], [2.0, 0.08, 3.0], [-2.0, 0.08, 3.0]])
    F = np.array([[0, 1, 2], [0, 2, 3]])
    res = raster.render([(V, F)])
    compare(res, davis, [(V, F)], 1, min_iou=0.9995, depth_tol=1e-5 * 3.0)   # relative 1e-5 at 3 m
    xy, valid = davis.pixel_rays()
    covered = res.obj_index == 0
    assert covered.sum() > 30000
    # exactly the rays pointing down (y > 0) within the plane's extent can see it; none above
    assert not np.any(covered & (xy[..., 1] <= 0))
    assert np.all(res.depth_m[covered] > davis.near_m)
    # a plane tilted to pass through the camera centre is seen edge-on: nothing
    V2 = np.array([[-2.0, 0.0, -1.0], [2.0, 0.0, -1.0], [2.0, 0.0, 3.0], [-2.0, 0.0, 3.0]])
    assert np.all(raster.render([(V2, F)]).obj_index == -1)


def test_box_partly_behind_camera_and_close_to_lens(raster, davis):
    # beside the optical axis, straddling the camera plane: its inner face is seen up close
    near_box = fronto_box((0.04, 0.06), -0.05, 0.05, (0.025, 0.0))
    behind = fronto_box((0.3, 0.3), -0.6, -0.3)               # entirely behind: its mirror image
    mirror = (behind[0] * [1, 1, -1], behind[1])               # would fill the image centre
    res = raster.render([near_box, behind])
    depth, obj, _ = compare(res, davis, [near_box, behind], 2, min_iou=0.999)
    assert np.count_nonzero(res.obj_index == 0) > 5000          # close to the lens, not vanished
    assert np.count_nonzero(res.obj_index == 1) == 0            # nothing from behind
    assert np.count_nonzero(raster.render([mirror]).obj_index == 0) > 5000
    assert res.depth_m[res.obj_index == 0].min() > davis.near_m


# ---------------------------------------------------------------------------- distortion
def test_large_triangle_strong_barrel_distortion():
    cam = CameraModel(CameraModel.davis346().K, [-0.42, 0.18, 0.0, 0.0, -0.03])
    r = Rasterizer(cam)
    # vertices inside the fast-path disc: one triangle over most of the image, edges bent by
    # several pixels in the distorted image; and a bigger one reaching outside the disc
    tri_in = np.array([[-0.62, -0.42, 1.0], [0.63, -0.38, 1.0], [0.05, 0.45, 1.0]]) * 0.8
    tri_out = np.array([[-1.5, -0.9, 1.0], [1.4, -0.7, 1.0], [0.1, 1.3, 1.0]])
    assert np.hypot(tri_in[:, 0], tri_in[:, 1]).max() / 0.8 < r.r_lim
    assert np.hypot(tri_out[:, 0], tri_out[:, 1]).max() > r.r_lim
    F = np.array([[0, 1, 2]])
    for tri in (tri_in, tri_out):
        res = r.render([(tri, F)])
        depth, obj, _ = o3d_cast(cam, [(tri, F)])
        ours, ref = res.obj_index == 0, obj == 0
        assert ref.sum() > 20000
        assert np.count_nonzero(ref & ~ours) <= 1, "missed pixels"
        assert np.count_nonzero(ours & ~ref) <= 1
    # distortion bends the edges: the straight-edged triangle between the distorted vertices
    # misses thousands of the covered pixels, and without the bend margin on the candidate
    # boxes the rasteriser would miss >1000 of them too
    uv, _ = cam.project(tri_in)
    vv, uu = np.mgrid[0:cam.height, 0:cam.width]
    e = [(b[0] - a[0]) * (vv - a[1]) - (b[1] - a[1]) * (uu - a[0])
         for a, b in ((uv[0], uv[1]), (uv[1], uv[2]), (uv[2], uv[0]))]
    straight = ((e[0] >= 0) & (e[1] >= 0) & (e[2] >= 0)) | ((e[0] <= 0) & (e[1] <= 0) & (e[2] <= 0))
    _, obj, _ = o3d_cast(cam, [(tri_in, F)])
    assert np.count_nonzero((obj == 0) & ~straight) > 1000
    r._c = 0.0
    assert np.count_nonzero((obj == 0) & (r.render([(tri_in, F)]).obj_index != 0)) > 1000


def test_numpy_distortion_matches_opencv():
    K = CameraModel.davis346().K
    rng = np.random.default_rng(0)
    xy = rng.uniform(-0.8, 0.8, (2000, 2))
    for dist in ([-0.362, 0.115, 0.0009576, 4.55e-06, 0.13], [0.1, -0.05, 0.001, -0.002],
                 [-0.3, 0.1, 0.001, 0.002, 0.01, 0.05, 0.01, 0.002],
                 [-0.3, 0.1, 0.001, 0.002, 0.01, 0.05, 0.01, 0.002, 0.001, -0.002, 0.0005, 0.001]):
        cam = CameraModel(K, dist)
        ref = cam.distort_normalized(xy)
        u, v = _distort_fn(cam)(xy[:, 0], xy[:, 1])
        assert np.abs(np.stack([u, v], 1) - ref).max() < 1e-9
        x32, y32 = xy[:, 0].astype(np.float32), xy[:, 1].astype(np.float32)
        u, v = _distort32_fn(cam, None)(x32, y32, x32 * x32 + y32 * y32)
        assert np.abs(np.stack([u, v], 1) - ref).max() < 2e-4


# ---------------------------------------------------------------------------- cameras
def test_pinhole_camera():
    cam = CameraModel(CameraModel.davis346().K, [])
    r = Rasterizer(cam)
    _, valid = cam.pixel_rays()
    assert valid.all()
    box = box_model("b", (0.1, 0.08, 0.12))
    T = T_from_rotvec([0.5, -0.4, 0.3], [0.02, 0.01, 0.35])
    res = r.render_objects([box], [T])
    compare(res, cam, [posed(box, T)], 1, min_iou=0.999)
    # a table plane under a pinhole camera: large triangles stay on the fast path
    V = np.array([[-2.0, 0.1, 0.2], [2.0, 0.1, 0.2], [2.0, 0.1, 3.0], [-2.0, 0.1, 3.0]])
    F = np.array([[0, 1, 2], [0, 2, 3]])
    compare(r.render([(V, F)]), cam, [(V, F)], 1, min_iou=0.9995, depth_tol=3e-5)


def test_fold_back_radius_inside_image_renders_nothing_on_invalid_rays():
    cam = CameraModel(CameraModel.davis346().K, [-0.6, 0.0, 0.0, 0.0])
    assert cam.r_max < 0.75
    r = Rasterizer(cam)
    _, valid = cam.pixel_rays()
    assert 0.3 < valid.mean() < 0.95                        # the image corners are folded back
    # a wall filling the whole field of view
    V = np.array([[-5.0, -5.0, 1.0], [5.0, -5.0, 1.0], [5.0, 5.0, 1.0], [-5.0, 5.0, 1.0]])
    F = np.array([[0, 1, 2], [0, 2, 3]])
    res = r.render([(V, F)])
    assert np.array_equal(res.obj_index == 0, valid)
    # an object in the folded-back corner region: covered pixels only where rays are valid
    box = box_model("b", (0.3, 0.3, 0.1))
    T = make_T(np.eye(3), [0.4, 0.3, 0.7])
    res = r.render_objects([box], [T])
    assert np.count_nonzero(res.obj_index == 0) > 2000
    assert not np.any((res.obj_index >= 0) & ~valid)
    assert np.count_nonzero(r.render([(V, F)]).obj_index == 0) > 0
    compare(res, cam, [posed(box, T)], 1, min_iou=0.999)


# ---------------------------------------------------------------------------- edge cases
def test_empty_input(raster):
    for res in (raster.render([]), raster.render_objects([], [])):
        assert res.depth_m.shape == (H_DAVIS, W_DAVIS) and res.depth_m.dtype == np.float32
        assert res.obj_index.dtype == np.int16 and np.all(res.obj_index == -1)
        assert np.all(np.isinf(res.depth_m)) and res.face_index is None
        assert res.visible_pixel_counts(0).shape == (0,)
    res = raster.render([(np.zeros((0, 3)), np.zeros((0, 3), int))], want_faces=True)
    assert np.all(res.face_index == -1) and res.visible_pixel_counts(1).tolist() == [0]
    assert raster.full_masks([], []) == []


def test_meshes_outside_frustum_are_culled_before_triangle_work(davis):
    r = Rasterizer(davis)
    box = box_model("b", (0.1, 0.1, 0.1))
    poses = [make_T(np.eye(3), t) for t in ([0, 0, -0.5], [2.0, 0, 0.5], [0, -2.0, 0.5], [-3, 0, 0.4], [0, 0, -0.05])]
    res = r.render_objects([box] * len(poses), poses)
    assert np.all(res.obj_index == -1)
    assert "vertices" not in r.timings, "culled models must not reach the vertex stage"
    meshes = [posed(box, T) for T in poses]
    res = r.render(meshes)
    assert np.all(res.obj_index == -1)
    assert "triangle boxes" not in r.timings
    assert not any(m.any() for m in r.full_masks([box] * len(poses), poses))


def test_degenerate_and_edge_on_triangles_cover_nothing():
    # pinhole with integer principal point: the row v = 130 has rays with y = 0 exactly
    cam = CameraModel([[290.0, 0, 173.0], [0, 290.0, 130.0], [0, 0, 1]], [])
    r = Rasterizer(cam)
    V = np.array([[-0.2, 0.0, 1.0], [0.1, 0.0, 1.0], [0.3, 0.0, 1.0],     # collinear on y = 0
                  [0.0, 0.0, 1.0], [0.0, 0.0, 2.0], [0.1, 0.1, 1.5],      # plane through the camera
                  [-0.1, 0.05, 0.8], [-0.1, 0.05, 0.8], [0.2, 0.1, 0.8],  # repeated vertex
                  [-0.3, -0.3, 1.0], [-0.1, -0.3, 1.0], [-0.2, -0.1, 1.0]])  # a normal one
    F = np.arange(12).reshape(4, 3)
    res = r.render([(V, F)], want_faces=True)
    assert set(np.unique(res.face_index).tolist()) == {-1, 3}
    # the oracle gets the normal triangle alone: with the edge-on one in its scene, open3d
    # (Embree) misses 4 pixels of the normal triangle whose rays lie in the edge-on plane
    _, obj, _ = o3d_cast(cam, [(V[9:], np.array([[0, 1, 2]]))])
    assert (obj == 0).sum() > 1500 and np.array_equal(res.obj_index == 0, obj == 0)


def test_tie_rule_shared_edge_has_no_cracks():
    # a quad split along its diagonal, the diagonal passing exactly through pixel centres
    cam = CameraModel([[290.0, 0, 173.0], [0, 290.0, 130.0], [0, 0, 1]], [])
    r = Rasterizer(cam)
    s = 50 / 290.0                                          # 50 px at z = 1
    V = np.array([[-s, -s, 1.0], [s, -s, 1.0], [s, s, 1.0], [-s, s, 1.0]])
    F = np.array([[0, 1, 2], [0, 2, 3]])
    res = r.render([(V, F)], want_faces=True)
    m = res.obj_index == 0
    assert m.sum() == 101 * 101                              # closed: edge pixels are inside
    diag = np.array([res.face_index[130 + i, 173 + i] for i in range(-50, 51)])
    assert np.all(diag >= 0)


def test_input_validation(raster):
    box = box_model("b")
    with pytest.raises(ValueError):
        raster.render_objects([box], [])
    with pytest.raises(ValueError):
        raster.render([(np.zeros((3, 3)), np.array([[0, 1, 3]]))])
    with pytest.raises(ValueError):
        raster.render([(np.zeros((3, 2)), np.array([[0, 1, 2]]))])
    with pytest.raises(ValueError):
        raster.render([(np.array([[0, 0, 1.0], [np.nan, 0, 1], [0, 1, 1]]), np.array([[0, 1, 2]]))])


# ---------------------------------------------------------------------------- property test
@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.lists(st.floats(-1.0, 1.0), min_size=9, max_size=9), st.floats(0.05, 2.0), st.floats(-0.3, 0.5))
def test_random_triangles_match_open3d(raster, davis, coords, depth, dz):
    """Random triangles, some crossing the near plane or reaching outside the image."""
    c = np.asarray(coords).reshape(3, 3)
    V = np.column_stack([c[:, 0] * depth, c[:, 1] * depth, depth + c[:, 2] * (depth + dz)])
    F = np.array([[0, 1, 2]])
    res = raster.render([(V, F)])
    _, obj, _ = o3d_cast(davis, [(V, F)])
    ours, ref = res.obj_index == 0, obj == 0
    assert np.count_nonzero(ours != ref) <= 3, (np.count_nonzero(ours & ~ref), np.count_nonzero(ref & ~ours))


def test_rasterisers_share_one_byte_bounded_cache_of_derived_mesh_arrays():
    """Issue 25.4: the app's four annotators of one scene (frame, space-time slices, kymograph, residual sweep)
    derive the same arrays from the same read-only meshes: one cache holds them once, within its byte bound, and
    an entry goes with its mesh."""
    import gc

    from evpose.core.label.raster import MESH_ARRAYS, MeshArrayCache

    a = np.arange(3000, dtype=np.float64).reshape(-1, 3)
    a.setflags(write=False)
    cache = MeshArrayCache(max_bytes=3 * a.nbytes)
    made = []

    def make(x):
        made.append(1)
        return x * 2.0

    first = cache.get(a, "twice", make)
    assert cache.get(a, "twice", make) is first and len(made) == 1 and cache.nbytes == a.nbytes
    others = [np.full_like(a, k) for k in range(4)]
    for o in others:
        o.setflags(write=False)
        cache.get(o, "twice", make)
    assert cache.nbytes <= 3 * a.nbytes and len(cache) == 3           # least recently used out
    del others, o
    gc.collect()
    assert len(cache) == 0 and cache.nbytes == 0                      # entries go with their arrays
    w = np.ones((4, 3))                                               # writable: never cached
    assert cache.get(w, "twice", make) is not cache.get(w, "twice", make)
    assert Rasterizer(CameraModel.davis346())._cache is Rasterizer(CameraModel.davis346())._cache is MESH_ARRAYS
