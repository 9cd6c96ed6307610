import json

import numpy as np
import pytest
import tomli_w

from evpose.core.data.event_writer import write_events_h5
from evpose.core.data.events import EventArray
from evpose.core.data.geometry import T_from_rotvec, apply_T, inv_T
from evpose.core.data.manifest import SceneError
from evpose.core.data.manifest_reader import load_manifest
from evpose.core.data.scene import Scene
from evpose.core.data.trajectory import Trajectory
from evpose.core.document.history import History

T0 = 1_700_000_000_000_000


def base_manifest():
    return {
        "format": "evpose-scene/1",
        "name": "tiny",
        "camera": {"width": 346, "height": 260,
                   "K": [[292.52, 0.0, 172.61], [0.0, 293.19, 130.125], [0.0, 0.0, 1.0]],
                   "dist": [-0.362, 0.115, 0.0009576, 0.00000455, 0.130]},
        "events": {"path": "events.h5"},
        "trajectory": {"path": "trajectory.csv", "frame": "cam"},
        "clock": {"offset_us": 1000, "skew_ppm": 0.0},
        "objects": [{"name": "box", "mesh": "models/box.ply", "mesh_scale": 1.0,
                     "T_base_obj": T_from_rotvec([0, 0, 0.3], [0.0, -0.75, 0.05]).tolist(), "class_id": 2}],
    }


@pytest.fixture
def scene_dir(tmp_path):
    import trimesh

    (tmp_path / "models").mkdir()
    trimesh.creation.box(extents=(0.1, 0.06, 0.1)).export(tmp_path / "models" / "box.ply")
    t = T0 + np.arange(0, 1_000_001, 10_000, dtype=np.int64)
    s = (t - T0) / 1e6
    pos = np.stack([0.1 * s, -0.4 + 0 * s, 0.4 + 0 * s], axis=1)
    from scipy.spatial.transform import Rotation

    q = Rotation.from_euler("x", (180 - 10 * s)[:, None], degrees=True).as_quat()
    Trajectory(t, pos, q).save_csv(tmp_path / "trajectory.csv")
    n = 1000
    ev_t = np.sort(np.random.default_rng(0).integers(T0 + 100_000, T0 + 900_000, n))
    write_events_h5(tmp_path / "events.h5", EventArray(np.zeros(n, np.uint16), np.zeros(n, np.uint16), ev_t,
                                                       np.ones(n, np.uint8)))
    (tmp_path / "scene.toml").write_text(tomli_w.dumps(base_manifest()))
    return tmp_path


def write(scene_dir, m):
    (scene_dir / "scene.toml").write_text(tomli_w.dumps(m))
    return scene_dir


def test_loads_and_resolves_relative_paths(scene_dir):
    m = load_manifest(scene_dir)
    assert m.name == "tiny" and m.events_path == scene_dir / "events.h5"
    assert m.objects[0].mesh == scene_dir / "models" / "box.ply"
    assert m.clock_offset_us == 1000 and m.warnings == []


@pytest.mark.parametrize("mutate,field", [
    (lambda m: m.pop("format"), "format"),
    (lambda m: m["camera"].update(K=[[1, 0], [0, 1]]), "camera: K"),
    (lambda m: m["camera"].update(dist=[0.1, 0.2]), "camera: dist"),
    (lambda m: m["camera"].pop("width"), "camera.width"),
    (lambda m: m["events"].update(path="missing.h5"), "events.path"),
    (lambda m: m["trajectory"].update(frame="robot"), "trajectory.frame"),
    (lambda m: m["trajectory"].update(frame="tcp"), "trajectory.hand_eye"),
    (lambda m: m["clock"].update(offset_us=1.5), "clock.offset_us"),
    (lambda m: m["clock"].update(skew_ppm=float("nan")), "clock.skew_ppm"),
    (lambda m: m["objects"][0].update(mesh="models/none.obj"), "objects[0].mesh"),
    (lambda m: m["objects"][0].update(mesh_scale=0), "objects[0].mesh_scale"),
    (lambda m: m["objects"][0].update(T_base_obj=[[1, 0, 0], [0, 1, 0], [0, 0, 1]]), "objects[0].T_base_obj"),
    (lambda m: m["objects"][0].update(T_base_obj=[[1, 0, 0, 0], [0, 1, 0, 0], [0, float("nan"), 1, 0], [0, 0, 0, 1]]),
     "objects[0].T_base_obj"),
    (lambda m: m["objects"].append(dict(m["objects"][0])), "objects[1].name"),
])
def test_errors_name_the_file_and_field(scene_dir, mutate, field):
    m = base_manifest()
    mutate(m)
    write(scene_dir, m)
    with pytest.raises(SceneError) as ei:
        load_manifest(scene_dir)
    msg = str(ei.value)
    assert str(scene_dir / "scene.toml") in msg and field in msg, msg


def test_non_orthonormal_rotation_reports_residual_and_repair_is_opt_in(scene_dir):
    m = base_manifest()
    T = np.array(m["objects"][0]["T_base_obj"])
    T[2, 0] = -0.55699  # E-POSE three_obj/potted_meat_can typo: residual ~0.5
    m["objects"][0]["T_base_obj"] = T.tolist()
    write(scene_dir, m)
    with pytest.raises(SceneError, match=r"objects\[0\].T_base_obj: rotation is not orthonormal \(max\|R R\^T - I\| = 0\.\d+"):
        load_manifest(scene_dir)
    m["objects"][0]["repair_rotation"] = True
    write(scene_dir, m)
    man = load_manifest(scene_dir)
    assert man.objects[0].rotation_residual > 0.3
    assert any("projected onto SO(3)" in w for w in man.warnings)


def test_bad_toml_and_missing_manifest(tmp_path):
    (tmp_path / "scene.toml").write_text("format = \n")
    with pytest.raises(SceneError, match="not valid TOML"):
        load_manifest(tmp_path)
    with pytest.raises(SceneError, match="manifest not found"):
        load_manifest(tmp_path / "nope")


def test_unknown_fields_warn(scene_dir):
    m = base_manifest()
    m["objects"][0]["mesh_scal"] = 0.001
    m["camera"]["fx"] = 1
    write(scene_dir, m)
    w = load_manifest(scene_dir).warnings
    assert any("objects[0].mesh_scal: unknown field" in x for x in w)
    assert any("camera.fx: unknown field" in x for x in w)


def test_manifest_save_roundtrip(scene_dir, tmp_path):
    man = load_manifest(scene_dir)
    man.save()
    again = load_manifest(scene_dir)
    np.testing.assert_array_equal(again.objects[0].T_base_obj, man.objects[0].T_base_obj)
    assert again.events_path == man.events_path


def test_T_cam_obj_matches_definition_and_corrections(scene_dir):
    scene = Scene.open(scene_dir)
    t_ev = np.array([T0 + 200_000, T0 + 500_000])
    T, valid = scene.T_cam_obj(t_ev)
    assert T.shape == (2, 1, 4, 4) and valid.all()
    clock = scene.clock
    assert clock.offset_us == 1000 and clock.t_ref_us == scene.events.t_first_us
    T_bc, _ = scene.trajectory.interpolate(clock.pose_time(t_ev))
    expected = inv_T(T_bc) @ scene.manifest.objects[0].T_base_obj
    np.testing.assert_allclose(T[:, 0], expected, atol=1e-12)

    h = History(scene.corrections)
    dT = T_from_rotvec([0, 0, 0.01], [0.002, 0, 0])
    h.set(("object", "box"), dT)
    h.set(("offset_us",), 4000)
    h.set(("hand_eye",), T_from_rotvec([0.001, 0, 0], [0, 0, 0.001]))
    T2, _ = scene.T_cam_obj(t_ev)
    T_bc2, _ = scene.trajectory.interpolate(scene.clock.pose_time(t_ev))
    assert scene.clock.offset_us == 5000
    expected2 = inv_T(T_bc2 @ scene.corrections.hand_eye_delta) @ dT @ scene.manifest.objects[0].T_base_obj
    np.testing.assert_allclose(T2[:, 0], expected2, atol=1e-12)


def test_labels_outside_trajectory_are_flagged_not_extrapolated(scene_dir):
    scene = Scene.open(scene_dir)
    T, valid = scene.T_cam_obj(np.array([T0 - 5000, T0 + 2_000_000]))
    assert not valid.any() and np.all(np.isfinite(T))


def test_corrections_autoload_and_save(scene_dir):
    scene = Scene.open(scene_dir)
    scene.corrections.set(("offset_us",), -10_000_000)
    p = scene.save_corrections()
    again = Scene.open(scene_dir)
    assert again.corrections.offset_us == -10_000_000 and again.clock.offset_us == -10_000_000 + 1000
    assert json.loads(p.read_text())["scene"] == "tiny"


def test_projected_object_lands_in_image(scene_dir):
    scene = Scene.open(scene_dir)
    T, _ = scene.T_cam_obj(np.array([T0 + 500_000]))
    uv, ok = scene.camera.project(apply_T(T[0, 0], scene.model("box").vertices_m))
    assert ok.all()


def test_scenes_share_a_mesh_loaded_alike_and_reload_an_edited_one(scene_dir):
    """The scenes of a dataset share their objects' models (core/data/model_cache: an export's driver and workers
    open sequence after sequence); the key is the file's identity and the load arguments, so a mesh edited in
    place, or the same file at another scale, is loaded anew."""
    import os

    import trimesh

    a, b = Scene.open(scene_dir), Scene.open(scene_dir)
    ma = a.model("box")
    assert b.model("box") is ma and b.raster_model("box") is a.raster_model("box")
    m = base_manifest()
    m["objects"][0]["mesh_scale"] = 0.5
    half = Scene.open(write(scene_dir, m))                   # the same file at half the scale
    assert half.model("box") is not ma
    assert np.allclose(half.model("box").vertices_m, ma.vertices_m * 0.5)
    write(scene_dir, base_manifest())
    trimesh.creation.box(extents=(0.2, 0.06, 0.1)).export(scene_dir / "models" / "box.ply")   # edited in place
    st = os.stat(scene_dir / "models" / "box.ply")
    os.utime(scene_dir / "models" / "box.ply", ns=(st.st_atime_ns, st.st_mtime_ns + 1_000_000))
    c = Scene.open(scene_dir)
    assert c.model("box") is not ma
    assert np.ptp(c.model("box").vertices_m[:, 0]) == pytest.approx(0.2)
