"""Back-face culling of closed meshes (core/data/mesh_closure.py) changes no pixel.

The rasteriser skips back faces of meshes that :func:`cull_sign` proves closed and oriented, when every
vertex lies beyond the near plane. These tests compare it with the same render without culling
(read-write face arrays are never culled), on both backends: depth bits, object and face index and
amodal masks identical on the E-POSE YCB meshes and on procedural closed shapes; open or inside-out
meshes are not culled (a hole shows the inside, a back face), and a mesh crossing the near plane is not
culled (the clipped front lets the camera see the far side's back faces).
"""
from __future__ import annotations

import numpy as np
import pytest
import trimesh

from evpose.core.data.camera import CameraModel
from evpose.core.data.geometry import T_from_rotvec, make_T
from evpose.core.data.objects import ObjectModel, box_model, cylinder_model
from evpose.core.data.mesh_closure import cull_sign
from evpose.core.label.raster import Rasterizer
from tests.core.test_raster import MODELS

YCB = ["nine_hole_peg.stl", "wrench.stl", "mustard_bottle.stl", "drill.obj", "cracker_box.obj", "sugar_box.obj",
       "scissors.stl", "timer.obj"]


def unculled(model: ObjectModel) -> ObjectModel:
    """The same mesh with writable face arrays after construction (the rasteriser never culls those)."""
    m = ObjectModel(model.name, model.vertices_m, model.faces)
    m.faces = np.array(m.faces)          # writable copy
    return m


@pytest.fixture(scope="module", params=["numba", "numpy"])
def raster(request):
    path = MODELS.parent / "camera_davis346.json"
    cam = CameraModel.from_json(path) if path.is_file() else CameraModel.davis346()
    return Rasterizer(cam, backend=request.param)


def assert_same_with_and_without(r: Rasterizer, models, poses) -> int:
    """Culled render == unculled render (every output); returns the number of covered pixels."""
    plain = [unculled(m) for m in models]
    a = r.render_objects(models, poses, want_faces=True, want_amodal=True)
    b = r.render_objects(plain, poses, want_faces=True, want_amodal=True)
    assert np.array_equal(a.obj_index, b.obj_index), f"{np.count_nonzero(a.obj_index != b.obj_index)} px differ"
    assert np.array_equal(a.face_index, b.face_index)
    assert np.array_equal(a.depth_m.view(np.uint32), b.depth_m.view(np.uint32))
    assert np.array_equal(a.amodal, b.amodal)
    for m, mp, full in zip(models, plain, a.amodal):
        assert np.array_equal(r.full_mask(m, poses[models.index(m)]), full)
    return int(np.count_nonzero(a.obj_index >= 0))


def random_poses(models, rng, z0=0.35):
    return [T_from_rotvec(rng.normal(0, 1.2, 3), [0.06 * (k - len(models) / 2) + rng.normal(0, 0.01),
                                                   rng.normal(0, 0.02), z0 + 0.04 * k])
            @ make_T(np.eye(3), -m.bbox_center_m) for k, m in enumerate(models)]


def test_cull_sign_of_closed_open_and_inverted_meshes():
    box = trimesh.creation.box((0.1, 0.2, 0.3))
    assert cull_sign(box.vertices, box.faces) == 1
    assert cull_sign(box.vertices, box.faces[:, ::-1]) == -1            # inside-out
    assert cull_sign(box.vertices, box.faces[1:]) == 0                   # a hole
    flipped_one = box.faces.copy()
    flipped_one[0] = flipped_one[0, ::-1]
    assert cull_sign(box.vertices, flipped_one) == 0                     # inconsistent winding
    # split along a 'seam' (duplicate vertices with the same coordinates, as OBJ files have): still closed
    V = box.vertices[box.faces.ravel()]
    assert cull_sign(V, np.arange(len(V)).reshape(-1, 3)) == 1
    # two pieces, one inside-out: not culled; both outward: culled
    other = trimesh.creation.icosphere(subdivisions=1, radius=0.05)
    V2 = np.vstack([box.vertices, other.vertices + 1.0])
    assert cull_sign(V2, np.vstack([box.faces, other.faces + 8])) == 1
    assert cull_sign(V2, np.vstack([box.faces, other.faces[:, ::-1] + 8])) == 0
    # a face repeating a vertex covers nothing and does not break closedness
    assert cull_sign(box.vertices, np.vstack([box.faces, [[0, 0, 1]]])) == 1


@pytest.mark.assets
def test_every_ycb_mesh_is_culled_and_no_pixel_changes(raster):
    if not all((MODELS / n).is_file() for n in YCB):
        pytest.skip(f"E-POSE meshes not found at {MODELS}")
    models = [ObjectModel.from_file(MODELS / n) for n in YCB]
    assert [cull_sign(m.vertices_m, m.faces) for m in models] == [1] * len(YCB)
    rng = np.random.default_rng(7)
    for group in (models[:3], models[3:6], models[5:]):
        for _ in range(2):
            assert assert_same_with_and_without(raster, group, random_poses(group, rng)) > 2000


def test_procedural_shapes_no_pixel_changes(raster):
    models = [box_model("box", (0.12, 0.08, 0.1)), cylinder_model("cyl", 0.04, 0.15),
              ObjectModel.from_trimesh(trimesh.creation.icosphere(subdivisions=4, radius=0.05), "ball")]
    assert [cull_sign(m.vertices_m, m.faces) for m in models] == [1, 1, 1]
    rng = np.random.default_rng(3)
    for z0 in (0.25, 0.6):
        assert assert_same_with_and_without(raster, models, random_poses(models, rng, z0)) > 1000


def test_open_mesh_shows_its_inside_and_is_not_culled(raster):
    """A box without its front face, seen through the hole: the far wall's inner side (a back face)
    is what the camera sees. Not culled: its pixels are covered."""
    box = trimesh.creation.box((0.1, 0.1, 0.1))
    normals = box.face_normals
    keep = ~(normals[:, 2] < -0.9)                   # drop the two triangles facing -z (the camera)
    open_box = ObjectModel("open", box.vertices, box.faces[keep])
    assert cull_sign(open_box.vertices_m, open_box.faces) == 0
    T = make_T(np.eye(3), [0.0, 0.0, 0.4])
    res = raster.render_objects([open_box], [T])
    h, w = res.obj_index.shape
    assert res.obj_index[h // 2, w // 2] == 0          # the inside of the far wall
    assert_same_with_and_without(raster, [open_box], [T])


def test_mesh_across_the_near_plane_is_not_culled(raster):
    """The camera inside a closed box (or the near plane cutting it): the walls around it are seen
    from inside, i.e. as back faces. They must all be drawn."""
    box = box_model("room", (0.4, 0.4, 0.4))
    T = make_T(np.eye(3), -box.bbox_center_m)        # box centred on the camera
    n = assert_same_with_and_without(raster, [box], [T])
    assert n > 0.9 * raster.width * raster.height


def test_scene_pays_the_closure_check_when_it_loads_a_model(tiny_scene_dir, monkeypatch):
    """The first frame must not pay for cull_sign (20-70 ms per YCB mesh): Scene.raster_model computes
    it, and renders reuse it (also from other rasterisers and for posed copies of the vertices)."""
    from evpose.core.data import mesh_closure, model_cache
    from evpose.core.data.scene import Scene

    model_cache.clear()        # models another test of this process loaded would be shared (computed there)
    calls = []
    real = mesh_closure.cull_sign
    monkeypatch.setattr(mesh_closure, "cull_sign", lambda V, F: calls.append(len(F)) or real(V, F))
    scene = Scene.open(tiny_scene_dir)
    models = [scene.raster_model(n) for n in scene.object_names]
    assert len(calls) == len(models)
    r = Rasterizer(CameraModel.davis346())
    r.render_objects(models, random_poses(models, np.random.default_rng(0)))
    Rasterizer(CameraModel.davis346()).full_masks(models, random_poses(models, np.random.default_rng(1)))
    assert len(calls) == len(models)
    assert mesh_closure.cached_cull_sign(models[0].vertices_m, np.array(models[0].faces)) == 0   # writable


def test_meshes_across_the_image_border_no_pixel_changes(raster, monkeypatch):
    """Objects straddling the image border and corners (vertices beyond the fast-path disc take the tile
    path): with every vertex in front of the near plane, back faces and faces outside every pixel's ray are
    left out of the tile path too. Renders equal the unculled ones, and the tile path did run."""
    tiled = []
    real = Rasterizer._tile_path

    def spy(self, V, FT, t, *a):
        tiled.append(len(t))
        return real(self, V, FT, t, *a)

    monkeypatch.setattr(Rasterizer, "_tile_path", spy)
    models = [box_model("box", (0.12, 0.08, 0.1)), cylinder_model("cyl", 0.04, 0.15),
              ObjectModel.from_trimesh(trimesh.creation.icosphere(subdivisions=4, radius=0.05), "ball")]
    rng = np.random.default_rng(11)
    covered = 0
    for x, y, z in ((0.1, 0.0, 0.12), (0.15, 0.05, 0.15), (-0.12, 0.08, 0.12), (0.2, 0.1, 0.2)):   # close, at the edge
        poses = [T_from_rotvec(rng.normal(0, 1.2, 3), [x + 0.02 * k, y - 0.015 * k, z + 0.04 * k])
                 @ make_T(np.eye(3), -m.bbox_center_m) for k, m in enumerate(models)]
        tiled.clear()
        covered += assert_same_with_and_without(raster, models, poses)
        assert sum(tiled) > 0, "the tile path did not run: the poses do not reach past the fast-path disc"
    assert covered > 3000
