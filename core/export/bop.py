"""BOP layout (https://github.com/thodan/bop_toolkit, docs/bop_datasets_format.md) of undistorted event frames.

Output::

    OUT/camera.json                      cx, cy, fx, fy, width, height, depth_scale of the undistorted camera
    OUT/models/obj_OOOOOO.ply            meshes in millimetres (binary PLY, float32 vertices)
    OUT/models/models_info.json          diameter, min_x/y/z, size_x/y/z (mm) per obj_id
    OUT/SSSSSS/rgb/IIIIII.png            event frame of window IIIIII (undistorted, polarity colours)
    OUT/SSSSSS/mask/IIIIII_GGGGGG.png    amodal mask of the GGGGGG-th ground-truth object (8-bit 0/255)
    OUT/SSSSSS/mask_visib/IIIIII_GGGGGG.png   visible mask (8-bit 0/255)
    OUT/SSSSSS/scene_camera.json         cam_K, depth_scale, cam_R_w2c, cam_t_w2c (world = robot base, mm)
    OUT/SSSSSS/scene_gt.json             obj_id, cam_R_m2c (row-major), cam_t_m2c (mm)
    OUT/SSSSSS/scene_gt_info.json        bbox_obj, bbox_visib, px_count_all/valid/visib, visib_fract
    OUT/SSSSSS/scene_times.json          t_start_us, t_end_us, t_label_us (event clock), n_events, offset_us, skew_ppm

``SSSSSS`` is the scene id (default 0), ``IIIIII`` the zero-based window index of the tiling (so ids
match the other formats and the manifest; unlabeled and unverified windows have no image, leaving
gaps), ``GGGGGG`` the position of the object in the image's ``scene_gt`` list: every exported object
appears in every image, in the scene's object order, also when out of view (then its masks are empty
and ``visib_fract`` 0).

Camera: the pinhole camera ``K_new`` (default: the raw camera's ``K``) without distortion, same size as
the sensor. Events move to undistorted integer pixels through :func:`evpose.core.label.event_frames.undistort.undistorter_for`
(each event to exactly one pixel, so counts are preserved; events whose pixel maps outside the image
are dropped). Masks are rasterised directly in the undistorted camera (exact, no resampling).

``rgb`` encoding: 8-bit RGB, ON events red, OFF events blue on black,
:func:`evpose.core.label.event_frames.display.polarity_rgb` (``count / s`` clipped to 1, ``s`` = 99th percentile of the window's
non-zero counts); G is 0.

``obj_id``: the scene's ``class_id`` when the exported objects' class ids are distinct and >= 1,
otherwise the 1-based position among the exported objects (recorded in export_manifest.json).

``px_count_valid``: amodal-mask pixels that are valid in the undistorted image (their ray falls on the
raw sensor within the monotonic distortion radius); there is no depth image.
``bbox_obj``: tight box of the amodal mask within the image (not extended beyond the image border).
"""
from __future__ import annotations

import json
import time

import numpy as np

from evpose.core.data.atomic import AtomicBatch, write_atomic
from evpose.core.data.geometry import inv_T
from evpose.core.export.encode import encode_png, json_text
from evpose.core.export.fingerprint import evpose_version
from evpose.core.export.options import ExportError
from evpose.core.export.writer import FormatWriter
from evpose.core.label.event_frames.counts import polarity_counts
from evpose.core.label.event_frames.undistort import undistorter_for
from evpose.core.label.labels import Request


def _K_of(scene, K_new):
    return np.asarray(scene.camera.K if K_new is None else K_new, np.float64)


def bop_obj_ids(scene, names) -> dict:
    """obj_id per exported object (see the module docstring)."""
    ids = [int(scene.manifest.object(n).class_id) for n in names]
    if len(set(ids)) == len(ids) and min(ids) >= 1:
        return dict(zip(names, ids))
    return {n: j for j, n in enumerate(names, 1)}


def polarity_rgb_black(pos: np.ndarray, neg: np.ndarray, percentile: float = 99.0) -> np.ndarray:
    """``polarity_rgb(pos, neg, background="black", percentile)``, bit-identical (tested against
    evpose.core.label.event_frames.display), computed only at pixels with events."""
    H, W = pos.shape
    out = np.zeros((H * W, 3), np.uint8)
    p, n = pos.ravel(), neg.ravel()
    idx = np.flatnonzero(p | n)
    if len(idx) == 0:
        return out.reshape(H, W, 3)
    pi, ni = p[idx], n[idx]
    vals = np.concatenate([np.abs(pi[pi != 0]), np.abs(ni[ni != 0])]).astype(np.float64)
    s = float(np.percentile(vals, percentile))
    if not s > 0:
        s = float(vals.max())
    for ch, a in ((0, pi), (2, ni)):                 # R = ON, B = OFF, G = 0
        v = np.clip(a / s, 0.0, 1.0)
        v *= 255.0
        np.rint(v, out=v)
        out[idx, ch] = v
    return out.reshape(H, W, 3)


def _dump_keyed(d: dict) -> str:
    """BOP-style JSON: one image id per line, ids in numeric order, floats exact (repr)."""
    keys = sorted(d, key=int)
    if not keys:
        return "{}\n"
    return "{\n" + ",\n".join(f"  {json.dumps(str(k))}: {json.dumps(d[k])}" for k in keys) + "\n}\n"


class BopWriter(FormatWriter):
    """BOP writer (see the module docstring for every encoding)."""

    fmt = "bop"

    def __init__(self, K_new=None, scene_id: int = 0, png_compression: int = 1):
        if K_new is not None:
            K_new = np.asarray(K_new, np.float64)
            if K_new.shape != (3, 3):
                raise ExportError(f"K_new: expected a 3x3 matrix, got shape {K_new.shape}")
            K_new = K_new.tolist()
        if isinstance(scene_id, bool) or int(scene_id) != scene_id or scene_id < 0:
            raise ExportError(f"scene_id: must be an integer >= 0, got {scene_id!r}")
        self.K_new = K_new
        self.scene_id = int(scene_id)
        self.png_compression = int(png_compression)

    def options(self) -> dict:
        return {"K_new": self.K_new, "scene_id": self.scene_id, "png_compression": self.png_compression}

    def output_camera(self, scene):
        return scene.camera.undistorted(_K_of(scene, self.K_new))

    def request(self, margin_m: float) -> Request:
        return Request(keypoints=False, masks_visible=True, masks_full=True, label_map=False, margin_m=margin_m)

    def scene_dir(self, out_dir):
        return out_dir / f"{self.scene_id:06d}"

    def last_file(self, ctx, index):
        return self.scene_dir(ctx.out_dir) / "rgb" / f"{index:06d}.png"

    # ------------------------------------------------------------------ parent
    def begin(self, ctx) -> None:
        import trimesh

        scene = ctx.scene
        sd = self.scene_dir(ctx.out_dir)
        dirs = [sd] + [sd / sub for sub in ("rgb", "mask", "mask_visib")] + [ctx.out_dir / "models"]
        ctx.owned.dirs([d for d in dirs if not d.is_dir()])       # logged before they exist (evpose.core.data.owned_files)
        for d in dirs:
            d.mkdir(exist_ok=True)
        ids = bop_obj_ids(scene, ctx.names)
        info = {}
        for n in ctx.names:
            m = scene.model(n)
            lo, hi = m.bbox_min_max
            data = trimesh.Trimesh(m.vertices_m * 1000.0, m.faces, process=False).export(file_type="ply")
            write_atomic(ctx.out_dir / "models" / f"obj_{ids[n]:06d}.ply", data, ctx.fsync, ctx.owned)
            info[str(ids[n])] = {"diameter": m.diameter_m * 1000.0,
                                 "min_x": float(lo[0] * 1000.0), "min_y": float(lo[1] * 1000.0),
                                 "min_z": float(lo[2] * 1000.0), "size_x": float((hi[0] - lo[0]) * 1000.0),
                                 "size_y": float((hi[1] - lo[1]) * 1000.0), "size_z": float((hi[2] - lo[2]) * 1000.0)}
        write_atomic(ctx.out_dir / "models" / "models_info.json", _dump_keyed(info).encode(), ctx.fsync, ctx.owned)
        K = _K_of(scene, self.K_new)
        cam = scene.camera
        write_atomic(ctx.out_dir / "camera.json",
                     json_text({"cx": K[0, 2], "cy": K[1, 2], "depth_scale": 1.0, "fx": K[0, 0], "fy": K[1, 1],
                                "height": cam.height, "width": cam.width}).encode(), ctx.fsync, ctx.owned)
        write_atomic(ctx.out_dir / "README.txt", self.readme(ctx).encode(), ctx.fsync, ctx.owned)
        ctx.extra["object_extra"] = {n: {"obj_id": ids[n]} for n in ctx.names}
        ctx.extra["manifest_extra"] = {"K_new": K.tolist(), "scene_id": self.scene_id}

    def finish(self, ctx, records) -> list[str]:
        sd = self.scene_dir(ctx.out_dir)
        written = {i: r for i, r in records.items() if r.get("status") == "written"}
        for name, key in (("scene_gt.json", "gt"), ("scene_gt_info.json", "info"), ("scene_camera.json", "cam"),
                          ("scene_times.json", "times")):
            write_atomic(sd / name, _dump_keyed({i: r[key] for i, r in written.items()}).encode(), ctx.fsync, ctx.owned)
        ids = bop_obj_ids(ctx.scene, ctx.names)
        s = f"{self.scene_id:06d}"
        files = ["camera.json", "models/models_info.json"] + [f"models/obj_{ids[n]:06d}.ply" for n in ctx.names]
        files += [f"{s}/{n}" for n in ("scene_gt.json", "scene_gt_info.json", "scene_camera.json", "scene_times.json")]
        files.append("README.txt")
        per = []
        for i in sorted(written):
            per.append(f"{s}/rgb/{i:06d}.png")
            for g in range(len(ctx.names)):
                per += [f"{s}/mask/{i:06d}_{g:06d}.png", f"{s}/mask_visib/{i:06d}_{g:06d}.png"]
        ctx.extra["n_window_files"] = len(per)
        patterns = [f"{s}/rgb/{{index:06d}}.png", f"{s}/mask/{{index:06d}}_{{gt:06d}}.png",
                    f"{s}/mask_visib/{{index:06d}}_{{gt:06d}}.png"]
        return files + per, patterns

    # ------------------------------------------------------------------ worker
    def setup_worker(self, wctx) -> dict:
        scene = wctx.scene
        raw = scene.camera
        K = _K_of(scene, self.K_new)
        cam = wctx.camera
        # undistorted pixels whose ray falls on the raw sensor within the monotonic distortion radius
        vv, uu = np.mgrid[0:cam.height, 0:cam.width].astype(np.float64)
        x = (uu - K[0, 2] - K[0, 1] * (vv - K[1, 2]) / K[1, 1]) / K[0, 0]
        y = (vv - K[1, 2]) / K[1, 1]
        ok_r = x * x + y * y <= raw.r_max ** 2
        uv = np.full((x.size, 2), np.nan)
        if ok_r.any():
            uv[ok_r.ravel()] = raw.distort_normalized(np.stack([x[ok_r], y[ok_r]], axis=1))
        with np.errstate(invalid="ignore"):
            valid = ((uv[:, 0] >= -0.5) & (uv[:, 0] < raw.width - 0.5)
                     & (uv[:, 1] >= -0.5) & (uv[:, 1] < raw.height - 0.5)).reshape(cam.height, cam.width)
        ids = bop_obj_ids(scene, wctx.names)
        clock = scene.clock
        return {"und": undistorter_for(raw, K), "valid": valid, "K": K.ravel().tolist(),
                "obj_ids": [ids[n] for n in wctx.names], "offset_us": int(clock.offset_us),
                "skew_ppm": float(clock.skew_ppm), "empty": None}

    def process(self, wctx, task, ev, labels):
        st = wctx.state
        cam = wctx.camera
        H, W = cam.height, cam.width
        w = task.window
        sd = self.scene_dir(wctx.out_dir)
        t0 = time.perf_counter()
        evu = st["und"].apply(ev)
        pos, neg = polarity_counts(evu, W, H)
        rgb = polarity_rgb_black(pos, neg)
        comp = self.png_compression
        blobs = []
        gt, info = [], []
        empty = None
        for g, (k, oid) in enumerate(zip(wctx.sel, st["obj_ids"])):
            o = labels.objects[k]
            T = o.T_cam_obj
            gt.append({"cam_R_m2c": T[:3, :3].ravel().tolist(), "cam_t_m2c": (T[:3, 3] * 1000.0).tolist(),
                       "obj_id": int(oid)})
            full, vis = o.mask_full, o.mask_visible
            if full is None or vis is None:
                if empty is None:
                    empty = encode_png(np.zeros((H, W), np.uint8), compression=comp)
                b_full = b_vis = empty
                n_valid = 0
            else:
                b_full = encode_png(full.view(np.uint8) * np.uint8(255), compression=comp)
                b_vis = b_full if vis is full else encode_png(vis.view(np.uint8) * np.uint8(255), compression=comp)
                n_valid = int(np.count_nonzero(full & st["valid"]))
            info.append({"bbox_obj": [int(v) for v in o.bbox_obj], "bbox_visib": [int(v) for v in o.bbox_visib],
                         "px_count_all": int(o.px_count_all), "px_count_valid": n_valid,
                         "px_count_visib": int(o.px_count_visib), "visib_fract": float(o.visib_fract)})
            blobs.append((sd / "mask" / f"{w.index:06d}_{g:06d}.png", b_full))
            blobs.append((sd / "mask_visib" / f"{w.index:06d}_{g:06d}.png", b_vis))
        blobs.append((sd / "rgb" / f"{w.index:06d}.png", encode_png(rgb, compression=comp)))
        T_cb = inv_T(task.T_base_cam)
        rec = {"i": w.index, "status": "written", "gt": gt, "info": info,
               "cam": {"cam_K": st["K"], "depth_scale": 1.0, "cam_R_w2c": T_cb[:3, :3].ravel().tolist(),
                       "cam_t_w2c": (T_cb[:3, 3] * 1000.0).tolist()},
               "times": {"t_start_us": int(w.t0_us), "t_end_us": int(w.t1_us), "t_label_us": int(w.t_label_us),
                         "n_events": int(len(ev)), "n_events_in_image": int(len(evu)),
                         "offset_us": st["offset_us"], "skew_ppm": st["skew_ppm"]}}
        t1 = time.perf_counter()
        with AtomicBatch(wctx.fsync_files, wctx.owned) as batch:
            for path, data in blobs:
                batch.add(path, data)                         # rgb last: marks the window complete
        t2 = time.perf_counter()
        wctx.timings["images"] += t1 - t0
        wctx.timings["write"] += t2 - t1
        return rec, None

    def readme(self, ctx) -> str:
        scene = ctx.scene
        clock = scene.clock
        K = _K_of(scene, self.K_new)
        ids = bop_obj_ids(scene, ctx.names)
        objs = ", ".join(f"obj_{ids[n]:06d} = {n}" for n in ctx.names)
        fp = ctx.fingerprint["windows"]
        win = (f"{fp['window_us']} us" if fp["window_us"] is not None else f"{fp['window_events']} events")
        return f"""BOP-layout export of event windows of scene "{scene.name}" written by evpose {evpose_version()}.
See export_manifest.json for the exact configuration, clock, corrections and per-window status.

- Images: one per labeled window [t0, t1) of {win} (half-open, tiling the recording; every event in one
  window); image id = zero-based window index. rgb/IIIIII.png: the window's events moved to the
  UNDISTORTED pinhole camera K_new = {K.tolist()} (no distortion, {scene.camera.width}x{scene.camera.height}),
  ON events red, OFF events blue on black, intensity = count / (99th percentile of the window's
  non-zero counts), clipped. Events whose undistorted pixel falls outside the image are dropped.
- Masks: rasterised in that same undistorted camera (exact, no resampling); mask = amodal, mask_visib =
  visible (occlusion by every scene object); 8-bit 0/255.
- Poses: cam_R_m2c (row-major), cam_t_m2c in mm at the window's label time
  ({"centre" if ctx.label_at == "center" else "end"} of the window, event clock); cam_R_w2c / cam_t_w2c: world = robot base.
- Timing sidecar scene_times.json (same ids): t_start_us, t_end_us, t_label_us on the event clock,
  n_events in the window (n_events_in_image after undistortion), and the clock used:
  t_pose = t_event + offset_us + skew_ppm*1e-6*(t_event - t_ref_us), offset_us = {clock.offset_us},
  skew_ppm = {clock.skew_ppm!r}, t_ref_us = {clock.t_ref_us} (the recording's first event).
- Objects: {objs}; models in mm. No depth images (depth_scale 1.0 is nominal); px_count_valid counts amodal
  pixels that the raw sensor covers.
"""
