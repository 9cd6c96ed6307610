"""E-POSE layout export: one test pins each defect of the original scripts (DESIGN section 6).

Each test states the defect and fails if it were reintroduced. Oracles: cv2.projectPoints,
scipy Slerp on trajectory.csv read independently, open3d ray casting, the event file itself.
"""
import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.io import loadmat
from scipy.ndimage import binary_fill_holes
from scipy.spatial.transform import Rotation, Slerp

from evpose.core.data.event_store import EventStore
from evpose.core.data.scene import Scene
from evpose.core.document.corrections import ReviewMark
from evpose.core.export import export_scene
from evpose.core.export.epose import EPOSE_CORNER_ORDER
from evpose.core.sim.synth import load_ground_truth

OFFSET_US = 20_000  # the tiny scene's true clock offset (the manifest prior is 0)


# ----------------------------------------------------------------------------------------- helpers
def read_trajectory(scene_dir):
    data = np.loadtxt(Path(scene_dir) / "trajectory.csv", delimiter=",", skiprows=1, dtype=object)
    t = data[:, 0].astype(np.int64)
    return t, data[:, 1:4].astype(np.float64), data[:, 4:8].astype(np.float64)


def T_base_cam_at(traj, t_pose_us: int) -> np.ndarray:
    """Independent interpolation: linear position, scipy Slerp between the bracketing samples."""
    t, pos, q = traj
    i = int(np.searchsorted(t, t_pose_us, side="right") - 1)
    i = min(max(i, 0), len(t) - 2)
    a = float(t_pose_us - t[i]) / float(t[i + 1] - t[i])
    assert 0.0 <= a <= 1.0
    R = Slerp([0.0, 1.0], Rotation.from_quat(q[i:i + 2]))([a]).as_matrix()[0]
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = pos[i] + a * (pos[i + 1] - pos[i])
    return T


def mats(out_dir):
    return sorted(Path(out_dir).glob("*_data.mat"))


def o3d_label_image(camera, models, poses):
    """Per-pixel index of the nearest object along each raw pixel-centre ray (-1: none)."""
    o3d = pytest.importorskip("open3d")
    xy, ok = camera.pixel_rays()
    H, W = ok.shape
    rays = np.concatenate([np.zeros((H, W, 3)), np.nan_to_num(xy), np.ones((H, W, 1))], axis=2).astype(np.float32)
    rc = o3d.t.geometry.RaycastingScene()
    gids = []
    for m, T in zip(models, poses):
        V = m.vertices_m @ T[:3, :3].T + T[:3, 3]
        gids.append(rc.add_triangles(o3d.core.Tensor(V.astype(np.float32)), o3d.core.Tensor(m.faces.astype(np.uint32))))
    gid = rc.cast_rays(o3d.core.Tensor(rays))["geometry_ids"].numpy().astype(np.int64)
    out = np.full((H, W), -1, np.int64)
    for k, g in enumerate(gids):
        out[gid == g] = k
    out[~ok] = -1
    return out


def read_png(path):
    return cv2.imread(str(path), cv2.IMREAD_UNCHANGED)


# ----------------------------------------------------------------------------------------- fixtures
@pytest.fixture(scope="module")
def exported(tiny_scene_dir, tmp_path_factory):
    """The tiny scene with the true clock offset as correction, exported once (all windows)."""
    base = tmp_path_factory.mktemp("epose")
    scene_dir = base / "scene"
    shutil.copytree(tiny_scene_dir, scene_dir)
    scene = Scene.open(scene_dir)
    scene.corrections.set(("offset_us",), OFFSET_US)
    scene.save_corrections()
    scene.close()
    out = base / "out"
    summary = export_scene(scene_dir, "epose", out)
    return scene_dir, out, summary


def _limited_export(tiny_scene_dir, tmp_path, n_windows=3, **kw):
    """Export only a few windows (through --only-verified and one verified mark)."""
    scene_dir = tmp_path / "scene"
    shutil.copytree(tiny_scene_dir, scene_dir)
    scene = Scene.open(scene_dir)
    t0 = scene.events.t_first_us + 300_000
    scene.corrections.set(("reviews",), [ReviewMark(t0, t0 + n_windows * 10_000, "verified")])
    scene.corrections.set(("offset_us",), OFFSET_US)
    scene.save_corrections()
    scene.close()
    out = tmp_path / "out"
    s = export_scene(scene_dir, "epose", out, only_verified=True, **kw)
    return scene_dir, out, s


# ----------------------------------------------------------------------------------------- layout
def test_layout_fields_and_shapes(exported):
    scene_dir, out, s = exported
    assert s.written == s.windows_total == len(mats(out)) == 80 and s.unlabeled == 0
    scene = Scene.open(scene_dir)
    k = len(scene.object_names)
    m = loadmat(mats(out)[10])
    assert m["pose"].shape == (4, 4 * k)
    assert m["keypointprojections"].shape == (8, 5 * k)
    assert m["centerInfo"].shape == (1, 2 * k)
    assert m["cameraPose"].shape == (3, 4)
    assert m["intrinsicMatrix"].shape == (3, 3) and np.array_equal(m["intrinsicMatrix"], scene.camera.K)
    assert m["time"].shape == (1, 1)
    assert m["events"].shape[1] == 4
    assert m["cls_index"].shape == (1, k)
    assert m["T_base_cam"].shape == (4, 4) and m["t_label_us"].dtype == np.int64
    names = [str(np.asarray(x).ravel()[0]) for x in m["object_names"].ravel()]
    assert names == scene.object_names
    stem = mats(out)[10].name[:4]
    for f in ["event_image", "mask_image_all", "mask_image_obj1", "mask_image_obj3", "segmented_image",
              "segmented_image_obj2", "three_channel_image"]:
        img = read_png(out / f"{stem}_{f}.png")
        assert img.shape[:2] == (scene.camera.height, scene.camera.width)
    assert (out / f"{stem}_bbox.txt").read_text().count("\n") == k
    assert (out / "README.txt").read_text().count("DELIBERATE DIFFERENCES") == 1
    assert (out / "box_box.txt").is_file() and (out / "three_channel_image_paths.txt").is_file()
    man = json.loads((out / "export_manifest.json").read_text())
    assert man["clock"]["offset_us"] == OFFSET_US and man["counts"]["windows_total"] == 80
    # a time field of the original is kept: seconds since the first event, at the label time
    t_ref = int(m["t_ref_us"][0, 0])
    assert m["time"][0, 0] == pytest.approx((int(m["t_label_us"][0, 0]) - t_ref) * 1e-6, abs=1e-12)


def test_single_object_names_and_bilevel_mask(tiny_scene_dir, tmp_path):
    _, out, s = _limited_export(tiny_scene_dir, tmp_path, objects=["cylinder"])
    assert s.written == 3
    stem = mats(out)[0].name[:4]
    assert (out / f"{stem}_mask_image.png").is_file() and not (out / f"{stem}_mask_image_all.png").exists()
    assert not list(out.glob("*_obj1.png"))
    mask = read_png(out / f"{stem}_mask_image.png")
    assert set(np.unique(mask)) <= {0, 255}
    m = loadmat(out / f"{stem}_data.mat")
    assert m["pose"].shape == (4, 4) and m["keypointprojections"].shape == (8, 5)
    assert len((out / f"{stem}_bbox.txt").read_text().split()) == 8


def test_skipped_products_leave_exactly_their_files_out(tiny_scene_dir, tmp_path):
    """``skip`` (issue 27.4: fewer files where a user does not need them): the skipped products' files are not
    written, every other file is byte for byte the full export's, the manifest lists what is there, and the
    configuration differs from the full export's (a rerun with another choice is another export)."""

    from evpose.core.export.epose import EposeWriter

    full_dir, skip_dir = tmp_path / "full", tmp_path / "skip"
    _, full, s_full = _limited_export(tiny_scene_dir, full_dir)
    _, part, s_part = _limited_export(tiny_scene_dir, skip_dir, format_options={"skip": ["segmented", "bbox"]})
    assert s_full.written == s_part.written == 3
    names = lambda d: {p.name for p in d.iterdir() if p.is_file()}                      # noqa: E731
    gone = names(full) - names(part)
    assert gone and all("_segmented_image" in n or n.endswith("_bbox.txt") for n in gone), sorted(gone)
    assert names(part) <= names(full)
    k = len(json.loads((full / "export_manifest.json").read_text())["objects"])
    per_full = len(EposeWriter().window_files(0, 4, k))
    per_part = len(EposeWriter(skip=("bbox", "segmented")).window_files(0, 4, k))
    assert len(gone) == 3 * (per_full - per_part) and per_part == per_full - (k + 2)
    for n in names(part) - {"export_manifest.json", "README.txt"}:
        assert (full / n).read_bytes() == (part / n).read_bytes(), n
    doc_full = json.loads((full / "export_manifest.json").read_text())
    doc_part = json.loads((part / "export_manifest.json").read_text())
    assert doc_part["format_options"]["skip"] == ["bbox", "segmented"] and "skip" not in doc_full["format_options"]
    assert doc_part["config_sha256"] != doc_full["config_sha256"]
    assert not any("segmented" in f for f in doc_part["window_files"]), doc_part["window_files"]
    with pytest.raises(Exception, match="unknown product 'mask'"):
        EposeWriter(skip=["mask"])


# ----------------------------------------------------------------------------------------- defects
def test_defect_corners_divided_by_first_corner_depth(exported):
    """Original: every corner's (u, v) used the FIRST corner's depth. Each corner must be projected
    with its own depth: (u, v) equals cv2.projectPoints of that corner's own (X, Y, Z)."""
    scene_dir, out, _ = exported
    scene = Scene.open(scene_dir)
    cam = scene.camera
    worst = 0.0
    for path in mats(out)[::8]:
        kp = loadmat(path)["keypointprojections"]
        for j in range(kp.shape[1] // 5):
            uv, xyz = kp[:, 5 * j:5 * j + 2], kp[:, 5 * j + 2:5 * j + 5]
            ref, _ = cv2.projectPoints(xyz, np.zeros(3), np.zeros(3), cam.K, cam.dist)
            assert np.abs(uv - ref.reshape(-1, 2)).max() < 1e-6
            # with the first corner's depth the error is large for these boxes (tens of px)
            wrong, _ = cv2.projectPoints(np.c_[xyz[:, :2] / xyz[:1, 2:3], np.ones(8)], np.zeros(3), np.zeros(3), cam.K,
                                         cam.dist)
            worst = max(worst, np.abs(wrong.reshape(-1, 2) - ref.reshape(-1, 2)).max())
    assert worst > 2.0  # the test data can tell the two apart


def test_defect_keypoints_undistorted_twice(exported):
    """Original: pinhole projection followed by undistortPoints (the points were 'undistorted' although
    they never were distorted). Keypoints must be distorted pixels of the raw camera, where the events
    are: equal to projectPoints WITH the distortion and far from the pinhole/undistorted positions."""
    scene_dir, out, _ = exported
    scene = Scene.open(scene_dir)
    cam = scene.camera
    diff_pinhole = []
    for path in mats(out)[::10]:
        m = loadmat(path)
        kp, pose = m["keypointprojections"], m["pose"]
        for j, name in enumerate(scene.object_names):
            T = pose[:, 4 * j:4 * j + 4]
            corners = scene.model(name).bbox_corners(0.0)[EPOSE_CORNER_ORDER]
            rvec, _ = cv2.Rodrigues(T[:3, :3])
            ref, _ = cv2.projectPoints(corners, rvec, T[:3, 3], cam.K, cam.dist)
            np.testing.assert_allclose(kp[:, 5 * j:5 * j + 2], ref.reshape(-1, 2), atol=1e-6)
            pin, _ = cv2.projectPoints(corners, rvec, T[:3, 3], cam.K, np.zeros(5))
            once = cv2.undistortPoints(pin.reshape(-1, 1, 2), cam.K, cam.dist, P=cam.K).reshape(-1, 2)
            diff_pinhole.append(min(np.abs(kp[:, 5 * j:5 * j + 2] - pin.reshape(-1, 2)).max(),
                                    np.abs(kp[:, 5 * j:5 * j + 2] - once).max()))
    assert max(diff_pinhole) > 2.0


def test_defect_camera_pose_from_a_fixed_frame(exported):
    """Original: cameraPose was the second frame's pose in every file. It must be T_base_cam at each
    window's own label time (independent Slerp of trajectory.csv at t_label + offset)."""
    scene_dir, out, _ = exported
    traj = read_trajectory(scene_dir)
    poses = []
    for path in mats(out):
        m = loadmat(path)
        T_ref = T_base_cam_at(traj, int(m["t_label_us"][0, 0]) + OFFSET_US)
        np.testing.assert_allclose(m["cameraPose"], T_ref[:3, :], atol=1e-12)
        np.testing.assert_allclose(m["T_base_cam"], T_ref, atol=1e-12)
        poses.append(m["cameraPose"])
    moves = [np.abs(a - b).max() for a, b in zip(poses, poses[1:])]
    assert max(moves) > 1e-3    # the camera moves: a fixed frame would fail the check above


def test_defect_masks_splatted_from_vertices(exported):
    """Original: masks splatted from mesh vertices (holes, per-vertex z test). Masks must match open3d
    ray casting of the triangles (IoU >= 0.99 per object, occlusion included) and have no holes."""
    scene_dir, out, _ = exported
    scene = Scene.open(scene_dir)
    models = [scene.model(n) for n in scene.object_names]
    checked = 0
    for path in mats(out)[5::15]:
        m = loadmat(path)
        stem = path.name[:4]
        poses = [m["pose"][:, 4 * j:4 * j + 4] for j in range(len(models))]
        ref = o3d_label_image(scene.camera, models, poses)
        for j in range(len(models)):
            mask = read_png(out / f"{stem}_mask_image_obj{j + 1}.png") > 0
            r = ref == j
            if r.sum() < 30:
                continue
            iou = (mask & r).sum() / (mask | r).sum()
            assert iou >= 0.99, (path.name, j, iou)
            assert np.array_equal(binary_fill_holes(mask), mask), "mask has holes"
            checked += 1
    assert checked >= 4


def test_defect_saturated_label_image(exported):
    """Original: the multi-object label image (values 1..k) was written as doubles and saturated to 255.
    mask_image_all must hold 0 and the object labels 1..k, consistent with the per-object masks."""
    _, out, _ = exported
    seen = set()
    for path in mats(out)[::5]:
        stem = path.name[:4]
        lab = read_png(out / f"{stem}_mask_image_all.png")
        assert lab.dtype == np.uint8 and set(np.unique(lab)) <= {0, 1, 2, 3}
        for j in (1, 2, 3):
            assert np.array_equal(lab == j, read_png(out / f"{stem}_mask_image_obj{j}.png") > 0)
        seen |= set(np.unique(lab).tolist())
    assert seen == {0, 1, 2, 3}


def test_defect_margin_shifts_instead_of_enlarging(tiny_scene_dir, tmp_path):
    """Original: '+1 mm' added to every coordinate (a shift). The margin must enlarge the box by 1 mm on
    every side: same centre, each extent 2 mm larger (checked in the object frame)."""
    scene_dir, out, s = _limited_export(tiny_scene_dir, tmp_path, margin_m=0.001)
    assert s.written == 3
    scene = Scene.open(scene_dir)
    for path in mats(out):
        m = loadmat(path)
        for j, name in enumerate(scene.object_names):
            T = m["pose"][:, 4 * j:4 * j + 4]
            xyz = m["keypointprojections"][:, 5 * j + 2:5 * j + 5]
            p_obj = (xyz - T[:3, 3]) @ T[:3, :3]
            lo, hi = scene.model(name).bbox_min_max
            np.testing.assert_allclose(p_obj.min(0), lo - 0.001, atol=1e-9)
            np.testing.assert_allclose(p_obj.max(0), hi + 0.001, atol=1e-9)
            np.testing.assert_allclose(p_obj.mean(0), (lo + hi) / 2, atol=1e-9)
    # the object-frame box file has the enlarged corners too
    box = np.loadtxt(out / "box_box.txt")
    lo, hi = scene.model("box").bbox_min_max
    np.testing.assert_allclose(box.min(1), lo - 0.001, atol=1e-6)
    np.testing.assert_allclose(box.max(1), hi + 0.001, atol=1e-6)


def test_defect_three_channel_accumulators_leak(exported):
    """Original: the 3-channel accumulators were never reset, so every image held all earlier windows.
    Each image must be a function of its own window's events: zero wherever the window has no event,
    non-zero wherever it has one, equal to evpose.core.label.event_frames on that window alone."""
    from evpose.core.label.event_frames.display import three_channel_rgb
    from evpose.core.label.event_frames.three_channel import three_channel

    scene_dir, out, _ = exported
    store = EventStore(Path(scene_dir) / "events.h5")
    for path in mats(out)[20:60:8]:
        m = loadmat(path)
        t0, t1 = int(m["t_start_us"][0, 0]), int(m["t_end_us"][0, 0])
        ev = store.window(t0, t1)
        img = read_png(path.with_name(path.name[:4] + "_three_channel_image.png"))[..., ::-1]   # BGR -> RGB
        has = np.zeros(img.shape[:2], bool)
        has[ev.y, ev.x] = True
        assert not img[~has].any()
        assert (img[has].max(axis=1) > 0).all()
        ref = three_channel_rgb(three_channel(ev, img.shape[1], img.shape[0], t0, t1))
        assert np.array_equal(img, ref)
    store.close()


def test_defect_boundary_events_in_two_windows(exported):
    """Original: windows [a, b] included both boundary events. The union of all windows' events must be
    the recording, each event exactly once, in order."""
    scene_dir, out, _ = exported
    parts, t_ref = [], None
    for path in mats(out):
        m = loadmat(path)
        t_ref = int(m["t_ref_us"][0, 0])
        e = m["events"]
        t = np.rint(e[:, 2] * 1e6).astype(np.int64) + t_ref
        assert (t >= int(m["t_start_us"][0, 0])).all() and (t < int(m["t_end_us"][0, 0])).all()
        parts.append(np.c_[e[:, 0], e[:, 1], t, (e[:, 3] > 0)].astype(np.int64))
    got = np.concatenate(parts)
    store = EventStore(Path(scene_dir) / "events.h5")
    ev = store.read(0, store.n_events)
    store.close()
    ref = np.c_[ev.x, ev.y, ev.t, ev.p].astype(np.int64)
    assert got.shape == ref.shape and np.array_equal(got, ref)
    assert set(np.unique(np.concatenate([loadmat(p)["events"][:, 3] for p in mats(out)[:5]]))) <= {-1.0, 1.0}


def test_defect_events_at_x0_or_y0_dropped(exported):
    """Original: events with x = 0 or y = 0 were skipped in the images (MATLAB 1-based indexing). They
    must be in the .mat events, the event image and the 3-channel image."""
    _, out, _ = exported
    n_border = 0
    for path in mats(out):
        e = loadmat(path)["events"]
        border = (e[:, 0] == 0) | (e[:, 1] == 0)
        if not border.any():
            continue
        stem = path.name[:4]
        ev_img = read_png(out / f"{stem}_event_image.png")
        c3 = read_png(out / f"{stem}_three_channel_image.png")
        x, y = e[border, 0].astype(int), e[border, 1].astype(int)
        assert (ev_img[y, x] == 255).all()
        assert (c3[y, x].max(axis=1) > 0).all()
        n_border += int(border.sum())
    assert n_border > 100


def test_defect_time_offset_in_one_product_only(exported):
    """Original: the time offset was applied in one script only. With an offset correction every
    product must follow the same clock: cameraPose and pose at t_label + offset, keypoints from that
    pose, masks (open3d) from that pose, segmentation from those masks and the window's events."""
    scene_dir, out, _ = exported
    scene = Scene.open(scene_dir)
    traj = read_trajectory(scene_dir)
    models = [scene.model(n) for n in scene.object_names]
    cam = scene.camera
    store = EventStore(Path(scene_dir) / "events.h5")
    for path in mats(out)[7::20]:
        m = loadmat(path)
        stem = path.name[:4]
        T_bc = T_base_cam_at(traj, int(m["t_label_us"][0, 0]) + OFFSET_US)
        np.testing.assert_allclose(m["T_base_cam"], T_bc, atol=1e-12)
        poses = []
        for j, name in enumerate(scene.object_names):
            T = np.linalg.inv(T_bc) @ scene.T_base_obj(name)
            np.testing.assert_allclose(m["pose"][:, 4 * j:4 * j + 4], T, atol=1e-9)
            rvec, _ = cv2.Rodrigues(T[:3, :3])
            ref, _ = cv2.projectPoints(scene.model(name).bbox_corners(0.0)[EPOSE_CORNER_ORDER], rvec, T[:3, 3], cam.K, cam.dist)
            np.testing.assert_allclose(m["keypointprojections"][:, 5 * j:5 * j + 2], ref.reshape(-1, 2), atol=1e-6)
            poses.append(T)
        ref_lab = o3d_label_image(cam, models, poses)
        lab = read_png(out / f"{stem}_mask_image_all.png").astype(np.int64) - 1
        agree = (lab == ref_lab).mean()
        assert agree > 0.995
        ev = store.window(int(m["t_start_us"][0, 0]), int(m["t_end_us"][0, 0]))
        seg = read_png(out / f"{stem}_segmented_image.png") > 0
        expect = np.zeros_like(seg)
        on = lab[ev.y, ev.x] >= 0
        expect[ev.y[on], ev.x[on]] = True
        assert np.array_equal(seg, expect)
    store.close()
    man = json.loads((out / "export_manifest.json").read_text())
    assert man["clock"]["offset_us"] == OFFSET_US and man["clock"]["correction_offset_us"] == OFFSET_US


def box_corners_p1_p4(model) -> np.ndarray:
    """The original's corners p1..p4 of the object's 3D box, (+x+y-z) (+x-y-z) (-x+y-z) (-x-y-z), written
    out here from the layout description (independent of EPOSE_CORNER_ORDER)."""
    (x0, y0, z0), (x1, y1, _) = model.bbox_min_max
    return np.array([[x1, y1, z0], [x1, y0, z0], [x0, y1, z0], [x0, y0, z0]])


def test_center_info_is_the_distorted_projection_of_the_origin(exported):
    """centerInfo holds (u, v) of each object's origin in the raw camera: cv2.projectPoints WITH the lens
    distortion of the pose in the same file; the pinhole projection is pixels away for this lens."""
    scene_dir, out, _ = exported
    cam = Scene.open(scene_dir).camera
    assert np.abs(cam.dist).max() > 0.1
    pinhole_error = 0.0
    for path in mats(out)[::4]:
        m = loadmat(path)
        c = m["centerInfo"].reshape(-1, 2)
        for j in range(len(c)):
            t = m["pose"][:3, 4 * j + 3]
            ref, _ = cv2.projectPoints(t[None], np.zeros(3), np.zeros(3), cam.K, cam.dist)
            np.testing.assert_allclose(c[j], ref.ravel(), atol=1e-6)
            pinhole_error = max(pinhole_error, float(np.abs(cam.K[:2] @ (t / t[2]) - ref.ravel()).max()))
    assert pinhole_error > 2.0     # the test can tell a projection without distortion apart


def test_bbox_txt_holds_the_distorted_corners_p1_to_p4(exported):
    """NNNN_bbox.txt: one line per object, its name, then (u, v) of corners p1..p4 in that order, the
    projection WITH distortion of the file's pose (to the %.4f precision of the text)."""
    scene_dir, out, _ = exported
    scene = Scene.open(scene_dir)
    cam = scene.camera
    for path in mats(out)[::6]:
        m = loadmat(path)
        lines = path.with_name(path.name[:4] + "_bbox.txt").read_text().splitlines()
        assert [ln.split("  ")[0] for ln in lines] == scene.object_names
        for j, (line, name) in enumerate(zip(lines, scene.object_names)):
            uv = np.array([float(v) for v in line.split("  ")[1].split(" ")]).reshape(4, 2)
            T = m["pose"][:, 4 * j:4 * j + 4]
            rvec, _ = cv2.Rodrigues(T[:3, :3])
            ref, _ = cv2.projectPoints(box_corners_p1_p4(scene.model(name)), rvec, T[:3, 3], cam.K, cam.dist)
            np.testing.assert_allclose(uv, ref.reshape(4, 2), atol=6e-5)


def test_mat_boxes_are_the_mask_extents(exported):
    """bbox_visib of the .mat is the tight [x y w h] box of mask_image_obj{K} (read back from the PNG),
    px_count_visib its pixel count."""
    _, out, _ = exported
    n_boxes = 0
    for path in mats(out)[::7]:
        m = loadmat(path)
        for j in range(m["bbox_visib"].shape[0]):
            mask = read_png(out / f"{path.name[:4]}_mask_image_obj{j + 1}.png") > 0
            ys, xs = np.nonzero(mask)
            box = [-1, -1, -1, -1] if len(xs) == 0 else [xs.min(), ys.min(), xs.max() - xs.min() + 1, ys.max() - ys.min() + 1]
            assert m["bbox_visib"][j].tolist() == box, (path.name, j)
            assert m["px_count_visib"][0, j] == mask.sum()
            n_boxes += len(xs) > 0
    assert n_boxes >= 20


def test_label_at_end_uses_window_end(tiny_scene_dir, tmp_path):
    _, out, s = _limited_export(tiny_scene_dir, tmp_path, n_windows=2, label_at="end")
    for path in mats(out):
        m = loadmat(path)
        assert int(m["t_label_us"][0, 0]) == int(m["t_end_us"][0, 0])


def test_ground_truth_corrections_give_true_poses(tiny_scene_dir, tmp_path):
    """With the ground-truth corrections the exported poses are the true ones (independent oracle)."""
    scene_dir = tmp_path / "scene"
    shutil.copytree(tiny_scene_dir, scene_dir)
    gt = load_ground_truth(scene_dir)
    scene = Scene.open(scene_dir)
    t0 = scene.events.t_first_us + 400_000
    scene.corrections.set(("offset_us",), gt["clock"]["offset_us"])
    for n in scene.object_names:
        T_true = np.array(gt["objects"][n]["T_base_obj"])
        scene.corrections.set(("object", n), T_true @ np.linalg.inv(scene.manifest.object(n).T_base_obj))
    scene.corrections.set(("reviews",), [ReviewMark(t0, t0 + 20_000, "verified")])
    out = tmp_path / "out"
    s = export_scene(scene, "epose", out, only_verified=True)    # a Scene object with unsaved corrections
    assert s.written == 2
    traj = read_trajectory(scene_dir)
    for path in mats(out):
        m = loadmat(path)
        T_bc = T_base_cam_at(traj, int(m["t_label_us"][0, 0]) + gt["clock"]["offset_us"])
        for j, n in enumerate(scene.object_names):
            T = np.linalg.inv(T_bc) @ np.array(gt["objects"][n]["T_base_obj"])
            np.testing.assert_allclose(m["pose"][:, 4 * j:4 * j + 4], T, atol=1e-9)


def test_masks_of_a_subset_of_objects(tiny_scene_dir, tmp_path):
    """Exported labels number the exported objects (scene order) from 1; the other objects are background
    (pins the worker's label table, evpose.core.export.epose): here the scene's first object is left out."""
    from evpose.core.label.annotate import Annotator
    from evpose.core.label.labels import Request
    from evpose.core.label.windows import time_windows

    names = Scene.open(tiny_scene_dir).object_names
    assert len(names) >= 3
    scene_dir, out, s = _limited_export(tiny_scene_dir, tmp_path, objects=names[1:])
    assert s.written == 3
    scene = Scene.open(scene_dir)
    wins = {w.index: w for w in time_windows(scene.events, 10_000)}
    ann = Annotator(scene, Request(keypoints=False, label_map=True))
    n_labelled = 0
    for mat in mats(out):
        stem = mat.name[:4]
        lm = ann.annotate(wins[int(stem)]).label_map
        want = np.zeros(lm.shape, np.uint8)
        for k in range(1, len(names)):
            want[lm == k] = k                       # scene object k is exported object k (the first left out)
        n_labelled += int((want > 0).sum())
        assert np.array_equal(read_png(out / f"{stem}_mask_image_all.png"), want)
        spike = read_png(out / f"{stem}_event_image.png")
        assert np.array_equal(read_png(out / f"{stem}_segmented_image.png"), np.where(want > 0, spike, 0))
        for k in range(1, len(names)):
            assert np.array_equal(read_png(out / f"{stem}_mask_image_obj{k}.png"), (want == k) * np.uint8(255))
            assert np.array_equal(read_png(out / f"{stem}_segmented_image_obj{k}.png"), np.where(want == k, spike, 0))
    assert n_labelled > 0 and (lm == 0).any()
    scene.close()
