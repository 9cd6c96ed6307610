"""NumPy ``.npz`` archives (``evpose import npz``).

Keys (one archive, or events and poses in two archives given as two sources):

* events: ``x``, ``y``, ``t``, ``p`` -- 1-D, equal length; integers (floats must be whole numbers for x/y/p).
  ``t`` in any unit (guessed from the event rate unless ``t_unit`` = ``"s"|"ms"|"us"|"ns"`` is stored or
  ``--time-unit`` is given); float times are converted with round half up.
* poses: ``t_us`` (int µs; or ``pose_t`` in a guessed unit / ``pose_t_unit``) with either ``position`` (N, 3,
  metres) and ``quaternion`` (N, 4, x y z w), or ``T_base_cam`` (N, 4, 4). Camera pose in the base frame.
* optional camera: ``K`` (3, 3), ``dist``, ``width``, ``height`` (or ``--camera``).

One archive without pose times makes an event-only scene (no trajectory, no objects; ``--objects`` refused).

The event arrays are **streamed** out of the zip member (:mod:`evpose.core.importers.npz_arrays`), so memory
does not grow with the archive; the pose and camera arrays are small and read whole. Pickled object arrays are
refused.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from evpose.core.data.camera import CameraError, CameraModel
from evpose.core.importers.calibration import load_camera
from evpose.core.importers.failure import ImportFailure, wrap_errors
from evpose.core.importers.npz_arrays import NpyMember, open_zip, small_array, stored_unit
from evpose.core.importers.object_args import collect_objects
from evpose.core.importers.pose_checks import make_trajectory, poses_from_matrices
from evpose.core.importers.report import ImportContext, result_summary
from evpose.core.importers.scene_builder import SceneBuilder, events_only
from evpose.core.importers.time_guess import resolve_time_unit
from evpose.core.importers.time_units import float_to_us

_CHUNK = 1 << 21
EVENT_KEYS = ("x", "y", "t", "p")


def import_npz(sources, out, ctx: ImportContext) -> dict:
    """Import one ``.npz`` (events and poses) or two (events, poses) into a scene folder; returns the summary."""
    if not sources or len(sources) > 2:
        raise ImportFailure(", ".join(map(str, sources)) or "(none)", "(arguments)", "SRC",
                            "give one .npz (events and poses) or two (events, poses)")
    paths = [Path(s) for s in sources]
    for p in paths:
        if not p.is_file():
            raise ImportFailure(p, "(file)", "SRC", "no such file")
    zfs = [open_zip(p) for p in paths]
    try:
        return _import(paths, zfs, out, ctx)
    finally:
        for z in zfs:
            z.close()


def _import(paths, zfs, out, ctx: ImportContext) -> dict:
    """Find the events and the poses among the archives, read poses and camera, stream the events, commit."""
    names = [{n[:-4] for n in z.namelist() if n.endswith(".npy")} for z in zfs]
    ev_i = next((i for i, nm in enumerate(names) if set(EVENT_KEYS) <= nm), None)
    if ev_i is None:
        raise ImportFailure(paths[0], "(archive)", "x/y/t/p", f"no archive holds all of x, y, t, p "
                            f"(keys: {', '.join(sorted(set().union(*names)))})")
    ps_i = next((i for i, nm in enumerate(names) if ("t_us" in nm or "pose_t" in nm)), None)
    if ps_i is None and len(paths) > 1:
        raise ImportFailure(paths[-1], "(archive)", "t_us", "no pose times (t_us or pose_t) in either archive")
    epath, ezf = paths[ev_i], zfs[ev_i]
    objects = collect_objects(ctx, None)
    if ps_i is None:                  # events without poses: an event-only scene
        events_only(ctx, epath, objects)
        traj, ps_i = None, ev_i
    else:
        traj = _read_trajectory(ctx, zfs[ps_i], paths[ps_i], names[ps_i])
    camera = _read_camera(ctx, (ezf, epath, names[ev_i]), (zfs[ps_i], paths[ps_i], names[ps_i]))
    members = [NpyMember(ezf, k, epath) for k in EVENT_KEYS]
    try:
        n = members[2].n
        for m in members:
            if m.n != n:
                raise ImportFailure(epath, f"array {m.key!r}", m.key, f"length {m.n} != {n} (t)")
        if n == 0:
            raise ImportFailure(epath, "array 't'", "t", "no events")
        stored = stored_unit(ezf, epath, names[ev_i], "t_unit")
        with SceneBuilder(out, ctx) as sb:
            sink = sb.event_sink(camera.width, camera.height, expected_events=n)
            _stream_events(ctx, members, n, stored, epath, sink)
            sb.finish_events(sink, epath)
            if traj is not None:
                sb.set_trajectory(traj, "cam")
                sb.add_cli_objects(objects)
            sb.commit(camera)
    finally:
        for m in members:
            m.close()
    ctx.progress(1.0, "done")
    return result_summary(ctx, sb.out)


def read_npz_trajectory(path, ctx: ImportContext):
    """The camera trajectory of one ``.npz`` archive (``t_us`` or ``pose_t`` with ``position`` + ``quaternion`` or
    ``T_base_cam``, as :func:`import_npz` reads it), validated; for ``evpose scene set-trajectory``."""
    path = Path(path)
    zf = open_zip(path)
    try:
        names = {n[:-4] for n in zf.namelist() if n.endswith(".npy")}
        if "t_us" not in names and "pose_t" not in names:
            raise ImportFailure(path, "(archive)", "t_us", f"no pose times (t_us or pose_t; keys: "
                                f"{', '.join(sorted(names)) or 'none'})")
        return _read_trajectory(ctx, zf, path, names)
    finally:
        zf.close()


def _pose_times(ctx: ImportContext, pzf, ppath: Path, pn: set) -> tuple[str, np.ndarray, np.ndarray]:
    """``(key, times as stored, times in µs)``: ``t_us`` (whole µs) or ``pose_t`` in a stored/guessed unit."""
    tkey = "t_us" if "t_us" in pn else "pose_t"
    tp = small_array(pzf, ppath, tkey)
    if tp.ndim != 1:
        raise ImportFailure(ppath, f"array {tkey!r}", tkey, f"expected a 1-D array, got shape {tp.shape}")
    if tp.dtype.kind == "f" and not np.all(np.isfinite(tp)):
        i = int(np.flatnonzero(~np.isfinite(tp))[0])
        raise ImportFailure(ppath, f"pose {i}", tkey, f"not finite ({tp[i]})")
    if tp.dtype.kind not in "iuf":
        raise ImportFailure(ppath, f"array {tkey!r}", tkey, f"expected numbers, got dtype {tp.dtype}")
    if tkey == "t_us":
        if tp.dtype.kind == "f" and np.any(tp != np.round(tp)):
            i = int(np.flatnonzero(tp != np.round(tp))[0])
            raise ImportFailure(ppath, f"pose {i}", "t_us", f"not an integer number of µs ({tp[i]})")
        unit = "us"
    else:
        unit = stored_unit(pzf, ppath, pn, "pose_t_unit") or resolve_time_unit(
            ctx, tp, what=f"{ppath.name}:pose_t", kind="poses")
    with wrap_errors(ppath, f"array {tkey!r}", tkey):
        t_pose = float_to_us(tp, unit)
    return tkey, tp, t_pose


def _read_trajectory(ctx: ImportContext, pzf, ppath: Path, pn: set):
    """The camera trajectory: pose times with ``position`` + ``quaternion`` or ``T_base_cam``."""
    tkey, tp, t_pose = _pose_times(ctx, pzf, ppath, pn)
    rec = lambda i: f"pose {i}"  # noqa: E731
    if "T_base_cam" in pn:
        T = small_array(pzf, ppath, "T_base_cam")
        if T.ndim != 3 or T.shape[1:] not in ((4, 4), (3, 4)) or len(T) != len(tp):
            raise ImportFailure(ppath, "array 'T_base_cam'", "T_base_cam", f"expected ({len(tp)}, 4, 4), got {T.shape}")
        if T.dtype.kind not in "iuf":
            raise ImportFailure(ppath, "array 'T_base_cam'", "T_base_cam", f"expected numbers, got {T.dtype}")
        pos, quat, _ = poses_from_matrices(ctx, ppath, T, rec)
    elif {"position", "quaternion"} <= pn:
        pos = small_array(pzf, ppath, "position")
        quat = small_array(pzf, ppath, "quaternion")
        for k, a, c in (("position", pos, 3), ("quaternion", quat, 4)):
            if a.shape != (len(tp), c) or a.dtype.kind not in "iuf":
                raise ImportFailure(ppath, f"array {k!r}", k, f"expected ({len(tp)}, {c}) numbers, got {a.shape} {a.dtype}")
    else:
        raise ImportFailure(ppath, "(archive)", "position/quaternion", "give position + quaternion or T_base_cam")
    return make_trajectory(ctx, ppath, t_pose, pos, quat, record_of=rec,
                           fields=(tkey, "position[0]", "position[1]", "position[2]", "quaternion[0]",
                                   "quaternion[1]", "quaternion[2]", "quaternion[3]"))


def _read_camera(ctx: ImportContext, events, poses) -> CameraModel:
    """``--camera``, else ``K``/``dist``/``width``/``height`` stored in the events or the poses archive."""
    opts = ctx.options
    if opts.camera:
        return load_camera(opts.camera, ctx)
    if "K" not in events[2] and "K" not in poses[2]:
        raise ImportFailure(events[1], "(archive)", "K", "no calibration: store K/dist/width/height or give --camera")
    zf, pth, nm = events if "K" in events[2] else poses
    K = small_array(zf, pth, "K")
    dist = small_array(zf, pth, "dist").ravel() if "dist" in nm else []
    try:
        w = opts.width or small_array(zf, pth, "width").reshape(-1)[0]
        h = opts.height or small_array(zf, pth, "height").reshape(-1)[0]
    except (ImportFailure, IndexError):
        raise ImportFailure(pth, "(archive)", "width/height", "K is stored but width/height are not") from None
    try:
        w, h = int(w), int(h)
    except (TypeError, ValueError, OverflowError):
        raise ImportFailure(pth, "(archive)", "width/height", f"expected integers, got {w!r} and {h!r}") from None
    try:
        return CameraModel(K, dist, w, h, source=str(pth))
    except (CameraError, TypeError, ValueError) as exc:
        raise ImportFailure(pth, "(archive)", "K/dist", str(exc)) from None


def _stream_events(ctx: ImportContext, members, n: int, unit: str | None, epath: Path, sink) -> None:
    """The event columns chunk by chunk into ``sink``; times in ``unit`` (stored, forced or guessed once)."""
    for i0 in range(0, n, _CHUNK):
        k = min(_CHUNK, n - i0)
        x, y, t, p = (m.read(k) for m in members)
        r = f"events [{i0}, {i0 + k})"
        if t.dtype.kind == "f":
            bad = ~np.isfinite(t)
            if bad.any():
                j = int(np.flatnonzero(bad)[0])
                if not ctx.repair:
                    raise ImportFailure(epath, f"event {i0 + j}", "t", f"not finite ({t[j]}); pass --repair "
                                        "to drop such events")
                ok = ~bad
                x, y, t, p = x[ok], y[ok], t[ok], p[ok]
                ctx.report.count("events_dropped_nonfinite_t", int(bad.sum()))
        if t.dtype.kind == "b":
            raise ImportFailure(epath, "array 't'", "t", "boolean times")
        if unit is None:
            unit = resolve_time_unit(ctx, t, what=f"{epath.name}:t (events)", kind="events")
        with wrap_errors(epath, r, "t"):
            tu = float_to_us(t, unit)
        sink.add(x, y, tu, p, file=epath, record=r)
        ctx.progress(0.97 * (i0 + k) / n, f"{i0 + k:,}/{n:,} events")
