"""BOP export: exact poses after ground-truth corrections, exact clock round trip through the
sidecar, masks of the undistorted camera vs open3d, layout. JSON is read back with the plain json
module (an independent reader). BOP's own definitions (pixel origin, calc_gt_info, models, targets)
are checked independently in tests/core/test_export_bop_toolkit.py."""
import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from evpose.core.data.scene import Scene
from evpose.core.document.corrections import ReviewMark
from evpose.core.export import export_scene
from evpose.core.label.event_frames.undistort import undistorter_for
from evpose.core.sim.synth import load_ground_truth


def read_trajectory(scene_dir):
    data = np.loadtxt(Path(scene_dir) / "trajectory.csv", delimiter=",", skiprows=1, dtype=object)
    return data[:, 0].astype(np.int64), data[:, 1:4].astype(np.float64), data[:, 4:8].astype(np.float64)


def T_base_cam_at(traj, t_pose_us: float) -> np.ndarray:
    t, pos, q = traj
    i = int(np.searchsorted(t, int(np.floor(t_pose_us)), side="right") - 1)
    i = min(max(i, 0), len(t) - 2)
    a = (t_pose_us - t[i]) / float(t[i + 1] - t[i])
    assert -1e-9 <= a <= 1 + 1e-9
    T = np.eye(4)
    T[:3, :3] = Slerp([0.0, 1.0], Rotation.from_quat(q[i:i + 2]))([a]).as_matrix()[0]
    T[:3, 3] = pos[i] + a * (pos[i + 1] - pos[i])
    return T


def pose_time(t_event, offset_us, skew_ppm, t_ref):
    """Independent clock model (DESIGN section 3), in float relative arithmetic."""
    return t_event + offset_us + skew_ppm * 1e-6 * (t_event - t_ref)


def set_ground_truth(scene, gt):
    scene.corrections.set(("offset_us",), gt["clock"]["offset_us"] - scene.manifest.clock_offset_us)
    scene.corrections.set(("skew_ppm",), gt["clock"]["skew_ppm"] - scene.manifest.clock_skew_ppm)
    for n in scene.object_names:
        T_true = np.array(gt["objects"][n]["T_base_obj"])
        scene.corrections.set(("object", n), T_true @ np.linalg.inv(scene.manifest.object(n).T_base_obj))


@pytest.fixture(scope="module")
def gt_export(tiny_scene_dir, tmp_path_factory):
    base = tmp_path_factory.mktemp("bop")
    scene_dir = base / "scene"
    shutil.copytree(tiny_scene_dir, scene_dir)
    gt = load_ground_truth(scene_dir)
    scene = Scene.open(scene_dir)
    set_ground_truth(scene, gt)
    scene.save_corrections()
    scene.close()
    out = base / "out"
    s = export_scene(scene_dir, "bop", out)
    return scene_dir, out, s, gt


def test_poses_equal_ground_truth(gt_export):
    scene_dir, out, s, gt = gt_export
    assert s.written == s.windows_total == 80
    sd = out / "test" / "000000"
    scene_gt = json.loads((sd / "scene_gt.json").read_text())
    times = json.loads((sd / "scene_times.json").read_text())
    cams = json.loads((sd / "scene_camera.json").read_text())
    info = json.loads((out / "models" / "models_info.json").read_text())
    assert set(scene_gt) == set(times) == set(cams) and len(scene_gt) == 80
    traj = read_trajectory(scene_dir)
    names = list(gt["objects"])
    ids = [gt["objects"][n]["class_id"] for n in names]
    assert sorted(int(k) for k in info) == sorted(ids)
    c = gt["clock"]
    worst_t = worst_R = 0.0
    for im_id, entries in scene_gt.items():
        t_label = times[im_id]["t_label_us"]
        T_bc = T_base_cam_at(traj, pose_time(t_label, c["offset_us"], c["skew_ppm"], c["t_ref_us"]))
        assert [e["obj_id"] for e in entries] == ids
        for e, n in zip(entries, names):
            T = np.linalg.inv(T_bc) @ np.array(gt["objects"][n]["T_base_obj"])
            worst_t = max(worst_t, np.abs(np.array(e["cam_t_m2c"]) - T[:3, 3] * 1000.0).max())
            worst_R = max(worst_R, np.abs(np.array(e["cam_R_m2c"]).reshape(3, 3) - T[:3, :3]).max())
        T_cb = np.linalg.inv(T_bc)
        np.testing.assert_allclose(np.array(cams[im_id]["cam_t_w2c"]), T_cb[:3, 3] * 1000.0, atol=1e-6)
        np.testing.assert_allclose(np.array(cams[im_id]["cam_R_w2c"]).reshape(3, 3), T_cb[:3, :3], atol=1e-9)
    assert worst_t <= 1e-6, worst_t      # mm
    assert worst_R <= 1e-9, worst_R


def test_layout_and_gt_info(gt_export):
    scene_dir, out, s, gt = gt_export
    sd = out / "test" / "000000"
    scene = Scene.open(scene_dir)
    H, W = scene.camera.height, scene.camera.width
    cams = json.loads((sd / "scene_camera.json").read_text())
    ginfo = json.loads((sd / "scene_gt_info.json").read_text())
    cam_json = json.loads((out / "camera.json").read_text())
    assert cam_json["fx"] == scene.camera.K[0, 0] and cam_json["width"] == W
    assert cam_json["cx"] == scene.camera.K[0, 2] + 0.5 and cam_json["cy"] == scene.camera.K[1, 2] + 0.5
    for im_id in list(ginfo)[::9]:
        i = int(im_id)
        K_bop = scene.camera.K.copy()
        K_bop[:2, 2] += 0.5                                                 # BOP: pixel origin at the corner
        assert cams[im_id]["cam_K"] == K_bop.ravel().tolist()               # K_new = K by default
        rgb = cv2.imread(str(sd / "rgb" / f"{i:06d}.png"), cv2.IMREAD_UNCHANGED)
        assert rgb.shape == (H, W, 3) and not rgb[..., 1].any()             # ON red, OFF blue, G = 0
        for g, e in enumerate(ginfo[im_id]):
            full = cv2.imread(str(sd / "mask" / f"{i:06d}_{g:06d}.png"), cv2.IMREAD_UNCHANGED)
            vis = cv2.imread(str(sd / "mask_visib" / f"{i:06d}_{g:06d}.png"), cv2.IMREAD_UNCHANGED)
            assert set(np.unique(full)) <= {0, 255} and set(np.unique(vis)) <= {0, 255}
            # px_count_all also counts the silhouette outside the image (calc_gt_info)
            assert e["px_count_all"] >= int((full > 0).sum()) and e["px_count_visib"] == int((vis > 0).sum())
            assert not ((vis > 0) & (full == 0)).any()
            assert e["px_count_valid"] <= e["px_count_all"]
            assert e["visib_fract"] == pytest.approx(e["px_count_visib"] / e["px_count_all"] if e["px_count_all"] else 0)
            if e["px_count_visib"]:
                ys, xs = np.nonzero(vis)
                assert e["bbox_visib"] == [int(xs.min()), int(ys.min()),
                                           int(xs.max() - xs.min()), int(ys.max() - ys.min())]
    ply = (out / "models" / "obj_000001.ply").read_bytes()
    assert ply.startswith(b"ply")
    models_info = json.loads((out / "models" / "models_info.json").read_text())
    lo, hi = scene.model("box").bbox_min_max
    assert models_info["1"]["size_x"] == pytest.approx((hi[0] - lo[0]) * 1000)
    assert models_info["1"]["diameter"] == pytest.approx(scene.model("box").diameter_m * 1000)


def mask_box(mask: np.ndarray) -> list[int]:
    """BOP ``[x, y, w, h]`` of a 0/255 mask image (``misc.calc_2d_bbox``: w = x_max - x_min; independent of
    the exporter), [-1] * 4 when empty."""
    ys, xs = np.nonzero(mask)
    if len(xs) == 0:
        return [-1, -1, -1, -1]
    return [int(xs.min()), int(ys.min()), int(xs.max() - xs.min()), int(ys.max() - ys.min())]


def test_models_written_in_millimetres(gt_export):
    """The PLY models are in mm (BOP): their vertices are the scene's meshes x 1000, their extents and
    diameter agree with models_info.json and with the built-in objects' known sizes (box 90 x 60 x 150 mm)."""
    import trimesh
    from scipy.spatial.distance import pdist

    scene_dir, out, _, gt = gt_export
    scene = Scene.open(scene_dir)
    info = json.loads((out / "models" / "models_info.json").read_text())
    known_mm = {"box": (90.0, 60.0, 150.0), "flatbox": (150.0, 100.0, 45.0), "cylinder": (70.0, 70.0, 120.0)}
    for n in scene.object_names:
        oid = gt["objects"][n]["class_id"]
        ply = trimesh.load(out / "models" / f"obj_{oid:06d}.ply", process=False)
        V = np.asarray(ply.vertices, np.float64)
        np.testing.assert_allclose(V, scene.model(n).vertices_m * 1000.0, rtol=1e-6, atol=1e-4)   # float32 in the file
        size = V.max(0) - V.min(0)
        e = info[str(oid)]
        np.testing.assert_allclose(size, [e["size_x"], e["size_y"], e["size_z"]], atol=1e-3)
        np.testing.assert_allclose(V.min(0), [e["min_x"], e["min_y"], e["min_z"]], atol=1e-3)
        np.testing.assert_allclose(size, known_mm[n], atol=0.01)
        assert pdist(V).max() == pytest.approx(e["diameter"], abs=1e-3)
        if n == "cylinder":     # a solid of revolution about its z axis through its centre (the BOP toolkit's form)
            (sym,) = e["symmetries_continuous"]
            np.testing.assert_allclose(np.abs(sym["axis"]), [0.0, 0.0, 1.0], atol=1e-6)
            np.testing.assert_allclose(sym["offset"], (V.max(0) + V.min(0)) / 2, atol=0.5)
        else:                   # the boxes' symmetries are discrete: none continuous
            assert "symmetries_continuous" not in e
    assert info["1"]["diameter"] == pytest.approx(np.sqrt(90.0**2 + 60.0**2 + 150.0**2), abs=0.01)


@pytest.fixture(scope="module")
def occluded_export(occlusion_scene_dir, tmp_path_factory):
    """Three windows of the occlusion scene (tests/occlusion_scene.py) exported as BOP."""
    base = tmp_path_factory.mktemp("bop-occlusion")
    scene_dir = base / "scene"
    shutil.copytree(occlusion_scene_dir, scene_dir)
    scene = Scene.open(scene_dir)
    t0 = scene.events.t_first_us + 50_000
    scene.corrections.set(("reviews",), [ReviewMark(t0, t0 + 30_000, "verified")])
    out = base / "out"
    s = export_scene(scene, "bop", out, only_verified=True)
    assert s.written == 3
    return scene, out


def _occluded_instances(scene, out):
    """``(image id, gt index, scene_gt entry, scene_gt_info entry, mask, mask_visib)`` of the occluded cube."""
    from occlusion_scene import OCCLUDED

    sd = out / "test" / "000000"
    scene_gt = json.loads((sd / "scene_gt.json").read_text())
    ginfo = json.loads((sd / "scene_gt_info.json").read_text())
    g = scene.object_names.index(OCCLUDED)
    for im_id in scene_gt:
        i = int(im_id)
        full = cv2.imread(str(sd / "mask" / f"{i:06d}_{g:06d}.png"), cv2.IMREAD_UNCHANGED)
        vis = cv2.imread(str(sd / "mask_visib" / f"{i:06d}_{g:06d}.png"), cv2.IMREAD_UNCHANGED)
        yield im_id, g, scene_gt[im_id][g], ginfo[im_id][g], full, vis


def test_amodal_mask_of_an_occluded_object(occluded_export):
    """mask/ is the amodal mask: for a cube that another cube half hides it differs from mask_visib/,
    contains it, and equals a render of the cube alone (evpose's rasteriser with only that object, and
    open3d ray casting) in the undistorted camera."""
    from evpose.core.label.raster import Rasterizer

    scene, out = occluded_export
    cam = scene.camera.undistorted()
    alone = Rasterizer(cam)
    n = 0
    for im_id, g, e, info, full, vis in _occluded_instances(scene, out):
        full, vis = full > 0, vis > 0
        assert 0 < vis.sum() < 0.8 * full.sum(), (im_id, vis.sum(), full.sum())   # really occluded
        assert not (vis & ~full).any()
        assert info["px_count_all"] >= int(full.sum()) and info["px_count_visib"] == int(vis.sum())
        T = np.eye(4)
        T[:3, :3] = np.array(e["cam_R_m2c"]).reshape(3, 3)
        T[:3, 3] = np.array(e["cam_t_m2c"]) / 1000.0
        model = scene.model(scene.object_names[g])
        assert np.array_equal(full, alone.render_objects([model], [T]).mask(0))
        n += 1
    assert n == 3
    o3d = pytest.importorskip("open3d")
    K = cam.K
    vv, uu = np.mgrid[0:cam.height, 0:cam.width].astype(np.float64)
    dirs = np.stack([(uu - K[0, 2]) / K[0, 0], (vv - K[1, 2]) / K[1, 1], np.ones_like(uu)], axis=-1)
    rays = o3d.core.Tensor(np.concatenate([np.zeros_like(dirs), dirs], axis=-1).astype(np.float32))
    for im_id, g, e, info, full, vis in _occluded_instances(scene, out):
        model = scene.model(scene.object_names[g])
        V = model.vertices_m @ np.array(e["cam_R_m2c"]).reshape(3, 3).T + np.array(e["cam_t_m2c"]) / 1000.0
        rc = o3d.t.geometry.RaycastingScene()
        rc.add_triangles(o3d.core.Tensor(V.astype(np.float32)), o3d.core.Tensor(model.faces.astype(np.uint32)))
        ref = np.isfinite(rc.cast_rays(rays)["t_hit"].numpy())
        full = full > 0
        assert (full & ref).sum() / (full | ref).sum() >= 0.99


def test_bbox_obj_is_the_amodal_box(occluded_export):
    """bbox_obj is the box of the whole (amodal) silhouette, bbox_visib that of the visible mask (both
    checked against the PNGs): bbox_visib equals the visible mask's box, bbox_obj contains the amodal
    mask's box and equals it where the object stays in the image; for the half-hidden cube the two differ."""
    scene, out = occluded_export
    sd = out / "test" / "000000"
    ginfo = json.loads((sd / "scene_gt_info.json").read_text())
    H, W = scene.camera.height, scene.camera.width
    for im_id, entries in ginfo.items():
        for g, e in enumerate(entries):
            full = cv2.imread(str(sd / "mask" / f"{int(im_id):06d}_{g:06d}.png"), cv2.IMREAD_UNCHANGED)
            vis = cv2.imread(str(sd / "mask_visib" / f"{int(im_id):06d}_{g:06d}.png"), cv2.IMREAD_UNCHANGED)
            assert e["bbox_visib"] == mask_box(vis), (im_id, g)
            if not vis.any():
                continue
            x, y, w, h = e["bbox_obj"]
            fx, fy, fw, fh = mask_box(full)
            assert x <= fx and y <= fy and x + w >= fx + fw and y + h >= fy + fh, (im_id, g)
            if e["px_count_all"] == int((full > 0).sum()):                   # all of it in the image
                assert e["bbox_obj"] == mask_box(full), (im_id, g)
            else:
                assert x < 0 or y < 0 or x + w > W - 1 or y + h > H - 1, (im_id, g)
    differ = [info["bbox_obj"] != info["bbox_visib"] for *_, info, full, vis in _occluded_instances(scene, out)]
    assert differ == [True] * 3


def test_rgb_preserves_event_counts(gt_export):
    """Events are moved to undistorted pixels one by one (never resampled as an image)."""
    scene_dir, out, s, _ = gt_export
    scene = Scene.open(scene_dir)
    times = json.loads((out / "test" / "000000" / "scene_times.json").read_text())
    und = undistorter_for(scene.camera)
    for im_id in list(times)[10:70:15]:
        t = times[im_id]
        ev = scene.events.window(t["t_start_us"], t["t_end_us"])
        assert len(ev) == t["n_events"]
        evu = und.apply(ev)
        assert len(evu) == t["n_events_in_image"]
        rgb = cv2.imread(str(out / "test" / "000000" / "rgb" / f"{int(im_id):06d}.png"))[..., ::-1]
        lit = np.zeros(rgb.shape[:2], bool)
        lit[evu.y, evu.x] = True
        assert np.array_equal(rgb.max(axis=2) > 0, lit)
        on = np.zeros_like(lit)
        on[evu.y[evu.p == 1], evu.x[evu.p == 1]] = True
        assert not (rgb[..., 0] > 0)[~on].any()


def test_masks_match_open3d_in_undistorted_camera(gt_export):
    o3d = pytest.importorskip("open3d")
    scene_dir, out, s, gt = gt_export
    scene = Scene.open(scene_dir)
    sd = out / "test" / "000000"
    scene_gt = json.loads((sd / "scene_gt.json").read_text())
    K = scene.camera.K
    H, W = scene.camera.height, scene.camera.width
    vv, uu = np.mgrid[0:H, 0:W].astype(np.float64)
    dirs = np.stack([(uu - K[0, 2]) / K[0, 0], (vv - K[1, 2]) / K[1, 1], np.ones_like(uu)], axis=-1)
    rays = np.concatenate([np.zeros_like(dirs), dirs], axis=-1).astype(np.float32)
    names = list(gt["objects"])
    checked = 0
    for im_id in list(scene_gt)[3::19]:
        i = int(im_id)
        rc = o3d.t.geometry.RaycastingScene()
        gids = []
        for e, n in zip(scene_gt[im_id], names):
            R = np.array(e["cam_R_m2c"]).reshape(3, 3)
            t = np.array(e["cam_t_m2c"]) / 1000.0
            m = scene.model(n)
            V = m.vertices_m @ R.T + t
            gids.append(rc.add_triangles(o3d.core.Tensor(V.astype(np.float32)), o3d.core.Tensor(m.faces.astype(np.uint32))))
            alone = o3d.t.geometry.RaycastingScene()
            alone.add_triangles(o3d.core.Tensor(V.astype(np.float32)), o3d.core.Tensor(m.faces.astype(np.uint32)))
            ref_full = np.isfinite(alone.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy())
            full = cv2.imread(str(sd / "mask" / f"{i:06d}_{len(gids) - 1:06d}.png"), cv2.IMREAD_UNCHANGED) > 0
            if ref_full.sum() >= 30:
                assert (full & ref_full).sum() / (full | ref_full).sum() >= 0.99
        gid = rc.cast_rays(o3d.core.Tensor(rays))["geometry_ids"].numpy()
        for g, gd in enumerate(gids):
            ref = gid == gd
            vis = cv2.imread(str(sd / "mask_visib" / f"{i:06d}_{g:06d}.png"), cv2.IMREAD_UNCHANGED) > 0
            if ref.sum() < 30:
                continue
            iou = (vis & ref).sum() / (vis | ref).sum()
            assert iou >= 0.99, (im_id, g, iou)
            checked += 1
    assert checked >= 4


def _shift_trajectory(scene_dir, shift_us: int) -> None:
    """Move the pose clock by shift_us (text edit of the time column, other columns untouched)."""
    p = Path(scene_dir) / "trajectory.csv"
    lines = p.read_text().splitlines()
    out = [lines[0]]
    for line in lines[1:]:
        t, rest = line.split(",", 1)
        out.append(f"{int(t) + shift_us},{rest}")
    p.write_text("\n".join(out) + "\n")


@pytest.mark.parametrize("shift_us,skew_ppm", [(10_000_000, 1000.0), (-10_000_000, -1000.0)])
def test_extreme_clock_round_trips_exactly(tiny_scene_dir, tmp_path, shift_us, skew_ppm):
    """Offsets of +-10 s and skews of +-1000 ppm reach the sidecar and the manifest exactly, and the
    poses follow that clock, t_ref included: the windows lie in a move of the camera, where a t_ref 1 ms
    off (a 1 us pose-time error at 1000 ppm) moves the exported poses by far more than the tolerance."""
    scene_dir = tmp_path / "scene"
    shutil.copytree(tiny_scene_dir, scene_dir)
    _shift_trajectory(scene_dir, shift_us)
    gt = load_ground_truth(scene_dir)
    offset = gt["clock"]["offset_us"] + shift_us
    scene = Scene.open(scene_dir)
    t0 = scene.events.t_first_us + 300_000            # mid-move (the camera dwells from about +486 ms)
    scene.corrections.set(("offset_us",), offset)
    scene.corrections.set(("skew_ppm",), skew_ppm)
    scene.corrections.set(("reviews",), [ReviewMark(t0, t0 + 30_000, "verified")])
    scene.save_corrections()
    t_ref = scene.events.t_first_us
    scene.close()
    out = tmp_path / "out"
    s = export_scene(scene_dir, "bop", out, only_verified=True)
    assert s.written == 3 and s.unlabeled == 0
    times = json.loads((out / "test" / "000000" / "scene_times.json").read_text())
    scene_gt = json.loads((out / "test" / "000000" / "scene_gt.json").read_text())
    man = json.loads((out / "export_manifest.json").read_text())
    assert man["clock"]["offset_us"] == offset and man["clock"]["skew_ppm"] == skew_ppm
    assert type(man["clock"]["offset_us"]) is int
    traj = read_trajectory(scene_dir)
    scene = Scene.open(scene_dir)
    for im_id, t in times.items():
        assert t["offset_us"] == offset and type(t["offset_us"]) is int
        assert t["skew_ppm"] == skew_ppm
        T_bc = T_base_cam_at(traj, pose_time(t["t_label_us"], offset, skew_ppm, t_ref))
        T_bc_ref_1ms = T_base_cam_at(traj, pose_time(t["t_label_us"], offset, skew_ppm, t_ref + 1000))
        for e, n in zip(scene_gt[im_id], scene.object_names):
            T = np.linalg.inv(T_bc) @ scene.T_base_obj(n)
            np.testing.assert_allclose(np.array(e["cam_t_m2c"]), T[:3, 3] * 1000, rtol=0, atol=1e-6)
            T_1ms = np.linalg.inv(T_bc_ref_1ms) @ scene.T_base_obj(n)
            assert np.abs(T_1ms[:3, 3] - T[:3, 3]).max() * 1000 > 1e-5     # 10 x the tolerance (measured: 1e-4)


def test_K_new_option_and_scene_id(tiny_scene_dir, tmp_path):
    scene_dir = tmp_path / "scene"
    shutil.copytree(tiny_scene_dir, scene_dir)
    scene = Scene.open(scene_dir)
    t0 = scene.events.t_first_us + 300_000
    scene.corrections.set(("reviews",), [ReviewMark(t0, t0 + 10_000, "verified")])
    K_new = scene.camera.K.copy()
    K_new[:2, :2] *= 0.8
    s = export_scene(scene, "bop", tmp_path / "out", only_verified=True, objects="box,flatbox",
                     format_options={"K_new": K_new.tolist(), "scene_id": 7})
    assert s.written == 1
    sd = tmp_path / "out" / "test" / "000007"
    cams = json.loads((sd / "scene_camera.json").read_text())
    gt = json.loads((sd / "scene_gt.json").read_text())
    (im_id,) = cams
    K_bop = K_new.copy()
    K_bop[:2, 2] += 0.5
    assert cams[im_id]["cam_K"] == K_bop.ravel().tolist()
    side = json.loads((sd / "evpose_scene.json").read_text())
    assert side["K_opencv"] == K_new.tolist() and side["K_bop"] == K_bop.tolist()
    assert [e["obj_id"] for e in gt[im_id]] == [1, 3]
    assert len(list((sd / "mask").glob("*.png"))) == 2


def test_resume_after_cancel_identical(tiny_scene_dir, tmp_path):
    """The per-window records come from the journal on resume: the aggregate JSON files are identical."""
    from evpose.core.data.events import Cancelled

    scene_dir = tmp_path / "scene"
    shutil.copytree(tiny_scene_dir, scene_dir)
    scene = Scene.open(scene_dir)
    t0 = scene.events.t_first_us + 100_000
    scene.corrections.set(("reviews",), [ReviewMark(t0, t0 + 100_000, "verified")])
    scene.save_corrections()
    scene.close()
    ref = tmp_path / "ref"
    export_scene(scene_dir, "bop", ref, only_verified=True)
    out = tmp_path / "out"
    n = {"k": 0}
    with pytest.raises(Cancelled):
        export_scene(scene_dir, "bop", out, only_verified=True, cancel=lambda: (n.__setitem__("k", n["k"] + 1), n["k"] > 4)[1])
    assert not (out / "test" / "000000" / "scene_gt.json").exists()
    assert not [p for p in out.rglob(".*.tmp")]
    s = export_scene(scene_dir, "bop", out, only_verified=True)
    assert s.skipped_complete == 4 and s.written == 6
    for p in ref.rglob("*"):
        if p.is_file() and ".evpose" not in p.parts and p.name != "export_manifest.json":
            assert p.read_bytes() == (out / p.relative_to(ref)).read_bytes(), p


def test_model_ply_header_survives_any_object_name():
    """Object names may hold any character; the PLY header is ASCII: the name is escaped, never an error."""
    from evpose.core.export.bop_models import ply_bytes

    data = ply_bytes(np.zeros((3, 3)), np.array([[0, 1, 2]]), np.tile([0.0, 0.0, 1.0], (3, 1)),
                     comment="evpose object tasse_café\x07 (mm)")
    head = data.split(b"end_header\n")[0].decode("ascii")
    assert "comment evpose object tasse_caf\\xe9 (mm)" in head and "\x07" not in head


def test_model_normals_are_never_zero(models_dir):
    """Issue 26.6: a vertex whose faces' normals cancel (a fin: one triangle both ways round), one used only by
    degenerate faces, and one no face uses all get a unit normal from their neighbours; on the published YCB
    meshes (two had one zero-normal vertex each) every vertex normal is a unit vector."""
    from evpose.core.data.objects import ObjectModel
    from evpose.core.export.bop_models import vertex_normals

    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0], [2, 2, 0], [0.5, 0.5, 0.0], [5, 5, 5]], float)
    F = np.array([[0, 1, 2], [1, 3, 2],             # a flat square: normals +z
                  [1, 3, 4], [1, 4, 3],             # a fin: vertex 4's two faces cancel
                  [5, 5, 0]])                       # vertex 5: only a degenerate face; vertex 6: no face
    n = vertex_normals(V, F)
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(n[[0, 2]], [[0, 0, 1], [0, 0, 1]], atol=1e-12)
    for p in sorted(models_dir.iterdir()):
        if p.suffix in (".obj", ".stl", ".ply"):
            m = ObjectModel.from_file(p)
            ln = np.linalg.norm(vertex_normals(m.vertices_m, m.faces), axis=1)
            assert np.all(np.abs(ln - 1.0) < 1e-9), (p.name, int(np.count_nonzero(np.abs(ln - 1.0) >= 1e-9)))
