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
from collections import Counter
from pathlib import Path

import numpy as np

from evpose.core.data.camera import DAVIS346_DIST, DAVIS346_K, CameraError, CameraModel
from evpose.core.data.geometry import ROTATION_TOLERANCE
from evpose.core.importers.common import (
    ImportContext,
    ImportFailure,
    SceneBuilder,
    check_T,
    derive_camera_trajectory,
    float_to_us,
    load_camera,
    make_trajectory,
    poses_from_matrices,
    resolve_time_unit,
    result_summary,
    wrap_errors,
)
from evpose.core.importers.epose_bag import EPOSE_PUBLISHED_TOLERANCE, collect_objects, find_mesh, load_epose_assets

_NAME = re.compile(r"^(\d+)_data\.mat$")
_FIELDS = ("events", "pose", "time", "intrinsicMatrix", "cls_index", "cameraPose")


def list_windows(sources) -> list[tuple[int, Path]]:
    files: dict[int, Path] = {}
    for s in map(Path, sources):
        cands = sorted(s.iterdir()) if s.is_dir() else [s] if s.is_file() else None
        if cands is None:
            raise ImportFailure(s, "(file)", "SRC", "no such file or folder")
        for p in cands:
            m = _NAME.match(p.name)
            if m:
                k = int(m.group(1))
                if k in files and files[k] != p:
                    raise ImportFailure(p, "(arguments)", "SRC", f"window {k} given twice ({files[k]})")
                files[k] = p
            elif not s.is_dir():
                raise ImportFailure(p, "(file)", "SRC", "expected NNNN_data.mat")
    return sorted(files.items())


def load_window(path: Path) -> dict:
    """The fields of one ``NNNN_data.mat`` as float64 arrays (MATLAB shapes kept)."""
    import h5py
    import scipy.io

    try:
        with wrap_errors(path, "(file)", "-", "not a readable MATLAB file"):
            raw = scipy.io.loadmat(str(path), squeeze_me=False, struct_as_record=True,
                                   variable_names=list(_FIELDS))
    except ImportFailure:
        try:
            is_h5 = h5py.is_hdf5(str(path))
        except Exception:  # noqa: BLE001
            is_h5 = False
        if not is_h5:
            raise
        raw = _load_v73(path)            # MATLAB -v7.3 files are HDF5
    out = {}
    for k in _FIELDS:
        if k in raw:
            v = raw[k]
            if not isinstance(v, np.ndarray) or v.dtype.kind not in "iufb":
                raise ImportFailure(path, "(file)", k, f"expected a numeric array, got {getattr(v, 'dtype', type(v))}")
            out[k] = v.astype(np.float64)
    return out


def _load_v73(path: Path) -> dict:
    import h5py

    out = {}
    with wrap_errors(path, "(file)", "-", "not a readable MATLAB v7.3 (HDF5) file"):
        with h5py.File(path, "r") as f:
            for k in _FIELDS:
                if k in f and isinstance(f[k], h5py.Dataset):
                    out[k] = np.asarray(f[k][()]).T     # MATLAB is column-major
    return out


def _events_of(d: dict, path: Path, rep, state: dict) -> np.ndarray:
    e = d.get("events")
    if e is None or e.size == 0:
        return np.empty((0, 4))
    if e.ndim != 2 or 4 not in e.shape:
        raise ImportFailure(path, "(file)", "events", f"expected (N, 4) [x y t p], got shape {e.shape}")
    if e.shape[1] != 4:
        if not state.get("transposed_events"):
            rep.assume(f"{path.name}: events stored as (4, N); read as its transpose")
            state["transposed_events"] = True
        e = e.T
    return e


def _K_of(d: dict, path: Path, rep) -> np.ndarray | None:
    K = d.get("intrinsicMatrix")
    if K is None:
        return None
    if K.shape != (3, 3) or not np.all(np.isfinite(K)):
        raise ImportFailure(path, "(file)", "intrinsicMatrix", f"expected a finite 3x3 matrix, got shape {K.shape}")
    if np.allclose(K[2], [0, 0, 1]):
        return K
    if np.allclose(K[:, 2], [0, 0, 1]):
        rep.assume(f"{path.name}: intrinsicMatrix is in MATLAB's transposed convention ([fx 0 0; s fy 0; cx cy 1]);"
                   " transposed")
        return K.T.copy()
    raise ImportFailure(path, "(file)", "intrinsicMatrix", f"neither its third row nor its third column is [0 0 1]: "
                        f"{K.tolist()}")


def import_epose_export(sources, out, ctx: ImportContext) -> dict:
    opts, rep = ctx.options, ctx.report
    wins = list_windows(sources)
    if not wins:
        raise ImportFailure(", ".join(map(str, sources)) or "(none)", "(folder)", "NNNN_data.mat", "no window files")
    folder = wins[0][1].parent
    assets = load_epose_assets(ctx, opts.assets, opts.scene, None, need_scene=False) if opts.assets else None
    objects = collect_objects(ctx, assets, require_T=False)
    cls_map = {}
    if opts.classes:
        for item in str(opts.classes).split(","):
            if "=" not in item:
                raise ImportFailure("--classes", item, "-", "expected cls=name")
            c, nm = item.split("=", 1)
            try:
                cls_map[int(float(c))] = nm.strip()
            except ValueError:
                raise ImportFailure("--classes", item, "cls", "not a number") from None
    # ---- first window: camera
    first = load_window(wins[0][1])
    K = _K_of(first, wins[0][1], rep)
    if opts.camera:
        camera = load_camera(opts.camera, ctx, default_size=(346, 260))
    elif assets is not None:
        camera = assets.camera
        if K is not None and not np.allclose(K, camera.K, atol=1e-6):
            rep.warn(f"{wins[0][1].name}: intrinsicMatrix differs from the assets' calibration; using the assets'")
    else:
        if K is None:
            raise ImportFailure(wins[0][1], "(file)", "intrinsicMatrix", "missing; give --camera")
        size = (opts.width or 346, opts.height or 260)
        if np.allclose(K, DAVIS346_K, atol=1e-6):
            dist = DAVIS346_DIST
            rep.assume("K is E-POSE's DAVIS346 K: its distortion coefficients assumed (not stored in the .mat)")
        else:
            dist = []
            rep.assume("no distortion in the .mat files and no --camera: distortion assumed zero")
        rep.assume(f"sensor size {size[0]}x{size[1]} (not stored in the .mat files; --width/--height)")
        try:
            camera = CameraModel(K, dist, size[0], size[1], source=str(wins[0][1]))
        except CameraError as exc:
            raise ImportFailure(wins[0][1], "(file)", "intrinsicMatrix", str(exc)) from None
    if opts.one_based:
        rep.assume("event x/y are 1-based (--one-based): 1 subtracted")
    tracks: dict[str, dict[int, np.ndarray]] = {}
    t_windows: list[int] = []
    n_dedup = n_time_fallback = 0
    unit = None
    lags = []
    state: dict = {}
    block_names: list[str] | None = None
    scene_names = list(objects)
    res_max, res_where, n_proj = 0.0, "", 0
    prev_k, prev_tail, prev_t = None, None, None
    with SceneBuilder(out, ctx) as sb:
        sink = sb.event_sink(camera.width, camera.height)
        for wi, (k, path) in enumerate(wins):
            ctx.check_cancel()
            d = first if wi == 0 else load_window(path)
            if wi and "intrinsicMatrix" in d:
                K2 = _K_of(d, path, rep) if not np.allclose(d["intrinsicMatrix"], first["intrinsicMatrix"]) else K
                if K is not None and K2 is not None and not np.allclose(K2, K, atol=1e-9):
                    rep.warn(f"{path.name}: intrinsicMatrix differs from the first window's")
            e = _events_of(d, path, rep, state)
            rec = f"window {k}"
            if not np.all(np.isfinite(e)):
                r, c = np.argwhere(~np.isfinite(e))[0]
                raise ImportFailure(path, f"{rec}, event row {r}", "events(:, %d) [%s]" % (c + 1, "xytp"[c]),
                                    f"not finite ({e[r, c]})")
            if len(e) and unit is None:
                unit = resolve_time_unit(ctx, e[:, 2], what="events t (.mat)", kind="events")
            with wrap_errors(path, rec, "events(:, 3) [t]"):
                t = float_to_us(e[:, 2], unit or "s") if len(e) else np.empty(0, np.int64)
            x, y, p = e[:, 0], e[:, 1], e[:, 3]
            if opts.one_based:
                x, y = x - 1, y - 1
            # shared boundary events of consecutive windows
            if len(t) and prev_tail is not None and prev_k == k - 1:
                tb = prev_tail[0][0] if len(prev_tail[0]) else None
                if tb is not None:
                    at = np.flatnonzero(t == tb)
                    if len(at):
                        avail = Counter(zip(prev_tail[1].tolist(), prev_tail[2].tolist(), prev_tail[3].tolist()))
                        drop = []
                        for j in at:
                            key = (float(x[j]), float(y[j]), float(p[j]))
                            if avail.get(key, 0) > 0:
                                avail[key] -= 1
                                drop.append(j)
                        if drop:
                            keep = np.ones(len(t), bool)
                            keep[drop] = False
                            x, y, t, p = x[keep], y[keep], t[keep], p[keep]
                            n_dedup += len(drop)
            if len(t):
                tl = int(t.max())
                m = t == tl
                prev_tail = (t[m], x[m].astype(float), y[m].astype(float), p[m].astype(float))
            elif prev_k != k - 1:
                prev_tail = None
            prev_k = k
            sink.add(x, y, t, p, file=path, record=rec)
            # label time
            tm = d.get("time")
            if tm is not None and tm.size >= 1 and np.isfinite(tm.reshape(-1)[0]):
                with wrap_errors(path, rec, "time"):
                    tw = int(float_to_us(tm.reshape(-1)[:1], unit or "s")[0])
                if len(t):
                    lags.append(tw - int(t.max()))
            elif tm is not None and tm.size >= 1:
                raise ImportFailure(path, rec, "time", f"not finite ({tm.reshape(-1)[0]})")
            elif len(t):
                tw = int(t.max())
                n_time_fallback += 1
            else:
                tw = None
            # poses
            P = d.get("pose")
            if P is not None and P.size and tw is not None:
                if P.ndim != 2 or P.shape[0] != 4 or P.shape[1] % 4:
                    raise ImportFailure(path, rec, "pose", f"expected (4, 4k), got shape {P.shape}")
                nb = P.shape[1] // 4
                cls = d.get("cls_index")
                cls = cls.ravel() if cls is not None else np.arange(1, nb + 1, dtype=float)
                if len(cls) != nb:
                    raise ImportFailure(path, rec, "cls_index", f"{len(cls)} classes for {nb} pose blocks")
                names = []
                for j, c in enumerate(cls):
                    ci = int(c)
                    if ci in cls_map:
                        names.append(cls_map[ci])
                    elif not cls_map and nb == len(scene_names):
                        names.append(scene_names[j])
                    else:
                        names.append(f"cls_{ci}")
                if block_names is None:
                    block_names = names
                    if not cls_map and nb == len(scene_names):
                        rep.assume("pose blocks in the order of the objects (--assets/--scene, --objects): " + ", ".join(
                            f"block {j} (cls_index {int(c)}) = {n}" for j, (c, n) in enumerate(zip(cls, names))))
                if len(set(names)) != len(names):
                    raise ImportFailure(path, rec, "cls_index", f"two pose blocks map to the same object: {names}")
                if tw in t_windows:
                    raise ImportFailure(path, rec, "time", f"label time {tw} µs repeats an earlier window's")
                widx = len(t_windows)
                t_windows.append(tw)
                for j, nm in enumerate(names):
                    B = P[:, 4 * j:4 * j + 4]
                    if not np.all(np.isfinite(B)):
                        rep.count("pose_blocks_not_finite")
                        continue
                    _, res = check_T(B, ctx, path, rec, f"pose(:, {4 * j + 1}:{4 * j + 4}) [{nm}]", quiet=True,
                                     tolerance=EPOSE_PUBLISHED_TOLERANCE)
                    if res > res_max:
                        res_max, res_where = res, f"{path.name} {nm}"
                    n_proj += res > ROTATION_TOLERANCE
                    tracks.setdefault(nm, {})[widx] = B
            ctx.progress(0.9 * (wi + 1) / len(wins), f"window {wi + 1}/{len(wins)}")
        sb.finish_events(sink, wins[0][1].parent)
        if n_dedup:
            rep.repair(f"dropped {n_dedup} boundary event(s) duplicated in consecutive windows")
            rep.counts["events_boundary_duplicates"] = n_dedup
        if n_time_fallback:
            rep.assume(f"{n_time_fallback} window(s) without 'time': label time = last event time")
        if lags:
            lg = np.asarray(lags)
            rep.details["label_time_minus_last_event_us"] = {"median": float(np.median(lg)), "min": int(lg.min()),
                                                              "max": int(lg.max())}
        if res_max > 1e-9:
            (rep.repair if n_proj else rep.assume)(f"pose blocks: rotations not orthonormal up to residual "
                                                   f"{res_max:.3g} ({res_where})")
        if not tracks:
            raise ImportFailure(folder, "(all windows)", "pose", "no object poses")
        if sink.x_min is not None and sink.x_min > 0 and sink.y_min > 0 and rep.counts.get("events_dropped_outside_sensor"):
            rep.warn("no event at x=0 or y=0 but some beyond the sensor: the .mat coordinates may be 1-based "
                     "(--one-based)")
        for nm in objects:
            if nm not in tracks:
                rep.warn(f"object {nm!r} (--objects/--assets) has no pose block in the windows; left out")
        known = {nm: objects[nm][1] for nm in tracks if nm in objects and objects[nm][1] is not None}
        t_arr = np.asarray(t_windows, np.int64)
        t_cam, T_cam, T_base_obj = derive_camera_trajectory(ctx, folder, t_arr, tracks, known)
        rec_of = {int(t): f"window {wins[i][0]}" for i, t in enumerate(t_windows)} if len(t_windows) == len(wins) \
            else {int(t): f"label time {int(t)} µs" for t in t_windows}
        pos, quat, _ = poses_from_matrices(ctx, folder, T_cam, lambda j: rec_of[int(t_cam[j])])
        traj = make_trajectory(ctx, folder, t_cam, pos, quat, record_of=lambda j: rec_of[int(t_cam[j])],
                               fields=("time", "x", "y", "z", "qx", "qy", "qz", "qw"))
        sb.set_trajectory(traj, "cam")
        sb.save_source_poses(t_arr, tracks)
        rep.assume("trajectory times are the windows' label times on the event clock; clock prior 0")
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
        sb.commit(camera, clock_offset_us=0)
    ctx.progress(1.0, "done")
    return result_summary(ctx, sb.out)
