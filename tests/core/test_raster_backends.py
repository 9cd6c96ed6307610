"""The numba rasteriser (core/label/raster_kernels.py) against the numpy pipeline it replaces.

Both backends of :class:`Rasterizer` must give the same depth (bit for bit), object index,
face index and amodal masks (also from the one-pass ``render_objects(want_amodal=True)``): on the shared tiny scene's objects, on procedural scenes that take
every path (one-pixel, 2 x 2 and long boxes, near-plane clipping, pixels off the image, a
zero-area triangle, the pinhole model) and on real YCB meshes (skipped without the assets), where
the masks also match open3d's ray caster (IoU 1.0000).
"""
from __future__ import annotations

import threading

import numpy as np
import pytest

from evpose.core.data.camera import CameraModel
from evpose.core.data.geometry import T_from_rotvec, make_T
from evpose.core.data.objects import ObjectModel, box_model, cylinder_model
from evpose.core.label import raster_kernels
from evpose.core.label import raster as raster_module
from evpose.core.label.raster import Rasterizer, _balanced_groups, warm_up
from tests.core.test_raster import MODELS, o3d_cast, iou, posed

pytestmark = pytest.mark.skipif(not raster_kernels.HAVE_NUMBA, reason="numba not importable")


def _camera_json() -> CameraModel:
    path = MODELS.parent / "camera_davis346.json"
    return CameraModel.from_json(path) if path.is_file() else CameraModel.davis346()


@pytest.fixture(scope="module")
def pair():
    cam = _camera_json()
    return Rasterizer(cam, backend="numpy"), Rasterizer(cam, backend="numba")


def assert_same(old: Rasterizer, new: Rasterizer, models, poses) -> None:
    """Identical depth, object and face index, and amodal masks."""
    a = old.render_objects(models, poses, want_faces=True)
    b = new.render_objects(models, poses, want_faces=True)
    assert np.array_equal(a.obj_index, b.obj_index), f"{np.count_nonzero(a.obj_index != b.obj_index)} px differ"
    assert np.array_equal(a.face_index, b.face_index)
    assert np.array_equal(a.depth_m.view(np.uint32), b.depth_m.view(np.uint32))   # same float32 bits
    full = old.full_masks(models, poses)
    for ma, mb in zip(full, new.full_masks(models, poses)):
        assert np.array_equal(ma, mb)
    for r in (old, new):       # one pass: the same z-buffer plus the amodal masks of full_masks
        c = r.render_objects(models, poses, want_faces=True, want_amodal=True)
        assert np.array_equal(c.obj_index, a.obj_index) and np.array_equal(c.face_index, a.face_index)
        assert np.array_equal(c.depth_m.view(np.uint32), a.depth_m.view(np.uint32))
        assert c.amodal.shape == (len(models),) + a.obj_index.shape
        for k, m in enumerate(full):
            assert np.array_equal(c.amodal[k], m), (r.backend, k, np.count_nonzero(c.amodal[k] != m))
    assert a.amodal is None


def test_backends_are_named_and_checked():
    cam = CameraModel.davis346()
    assert Rasterizer(cam).backend == "numba"
    assert Rasterizer(cam, backend="numpy").backend == "numpy"
    with pytest.raises(ValueError):
        Rasterizer(cam, backend="cuda")


def test_same_output_on_tiny_scene_objects(pair, tiny_scene_dir):
    from evpose.core.data.scene import Scene

    scene = Scene.open(tiny_scene_dir)
    models = [scene.raster_model(n) for n in scene.object_names] + [scene.model(n) for n in scene.object_names]
    poses = [T_from_rotvec([0.3 * k, 0.5, 0.1], [0.02 * k - 0.02, 0.01, 0.3 + 0.05 * k]) @
             make_T(np.eye(3), -m.bbox_center_m) for k, m in enumerate(models)]
    old, new = pair
    assert_same(old, new, models, poses)
    assert np.count_nonzero(new.render_objects(models, poses).obj_index >= 0) > 1000


def test_same_output_on_every_path(pair):
    old, new = pair
    box, cyl = box_model("box", (0.12, 0.08, 0.1)), cylinder_model("cyl", 0.04, 0.15)
    fine = ObjectModel.from_trimesh(__import__("trimesh").creation.icosphere(subdivisions=5, radius=0.05), "s")
    table = ObjectModel("table", np.array([[-1.5, 0.12, -1.0], [1.5, 0.12, -1.0], [1.5, 0.12, 2.0],
                                           [-1.5, 0.12, 2.0], [0.0, 0.0, 1.0]]),
                        np.array([[0, 1, 2], [0, 2, 3], [4, 4, 4]]))        # near-plane crossing; zero area
    models = [box, cyl, fine, table, box]
    poses = [T_from_rotvec([0.4, 0.6, 0.2], [-0.03, 0.01, 0.5]),
             T_from_rotvec([1.1, 0.0, 0.3], [0.04, -0.02, 0.38]),
             T_from_rotvec([0.2, 0.1, 0.0], [0.0, 0.02, 0.7]),          # sub-pixel and 2 x 2 triangles
             np.eye(4),
             T_from_rotvec([0.0, 0.3, 0.0], [0.33, 0.0, 0.4])]           # across the image border
    assert_same(old, new, models, poses)
    pinhole = CameraModel(CameraModel.davis346().K, [])
    assert_same(Rasterizer(pinhole, backend="numpy"), Rasterizer(pinhole, backend="numba"), models, poses)


def every_path_scene():
    """Models and poses of :func:`test_same_output_on_every_path`."""
    box, cyl = box_model("box", (0.12, 0.08, 0.1)), cylinder_model("cyl", 0.04, 0.15)
    fine = ObjectModel.from_trimesh(__import__("trimesh").creation.icosphere(subdivisions=5, radius=0.05), "s")
    table = ObjectModel("table", np.array([[-1.5, 0.12, -1.0], [1.5, 0.12, -1.0], [1.5, 0.12, 2.0],
                                           [-1.5, 0.12, 2.0], [0.0, 0.0, 1.0]]),
                        np.array([[0, 1, 2], [0, 2, 3], [4, 4, 4]]))
    poses = [T_from_rotvec([0.4, 0.6, 0.2], [-0.03, 0.01, 0.5]), T_from_rotvec([1.1, 0.0, 0.3], [0.04, -0.02, 0.38]),
             T_from_rotvec([0.2, 0.1, 0.0], [0.0, 0.02, 0.7]), np.eye(4),
             T_from_rotvec([0.0, 0.3, 0.0], [0.33, 0.0, 0.4])]
    return [box, cyl, fine, table, box], poses


@pytest.mark.parametrize("threads", [2, 3])
def test_threads_give_the_same_output(pair, monkeypatch, threads):
    """Meshes split over threads, each group into its own z-buffer, merged by the minimum key: identical
    depth bits, object and face index and amodal masks (tile path and near-plane clipping included)."""
    monkeypatch.setattr(raster_module, "_PARALLEL_MIN_FACES", 0)
    one = pair[1]
    par = Rasterizer(one.camera, threads=threads)
    models, poses = every_path_scene()
    assert_same(one, par, models, poses)
    assert par.timings.get("merge", 0.0) > 0.0          # the threaded path ran
    # a mesh of a later group nearer than one of the first group: the merge must keep the nearer
    front = [T_from_rotvec([0.0, 0.0, 0.0], [0.0, 0.0, 0.45]), T_from_rotvec([0.0, 0.0, 0.0], [0.0, 0.0, 0.35])]
    assert_same(one, par, [box_model("a", (0.1, 0.1, 0.1)), box_model("b", (0.05, 0.05, 0.05))], front)


def test_balanced_groups():
    assert _balanced_groups([0, 1, 2], [65536, 40000, 42000], 2) == [[0], [2, 1]]
    assert sorted(_balanced_groups([4, 7], [10, 10], 3)) == [[4], [7]]   # never an empty group
    groups = _balanced_groups(list(range(6)), [5, 9, 2, 7, 1, 3], 2)
    assert sorted(k for g in groups for k in g) == list(range(6)) and len(groups) == 2


REAL_SETS = [["drill.obj", "cracker_box.obj", "mustard_bottle.stl"],
             ["nine_hole_peg.stl", "wrench.stl", "mustard_bottle.stl", "sugar_box.obj", "scissors.stl"]]


@pytest.mark.assets
@pytest.mark.parametrize("names", REAL_SETS, ids=["3 objects", "5 objects"])
def test_same_output_on_real_meshes_and_open3d_iou_1(pair, names):
    if not all((MODELS / n).is_file() for n in names):
        pytest.skip(f"E-POSE meshes not found at {MODELS}")
    old, new = pair
    models = [ObjectModel.from_file(MODELS / n) for n in names]
    rng = np.random.default_rng(3)
    for frame in range(3):        # mutually occluding, 0.35-0.6 m, jittered per frame
        poses = [T_from_rotvec(rng.normal(0, 1.0, 3), [0.05 * (k - 2) + rng.normal(0, 0.005), rng.normal(0, 0.02),
                                                         0.35 + 0.05 * k]) @ make_T(np.eye(3), -m.bbox_center_m)
                 for k, m in enumerate(models)]
        assert_same(old, new, models, poses)
    assert_same(new, Rasterizer(new.camera, threads=2), models, poses)      # two threads, same bits
    res = new.render_objects(models, poses)
    depth, obj, _ = o3d_cast(new.camera, [posed(m, T) for m, T in zip(models, poses)])
    for k in range(len(models)):
        assert iou(res.obj_index == k, obj == k) >= 0.99995, k
    same = (res.obj_index == obj) & (obj >= 0)
    err = np.abs(res.depth_m[same].astype(np.float64) - depth[same])
    assert np.quantile(err, 0.999) < 1e-6 and err.max() < 1e-5          # float32 keys; grazing faces


def test_warm_up_compiles_off_the_first_frame():
    assert warm_up() >= 0.0
    cam = CameraModel.davis346()
    r = Rasterizer(cam)
    t = threading.Thread(target=r.warm_up)          # as the app does at start-up
    t.start()
    t.join()
    assert r.timings == {}                          # the warm-up frames are not counted
    box = box_model("b", (0.1, 0.08, 0.12))
    res = r.render_objects([box], [T_from_rotvec([0.5, -0.4, 0.3], [0.02, 0.01, 0.35])])
    assert np.count_nonzero(res.obj_index == 0) > 1000 and "kernel" in r.timings
