"""YCB-Ev (Rojtberg & Pöllabauer, github.com/paroj/ycbev): zstd event files + BOP annotations (``evpose import ycbev``).

Sources: the sequence folder (``scene_gt.json``, optional ``scene_camera.json``, ``scene_times.json``) and/or
files; missing pieces (events, calibrations, models) are looked up beside the folder as the published layout has
them, and the zstd event stream is decoded in bounded memory (:mod:`evpose.core.importers.ycbev_files`).
``--time-origin-us`` is added to every time (default 0).

Poses: ``scene_gt.json`` (BOP: per image id a list of ``{obj_id, cam_R_m2c (9, row-major), cam_t_m2c (3, mm)}``).
Image ``j`` is at ``time_origin + (j + frame_index_offset) * frame_us`` with the defaults ``frame_us = 33333``
(``1000000 // 30``) and ``frame_index_offset = 1``, which reproduces the authors' ``event_pose_overlay.py``
(``lerp_poses``: at event time ``k * 33333`` µs the pose is image ``k - 1``'s). A ``scene_times.json`` beside
``scene_gt.json`` (our BOP export's timing sidecar: ``t_label_us`` per image id) overrides that rule.
The poses are in the RGB camera; they are moved into the event camera with ``T_ev_rgb`` from
``calib_stereo_c2ev.json`` (``R_c2ev``, ``t_c2ev`` in mm) when that file is given or found (``--rgb-to-event
none`` if the poses are already in the event camera, as after our export).

The scene is static and the camera moves, so ``T_base_cam`` is derived from the object poses: with
``scene_camera.json`` world poses (``cam_R_w2c``/``cam_t_w2c``) the base is that world; else, with
``--objects name=mesh:T.json`` the given objects anchor the base frame; else the base frame is the frame of the
object seen most often. Other objects' ``T_base_obj`` is the mean over frames; the disagreement is reported.

The poses as read (in the event camera, metres) are kept in ``source_poses.npz``. Meshes given with ``--objects``
are taken in metres.

Calibration: ``--camera``, else ``calib_prophesee.json`` (``camera_matrix``, ``distortion_coefficients``,
``img_size``), else ``cam_K`` of ``scene_camera.json`` without distortion (size from ``--width/--height``,
default 1280x720 of the Prophesee Gen4, reported). Meshes: BOP ``obj_XXXXXX.ply`` in mm (``mesh_scale =
0.001`` unless ``--mesh-scale``); object names from the YCB-Video list
(:data:`~evpose.core.importers.ycbev_files.YCBV_NAMES`; ``obj_XXXXXX`` otherwise).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from evpose.core.data.camera import CameraError, CameraModel
from evpose.core.data.geometry import make_T
from evpose.core.importers.calibration import load_camera
from evpose.core.importers.failure import ImportFailure, wrap_errors
from evpose.core.importers.object_args import parse_objects_arg
from evpose.core.importers.pose_checks import check_T, make_trajectory, poses_from_matrices
from evpose.core.importers.report import ImportContext, result_summary
from evpose.core.importers.scene_builder import SceneBuilder
from evpose.core.importers.static_scene import chordal_mean, derive_camera_trajectory
from evpose.core.importers.ycbev_files import (
    PSHIFT,
    XMASK,
    YCBV_NAMES,
    YSHIFT,
    iter_event_file,
    locate,
    read_json,
)


def import_ycbev(sources, out, ctx: ImportContext) -> dict:
    """Import a YCB-Ev sequence into a scene folder; returns the summary (see ``result_summary``)."""
    found = locate(sources, ctx)
    for role, what in (("gt", "scene_gt.json"), ("events", "an events .zst file")):
        if role not in found:
            raise ImportFailure(", ".join(map(str, sources)), "(arguments)", role, f"no {what} among the sources")
    gt_path = found["gt"]
    gt = read_json(gt_path)
    if not isinstance(gt, dict) or not gt:
        raise ImportFailure(gt_path, "(file)", "-", "expected a non-empty object {image id: [annotations]}")
    scam = read_json(found["scene_camera"]) if "scene_camera" in found else None
    if scam is not None and not isinstance(scam, dict):
        raise ImportFailure(found["scene_camera"], "(file)", "-", "expected an object {image id: {...}}")
    ids, t_us = _frame_times(ctx, gt, gt_path, found)
    tracks, obj_ids = _read_tracks(ctx, gt, gt_path, ids, _rgb_to_event(ctx, found))
    camera = _camera(ctx, found, scam, ids, gt_path)
    given = {a.name: a for a in parse_objects_arg(ctx.options.objects, ctx)}
    for nm in given:
        if nm not in tracks:
            raise ImportFailure("--objects", nm, "name", f"no such object in scene_gt.json (have {', '.join(tracks)})")
    t_cam, T_cam, T_base_obj = _base_frame(ctx, tracks, given, scam, ids, t_us, found, gt_path)
    rec_of = {int(t): f"image {i}" for t, i in zip(t_us, ids)}
    pos, quat, _ = poses_from_matrices(ctx, gt_path, T_cam, lambda j: rec_of[int(t_cam[j])])
    traj = make_trajectory(ctx, gt_path, t_cam, pos, quat, record_of=lambda j: rec_of[int(t_cam[j])])
    meshes = _Meshes(ctx, found, given, obj_ids, gt_path)
    with SceneBuilder(out, ctx) as sb:
        sink = sb.event_sink(camera.width, camera.height)
        _stream_events(ctx, found["events"], sink)
        sb.finish_events(sink, found["events"])
        sb.set_trajectory(traj, "cam")
        sb.save_source_poses(t_us, tracks)
        for nm, T in T_base_obj.items():
            if T is None:
                ctx.report.warn(f"{nm}: never seen together with a camera pose; left out")
                continue
            mesh, scale = meshes.of(nm)
            sb.add_object(nm, mesh, T, mesh_scale=scale, class_id=obj_ids[nm], source=str(gt_path))
        sb.commit(camera)
    ctx.progress(1.0, "done")
    return result_summary(ctx, sb.out)


def _frame_times(ctx: ImportContext, gt: dict, gt_path: Path, found: dict) -> tuple[list[int], np.ndarray]:
    """Sorted image ids and their times (µs): ``scene_times.json`` if present, else the overlay-script rule."""
    opts, rep = ctx.options, ctx.report
    ids = []
    for key in gt:
        try:
            ids.append(int(key))
        except ValueError:
            raise ImportFailure(gt_path, f"image {key!r}", "key", "image ids must be integers") from None
    ids.sort()
    origin = int(opts.time_origin_us)
    if "times" in found:
        tj = read_json(found["times"])
        t_us = []
        for i in ids:
            e = tj.get(str(i)) if isinstance(tj, dict) else None
            if not isinstance(e, dict) or not isinstance(e.get("t_label_us"), int):
                raise ImportFailure(found["times"], f"image {i}", "t_label_us", "missing or not an integer")
            t_us.append(e["t_label_us"] + origin)
        with wrap_errors(found["times"], "(file)", "t_label_us", "outside the int64 µs range"):
            t_us = np.asarray(t_us, np.int64)
        rep.assume(f"image times from {found['times'].name} (t_label_us)" + (f" + {origin} µs" if origin else ""))
    else:
        with wrap_errors(gt_path, "(file)", "key", "image id outside the int64 range"):
            t_us = origin + (np.asarray(ids, np.int64) + int(opts.frame_index_offset)) * int(opts.frame_us)
        rep.assume(f"image j at {origin} + (j + {opts.frame_index_offset}) * {opts.frame_us} µs (YCB-Ev overlay "
                   "script convention; --frame-us/--frame-index-offset/--time-origin-us)")
    return ids, t_us


def _rgb_to_event(ctx: ImportContext, found: dict) -> np.ndarray | None:
    """``T_ev_rgb`` from ``calib_stereo_c2ev.json`` (``--rgb-to-event``: auto, a path, or none)."""
    opts, rep = ctx.options, ctx.report
    c2ev = found.get("c2ev")
    if opts.rgb_to_event not in (None, "auto", "none"):
        c2ev = Path(opts.rgb_to_event)
    elif opts.rgb_to_event == "auto" and c2ev is None:
        c2ev = found.get("c2ev_auto")
    if opts.rgb_to_event == "none":
        c2ev = None
    if c2ev is None:
        rep.assume("scene_gt poses are taken as already in the event camera (no calib_stereo_c2ev.json)")
        return None
    d = read_json(c2ev)
    with wrap_errors(c2ev, "(file)", "R_c2ev/t_c2ev", "malformed"):
        T = make_T(np.asarray(d["R_c2ev"], np.float64).reshape(3, 3),
                   np.asarray(d["t_c2ev"], np.float64).ravel()[:3] * 1e-3)
    T_ev_rgb, _ = check_T(T, ctx, c2ev, "(file)", "R_c2ev")
    rep.assume(f"scene_gt poses are in the RGB camera; moved into the event camera with {c2ev.name} "
               "(t_c2ev in mm)")
    return T_ev_rgb


def _read_tracks(ctx: ImportContext, gt: dict, gt_path: Path, ids, T_ev_rgb):
    """``({object: {frame index: T_cam_obj}}, {object: obj_id})`` from ``scene_gt.json`` (event camera, metres);
    a second instance of an object in one image is ``<name>_2``."""
    tracks: dict[str, dict[int, np.ndarray]] = {}
    obj_ids: dict[str, int] = {}
    for k, i in enumerate(ids):
        anns = gt[str(i)] if str(i) in gt else gt[next(key for key in gt if int(key) == i)]
        if not isinstance(anns, list):
            raise ImportFailure(gt_path, f"image {i}", "-", "expected a list of annotations")
        seen: dict[int, int] = {}
        for a_i, a in enumerate(anns):
            oid, T = _annotation(ctx, a, gt_path, f"image {i}, annotation {a_i}")
            seen[oid] = seen.get(oid, 0) + 1
            base = YCBV_NAMES.get(oid, f"obj_{oid:06d}")
            name = base if seen[oid] == 1 else f"{base}_{seen[oid]}"
            obj_ids[name] = oid
            tracks.setdefault(name, {})[k] = T if T_ev_rgb is None else T_ev_rgb @ T
    if not tracks:
        raise ImportFailure(gt_path, "(all images)", "-", "no annotations")
    return tracks, obj_ids


def _annotation(ctx: ImportContext, a, gt_path: Path, rec: str) -> tuple[int, np.ndarray]:
    """``(obj_id, T_cam_obj)`` of one BOP annotation (``cam_t_m2c`` in mm -> metres)."""
    if not isinstance(a, dict):
        raise ImportFailure(gt_path, rec, "-", "expected an object")
    oid = a.get("obj_id")
    if not isinstance(oid, int) or isinstance(oid, bool) or oid < 0:
        raise ImportFailure(gt_path, rec, "obj_id", f"expected a non-negative integer, got {oid!r}")
    try:
        R = np.asarray(a["cam_R_m2c"], np.float64)
        tt = np.asarray(a["cam_t_m2c"], np.float64)
    except KeyError as exc:
        raise ImportFailure(gt_path, rec, exc.args[0], "missing") from None
    except (TypeError, ValueError):
        raise ImportFailure(gt_path, rec, "cam_R_m2c/cam_t_m2c", "not numbers") from None
    if R.size != 9 or tt.size != 3:
        raise ImportFailure(gt_path, rec, "cam_R_m2c" if R.size != 9 else "cam_t_m2c",
                            f"expected 9 and 3 numbers, got {R.size} and {tt.size}")
    T = make_T(R.reshape(3, 3), tt.ravel() * 1e-3)
    check_T(T, ctx, gt_path, rec, "cam_R_m2c", quiet=True)
    return oid, T


def _camera(ctx: ImportContext, found: dict, scam, ids, gt_path: Path) -> CameraModel:
    """``--camera`` or ``calib_prophesee.json``, else ``cam_K`` of ``scene_camera.json`` without distortion."""
    opts = ctx.options
    if opts.camera or "camera" in found:
        return load_camera(opts.camera or found["camera"], ctx, default_size=(1280, 720))
    if scam is None:
        raise ImportFailure(gt_path, "(arguments)", "camera", "no calibration (calib_prophesee.json, --camera or "
                            "scene_camera.json)")
    e = scam.get(str(ids[0]))
    if not isinstance(e, dict) or "cam_K" not in e:
        raise ImportFailure(found["scene_camera"], f"image {ids[0]}", "cam_K", "missing")
    size = (opts.width or 1280, opts.height or 720)
    try:
        camera = CameraModel(np.asarray(e["cam_K"], np.float64).reshape(3, 3), [], size[0], size[1],
                             source=str(found["scene_camera"]))
    except (CameraError, ValueError, TypeError) as exc:
        raise ImportFailure(found["scene_camera"], f"image {ids[0]}", "cam_K", str(exc)) from None
    ctx.report.assume(f"camera from scene_camera.json cam_K without distortion, sensor {size[0]}x{size[1]}")
    return camera


def _base_frame(ctx: ImportContext, tracks: dict, given: dict, scam, ids, t_us, found: dict, gt_path: Path):
    """``(t_cam, T_base_cam, {object: T_base_obj or None})``: the world of ``scene_camera.json`` when every
    image has a world pose and no ``T_base_obj`` is given, else derived from the objects (static scene)."""
    known = {nm: a.T_raw for nm, a in given.items() if a.T_raw is not None}
    world = _world_poses(scam, ids, found.get("scene_camera"), ctx) if scam is not None and not known else None
    if world is None:
        return derive_camera_trajectory(ctx, gt_path, t_us, tracks, known)
    t_cam, T_cam = t_us[world[0]], world[1]
    T_base_obj = {}
    for nm, tr in tracks.items():
        ks = [k for k in tr if k in set(world[0].tolist())]
        idx = {int(k): j for j, k in enumerate(world[0])}
        T_base_obj[nm] = chordal_mean(np.stack([T_cam[idx[k]] @ tr[k] for k in ks])) if ks else None
    ctx.report.assume("base frame = the world of scene_camera.json (cam_R_w2c/cam_t_w2c)")
    return t_cam, T_cam, T_base_obj


def _world_poses(scam: dict, ids, path, ctx: ImportContext):
    """(frame indices, T_world_cam) from ``cam_R_w2c``/``cam_t_w2c`` (mm) when every image has them."""
    ks, Ts = [], []
    for k, i in enumerate(ids):
        e = scam.get(str(i))
        if not isinstance(e, dict) or "cam_R_w2c" not in e or "cam_t_w2c" not in e:
            return None
        with wrap_errors(path, f"image {i}", "cam_R_w2c/cam_t_w2c", "malformed"):
            T = make_T(np.asarray(e["cam_R_w2c"], np.float64).reshape(3, 3),
                       np.asarray(e["cam_t_w2c"], np.float64).ravel()[:3] * 1e-3)
        T, _ = check_T(T, ctx, path, f"image {i}", "cam_R_w2c", quiet=True)
        ks.append(k)
        Ts.append(np.linalg.inv(T))
    return np.asarray(ks), np.stack(Ts)


class _Meshes:
    """The mesh of each object: ``--objects`` (metres), else BOP ``obj_XXXXXX.ply`` in ``--models`` or the
    models folder found beside the sequence (mm unless ``--mesh-scale``, reported)."""

    def __init__(self, ctx: ImportContext, found: dict, given: dict, obj_ids: dict, gt_path: Path):
        opts = ctx.options
        self.given, self.obj_ids = given, obj_ids
        self.models = Path(opts.models) if opts.models else found.get("models")
        self.scale = float(opts.mesh_scale) if opts.mesh_scale else 1e-3
        if not opts.mesh_scale:
            ctx.report.assume("BOP meshes in millimetres: mesh_scale = 0.001 (--mesh-scale)")

    def of(self, nm: str) -> tuple[Path, float]:
        """``(mesh file, mesh_scale)`` of object ``nm``."""
        a = self.given.get(nm)
        if a is not None and a.mesh is not None:
            return a.mesh, 1.0
        mesh = self.models / f"obj_{self.obj_ids[nm]:06d}.ply" if self.models is not None else None
        if mesh is None or not mesh.is_file():
            raise ImportFailure(mesh or "(models)", nm, "mesh", "no mesh: give --models DIR (BOP "
                                "obj_XXXXXX.ply) or --objects name=mesh")
        return mesh, self.scale


def _stream_events(ctx: ImportContext, ev: Path, sink) -> None:
    """Decode the packed events of the zstd file chunk by chunk into ``sink`` (times + ``--time-origin-us``)."""
    origin = int(ctx.options.time_origin_us)
    size = ev.stat().st_size
    for i0, d, nread in iter_event_file(ev, ctx):
        packed = d[:, 1]
        x = packed & XMASK
        y = (packed >> YSHIFT) & XMASK
        p = (packed >> PSHIFT) & 0xF
        sink.add(x, y, d[:, 0].astype(np.int64) + origin, p, file=ev, record=f"events [{i0}, {i0 + len(d)})")
        ctx.progress(0.97 * nread / max(size, 1), f"{i0 + len(d):,} events")
