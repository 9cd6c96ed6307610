"""The BOP export as the BOP toolkit (thodan/bop_toolkit) sees it (issue 18), checked against BOP's own
definitions implemented here independently of the exporter: the toolkit is not installable from PyPI
(``pip download bop_toolkit_lib``: no distribution), so its rules are re-implemented from its source:

- the renderers (``rendering/renderer_vispy.py::_calc_calib_proj``) put the pixel origin at the corner of
  the top-left pixel: pixel ``i`` is sampled at ``u = i + 0.5`` with ``cam_K`` as written;
- ``scripts/calc_gt_info.py``: the object alone on a canvas of 3 x 3 images (image at offset ``(W, H)``),
  ``px_count_all`` = its pixels there, ``visib_fract = px_count_visib / px_count_all``, boxes by
  ``misc.calc_2d_bbox`` (``w = x_max - x_min``, not clipped), ``bbox_obj`` only when something is visible;
- ``inout.load_ply`` (binary: ``float``/``double``/``int``/``uint``/``uchar``; ``normals`` only with
  nx, ny, nz) and ``inout.get_im_targets`` / ``scripts/create_test_targets.py`` for the targets.

Masks are cast with open3d's ``RaycastingScene`` on the exported PLY models (float32 ray casting: pixels
within ~1e-5 px of an edge may differ, hence the small tolerances), on the occlusion scene
(tests/occlusion_scene.py), where cubes leave the image and hide each other.
"""
import json
import shutil
import struct

import cv2
import numpy as np
import pytest

from evpose.core.data.scene import Scene
from evpose.core.export import ExportError, export_scene

FACTOR = 3          # calc_gt_info's canvas: 3 x the image in width and height
SD = ("test", "000000")


# ------------------------------------------------------------------------------------- BOP, independently
def toolkit_load_ply(path) -> dict:
    """``bop_toolkit_lib.inout.load_ply``'s reading rules (vectorised): header properties, binary types
    float/double/int/uint/uchar (native little endian), ``normals`` only when nx, ny, nz are present."""
    fmt = {"float": "<f4", "double": "<f8", "int": "<i4", "uint": "<u4", "uchar": "u1"}
    with open(path, "rb") as f:
        pt_props, face_props, section, n_pts, n_faces, binary = [], [], None, 0, 0, False
        while True:
            line = f.readline().decode("utf8").rstrip("\n").rstrip("\r")
            if line.startswith("element vertex"):
                n_pts, section = int(line.split()[-1]), "v"
            elif line.startswith("element face"):
                n_faces, section = int(line.split()[-1]), "f"
            elif line.startswith("element"):
                section = None
            elif line.startswith("property") and section == "v":
                pt_props.append((line.split()[-1], line.split()[-2]))
            elif line.startswith("property list") and section == "f":
                e = line.split()
                assert e[-1] in ("vertex_indices", "vertex_index")
                face_props = [("n", e[2])] + [(f"i{k}", e[3]) for k in range(3)]
            elif line.startswith("format"):
                binary = "binary" in line
            elif line.startswith("end_header"):
                break
        assert binary
        v = np.frombuffer(f.read(n_pts * sum(np.dtype(fmt[t]).itemsize for _, t in pt_props)),
                          dtype=[(n, fmt[t]) for n, t in pt_props])
        fc = np.frombuffer(f.read(), dtype=[(n, fmt[t]) for n, t in face_props], count=n_faces)
    assert (fc["n"] == 3).all()
    model = {"pts": np.stack([v["x"], v["y"], v["z"]], 1).astype(np.float64),
             "faces": np.stack([fc["i0"], fc["i1"], fc["i2"]], 1).astype(np.int64)}
    if {"nx", "ny", "nz"} <= {n for n, _ in pt_props}:
        model["normals"] = np.stack([v["nx"], v["ny"], v["nz"]], 1).astype(np.float64)
    return model


def calc_2d_bbox(xs, ys) -> list[int]:
    """``misc.calc_2d_bbox`` (clip=False)."""
    return [int(xs.min()), int(ys.min()), int(xs.max() - xs.min()), int(ys.max() - ys.min())]


def canvas_rays(cam_K, W, H, factor=FACTOR):
    """Rays of calc_gt_info's canvas as the toolkit's renderer samples them: pixel (i, j) at
    (i + 0.5, j + 0.5) from the corner, principal point (cx + W, cy + H) of the written cam_K."""
    K = np.asarray(cam_K, np.float64).reshape(3, 3)
    off_x, off_y = W * (factor // 2), H * (factor // 2)
    jj, ii = np.mgrid[0:factor * H, 0:factor * W].astype(np.float64)
    d = np.stack([(ii + 0.5 - (K[0, 2] + off_x)) / K[0, 0], (jj + 0.5 - (K[1, 2] + off_y)) / K[1, 1],
                  np.ones_like(ii)], axis=-1)
    return np.concatenate([np.zeros_like(d), d], axis=-1).astype(np.float32), (off_x, off_y)


def bop_instances(o3d, models, entries, cam_K, W, H):
    """Per ground-truth entry: (its silhouette on the canvas, its visible pixels in the image), from
    models in mm posed by cam_R_m2c / cam_t_m2c, visibility = nearest surface among all entries."""
    rays, (ox, oy) = canvas_rays(cam_K, W, H)
    rays = o3d.core.Tensor(rays)
    every = o3d.t.geometry.RaycastingScene()
    sil, gids = [], []
    for e in entries:
        m = models[e["obj_id"]]
        V = m["pts"] @ np.array(e["cam_R_m2c"]).reshape(3, 3).T + np.array(e["cam_t_m2c"])
        V32 = o3d.core.Tensor(V.astype(np.float32))
        F32 = o3d.core.Tensor(m["faces"].astype(np.uint32))
        alone = o3d.t.geometry.RaycastingScene()
        alone.add_triangles(V32, F32)
        sil.append(np.isfinite(alone.cast_rays(rays)["t_hit"].numpy()))
        gids.append(every.add_triangles(V32, F32))
    nearest = every.cast_rays(rays)["geometry_ids"].numpy()[oy:oy + H, ox:ox + W]
    return [(s, nearest == g) for s, g in zip(sil, gids)], (ox, oy)


def bop_gt_info(silhouette, visible, offset) -> dict:
    """calc_gt_info's fields from the canvas silhouette and the in-image visible mask."""
    ox, oy = offset
    n_all, n_vis = int(silhouette.sum()), int(visible.sum())
    info = {"px_count_all": n_all, "px_count_visib": n_vis, "visib_fract": n_vis / n_all if n_all else 0.0,
            "bbox_obj": [-1] * 4, "bbox_visib": [-1] * 4}
    if n_vis:
        ys, xs = np.nonzero(silhouette)
        info["bbox_obj"] = calc_2d_bbox(xs - ox, ys - oy)
        ys, xs = np.nonzero(visible)
        info["bbox_visib"] = calc_2d_bbox(xs, ys)
    return info


# ------------------------------------------------------------------------------------------- fixture
@pytest.fixture(scope="module", params=[1.0, 2.0], ids=["K", "zoom2"])
def bop_export(request, occlusion_scene_dir, tmp_path_factory):
    """The whole occlusion scene (21 windows of 10 ms, 5 cubes) exported as BOP: in the scene's camera, and
    zoomed in twice (K_new: focal lengths x 2), where most cubes leave the image, some entirely (still on
    calc_gt_info's canvas), and some stay less than 10 % visible."""
    base = tmp_path_factory.mktemp("bop-toolkit")
    scene_dir = base / "scene"
    shutil.copytree(occlusion_scene_dir, scene_dir)
    scene = Scene.open(scene_dir)
    K = scene.camera.K.copy()
    K[0, 0] *= request.param
    K[1, 1] *= request.param
    out = base / "out"
    s = export_scene(scene, "bop", out, format_options={"K_new": K.tolist()})
    assert s.written == s.windows_total > 15
    return scene, out


def _read(out, *parts):
    return json.loads(out.joinpath(*parts).read_text())


def _mask(out, kind, im_id, g):
    return cv2.imread(str(out.joinpath(*SD, kind, f"{int(im_id):06d}_{g:06d}.png")), cv2.IMREAD_UNCHANGED) > 0


def _models(out):
    info = _read(out, "models", "models_info.json")
    return {int(k): toolkit_load_ply(out / "models" / f"obj_{int(k):06d}.ply") for k in info}


# ---------------------------------------------------------------------------------------------- tests
def test_cam_K_is_in_the_toolkits_pixel_convention(bop_export):
    """Rendering the exported poses with the exported cam_K the way the toolkit's renderer samples pixels
    (i + 0.5 from the corner) reproduces the exported masks: at most 1 % of a mask's pixels (float32 ray
    casting at edges) differ, where the OpenCV K (pixel centres at integers) shifts every edge by half a
    pixel. camera.json holds the same cx, cy; evpose_scene.json keeps K_opencv = cam_K - 0.5."""
    o3d = pytest.importorskip("open3d")
    scene, out = bop_export
    W, H = scene.camera.width, scene.camera.height
    cams, gts = _read(out, *SD, "scene_camera.json"), _read(out, *SD, "scene_gt.json")
    models = _models(out)
    side = _read(out, *SD, "evpose_scene.json")
    K = np.array(side["K_opencv"])
    np.testing.assert_array_equal(np.array(cams["0"]["cam_K"]).reshape(3, 3), K + [[0, 0, 0.5], [0, 0, 0.5], [0, 0, 0]])
    cam_json = _read(out, "camera.json")
    assert (cam_json["cx"], cam_json["cy"]) == (cams["0"]["cam_K"][2], cams["0"]["cam_K"][5])
    checked = 0
    for im_id in list(gts)[::4]:
        inst, (ox, oy) = bop_instances(o3d, models, gts[im_id], cams[im_id]["cam_K"], W, H)
        for g, (sil, _) in enumerate(inst):
            ref, got = sil[oy:oy + H, ox:ox + W], _mask(out, "mask", im_id, g)
            if ref.sum() < 50:
                continue
            assert (ref ^ got).sum() <= 0.01 * (ref | got).sum(), (im_id, g, int((ref ^ got).sum()), int(ref.sum()))
            checked += 1
    assert checked >= 10


def test_scene_gt_info_follows_calc_gt_info(bop_export):
    """px_count_all, visib_fract and bbox_obj count the whole silhouette on calc_gt_info's 3 x 3 canvas (the
    part outside the image too), boxes are calc_2d_bbox boxes; checked on instances that leave the image
    and instances that others hide. Exact where the PNGs decide (bbox_visib; every field of an object
    inside the image), within float32 ray-casting tolerance elsewhere."""
    o3d = pytest.importorskip("open3d")
    scene, out = bop_export
    W, H = scene.camera.width, scene.camera.height
    cams, gts = _read(out, *SD, "scene_camera.json"), _read(out, *SD, "scene_gt.json")
    infos = _read(out, *SD, "scene_gt_info.json")
    models = _models(out)
    truncated = occluded = both = off_image = 0
    in_image_fract_off = []
    for im_id in list(gts)[::2]:
        inst, off = bop_instances(o3d, models, gts[im_id], cams[im_id]["cam_K"], W, H)
        for g, (sil, vis_ref) in enumerate(inst):
            e, ref = infos[im_id][g], bop_gt_info(sil, vis_ref, off)
            full, vis = _mask(out, "mask", im_id, g), _mask(out, "mask_visib", im_id, g)
            # the visible mask is the nearest surface (the PNG against open3d), boxes from the PNG are exact
            assert abs(e["px_count_visib"] - ref["px_count_visib"]) <= 2 + 0.01 * ref["px_count_visib"]
            assert e["px_count_visib"] == int(vis.sum())
            ys, xs = np.nonzero(vis)
            assert e["bbox_visib"] == (calc_2d_bbox(xs, ys) if len(xs) else [-1] * 4), (im_id, g)
            # the whole silhouette, on the canvas
            assert abs(e["px_count_all"] - ref["px_count_all"]) <= 2 + 0.01 * ref["px_count_all"], (im_id, g, e, ref)
            assert abs(e["visib_fract"] - ref["visib_fract"]) <= 0.01, (im_id, g, e, ref)
            assert e["visib_fract"] == (e["px_count_visib"] / e["px_count_all"] if e["px_count_all"] else 0.0)
            if ref["bbox_obj"] == [-1] * 4 or e["bbox_obj"] == [-1] * 4:
                assert e["bbox_obj"] == ref["bbox_obj"] == [-1] * 4 or e["px_count_visib"] <= 2
            else:
                assert np.abs(np.subtract(e["bbox_obj"], ref["bbox_obj"])).max() <= 1, (im_id, g, e, ref)
            outside = ref["px_count_all"] - int(sil[off[1]:off[1] + H, off[0]:off[0] + W].sum())
            if outside == 0 and e["px_count_all"] == int(full.sum()) and vis.any():
                ys, xs = np.nonzero(full)
                assert e["bbox_obj"] == calc_2d_bbox(xs, ys)
            if outside > 20 and vis.any():
                truncated += 1
                assert e["px_count_all"] > int(full.sum())
                in_image_fract_off.append(int(vis.sum()) / int(full.sum()) - e["visib_fract"])
                x, y, w, h = e["bbox_obj"]
                assert x < 0 or y < 0 or x + w > W - 1 or y + h > H - 1      # not clipped to the image
            if vis.sum() < 0.9 * full.sum():                                  # hidden by another cube
                occluded += 1
                both += outside > 20
            off_image += e["px_count_all"] > 0 and not full.any()
    assert truncated >= 5, truncated
    if _read(out, *SD, "evpose_scene.json")["K_opencv"] == scene.camera.K.tolist():
        assert occluded >= 3 and both >= 1, (occluded, both)
    else:                                        # zoomed: cubes outside the image still count on the canvas
        assert off_image >= 3, off_image
    assert max(in_image_fract_off) > 0.2        # counting only in-image pixels would change visib_fract a lot


def test_models_are_what_the_toolkit_reads(bop_export):
    """The PLY models load with the toolkit's reader rules, with vertex normals (its Phong renderer needs
    them): unit length, angle-weighted like trimesh's (MeshLab's rule, as BOP's models), pointing out of
    the cubes; vertices are the scene's meshes in mm, in the mesh's own origin."""
    import trimesh

    scene, out = bop_export
    info = _read(out, "models", "models_info.json")
    side = _read(out, *SD, "evpose_scene.json")
    names = {o["obj_id"]: o["name"] for o in side["objects"]}
    assert sorted(int(k) for k in info) == sorted(names)
    for oid, m in _models(out).items():
        model = scene.model(names[oid])
        np.testing.assert_allclose(m["pts"], model.vertices_m * 1000.0, rtol=1e-6, atol=1e-4)
        np.testing.assert_array_equal(m["faces"], model.faces)
        n = m["normals"]
        np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-6)
        ref = trimesh.Trimesh(m["pts"], m["faces"], process=False).vertex_normals
        np.testing.assert_allclose(n, ref, atol=1e-5)
        centre = (m["pts"].min(0) + m["pts"].max(0)) / 2
        assert (np.einsum("ij,ij->i", n, m["pts"] - centre) > 0).all()
        np.testing.assert_allclose(m["pts"].min(0), [info[str(oid)][k] for k in ("min_x", "min_y", "min_z")], atol=1e-3)
    assert "mesh origin" in side["model_origin"]


def test_targets_list_the_exported_instances(bop_export):
    """test_targets_bop19.json: per image and obj_id the instances with visib_fract >= 0.1 (get_im_targets,
    localisation); test_targets_bop24.json: every image (create_test_targets.py, detection)."""
    _, out = bop_export
    gts, infos = _read(out, *SD, "scene_gt.json"), _read(out, *SD, "scene_gt_info.json")
    expect = []
    for im_id in sorted(gts, key=int):
        counts = {}
        for gt, info in zip(gts[im_id], infos[im_id]):
            if info["visib_fract"] >= 0.1:
                counts[gt["obj_id"]] = counts.get(gt["obj_id"], 0) + 1
        expect += [{"im_id": int(im_id), "inst_count": c, "obj_id": o, "scene_id": 0}
                   for o, c in sorted(counts.items())]
    t19 = _read(out, "test_targets_bop19.json")
    assert t19 == expect
    low = [i["visib_fract"] for v in infos.values() for i in v if 0 < i["visib_fract"] < 0.1]
    if low:                                                        # the zoomed export has such instances
        assert len(t19) < sum(len(v) for v in gts.values())
    assert _read(out, "test_targets_bop24.json") == [{"im_id": int(i), "scene_id": 0} for i in sorted(gts, key=int)]


def test_split_folder_is_chosen_by_the_user(tiny_scene_dir, tmp_path):
    """Scenes go under the split folder (test by default, train or val on request), the models, camera and
    targets at the dataset root; a split BOP does not know is refused before anything is written."""
    s = export_scene(tiny_scene_dir, "bop", tmp_path / "o", objects="box", window_us=100_000,
                     format_options={"split": "train"})
    assert s.written > 0
    top = {p.name for p in (tmp_path / "o").iterdir()}
    assert {"train", "models", "camera.json", "test_targets_bop19.json", "test_targets_bop24.json"} <= top
    assert "test" not in top and (tmp_path / "o" / "train" / "000000" / "scene_gt.json").is_file()
    with pytest.raises(ExportError, match="split"):
        export_scene(tiny_scene_dir, "bop", tmp_path / "bad", format_options={"split": "../x"})
    assert not (tmp_path / "bad").exists() or not any((tmp_path / "bad").iterdir())


def test_ply_reader_in_this_file_rejects_what_the_toolkit_would(tmp_path):
    """The reader above follows the toolkit: a type name it does not know (e.g. float32) fails."""
    p = tmp_path / "m.ply"
    p.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty float32 x\nend_header\n"
                  + struct.pack("<f", 1.0))
    with pytest.raises(KeyError):
        toolkit_load_ply(p)


def test_detection_targets_list_images_without_localisation_targets(occlusion_scene_dir, tmp_path):
    """Only cube2, zoomed twice: it drops below 10 % visible mid-sequence, so later images have no
    localisation target, yet every image is a detection target (bop24)."""
    scene = Scene.open(occlusion_scene_dir)
    K = scene.camera.K.copy()
    K[:2, :2] *= 2.0
    out = tmp_path / "o"
    s = export_scene(scene, "bop", out, objects="cube2", format_options={"K_new": K.tolist()})
    scene.close()
    ids = sorted(int(k) for k in _read(out, *SD, "scene_gt.json"))
    t19, t24 = _read(out, "test_targets_bop19.json"), _read(out, "test_targets_bop24.json")
    assert len(ids) == s.written and 0 < len(t19) < len(ids)
    assert [e["im_id"] for e in t24] == ids


@pytest.mark.parametrize("whole", [True, False], ids=["whole", "tiles"])
@pytest.mark.parametrize("side", ["left", "right", "top", "bottom", "corner"])
@pytest.mark.parametrize("overhang_px", [0.3, 1.6, 3.2])
def test_silhouettes_just_past_the_border_count(side, overhang_px, whole, monkeypatch):
    """A box whose silhouette ends a fraction of a pixel to a few pixels past an image border (or past two,
    at the bottom-right corner): the pixels it covers outside the image (their centres, BOP's sampling)
    count in px_count_all and bbox_obj, exactly as open3d casts them on the canvas (none for 0.3 px: the
    next pixel centre is 1 px out); rendered on the whole canvas or tile by tile (large sensors)."""
    o3d = pytest.importorskip("open3d")
    import trimesh

    from evpose.core.data.camera import CameraModel
    from evpose.core.data.objects import ObjectModel
    from evpose.core.export import bop_gt_info as gt_info_module
    from evpose.core.export.bop_gt_info import EnlargedCanvas, gt_info
    from evpose.core.label.raster import Rasterizer

    if not whole:
        monkeypatch.setattr(gt_info_module, "WHOLE_CANVAS_MAX_PX", 0)

    W, H, f = 60, 40, 50.0
    cam = CameraModel([[f, 0, 29.3], [0, f, 19.6], [0, 0, 1]], (), W, H)
    box = trimesh.creation.box(extents=(0.02, 0.02, 0.02))
    model = ObjectModel("b", np.asarray(box.vertices), np.asarray(box.faces))
    z, half = 0.5, 0.01                     # front face at z - half: its edges are the silhouette's
    zf = z - half
    edge = {"left": -0.5 - overhang_px, "right": W - 0.5 + overhang_px,
            "top": -0.5 - overhang_px, "bottom": H - 0.5 + overhang_px, "corner": None}[side]
    T = np.eye(4)
    if side in ("left", "right"):
        sgn = -1 if side == "left" else 1
        T[:3, 3] = [(edge - cam.K[0, 2]) / f * zf - sgn * half, 0.0, z]
    elif side in ("top", "bottom"):
        sgn = -1 if side == "top" else 1
        T[:3, 3] = [0.0, (edge - cam.K[1, 2]) / f * zf - sgn * half, z]
    else:
        T[:3, 3] = [(W - 0.5 + overhang_px - cam.K[0, 2]) / f * zf - half,
                    (H - 0.5 + overhang_px - cam.K[1, 2]) / f * zf - half, z]
    full = Rasterizer(cam).full_mask(model, T)
    e = gt_info(full, full, np.ones((H, W), bool), EnlargedCanvas(cam).outside(model, T))
    K_bop = cam.K + [[0, 0, 0.5], [0, 0, 0.5], [0, 0, 0]]
    rays, off = canvas_rays(K_bop, W, H)
    rc = o3d.t.geometry.RaycastingScene()
    V = np.asarray(box.vertices) @ T[:3, :3].T + T[:3, 3]
    rc.add_triangles(o3d.core.Tensor(V.astype(np.float32)), o3d.core.Tensor(np.asarray(box.faces, np.uint32)))
    sil = np.isfinite(rc.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy())
    ref = bop_gt_info(sil, sil[off[1]:off[1] + H, off[0]:off[0] + W], off)
    outside = ref["px_count_all"] - int(full.sum())
    assert (outside == 0) == (overhang_px < 1), outside
    assert e["px_count_all"] == ref["px_count_all"] and e["bbox_obj"] == ref["bbox_obj"], (e, ref)


def test_cli_split_option(tiny_scene_dir, tmp_path, capsys):
    """``evpose export --format bop --split train``; ``--split`` with another format is refused (exit 2)."""
    import argparse

    from evpose.app.cli.export import add_export_parser

    def cli(argv):
        p = argparse.ArgumentParser(prog="evpose")
        add_export_parser(p.add_subparsers(dest="command"))
        args = p.parse_args(["export", *argv])
        return args.func(args)

    common = [str(tiny_scene_dir), "--objects", "box", "--window-ms", "100", "-q"]
    assert cli(common + ["--format", "bop", "--out", str(tmp_path / "b"), "--split", "train"]) == 0
    assert (tmp_path / "b" / "train" / "000000" / "scene_gt.json").is_file()
    assert cli(common + ["--format", "h5", "--out", str(tmp_path / "h"), "--split", "train"]) == 2
    assert "--split" in capsys.readouterr().err and not (tmp_path / "h").exists()
    assert cli(common + ["--format", "bop", "--out", str(tmp_path / "x"), "--split", "holdout"]) == 2
    assert "split" in capsys.readouterr().err
