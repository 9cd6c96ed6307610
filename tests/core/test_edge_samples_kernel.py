"""The compiled contour sampler (evpose.core.align.edge_samples_kernel) returns exactly what the numpy reference
path of evpose.core.align.contours._edge_samples returns: procedural meshes with open boundaries and a real YCB
mesh, views from all sides, edges behind the near plane, a degenerate (edge-on) projection."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from evpose.core.align import contours, edge_samples_kernel
from evpose.core.align.mesh_edges import MeshEdges
from evpose.core.data.camera import CameraModel
from evpose.core.data.geometry import make_T
from evpose.core.data.objects import ObjectModel, box_model, cylinder_model

pytestmark = pytest.mark.skipif(not edge_samples_kernel.HAVE_NUMBA, reason="numba not importable")


def _camera():
    return CameraModel(np.array([[290.0, 0, 173], [0, 290.0, 130], [0, 0, 1]]), np.zeros(5))


def _views(n, rng, dist_m):
    """Camera <- object poses looking at the object from random directions, some with the object half behind
    the near plane."""
    out = []
    for k in range(n):
        R = Rotation.random(random_state=rng).as_matrix()
        t = np.array([*rng.normal(0, 0.02, 2), dist_m if k % 5 else 0.02])   # every 5th: cut by the near plane
        out.append(make_T(R, t))
    return out


def _same(cam, me, T, spacing):
    a = contours._edge_samples(cam, me, T, spacing, compiled=False)
    b = contours._edge_samples(cam, me, T, spacing, compiled=True)
    if a is None or b is None:
        assert a is None and b is None
        return 0
    for x, y in zip(a, b):
        assert x.shape == y.shape
        np.testing.assert_allclose(y, x, rtol=0, atol=1e-12)
    return len(a[0])


def _open_cylinder():
    """A cylinder without its caps: every rim edge is an open boundary."""
    m = cylinder_model("tube", 0.03, 0.1, sections=24)
    V = np.asarray(m.vertices_m)
    F = np.asarray(m.faces)
    z = V[:, 2]
    side = np.ptp(z[F], axis=1) > 1e-9          # faces spanning the height: the mantle
    return ObjectModel("tube", V, F[side])


@pytest.mark.parametrize("make", [lambda: box_model("box", (0.1, 0.06, 0.16)), _open_cylinder],
                         ids=["box", "open_cylinder"])
def test_kernel_matches_numpy_on_procedural_meshes(make):
    cam, rng = _camera(), np.random.default_rng(3)
    me = MeshEdges(make())
    n = [_same(cam, me, T, s) for T in _views(20, rng, 0.4) for s in (0.5, 2.0)]
    assert sum(n) > 1000                        # the views did see contours


def test_kernel_matches_numpy_on_a_ycb_mesh(models_dir):
    cam, rng = _camera(), np.random.default_rng(4)
    me = MeshEdges(ObjectModel.from_file(models_dir / "mustard_bottle.stl"))
    assert sum(_same(cam, me, T, 0.5) for T in _views(10, rng, 0.5)) > 1000


def test_degenerate_projection_is_bounded():
    """An edge seen end-on projects to one point (one sample); an edge grazing the near plane to a huge length
    (capped per edge)."""
    cam = _camera()
    me = MeshEdges(box_model("cube", (0.1, 0.1, 0.1), max_edge_m=None))
    T = make_T(np.eye(3), np.array([0.0, 0.0, 0.0511]))        # front face 0.1 mm in front of the 1 mm near plane
    n = _same(cam, me, T, 0.5)
    assert 0 < n <= len(me.edges) * edge_samples_kernel.MAX_SAMPLES_PER_EDGE
