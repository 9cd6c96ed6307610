"""Published E-POSE per-window products (``NNNN_data.mat``) back into a scene (``evpose import epose-export``).

Sources: folders (or the ``.mat`` files) holding ``NNNN_data.mat``; windows are taken in numeric order of
``NNNN``. The other per-window files (PNG images, ``_bbox.txt``) are not needed.

Assumed MATLAB layout (``save`` of the original scripts, as ``scipy.io.loadmat`` returns it; MATLAB v7.3/HDF5
files are read with h5py and transposed back):

=====================  ==========================  =========================================================
field                  shape                       meaning
=====================  ==========================  =========================================================
``events``             (N, 4) double               ``[x y t p]`` per row; (4, N) is transposed back (reported);
                                                   (0, 0) / missing = empty window. x/y 0-based (raw DVS
                                                   pixels; ``--one-based`` for 1-based), p 0/1 or -1/+1,
                                                   t in a unit guessed from the event rate (seconds expected)
``pose``               (4, 4k) double              ``T_cam_obj`` of k objects side by side (``pose(:, 4j+1:4j+4)``)
``time``               (1, 1) double               the window's label time (E-POSE: window end), same clock and
                                                   unit as the events' t; missing -> last event time (reported)
``intrinsicMatrix``    (3, 3) double               K; MATLAB's ``cameraIntrinsics.IntrinsicMatrix`` convention
                                                   ``[fx 0 0; s fy 0; cx cy 1]`` is detected (third row not
                                                   ``[0 0 1]``, third column is) and transposed (reported)
``cls_index``          (1, k) or (k, 1)            class index of each pose block
``cameraPose``         (4, 4)                      ignored: the original scripts store the second frame's pose
                                                   in every window (known defect)
``keypointprojections``, ``centerInfo``            ignored (derived quantities)
=====================  ==========================  =========================================================

Windows were cut with closed intervals, so consecutive windows share the events stamped exactly at their
boundary: for windows ``k`` and ``k+1`` (consecutive numbers) the rows of ``k+1`` with ``t`` equal to the last
time of ``k`` that also appear (same ``x, y, t, p``, as a multiset) among those rows of ``k`` are dropped --
exactly those, counted in the report. Events are otherwise streamed window by window (bounded memory).

Poses: one ``T_cam_obj`` track per object at the window times; the camera trajectory ``T_base_cam`` follows from
``T_base_obj`` (``--assets/--scene`` or ``--objects name=mesh:T.json``; else the base frame is the first
object's frame and the others are estimated, reported) as ``T_base_obj @ inv(T_cam_obj)`` (general matrix
inverse, so labels computed from a non-orthonormal ``T_base_obj`` give the camera pose back exactly; then
projected to SO(3) with the residual reported). Trajectory times are the window label times on the event clock,
so the clock prior is 0 (whatever shift the original pipeline applied is already inside the labels).
The pose blocks as read are kept in ``source_poses.npz`` (``t_us``, ``names``,
``T_cam_obj`` (F, K, 4, 4)) for comparison with the corrected scene. Object names: ``--classes cls=name,...``; else, with as many pose blocks as objects given (``--assets/--scene``
objects, then ``--objects`` entries), block ``j`` is object ``j`` (reported); else ``cls_<index>``.
"""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from evpose.core.data.camera import DAVIS346_DIST, DAVIS346_K, CameraError, CameraModel
from evpose.core.importers.calibration import load_camera
from evpose.core.importers.epose_assets import EposeAssets, find_mesh, load_epose_assets
from evpose.core.importers.epose_mat import K_of, list_windows, load_window
from evpose.core.importers.epose_windows import ExportWindows
from evpose.core.importers.failure import ImportFailure
from evpose.core.importers.object_args import collect_objects
from evpose.core.importers.pose_checks import make_trajectory, poses_from_matrices
from evpose.core.importers.report import ImportContext, result_summary
from evpose.core.importers.scene_builder import SceneBuilder
from evpose.core.importers.static_scene import derive_camera_trajectory


def import_epose_export(sources, out, ctx: ImportContext) -> dict:
    """Import the ``NNNN_data.mat`` windows of an E-POSE export into a scene folder; returns the summary."""
    opts, rep = ctx.options, ctx.report
    wins = list_windows(sources)
    if not wins:
        raise ImportFailure(", ".join(map(str, sources)) or "(none)", "(folder)", "NNNN_data.mat", "no window files")
    folder = wins[0][1].parent
    assets = load_epose_assets(ctx, opts.assets, opts.scene, None, need_scene=False) if opts.assets else None
    objects = collect_objects(ctx, assets, require_T=False)
    cls_map = parse_classes(opts.classes)
    first = load_window(wins[0][1])
    K = K_of(first, wins[0][1], rep)
    camera = _camera(ctx, assets, K, wins[0][1])
    if opts.one_based:
        rep.assume("event x/y are 1-based (--one-based): 1 subtracted")
    windows = ExportWindows(ctx, first, K, objects, cls_map)
    with SceneBuilder(out, ctx) as sb:
        sink = sb.event_sink(camera.width, camera.height)
        if not opts.one_based:
            sink.off_sensor_hint = " (the .mat pixels may be 1-based: --one-based)"
        for wi, (k, path) in enumerate(wins):
            windows.read(wi, k, path, sink)
            ctx.progress(0.9 * (wi + 1) / len(wins), f"window {wi + 1}/{len(wins)}")
        sb.finish_events(sink, wins[0][1].parent)
        windows.report()
        if not windows.tracks:
            raise ImportFailure(folder, "(all windows)", "pose", "no object poses")
        if sink.x_min is not None and sink.x_min > 0 and sink.y_min > 0 and rep.counts.get("events_dropped_outside_sensor"):
            rep.warn("no event at x=0 or y=0 but some beyond the sensor: the .mat coordinates may be 1-based "
                     "(--one-based)")
        for nm in objects:
            if nm not in windows.tracks:
                rep.warn(f"object {nm!r} (--objects/--assets) has no pose block in the windows; left out")
        known = {nm: objects[nm][1] for nm in windows.tracks if nm in objects and objects[nm][1] is not None}
        T_base_obj = _write_trajectory(ctx, sb, folder, wins, windows, known)
        _add_objects(ctx, sb, folder, windows.tracks, objects, T_base_obj, known)
        sb.commit(camera, clock_offset_us=0)
    ctx.progress(1.0, "done")
    return result_summary(ctx, sb.out)


def parse_classes(spec: str | None) -> dict[int, str]:
    """``--classes "cls=name,..."`` -> ``{cls_index: object name}``."""
    cls_map: dict[int, str] = {}
    if spec:
        for item in str(spec).split(","):
            if "=" not in item:
                raise ImportFailure("--classes", item, "-", "expected cls=name")
            c, nm = item.split("=", 1)
            try:
                cls_map[int(float(c))] = nm.strip()
            except (ValueError, OverflowError):
                raise ImportFailure("--classes", item, "cls", "not a number") from None
    return cls_map


def _camera(ctx: ImportContext, assets: EposeAssets | None, K, first: Path) -> CameraModel:
    """``--camera``, else the assets' calibration, else the first window's ``intrinsicMatrix`` (DAVIS346
    distortion when K is E-POSE's, else none; sensor size from ``--width/--height`` or 346x260; reported)."""
    opts, rep = ctx.options, ctx.report
    if opts.camera:
        return load_camera(opts.camera, ctx, default_size=(346, 260))
    if assets is not None:
        if K is not None and not np.allclose(K, assets.camera.K, atol=1e-6):
            rep.warn(f"{first.name}: intrinsicMatrix differs from the assets' calibration; using the assets'")
        return assets.camera
    if K is None:
        raise ImportFailure(first, "(file)", "intrinsicMatrix", "missing; give --camera")
    size = (opts.width or 346, opts.height or 260)
    if np.allclose(K, DAVIS346_K, atol=1e-6):
        dist = DAVIS346_DIST
        rep.assume("K is E-POSE's DAVIS346 K: its distortion coefficients assumed (not stored in the .mat)")
    else:
        dist = []
        rep.assume("no distortion in the .mat files and no --camera: distortion assumed zero")
    rep.assume(f"sensor size {size[0]}x{size[1]} (not stored in the .mat files; --width/--height)")
    try:
        return CameraModel(K, dist, size[0], size[1], source=str(first))
    except CameraError as exc:
        raise ImportFailure(first, "(file)", "intrinsicMatrix", str(exc)) from None


def _write_trajectory(ctx: ImportContext, sb: SceneBuilder, folder: Path, wins, windows: ExportWindows,
                      known: dict) -> dict:
    """``T_base_cam`` at the label times from the pose blocks (static scene); the blocks as read go to
    ``source_poses.npz``. Returns ``T_base_obj`` of every object."""
    t_windows = windows.t_windows
    t_arr = np.asarray(t_windows, np.int64)
    t_cam, T_cam, T_base_obj = derive_camera_trajectory(ctx, folder, t_arr, windows.tracks, known)
    rec_of = {int(t): f"window {wins[i][0]}" for i, t in enumerate(t_windows)} if len(t_windows) == len(wins) \
        else {int(t): f"label time {int(t)} µs" for t in t_windows}
    pos, quat, _ = poses_from_matrices(ctx, folder, T_cam, lambda j: rec_of[int(t_cam[j])])
    traj = make_trajectory(ctx, folder, t_cam, pos, quat, record_of=lambda j: rec_of[int(t_cam[j])],
                           fields=("time", "x", "y", "z", "qx", "qy", "qz", "qw"))
    sb.set_trajectory(traj, "cam")
    sb.save_source_poses(t_arr, windows.tracks)
    ctx.report.assume("trajectory times are the windows' label times on the event clock; clock prior 0")
    return T_base_obj


def _add_objects(ctx: ImportContext, sb: SceneBuilder, folder: Path, tracks: dict, objects: dict, T_base_obj: dict,
                 known: dict) -> None:
    """Every object with pose blocks, with its mesh (``--objects``/assets, or found in the assets' models)."""
    opts = ctx.options
    for i, nm in enumerate(tracks):
        if nm in objects:
            mesh, _, cid, src = objects[nm]
        else:
            mesh = find_mesh(Path(opts.assets) / "models", nm) if opts.assets else None
            cid, src = i + 1, "derived"
        if mesh is None:
            raise ImportFailure(folder, nm, "mesh", f"no mesh for object {nm!r}: give --objects {nm}=mesh.obj "
                                "(or --assets/--scene/--classes)")
        m = re.match(r"cls_(\d+)$", nm)
        sb.add_object(nm, mesh, T_base_obj[nm], class_id=int(m.group(1)) if m else cid,
                      source=src if nm in known else "estimated from the pose blocks")
