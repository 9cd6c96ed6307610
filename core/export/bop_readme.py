"""The README.txt of a BOP export and its sidecar ``evpose_scene.json``: every convention of the files,
what differs from BOP's own datasets, and what evpose needs to read the export back
(:mod:`evpose.core.importers.bop`)."""
from __future__ import annotations

from evpose.core.export.bop_conventions import VISIB_GT_MIN, bop_K
from evpose.core.export.bop_shards import web_dir_name
from evpose.core.export.fingerprint import evpose_version

__all__ = ["readme_text", "scene_sidecar", "SIDECAR_NAME", "SIDECAR_FORMAT"]

#: Per-scene sidecar beside scene_gt.json (moves with the scene folder when scenes are assembled).
SIDECAR_NAME = "evpose_scene.json"
SIDECAR_FORMAT = "evpose-bop-scene/1"


def scene_sidecar(ctx, K, obj_ids: dict, split: str) -> dict:
    """``evpose_scene.json``: the OpenCV camera matrix beside BOP's ``cam_K``, the raw camera, the objects'
    names, the windows and the clock of the export of ``ctx`` (``K``: the OpenCV ``K_new``)."""
    scene = ctx.scene
    clock = scene.clock
    cam = scene.camera
    fp = ctx.fingerprint["windows"]
    return {
        "format": SIDECAR_FORMAT, "scene": scene.name, "split": split,
        "K_opencv": K.tolist(), "K_bop": bop_K(K).tolist(), "width": cam.width, "height": cam.height,
        "K_convention": "cam_K (BOP) = K_opencv with cx + 0.5 and cy + 0.5: BOP's renderers put the pixel origin "
                        "at the top-left pixel's corner (pixel i sampled at i + 0.5), OpenCV/evpose at its centre",
        "images": "rgb/: events of each window moved to the undistorted camera K_opencv (no distortion); "
                  "R = ON events, B = OFF events, G = 0; no depth",
        "raw_camera": cam.to_dict(),
        "objects": [{"obj_id": int(obj_ids[n]), "name": n, "symmetric": bool(scene.manifest.object(n).symmetric)}
                    for n in ctx.names],
        "model_origin": "mesh origin of the scene's model (not the 3D bounding-box centre)",
        "windows": {"window_us": fp["window_us"], "window_events": fp["window_events"], "label_at": ctx.label_at},
        "clock": {"offset_us": int(clock.offset_us), "skew_ppm": float(clock.skew_ppm),
                  "t_ref_us": int(clock.t_ref_us)},
    }


def readme_text(ctx, K, obj_ids: dict, split: str, scene_id: int) -> str:
    """The README of the BOP export of ``ctx`` (``K``: the OpenCV ``K_new``)."""
    scene = ctx.scene
    clock = scene.clock
    objs = ", ".join(f"obj_{obj_ids[n]:06d} = {n}" for n in ctx.names)
    fp = ctx.fingerprint["windows"]
    win = (f"{fp['window_us']} us" if fp["window_us"] is not None else f"{fp['window_events']} events")
    s = f"{split}/{scene_id:06d}"
    Kb = bop_K(K)
    return f"""BOP-format export of event windows of scene "{scene.name}" written by evpose {evpose_version()}.
See export_manifest.json for the exact configuration, clock, corrections and per-window status.

- Layout: camera.json, models/, {s}/ (split "{split}", scene id {scene_id}), test_targets_bop19.json,
  test_targets_bop24.json. Use it with the BOP toolkit by registering a dataset name (see the evpose README).
- Images: one per labeled window [t0, t1) of {win} (half-open, tiling the recording; every event in one
  window); image id = zero-based window index. rgb/IIIIII.png: the window's events moved to the
  UNDISTORTED pinhole camera (no distortion, {scene.camera.width}x{scene.camera.height}) as an event-polarity
  image: ON events red, OFF events blue, green 0, intensity = count / (99th percentile of the window's
  non-zero counts), clipped. Events whose undistorted pixel falls outside the image are dropped.
  There is no depth image (depth_scale 1.0 is nominal): the depth-based VSD error does not apply;
  MSSD, MSPD (and ADD/ADI) do.
- cam_K is in BOP's pixel convention, origin at the top-left pixel's CORNER (pixel i sampled at i + 0.5,
  as the toolkit's renderers do): cam_K = {Kb.tolist()}.
  evpose and OpenCV put pixel centres at integers: K_opencv = cam_K with cx - 0.5, cy - 0.5 =
  {K.tolist()} (also in {s}/evpose_scene.json).
- Masks: rasterised in that undistorted camera (exact, no resampling); mask = amodal, mask_visib = visible
  (nearest surface along each pixel ray, every scene object occluding); 8-bit 0/255.
- scene_gt_info.json as BOP's calc_gt_info: px_count_all counts the whole silhouette on a canvas 3 x the
  image (also outside the image); visib_fract = px_count_visib / px_count_all; bbox_obj (whole silhouette,
  not clipped) and bbox_visib are [x, y, x_max - x_min, y_max - y_min], [-1, -1, -1, -1] when nothing is
  visible. px_count_valid: in-image silhouette pixels that the raw sensor covers.
- Targets: test_targets_bop19.json lists per image and obj_id the instances with visib_fract >= {VISIB_GT_MIN};
  test_targets_bop24.json lists every image.
- Poses: cam_R_m2c (row-major), cam_t_m2c in mm at the window's label time
  ({"centre" if ctx.label_at == "center" else "end"} of the window, event clock);
  cam_R_w2c / cam_t_w2c: world = robot base.
- Timing sidecar {s}/scene_times.json (same ids): t_start_us, t_end_us, t_label_us on the event clock,
  n_events in the window (n_events_in_image after undistortion), and the clock used:
  t_pose = t_event + offset_us + skew_ppm*1e-6*(t_event - t_ref_us), offset_us = {clock.offset_us},
  skew_ppm = {clock.skew_ppm!r}, t_ref_us = {clock.t_ref_us} (the recording's first event).
- Objects: {objs}. Models: binary PLY in mm with vertex normals; the model origin is the origin of the
  scene's mesh, NOT the centre of its 3D bounding box (models_info.json min_x/y/z say where the box is).
""" + _shards_text(ctx, split)


def _shards_text(ctx, split: str) -> str:
    """The README's paragraph on BOP-webdataset shards (``--bop-shards``; empty without)."""
    S = getattr(ctx.writer, "shard_windows", 0)
    if not S:
        return ""
    web = web_dir_name(split)
    return f"""- Shards (--bop-shards {S}): images and masks are NOT in rgb/, mask/, mask_visib/ but in
  {web}/shard-NNNNNN.tar (BOP-webdataset, bop_toolkit_lib/dataset/bop_webdataset.py), shard N = windows
  [{S}N, {S}(N+1)), not shuffled; {web}/key_to_shard.json maps each image KEY = SSSSSS_IIIIII
  (scene id {ctx.writer.key_scene_id}, image id) to its shard. Members: KEY.rgb.png, KEY.camera.json, KEY.gt.json, KEY.gt_info.json, KEY.mask.json and
  KEY.mask_visib.json ({{instance: uncompressed COCO RLE}} as bop_toolkit's pycoco_utils.binary_mask_to_rle,
  column-major runs starting with zeros). The scene-wise JSON files in {split}/ are written too.
"""
