"""A BOP scene of event frames as an evpose scene (``evpose import bop BOP_DIR --scene ID``), to verify its
labels visually when no raw events exist.

Reads, from the scene folder (:mod:`evpose.core.importers.bop_files` finds it): ``scene_gt.json`` (per
image id ``obj_id``, ``cam_R_m2c``, ``cam_t_m2c`` in mm), ``scene_camera.json`` (``cam_K`` in BOP's pixel
convention; optional ``cam_R_w2c``/``cam_t_w2c``), ``rgb/IIIIII.png`` (event-polarity images, read back as
events), and when present evpose's sidecars ``scene_times.json`` and ``evpose_scene.json``; models from
``DATASET/models/obj_OOOOOO.ply`` (mm, ``mesh_scale = 0.001``) or ``--models``.

- Camera: the pinhole camera of the images, no distortion (the images are undistorted), size of the
  images. ``K`` = ``K_opencv`` of ``evpose_scene.json`` when present, else ``cam_K`` with ``cx - 0.5``,
  ``cy - 0.5`` (:func:`~evpose.core.export.bop_conventions.opencv_K`: BOP's pixel origin is the corner of
  the top-left pixel, evpose's its centre). Every image must have the same ``cam_K``.
- Timing: ``scene_times.json`` (evpose's) restores each image's window ``[t_start_us, t_end_us)`` and label
  time ``t_label_us`` on the event clock; without it image ``i`` is the window
  ``[origin + i * frame_us, origin + (i + 1) * frame_us)`` labelled at its centre (``--frame-us``, default
  33333 µs = 30 Hz nominal, ``--time-origin-us``), reported as an assumption.
- Events: one per lit pixel and polarity, spread over the image's window
  (:func:`~evpose.core.importers.bop_files.image_events`).
- Poses: the camera trajectory is sampled at the label times. With world poses (``cam_R_w2c``,
  ``cam_t_w2c`` in every image; evpose writes the robot base) the base frame is that world and each
  object's ``T_base_obj`` is the mean over the images (the largest disagreement is reported); else the
  scene is taken as static and the camera poses are derived from the objects
  (:func:`~evpose.core.importers.static_scene.derive_camera_trajectory`). The clock prior is zero: the
  trajectory is already on the event clock (the exported poses were interpolated with the clock in
  effect, which ``scene_times.json`` records and the report repeats). The poses as read are kept in
  ``source_poses.npz``.
- Objects: named after ``evpose_scene.json`` when present, else ``obj_OOOOOO``; a second instance of an
  ``obj_id`` in one image is ``<name>_2`` (instances are matched across images by their order).

Round trip: exporting the imported scene to BOP with the same window length and label time gives the
same windows, poses and lit pixels (``tests/core/test_import_bop.py``); the image ids start at the first
image with events.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from evpose.core.data.camera import CameraError, CameraModel
from evpose.core.data.geometry import make_T, orthonormalize, rotation_angle
from evpose.core.export.bop_conventions import opencv_K
from evpose.core.importers.bop_files import image_events, image_path, locate_scene, read_image, read_json
from evpose.core.importers.failure import ImportFailure
from evpose.core.importers.pose_checks import check_T, make_trajectory, poses_from_matrices
from evpose.core.importers.report import ImportContext, result_summary
from evpose.core.importers.scene_builder import SceneBuilder
from evpose.core.importers.static_scene import chordal_mean, derive_camera_trajectory

__all__ = ["import_bop"]

#: Objects whose per-image world poses disagree by more than this are reported (m, degrees).
WARN_SPREAD_M, WARN_SPREAD_DEG = 1e-3, 0.1


def import_bop(sources, out, ctx: ImportContext) -> dict:
    """Import one BOP scene into a scene folder; returns the summary (see ``result_summary``)."""
    where = locate_scene(sources, ctx.options.scene)
    sd = where.folder
    gt = read_json(sd / "scene_gt.json")
    if not isinstance(gt, dict) or not gt:
        raise ImportFailure(sd / "scene_gt.json", "(file)", "-",
                            "expected a non-empty object {image id: [annotations]}")
    ids = _image_ids(gt, sd / "scene_gt.json")
    scam = read_json(sd / "scene_camera.json") if (sd / "scene_camera.json").is_file() else {}
    side = read_json(sd / "evpose_scene.json") if (sd / "evpose_scene.json").is_file() else {}
    if not isinstance(scam, dict) or not isinstance(side, dict):
        raise ImportFailure(sd / ("scene_camera.json" if not isinstance(scam, dict) else "evpose_scene.json"),
                            "(file)", "-", "expected a JSON object")
    times = _times(ctx, sd, ids)
    camera = _camera(ctx, sd, scam, side, ids)
    tracks, obj_ids = _tracks(ctx, gt, sd / "scene_gt.json", ids, _names(side))
    t_label = times[:, 2]
    t_cam, T_cam, T_base_obj = _base_frame(ctx, sd, scam, ids, t_label, tracks)
    rec_of = {int(t): f"image {i}" for t, i in zip(t_label, ids)}
    pos, quat, _ = poses_from_matrices(ctx, sd / "scene_camera.json", T_cam, lambda j: rec_of[int(t_cam[j])])
    traj = make_trajectory(ctx, sd / "scene_gt.json", t_cam, pos, quat, record_of=lambda j: rec_of[int(t_cam[j])])
    models = _models_dir(ctx, where)
    symmetric = {int(o.get("obj_id", -1)): bool(o.get("symmetric")) for o in side.get("objects", [])
                 if isinstance(o, dict)}
    ctx.report.details["bop"] = {"scene_folder": str(sd), "split": where.split, "scene_id": where.scene_id,
                                 "images": len(ids), "models": str(models)}
    with SceneBuilder(out, ctx) as sb:
        sink = sb.event_sink(camera.width, camera.height)
        _stream_events(ctx, sd, ids, times, (camera.width, camera.height), sink)
        sb.finish_events(sink, sd / "rgb")
        sb.set_trajectory(traj, "cam")
        sb.save_source_poses(t_label, tracks)
        for nm, T in T_base_obj.items():
            if T is None:
                ctx.report.warn(f"{nm}: never seen together with a camera pose; left out")
                continue
            mesh = models / f"obj_{obj_ids[nm]:06d}.ply"
            if not mesh.is_file():
                raise ImportFailure(mesh, nm, "mesh", "no model: give --models DIR (BOP obj_OOOOOO.ply, mm)")
            sb.add_object(nm, mesh, T, mesh_scale=_mesh_scale(ctx), class_id=obj_ids[nm],
                          symmetric=symmetric.get(obj_ids[nm], False), source=str(sd / "scene_gt.json"))
        sb.commit(camera, name=ctx.options.name or side.get("scene") or None)
    ctx.progress(1.0, "done")
    return result_summary(ctx, sb.out)


def _image_ids(gt: dict, path) -> list[int]:
    ids = []
    for key in gt:
        try:
            ids.append(int(key))
        except ValueError:
            raise ImportFailure(path, f"image {key!r}", "key", "image ids must be integers") from None
        if ids[-1] < 0:
            raise ImportFailure(path, f"image {key!r}", "key", "image ids must be >= 0")
    return sorted(ids)


def _times(ctx: ImportContext, sd, ids) -> np.ndarray:
    """``(N, 3)`` int64 ``t_start_us, t_end_us, t_label_us`` per image (see the module docstring)."""
    path = sd / "scene_times.json"
    if not path.is_file():
        f, origin = int(ctx.options.frame_us), int(ctx.options.time_origin_us)
        t0 = origin + np.asarray(ids, np.int64) * f
        ctx.report.assume(f"no scene_times.json: image i is the window [{origin} + i * {f}, "
                          f"{origin} + (i + 1) * {f}) µs, "
                          "labelled at its centre (--frame-us, --time-origin-us)")
        return np.stack([t0, t0 + f, t0 + f // 2], axis=1)
    doc = read_json(path)
    out = np.empty((len(ids), 3), np.int64)
    for k, i in enumerate(ids):
        e = doc.get(str(i)) if isinstance(doc, dict) else None
        if not isinstance(e, dict):
            raise ImportFailure(path, f"image {i}", "-", "missing (scene_gt.json has this image)")
        for j, key in enumerate(("t_start_us", "t_end_us", "t_label_us")):
            v = e.get(key)
            if not isinstance(v, int) or isinstance(v, bool) or abs(v) >= 2**62:
                raise ImportFailure(path, f"image {i}", key, f"expected an integer µs, got {v!r}")
            out[k, j] = v
        if not out[k, 0] <= out[k, 2] <= out[k, 1] or out[k, 1] <= out[k, 0]:
            raise ImportFailure(path, f"image {i}", "t_label_us", f"expected t_start_us <= t_label_us <= t_end_us "
                                f"and t_start_us < t_end_us, got {out[k].tolist()}")
    ctx.report.assume("image windows and label times from scene_times.json (event clock)")
    return out


def _camera(ctx: ImportContext, sd, scam: dict, side: dict, ids) -> CameraModel:
    """The pinhole camera of the images (see the module docstring)."""
    path = sd / "scene_camera.json"
    Ks = {}
    for i in ids:
        e = scam.get(str(i))
        if isinstance(e, dict) and "cam_K" in e:
            try:
                Ks[i] = np.asarray(e["cam_K"], np.float64).reshape(3, 3)
            except (TypeError, ValueError):
                raise ImportFailure(path, f"image {i}", "cam_K", "expected 9 numbers") from None
    if Ks:
        first = next(iter(Ks))
        for i, K in Ks.items():
            if not np.array_equal(K, Ks[first]):
                raise ImportFailure(path, f"image {i}", "cam_K", f"differs from image {first}'s: an evpose scene has "
                                    "one camera")
    if "K_opencv" in side:
        K, src = side["K_opencv"], "K_opencv of evpose_scene.json"
    elif Ks:
        K = opencv_K(Ks[first])
        src = "cam_K of scene_camera.json with cx - 0.5, cy - 0.5 (BOP pixel origin at the corner)"
    else:
        raise ImportFailure(path, "(file)", "cam_K", "no camera matrix (scene_camera.json cam_K)")
    first_img = image_path(sd, ids[0])
    size = (side.get("width"), side.get("height"))
    if not all(isinstance(v, int) and not isinstance(v, bool) for v in size):
        img = read_image(first_img, ids[0])
        size = (img.shape[1], img.shape[0])
    try:
        camera = CameraModel(K, [], size[0], size[1], source=str(path))
    except (CameraError, ValueError, TypeError) as exc:
        raise ImportFailure(path, "(file)", "cam_K", str(exc)) from None
    ctx.report.assume(f"camera: undistorted pinhole {size[0]}x{size[1]}, K from {src}")
    return camera


def _names(side: dict) -> dict[int, str]:
    """obj_id -> object name from evpose's sidecar (empty without it)."""
    out = {}
    for o in side.get("objects", []) if isinstance(side.get("objects"), list) else []:
        if isinstance(o, dict) and isinstance(o.get("obj_id"), int) and isinstance(o.get("name"), str) and o["name"]:
            out[o["obj_id"]] = o["name"]
    return out


def _tracks(ctx: ImportContext, gt: dict, path, ids, names: dict):
    """``({object: {image index: T_cam_obj}}, {object: obj_id})`` (metres)."""
    tracks: dict[str, dict[int, np.ndarray]] = {}
    obj_ids: dict[str, int] = {}
    for k, i in enumerate(ids):
        anns = gt[str(i)] if str(i) in gt else gt[next(key for key in gt if int(key) == i)]
        if not isinstance(anns, list):
            raise ImportFailure(path, f"image {i}", "-", "expected a list of annotations")
        seen: dict[int, int] = {}
        for a_i, a in enumerate(anns):
            rec = f"image {i}, annotation {a_i}"
            if not isinstance(a, dict):
                raise ImportFailure(path, rec, "-", "expected an object")
            oid = a.get("obj_id")
            if not isinstance(oid, int) or isinstance(oid, bool) or oid < 0:
                raise ImportFailure(path, rec, "obj_id", f"expected a non-negative integer, got {oid!r}")
            T = _pose(ctx, a, path, rec, "cam_R_m2c", "cam_t_m2c")
            seen[oid] = seen.get(oid, 0) + 1
            base = names.get(oid, f"obj_{oid:06d}")
            name = base if seen[oid] == 1 else f"{base}_{seen[oid]}"
            obj_ids[name] = oid
            tracks.setdefault(name, {})[k] = T
    if not tracks:
        raise ImportFailure(path, "(all images)", "-", "no annotations")
    return tracks, obj_ids


def _pose(ctx: ImportContext, e: dict, path, rec: str, kR: str, kt: str) -> np.ndarray:
    """A 4x4 pose from a row-major rotation ``e[kR]`` (9 numbers) and a translation ``e[kt]`` in mm."""
    try:
        R = np.asarray(e[kR], np.float64)
        t = np.asarray(e[kt], np.float64)
    except KeyError as exc:
        raise ImportFailure(path, rec, exc.args[0], "missing") from None
    except (TypeError, ValueError):
        raise ImportFailure(path, rec, f"{kR}/{kt}", "not numbers") from None
    if R.size != 9 or t.size != 3:
        raise ImportFailure(path, rec, kR if R.size != 9 else kt,
                            f"expected 9 and 3 numbers, got {R.size} and {t.size}")
    T, _ = check_T(make_T(R.reshape(3, 3), t.ravel() * 1e-3), ctx, path, rec, kR, quiet=True)
    return T


def _base_frame(ctx: ImportContext, sd, scam: dict, ids, t_label, tracks: dict):
    """``(t_us, T_base_cam, {object: T_base_obj or None})``: the world of scene_camera.json when every
    image has one, else derived from the objects (static scene)."""
    path = sd / "scene_camera.json"
    worlds = []
    for i in ids:
        e = scam.get(str(i))
        if not isinstance(e, dict) or "cam_R_w2c" not in e or "cam_t_w2c" not in e:
            return derive_camera_trajectory(ctx, sd / "scene_gt.json", t_label, tracks, {})
        worlds.append(np.linalg.inv(_pose(ctx, e, path, f"image {i}", "cam_R_w2c", "cam_t_w2c")))
    T_cam = np.stack(worlds)
    T_base_obj: dict[str, np.ndarray | None] = {}
    worst = (0.0, 0.0, "")
    for nm, tr in tracks.items():
        ests = np.stack([T_cam[k] @ T for k, T in tr.items()])
        T_base_obj[nm] = M = chordal_mean(ests)
        for E in ests:
            dt = float(np.linalg.norm(E[:3, 3] - M[:3, 3]))
            dr = math.degrees(float(rotation_angle(M[:3, :3].T @ orthonormalize(E[:3, :3])[0])))
            if dt > worst[0] or dr > worst[1]:
                worst = (max(dt, worst[0]), max(dr, worst[1]), nm)
    ctx.report.assume("base frame = the world of scene_camera.json (cam_R_w2c/cam_t_w2c); T_base_obj = the mean "
                      "over the images (static objects)")
    ctx.report.details["object_spread"] = {"max_mm": worst[0] * 1e3, "max_deg": worst[1]}
    if worst[0] > WARN_SPREAD_M or worst[1] > WARN_SPREAD_DEG:
        ctx.report.warn(f"{sd / 'scene_gt.json'}: object {worst[2]!r} moves in the world frame by up to "
                        f"{worst[0] * 1e3:.2f} mm / {worst[1]:.3f} deg; the scene holds its mean pose")
    return np.asarray(t_label, np.int64), T_cam, T_base_obj


def _models_dir(ctx: ImportContext, where) -> Path:
    if ctx.options.models:
        return Path(ctx.options.models)
    for d in (where.root / "models", where.folder.parent / "models"):
        if d.is_dir():
            return d
    return where.root / "models"


def _mesh_scale(ctx: ImportContext) -> float:
    return float(ctx.options.mesh_scale) if ctx.options.mesh_scale else 1e-3


def _stream_events(ctx: ImportContext, sd, ids, times: np.ndarray, size, sink) -> None:
    """The events of every image, in window order."""
    order = np.argsort(times[:, 0], kind="stable")
    for n, j in enumerate(order):
        ctx.check_cancel()
        i = ids[j]
        path = image_path(sd, i)
        x, y, t, p = image_events(path, i, int(times[j, 0]), int(times[j, 1]), size)
        sink.add(x, y, t, p, file=path, record=f"image {i}")
        ctx.progress((n + 1) / len(order), f"image {i}")
    ctx.report.assume("events from the event images: one per lit pixel and polarity (R = ON, B = OFF), spread "
                      "over each image's window in a fixed pseudo-random pixel order")
