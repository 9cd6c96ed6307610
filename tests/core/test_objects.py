import numpy as np
import pytest

from evpose.core.data.objects import BBOX_EDGES, ObjectModel, ObjectModelError, box_model, cylinder_model


def test_bbox_margin_enlarges_on_every_side():
    m = box_model("b", (0.1, 0.2, 0.3))
    c0 = m.bbox_corners()
    c1 = m.bbox_corners(margin_m=0.001)
    np.testing.assert_allclose(np.abs(c1) - np.abs(c0), 0.001)  # every coordinate moves outward by 1 mm
    np.testing.assert_allclose(c1.mean(0), c0.mean(0), atol=1e-15)  # centre unchanged: enlarged, not shifted
    assert len(BBOX_EDGES) == 12
    for i, j in BBOX_EDGES:
        assert np.count_nonzero(c0[i] != c0[j]) == 1


def test_diameter_and_centre():
    m = box_model("b", (0.1, 0.2, 0.3))
    assert m.diameter_m == pytest.approx(np.sqrt(0.01 + 0.04 + 0.09))
    c = cylinder_model("c", radius_m=0.05, height_m=0.1, sections=64)
    assert c.diameter_m == pytest.approx(np.sqrt(0.1**2 + 0.1**2), rel=1e-3)
    np.testing.assert_allclose(c.bbox_center_m, 0, atol=1e-12)


def test_mesh_scale_and_formats(tmp_path):
    import trimesh

    mesh = trimesh.creation.box(extents=(100, 50, 20))  # millimetres
    for ext in ("stl", "ply", "obj"):
        p = tmp_path / f"m.{ext}"
        mesh.export(p)
        m = ObjectModel.from_file(p, mesh_scale=0.001)
        np.testing.assert_allclose(m.bbox_min_max[1] - m.bbox_min_max[0], [0.1, 0.05, 0.02], atol=1e-9)


def test_bad_mesh_files_are_named(tmp_path):
    with pytest.raises(ObjectModelError, match="nope.obj: mesh file not found"):
        ObjectModel.from_file(tmp_path / "nope.obj")
    bad = tmp_path / "bad.stl"
    bad.write_bytes(b"\x00garbage")
    with pytest.raises(ObjectModelError, match="bad.stl"):
        ObjectModel.from_file(bad)
    with pytest.raises(ObjectModelError, match="mesh_scale"):
        ObjectModel.from_file(bad, mesh_scale=-1)
    with pytest.raises(ObjectModelError, match="faces: vertex index out of range"):
        ObjectModel("x", np.zeros((3, 3)), np.array([[0, 1, 3]]))


def test_published_meshes_load_geometry_only(models_dir):
    """The YCB OBJ files reference texture images that are missing: geometry must still load."""
    files = sorted(p for p in models_dir.iterdir() if p.suffix in (".obj", ".stl", ".ply"))
    assert len(files) >= 10
    for p in files:
        m = ObjectModel.from_file(p)
        assert len(m.faces) > 10_000, p.name
        assert 0.05 < m.diameter_m < 0.5, (p.name, m.diameter_m)  # metres, as published
