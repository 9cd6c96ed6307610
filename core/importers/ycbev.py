"""YCB-Ev (Rojtberg & Pöllabauer, github.com/paroj/ycbev): zstd event files + BOP annotations (``evpose import ycbev``).

Sources: the sequence folder (``scene_gt.json``, optional ``scene_camera.json``, ``scene_times.json``) and/or
files; missing pieces are looked up beside the folder as the published layout has them:
``<parent>/<seq>_events.int32.zst``, ``<parent>/calib_prophesee.json``, ``<parent>/calib_stereo_c2ev.json``,
``<parent>/ycbv_models/models_eval/obj_XXXXXX.ply``.

Event file (as ``ycbev.load_event_data`` of the authors' repository reads it): a zstd stream (one or more
frames) of little-endian int32 pairs ``[t, packed]`` with ``t`` in µs from the recording start and
``packed = x | y << 14 | p << 28`` (x, y: 14 bits each; p: 4 bits, 0/1). It is decompressed as a stream
(bounded memory); a truncated frame is an error. ``--time-origin-us`` is added to every time (default 0).

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
0.001`` unless ``--mesh-scale``); object names from the YCB-Video list below (``obj_XXXXXX`` otherwise).
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from evpose.core.data.camera import CameraError, CameraModel
from evpose.core.data.geometry import make_T
from evpose.core.importers.common import (
    ImportContext,
    ImportFailure,
    SceneBuilder,
    check_T,
    chordal_mean,
    derive_camera_trajectory,
    load_camera,
    make_trajectory,
    parse_objects_arg,
    poses_from_matrices,
    result_summary,
    wrap_errors,
)

XMASK, YSHIFT, PSHIFT = 0x3FFF, 14, 28
#: YCB-Video object ids (BOP ycbv) -> names.
YCBV_NAMES = {1: "master_chef_can", 2: "cracker_box", 3: "sugar_box", 4: "tomato_soup_can", 5: "mustard_bottle",
              6: "tuna_fish_can", 7: "pudding_box", 8: "gelatin_box", 9: "potted_meat_can", 10: "banana",
              11: "pitcher_base", 12: "bleach_cleanser", 13: "bowl", 14: "mug", 15: "power_drill", 16: "wood_block",
              17: "scissors", 18: "large_marker", 19: "large_clamp", 20: "extra_large_clamp", 21: "foam_brick"}
_READ = 1 << 20


def pack_events(t_us, x, y, p) -> bytes:
    """Raw (uncompressed) bytes of the YCB-Ev event layout (for tests and converters)."""
    d = np.empty((len(t_us), 2), "<i4")
    d[:, 0] = t_us
    d[:, 1] = (np.asarray(x, np.int32) & XMASK) | ((np.asarray(y, np.int32) & XMASK) << YSHIFT) | (
        (np.asarray(p, np.int32) & 0xF) << PSHIFT)
    return d.tobytes()


def iter_event_file(path: Path, ctx: ImportContext, chunk_events: int = 1 << 20):
    """Yield ``(index of first event, int32 array (n, 2), compressed bytes read)`` from a zstd event file,
    streamed frame by frame."""
    import zstandard

    dctx = zstandard.ZstdDecompressor()
    with wrap_errors(path, "(file)", "-", "cannot open"):
        f = open(path, "rb")
    with f:
        dobj, in_frame = dctx.decompressobj(), False
        pending = bytearray()
        n_done, pos = 0, 0
        rec_bytes = 8 * chunk_events
        while True:
            ctx.check_cancel()
            with wrap_errors(path, f"byte {pos}", "-", "cannot read"):
                data = f.read(_READ)
            if not data:
                break
            pos += len(data)
            while data:
                with wrap_errors(path, f"compressed byte ~{pos}", "zstd", "corrupt zstd stream"):
                    pending += dobj.decompress(data)
                in_frame = True
                data = b""
                if dobj.eof:
                    data = dobj.unused_data
                    dobj, in_frame = dctx.decompressobj(), False
            while len(pending) >= rec_bytes:
                yield n_done, np.frombuffer(bytes(pending[:rec_bytes]), "<i4").reshape(-1, 2), pos
                del pending[:rec_bytes]
                n_done += chunk_events
        if in_frame and not dobj.eof:
            raise ImportFailure(path, f"event {n_done + len(pending) // 8}", "zstd",
                                "the compressed stream ends inside a frame (truncated file)")
        if len(pending) % 8:
            raise ImportFailure(path, f"event {n_done + len(pending) // 8}", "t/packed",
                                f"{len(pending) % 8} trailing byte(s): the data is not int32 pairs")
        if pending:
            yield n_done, np.frombuffer(bytes(pending), "<i4").reshape(-1, 2), pos


def _json(path: Path):
    with wrap_errors(path, "(file)", "-", "cannot read"):
        text = path.read_bytes().decode("utf-8")
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise ImportFailure(path, f"line {exc.lineno}", "-", f"not valid JSON ({exc.msg})") from None


def _locate(sources, ctx: ImportContext) -> dict:
    found: dict[str, Path] = {}
    folders = []
    for s in map(Path, sources):
        if s.is_dir():
            folders.append(s)
            for nm, role in (("scene_gt.json", "gt"), ("scene_camera.json", "scene_camera"),
                             ("scene_times.json", "times")):
                if (s / nm).is_file():
                    found.setdefault(role, s / nm)
        elif s.is_file():
            nm = s.name
            if nm.endswith(".zst"):
                found["events"] = s
            elif nm == "scene_gt.json":
                found["gt"] = s
                folders.append(s.parent)
            elif nm == "scene_camera.json":
                found["scene_camera"] = s
            elif nm == "scene_times.json":
                found["times"] = s
            elif nm.endswith(".json"):
                d = _json(s)
                if isinstance(d, dict) and "R_c2ev" in d:
                    found["c2ev"] = s
                elif isinstance(d, dict) and ("camera_matrix" in d or "K" in d):
                    found["camera"] = s
                else:
                    raise ImportFailure(s, "(file)", "SRC", "unknown JSON (expected scene_gt/scene_camera/"
                                        "calibration)")
            else:
                raise ImportFailure(s, "(file)", "SRC", "unknown role (expected a sequence folder, *.zst, *.json)")
        else:
            raise ImportFailure(s, "(file)", "SRC", "no such file or folder")
    for d in folders:
        for nm, role in (("scene_camera.json", "scene_camera"), ("scene_times.json", "times")):
            if (d / nm).is_file():
                found.setdefault(role, d / nm)
        par = d.parent
        if "events" not in found:
            for c in (par / f"{d.name}_events.int32.zst", d / "events.int32.zst"):
                if c.is_file():
                    found["events"] = c
                    ctx.report.assume(f"event file found beside the sequence: {c}")
                    break
        if "camera" not in found and (par / "calib_prophesee.json").is_file():
            found["camera"] = par / "calib_prophesee.json"
        if "c2ev" not in found and (par / "calib_stereo_c2ev.json").is_file():
            found["c2ev_auto"] = par / "calib_stereo_c2ev.json"
        if "models" not in found:
            for c in (par / "ycbv_models" / "models_eval", par / "models_eval", par / "models"):
                if c.is_dir():
                    found["models"] = c
                    break
    return found


def import_ycbev(sources, out, ctx: ImportContext) -> dict:
    opts, rep = ctx.options, ctx.report
    found = _locate(sources, ctx)
    for role, what in (("gt", "scene_gt.json"), ("events", "an events .zst file")):
        if role not in found:
            raise ImportFailure(", ".join(map(str, sources)), "(arguments)", role, f"no {what} among the sources")
    gt_path = found["gt"]
    gt = _json(gt_path)
    if not isinstance(gt, dict) or not gt:
        raise ImportFailure(gt_path, "(file)", "-", "expected a non-empty object {image id: [annotations]}")
    scam = _json(found["scene_camera"]) if "scene_camera" in found else None
    if scam is not None and not isinstance(scam, dict):
        raise ImportFailure(found["scene_camera"], "(file)", "-", "expected an object {image id: {...}}")
    # ---- frame times
    try:
        ids = sorted(int(k) for k in gt)
    except ValueError:
        bad = next(k for k in gt if not k.strip().lstrip("-").isdigit())
        raise ImportFailure(gt_path, f"image {bad!r}", "key", "image ids must be integers") from None
    origin = int(opts.time_origin_us)
    if "times" in found:
        tj = _json(found["times"])
        t_us = []
        for i in ids:
            e = tj.get(str(i)) if isinstance(tj, dict) else None
            if not isinstance(e, dict) or not isinstance(e.get("t_label_us"), int):
                raise ImportFailure(found["times"], f"image {i}", "t_label_us", "missing or not an integer")
            t_us.append(e["t_label_us"] + origin)
        t_us = np.asarray(t_us, np.int64)
        rep.assume(f"image times from {found['times'].name} (t_label_us)" + (f" + {origin} µs" if origin else ""))
    else:
        t_us = origin + (np.asarray(ids, np.int64) + int(opts.frame_index_offset)) * int(opts.frame_us)
        rep.assume(f"image j at {origin} + (j + {opts.frame_index_offset}) * {opts.frame_us} µs (YCB-Ev overlay "
                   "script convention; --frame-us/--frame-index-offset/--time-origin-us)")
    # ---- RGB -> event camera
    T_ev_rgb = None
    c2ev = found.get("c2ev")
    if opts.rgb_to_event not in (None, "auto", "none"):
        c2ev = Path(opts.rgb_to_event)
    elif opts.rgb_to_event == "auto" and c2ev is None:
        c2ev = found.get("c2ev_auto")
    if opts.rgb_to_event == "none":
        c2ev = None
    if c2ev is not None:
        d = _json(c2ev)
        with wrap_errors(c2ev, "(file)", "R_c2ev/t_c2ev", "malformed"):
            T = make_T(np.asarray(d["R_c2ev"], np.float64).reshape(3, 3),
                       np.asarray(d["t_c2ev"], np.float64).ravel()[:3] * 1e-3)
        T_ev_rgb, _ = check_T(T, ctx, c2ev, "(file)", "R_c2ev")
        rep.assume(f"scene_gt poses are in the RGB camera; moved into the event camera with {c2ev.name} "
                   "(t_c2ev in mm)")
    else:
        rep.assume("scene_gt poses are taken as already in the event camera (no calib_stereo_c2ev.json)")
    # ---- tracks
    tracks: dict[str, dict[int, np.ndarray]] = {}
    obj_ids: dict[str, int] = {}
    for k, i in enumerate(ids):
        anns = gt[str(i)] if str(i) in gt else gt[next(key for key in gt if int(key) == i)]
        if not isinstance(anns, list):
            raise ImportFailure(gt_path, f"image {i}", "-", "expected a list of annotations")
        seen: dict[int, int] = {}
        for a_i, a in enumerate(anns):
            rec = f"image {i}, annotation {a_i}"
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
            seen[oid] = seen.get(oid, 0) + 1
            base = YCBV_NAMES.get(oid, f"obj_{oid:06d}")
            name = base if seen[oid] == 1 else f"{base}_{seen[oid]}"
            obj_ids[name] = oid
            tracks.setdefault(name, {})[k] = T if T_ev_rgb is None else T_ev_rgb @ T
    if not tracks:
        raise ImportFailure(gt_path, "(all images)", "-", "no annotations")
    # ---- camera
    camera = None
    if opts.camera or "camera" in found:
        camera = load_camera(opts.camera or found["camera"], ctx, default_size=(1280, 720))
    elif scam is not None:
        e = scam.get(str(ids[0]))
        if not isinstance(e, dict) or "cam_K" not in e:
            raise ImportFailure(found["scene_camera"], f"image {ids[0]}", "cam_K", "missing")
        size = (opts.width or 1280, opts.height or 720)
        try:
            camera = CameraModel(np.asarray(e["cam_K"], np.float64).reshape(3, 3), [], size[0], size[1],
                                 source=str(found["scene_camera"]))
        except (CameraError, ValueError, TypeError) as exc:
            raise ImportFailure(found["scene_camera"], f"image {ids[0]}", "cam_K", str(exc)) from None
        rep.assume(f"camera from scene_camera.json cam_K without distortion, sensor {size[0]}x{size[1]}")
    else:
        raise ImportFailure(gt_path, "(arguments)", "camera", "no calibration (calib_prophesee.json, --camera or "
                            "scene_camera.json)")
    # ---- base frame and camera trajectory
    given = {a.name: a for a in parse_objects_arg(opts.objects, ctx)}
    for nm in given:
        if nm not in tracks:
            raise ImportFailure("--objects", nm, "name", f"no such object in scene_gt.json (have {', '.join(tracks)})")
    known = {nm: a.T_raw for nm, a in given.items() if a.T_raw is not None}
    world = _world_poses(scam, ids, found.get("scene_camera"), ctx) if scam is not None and not known else None
    if world is not None:
        t_cam, T_cam = t_us[world[0]], world[1]
        T_base_obj = {}
        for nm, tr in tracks.items():
            ks = [k for k in tr if k in set(world[0].tolist())]
            idx = {int(k): j for j, k in enumerate(world[0])}
            T_base_obj[nm] = chordal_mean(np.stack([T_cam[idx[k]] @ tr[k] for k in ks])) if ks else None
        rep.assume("base frame = the world of scene_camera.json (cam_R_w2c/cam_t_w2c)")
    else:
        t_cam, T_cam, T_base_obj = derive_camera_trajectory(ctx, gt_path, t_us, tracks, known)
    rec_of = {int(t): f"image {i}" for t, i in zip(t_us, ids)}
    pos, quat, _ = poses_from_matrices(ctx, gt_path, T_cam, lambda j: rec_of[int(t_cam[j])])
    traj = make_trajectory(ctx, gt_path, t_cam, pos, quat, record_of=lambda j: rec_of[int(t_cam[j])])
    # ---- meshes
    models = Path(opts.models) if opts.models else found.get("models")
    scale = float(opts.mesh_scale) if opts.mesh_scale else 1e-3
    if not opts.mesh_scale:
        rep.assume("BOP meshes in millimetres: mesh_scale = 0.001 (--mesh-scale)")

    with SceneBuilder(out, ctx) as sb:
        sink = sb.event_sink(camera.width, camera.height)
        ev = found["events"]
        size = ev.stat().st_size
        for i0, d, nread in iter_event_file(ev, ctx):
            packed = d[:, 1]
            x = packed & XMASK
            y = (packed >> YSHIFT) & XMASK
            p = (packed >> PSHIFT) & 0xF
            sink.add(x, y, d[:, 0].astype(np.int64) + origin, p, file=ev, record=f"events [{i0}, {i0 + len(d)})")
            ctx.progress(0.97 * nread / max(size, 1), f"{i0 + len(d):,} events")
        sb.finish_events(sink, ev)
        sb.set_trajectory(traj, "cam")
        sb.save_source_poses(t_us, tracks)
        for nm, T in T_base_obj.items():
            if T is None:
                rep.warn(f"{nm}: never seen together with a camera pose; left out")
                continue
            a = given.get(nm)
            if a is not None and a.mesh is not None:
                mesh, sc = a.mesh, 1.0
            else:
                mesh = models / f"obj_{obj_ids[nm]:06d}.ply" if models is not None else None
                sc = scale
                if mesh is None or not mesh.is_file():
                    raise ImportFailure(mesh or "(models)", nm, "mesh", "no mesh: give --models DIR (BOP "
                                        "obj_XXXXXX.ply) or --objects name=mesh")
            sb.add_object(nm, mesh, T, mesh_scale=sc, class_id=obj_ids[nm], source=str(gt_path))
        sb.commit(camera)
    ctx.progress(1.0, "done")
    return result_summary(ctx, sb.out)


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

