"""BOP format (https://github.com/thodan/bop_toolkit, docs/bop_datasets_format.md) of undistorted event frames.

Output (``SPLIT``: ``test`` unless chosen, see :func:`~evpose.core.export.bop_conventions.check_split`)::

    OUT/camera.json                      cx, cy, fx, fy (BOP pixel convention), width, height, depth_scale
    OUT/models/obj_OOOOOO.ply            meshes in mm with vertex normals (:mod:`~evpose.core.export.bop_models`)
    OUT/models/models_info.json          diameter, min_x/y/z, size_x/y/z (mm) per obj_id
    OUT/test_targets_bop19.json          localisation targets: instances with visib_fract >= 0.1
    OUT/test_targets_bop24.json          detection targets: every image
    OUT/SPLIT/SSSSSS/rgb/IIIIII.png      event frame of window IIIIII (undistorted, R = ON, B = OFF, G = 0)
    OUT/SPLIT/SSSSSS/mask/IIIIII_GGGGGG.png        amodal mask of the GGGGGG-th ground-truth object (8-bit 0/255)
    OUT/SPLIT/SSSSSS/mask_visib/IIIIII_GGGGGG.png  visible mask (8-bit 0/255)
    OUT/SPLIT/SSSSSS/scene_camera.json   cam_K (BOP convention), depth_scale, cam_R_w2c, cam_t_w2c (world = base, mm)
    OUT/SPLIT/SSSSSS/scene_gt.json       obj_id, cam_R_m2c (row-major), cam_t_m2c (mm)
    OUT/SPLIT/SSSSSS/scene_gt_info.json  as BOP's calc_gt_info (:mod:`~evpose.core.export.bop_gt_info`)
    OUT/SPLIT/SSSSSS/scene_times.json    t_start_us, t_end_us, t_label_us (event clock), n_events, offset_us, skew_ppm
    OUT/SPLIT/SSSSSS/scene_gt_uncertainty.json  with --label-sigma: obj_id, sigma_t_mm, sigma_R_deg, sigma_px per
                                                instance (evpose.core.label.uncertainty)
    OUT/SPLIT/SSSSSS/evpose_scene.json   the OpenCV K, raw camera, object names, windows, clock (evpose's sidecar)

``SSSSSS`` is the scene id (default 0), ``IIIIII`` the zero-based window index of the tiling (so ids
match the other formats and the manifest; unlabeled and unverified windows have no image, leaving
gaps), ``GGGGGG`` the position of the object in the image's ``scene_gt`` list: every exported object
appears in every image, in the scene's object order, also when out of view (then its masks are empty
and ``visib_fract`` 0).

Camera: the pinhole camera ``K_new`` (default: the raw camera's ``K``) without distortion, same size as
the sensor. ``cam_K`` and ``camera.json`` hold it in BOP's pixel convention, ``cx + 0.5`` and ``cy + 0.5``
(:func:`~evpose.core.export.bop_conventions.bop_K`: the toolkit's renderers put the origin at the corner
of the top-left pixel), so that the toolkit renders the masks evpose wrote; ``evpose_scene.json`` keeps
``K_new`` in evpose's (OpenCV's) convention. Events move to undistorted integer pixels through
:func:`evpose.core.label.event_frames.undistort.undistorter_for` (each event to exactly one pixel, so counts
are preserved; events whose pixel maps outside the image are dropped). Masks are rasterised directly in
the undistorted camera (exact, no resampling).

``rgb`` encoding: 8-bit RGB, ON events red, OFF events blue on black,
:func:`evpose.core.label.event_frames.display.polarity_rgb` (``count / s`` clipped to 1, ``s`` = 99th percentile of the window's
non-zero counts); G is 0. No depth images.

With ``shard_windows`` S > 0 (``--bop-shards``) the images and masks go into BOP-webdataset shards instead of
``rgb/``, ``mask/``, ``mask_visib/``: ``OUT/SPLIT_web/shard-NNNNNN.tar`` of windows ``[N*S, (N+1)*S)`` and
``key_to_shard.json`` (:mod:`evpose.core.export.bop_shards`); the scene-wise JSON files are written as above. A chunk
of work holds whole shards (:meth:`BopWriter.chunk_group`); its worker writes them at the chunk's end.

``obj_id``: the scene's ``class_id`` when the exported objects' class ids are distinct and >= 1,
otherwise the 1-based position among the exported objects (recorded in export_manifest.json).
"""
from __future__ import annotations

import copy
import json
import threading
import time
import weakref

import numpy as np

from evpose.core.data.atomic import AtomicBatch, write_atomic
from evpose.core.data.geometry import inv_T
from evpose.core.export.bop_conventions import (
    DEFAULT_SPLIT,
    TARGETS_BOP19,
    TARGETS_BOP24,
    bop_K,
    check_split,
    targets_bop19,
    targets_bop24,
)
from evpose.core.export.bop_gt_info import EnlargedCanvas, gt_info
from evpose.core.export.bop_models import models_info_entry, ply_bytes, vertex_normals
from evpose.core.export.bop_readme import SIDECAR_NAME, readme_text, scene_sidecar
from evpose.core.export.bop_shards import (
    KEY_TO_SHARD,
    check_shard_windows,
    image_key,
    json_member,
    mask_rle,
    shard_name,
    shard_tar,
    web_dir_name,
)
from evpose.core.export.encode import encode_png, json_text
from evpose.core.export.options import ExportError
from evpose.core.export.writer import FormatWriter
from evpose.core.label.event_frames.counts import polarity_counts
from evpose.core.label.event_frames.undistort import undistorter_for
from evpose.core.label.labels import Request

__all__ = ["BopWriter", "bop_obj_ids", "polarity_rgb_black"]

_SCENE_FILES = ("scene_gt.json", "scene_gt_info.json", "scene_camera.json", "scene_times.json")


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


def _dump_keyed(d: dict, texts: dict | None = None) -> str:
    """BOP-style JSON: one image id per line, ids in numeric order, floats exact (repr). ``texts``: the
    ``json.dumps`` of some values, encoded already (by the workers: :data:`_TEXT_KEYS`)."""
    keys = sorted(d, key=int)
    if not keys:
        return "{}\n"
    texts = texts or {}
    return "{\n" + ",\n".join(f"  {json.dumps(str(k))}: {texts.get(k) or json.dumps(d[k])}" for k in keys) + "\n}\n"


#: The record fields of a window that go into the scene files, in :data:`_SCENE_FILES` order; a worker sends their
#: JSON text with the record (the payload), so the driver's ``finish`` joins text instead of encoding ~60 floats an
#: object per window (0.27 ms a 5-object window: the driver's largest cost per window, issue 27.2).
_TEXT_KEYS = ("gt", "info", "cam", "times")


def dump_list(items: list) -> str:
    """A JSON list, one item per line (the test targets)."""
    if not items:
        return "[]\n"
    return "[\n" + ",\n".join(f"  {json.dumps(e)}" for e in items) + "\n]\n"


#: model -> {object name: (PLY bytes, models_info entry)}: a dataset's scenes share their models
#: (:mod:`evpose.core.data.model_cache`), so a driver computes each object's normals and info once, not per scene.
_MODEL_FILES: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()
_MODEL_FILES_LOCK = threading.Lock()


#: Beside scene_gt.json with --label-sigma: per image, per instance (scene_gt's order) the label's 1-sigma.
UNCERTAINTY_FILE = "scene_gt_uncertainty.json"


def uncertainty_entries(written: dict, sigma: dict) -> dict:
    """``{image id: [{"obj_id", "sigma_t_mm", "sigma_R_deg", "sigma_px"}, ...]}`` of the written images, instances
    in ``scene_gt``'s order."""
    out = {}
    for i, rec in written.items():
        s = sigma[i]
        out[i] = [{"obj_id": g["obj_id"], "sigma_R_deg": _finite(s[k, 1]), "sigma_px": _finite(s[k, 2]),
                   "sigma_t_mm": _finite(s[k, 0])} for k, g in enumerate(rec["gt"])]
    return out


def _finite(v) -> float | None:
    """A float for JSON (null where not finite: a box wholly behind the camera has no contour sigma)."""
    v = float(v)
    return v if np.isfinite(v) else None


def _model_files(model, name: str) -> tuple[bytes, dict]:
    """``(PLY bytes, models_info entry)`` of ``name``'s model (cached while the model lives)."""
    with _MODEL_FILES_LOCK:
        hit = _MODEL_FILES.get(model, {}).get(name)
    if hit is None:
        V = model.vertices_m * 1000.0
        hit = (ply_bytes(V, model.faces, vertex_normals(V, model.faces), comment=f"evpose object {name} (mm, mesh origin)"),
               models_info_entry(model))
        with _MODEL_FILES_LOCK:
            _MODEL_FILES.setdefault(model, {})[name] = hit
    return hit[0], copy.deepcopy(hit[1])


class BopWriter(FormatWriter):
    """BOP writer (see the module docstring for every encoding)."""

    fmt = "bop"

    def __init__(self, K_new=None, scene_id: int = 0, png_compression: int = 1, split: str = DEFAULT_SPLIT,
                 shard_windows: int = 0, key_scene_id: int | None = None):
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
        self.split = check_split(split)
        try:
            self.shard_windows = check_shard_windows(shard_windows)
        except ValueError as exc:
            raise ExportError(str(exc)) from None
        if key_scene_id is not None and (isinstance(key_scene_id, bool) or int(key_scene_id) != key_scene_id
                                         or key_scene_id < 0):
            raise ExportError(f"key_scene_id: must be an integer >= 0, got {key_scene_id!r}")
        #: the scene id in the shards' image keys (a dataset export gives each scene its id in the dataset)
        self.key_scene_id = self.scene_id if key_scene_id is None else int(key_scene_id)

    def options(self) -> dict:
        opts = {"K_new": self.K_new, "scene_id": self.scene_id, "png_compression": self.png_compression,
                "split": self.split}
        if self.shard_windows:
            opts.update(shard_windows=self.shard_windows, key_scene_id=self.key_scene_id)
        return opts

    # ------------------------------------------------------------------ shards (evpose.core.export.bop_shards)
    def web_dir(self, out_dir):
        return out_dir / web_dir_name(self.split)

    def shard_of(self, index: int) -> int:
        return int(index) // self.shard_windows

    def chunk_group(self):
        if not self.shard_windows:
            return None
        S = self.shard_windows
        return lambda task: task.window.index // S

    def output_camera(self, scene):
        return scene.camera.undistorted(_K_of(scene, self.K_new))

    def request(self, margin_m: float) -> Request:
        return Request(keypoints=False, masks_visible=True, masks_full=True, label_map=False, margin_m=margin_m)

    def scene_rel(self) -> str:
        """The scene folder relative to the export folder: ``SPLIT/SSSSSS``."""
        return f"{self.split}/{self.scene_id:06d}"

    def scene_dir(self, out_dir):
        return out_dir / self.split / f"{self.scene_id:06d}"

    def last_file(self, ctx, index):
        if self.shard_windows:
            return self.web_dir(ctx.out_dir) / shard_name(self.shard_of(index))
        return self.scene_dir(ctx.out_dir) / "rgb" / f"{index:06d}.png"

    def completed(self, ctx) -> dict[int, dict]:
        """Resume: with shards, a window is complete when its shard exists and every window of the shard that this
        export writes is journaled (a shard is written whole; one written before a kill took its journal lines is
        written again, whole)."""
        done = super().completed(ctx)
        if not self.shard_windows:
            return done
        expected: dict[int, set] = {}
        for w, v in zip(ctx.extra.get("selected", []), ctx.extra.get("valid", [])):
            if v:
                expected.setdefault(self.shard_of(w.index), set()).add(w.index)
        whole = {n for n, idx in expected.items() if idx <= done.keys()}
        return {i: r for i, r in done.items() if self.shard_of(i) in whole}

    # ------------------------------------------------------------------ parent
    def begin(self, ctx) -> None:
        scene = ctx.scene
        sd = self.scene_dir(ctx.out_dir)
        dirs = [ctx.out_dir / self.split, sd]
        if self.shard_windows:
            dirs.append(self.web_dir(ctx.out_dir))
        else:
            dirs += [sd / sub for sub in ("rgb", "mask", "mask_visib")]
        dirs.append(ctx.out_dir / "models")
        ctx.owned.dirs([d for d in dirs if not d.is_dir()])       # logged before they exist (evpose.core.data.owned_files)
        for d in dirs:
            d.mkdir(exist_ok=True)
        ids = bop_obj_ids(scene, ctx.names)
        info = {}
        for n in ctx.names:
            data, info[str(ids[n])] = _model_files(scene.model(n), n)
            write_atomic(ctx.out_dir / "models" / f"obj_{ids[n]:06d}.ply", data, ctx.fsync, ctx.owned)
        write_atomic(ctx.out_dir / "models" / "models_info.json", _dump_keyed(info).encode(), ctx.fsync, ctx.owned)
        K = _K_of(scene, self.K_new)
        Kb = bop_K(K)
        cam = scene.camera
        write_atomic(ctx.out_dir / "camera.json",
                     json_text({"cx": Kb[0, 2], "cy": Kb[1, 2], "depth_scale": 1.0, "fx": Kb[0, 0],
                                "fy": Kb[1, 1],
                                "height": cam.height, "width": cam.width}).encode(), ctx.fsync, ctx.owned)
        write_atomic(sd / SIDECAR_NAME, json_text(scene_sidecar(ctx, K, ids, self.split)).encode(), ctx.fsync,
                     ctx.owned)
        write_atomic(ctx.out_dir / "README.txt", self.readme(ctx).encode(), ctx.fsync, ctx.owned)
        ctx.extra["object_extra"] = {n: {"obj_id": ids[n]} for n in ctx.names}
        ctx.extra["manifest_extra"] = {"K_new": K.tolist(), "cam_K_bop": Kb.tolist(), "scene_id": self.scene_id,
                                       "split": self.split}

    def finish(self, ctx, records) -> list[str]:
        sd = self.scene_dir(ctx.out_dir)
        written = {i: r for i, r in records.items() if r.get("status") == "written"}
        texts = ctx.extra.get("bop_texts", {})         # window -> the worker's JSON of _TEXT_KEYS (not on resume)
        for j, (name, key) in enumerate(zip(_SCENE_FILES, _TEXT_KEYS)):
            known = {i: t[j] for i, t in texts.items()}
            write_atomic(sd / name, _dump_keyed({i: r[key] for i, r in written.items()}, known).encode(), ctx.fsync,
                         ctx.owned)
        sigma = ctx.extra.get("label_sigma")
        if sigma is not None:              # --label-sigma: evpose.core.label.uncertainty
            write_atomic(sd / UNCERTAINTY_FILE, _dump_keyed(uncertainty_entries(written, sigma)).encode(), ctx.fsync,
                         ctx.owned)
        t19 = targets_bop19(self.scene_id, {i: (r["gt"], r["info"]) for i, r in written.items()})
        write_atomic(ctx.out_dir / TARGETS_BOP19, dump_list(t19).encode(), ctx.fsync, ctx.owned)
        write_atomic(ctx.out_dir / TARGETS_BOP24, dump_list(targets_bop24(self.scene_id, written)).encode(),
                     ctx.fsync, ctx.owned)
        ids = bop_obj_ids(ctx.scene, ctx.names)
        s = self.scene_rel()
        files = ["camera.json", "models/models_info.json", TARGETS_BOP19, TARGETS_BOP24]
        files += [f"models/obj_{ids[n]:06d}.ply" for n in ctx.names]
        files += [f"{s}/{n}" for n in _SCENE_FILES + (SIDECAR_NAME,)]
        if sigma is not None:
            files.append(f"{s}/{UNCERTAINTY_FILE}")
        files.append("README.txt")
        if self.shard_windows:
            web = web_dir_name(self.split)
            keys = {image_key(self.key_scene_id, i): self.shard_of(i) for i in sorted(written)}
            write_atomic(self.web_dir(ctx.out_dir) / KEY_TO_SHARD, json_member(keys), ctx.fsync,
                         ctx.owned)
            files.append(f"{web}/{KEY_TO_SHARD}")
            per = [f"{web}/{shard_name(n)}" for n in sorted(set(keys.values()))]
            patterns = [f"{web}/shard-{{shard:06d}}.tar"]
        else:
            per = []
            for i in sorted(written):
                per.append(f"{s}/rgb/{i:06d}.png")
                for g in range(len(ctx.names)):
                    per += [f"{s}/mask/{i:06d}_{g:06d}.png", f"{s}/mask_visib/{i:06d}_{g:06d}.png"]
            patterns = [f"{s}/rgb/{{index:06d}}.png", f"{s}/mask/{{index:06d}}_{{gt:06d}}.png",
                        f"{s}/mask_visib/{{index:06d}}_{{gt:06d}}.png"]
        ctx.extra["n_window_files"] = len(per)
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
        return {"und": undistorter_for(raw, K), "valid": valid, "K": bop_K(K).ravel().tolist(),
                "obj_ids": [ids[n] for n in wctx.names], "offset_us": int(clock.offset_us),
                "skew_ppm": float(clock.skew_ppm), "canvas": EnlargedCanvas(cam),
                "models": [scene.raster_model(n) for n in wctx.names], "shards": {}}

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
        sharded = bool(self.shard_windows)
        blobs = []
        gt, info = [], []
        rle_full, rle_vis = {}, {}
        empty = None
        for g, (k, oid) in enumerate(zip(wctx.sel, st["obj_ids"])):
            o = labels.objects[k]
            T = o.T_cam_obj
            gt.append({"cam_R_m2c": T[:3, :3].ravel().tolist(), "cam_t_m2c": (T[:3, 3] * 1000.0).tolist(),
                       "obj_id": int(oid)})
            full, vis = o.mask_full, o.mask_visible
            if full is None or vis is None:
                full = vis = None
            info.append(gt_info(full, vis, st["valid"], st["canvas"].outside(st["models"][g], T)))
            if sharded:                     # masks as RLE members of the shard (bop_imagewise.save_masks)
                rle_full[str(g)] = mask_rle(full, (H, W))
                rle_vis[str(g)] = rle_full[str(g)] if vis is full else mask_rle(vis, (H, W))
                continue
            if full is None:
                if empty is None:
                    empty = encode_png(np.zeros((H, W), np.uint8), compression=comp)
                b_full = b_vis = empty
            else:
                b_full = encode_png(full.view(np.uint8) * np.uint8(255), compression=comp)
                b_vis = b_full if vis is full else encode_png(vis.view(np.uint8) * np.uint8(255), compression=comp)
            blobs.append((sd / "mask" / f"{w.index:06d}_{g:06d}.png", b_full))
            blobs.append((sd / "mask_visib" / f"{w.index:06d}_{g:06d}.png", b_vis))
        rgb_png = encode_png(rgb, compression=comp)
        if not sharded:
            blobs.append((sd / "rgb" / f"{w.index:06d}.png", rgb_png))
        T_cb = inv_T(task.T_base_cam)
        rec = {"i": w.index, "status": "written", "gt": gt, "info": info,
               "cam": {"cam_K": st["K"], "depth_scale": 1.0, "cam_R_w2c": T_cb[:3, :3].ravel().tolist(),
                       "cam_t_w2c": (T_cb[:3, 3] * 1000.0).tolist()},
               "times": {"t_start_us": int(w.t0_us), "t_end_us": int(w.t1_us), "t_label_us": int(w.t_label_us),
                         "n_events": int(len(ev)), "n_events_in_image": int(len(evu)),
                         "offset_us": st["offset_us"], "skew_ppm": st["skew_ppm"]}}
        texts = tuple(json.dumps(rec[k]) for k in _TEXT_KEYS)     # the scene files' entries, encoded once
        t1 = time.perf_counter()
        if sharded:                          # written with its shard at the chunk's end (end_chunk)
            gt_text, info_text, cam_text, _ = texts
            members = {"rgb.png": rgb_png, "camera.json": cam_text.encode(), "gt.json": gt_text.encode(),
                       "gt_info.json": info_text.encode(), "mask.json": json_member(rle_full),
                       "mask_visib.json": json_member(rle_vis)}
            st["shards"].setdefault(self.shard_of(w.index), {})[image_key(self.key_scene_id, w.index)] = members
        else:
            with AtomicBatch(wctx.fsync_files, wctx.owned) as batch:
                for path, data in blobs:
                    batch.add(path, data)                         # rgb last: marks the window complete
        t2 = time.perf_counter()
        wctx.timings["images"] += t1 - t0
        wctx.timings["write"] += t2 - t1
        return rec, {"json": texts}

    def begin_chunk(self, wctx) -> None:
        wctx.state["shards"] = {}

    def end_chunk(self, wctx) -> None:
        """Write each shard of the chunk whole, atomically (the chunk holds whole shards: chunk_group)."""
        shards, wctx.state["shards"] = wctx.state.get("shards", {}), {}
        web = self.web_dir(wctx.out_dir)
        for n in sorted(shards):
            write_atomic(web / shard_name(n), shard_tar(list(shards[n].items())), wctx.fsync_files, wctx.owned)

    def accept(self, ctx, record, payload, line=None) -> None:
        super().accept(ctx, record, payload, line)
        if payload is not None:
            ctx.extra.setdefault("bop_texts", {})[record["i"]] = payload["json"]

    def readme(self, ctx) -> str:
        return readme_text(ctx, _K_of(ctx.scene, self.K_new), bop_obj_ids(ctx.scene, ctx.names), self.split,
                           self.scene_id)
