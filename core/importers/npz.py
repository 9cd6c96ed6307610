"""NumPy ``.npz`` archives (``evpose import npz``).

Keys (one archive, or events and poses in two archives given as two sources):

* events: ``x``, ``y``, ``t``, ``p`` -- 1-D, equal length; integers (floats must be whole numbers for x/y/p).
  ``t`` in any unit (guessed from the event rate unless ``t_unit`` = ``"s"|"ms"|"us"|"ns"`` is stored or
  ``--time-unit`` is given); float times are converted with round half up.
* poses: ``t_us`` (int µs; or ``pose_t`` in a guessed unit / ``pose_t_unit``) with either ``position`` (N, 3,
  metres) and ``quaternion`` (N, 4, x y z w), or ``T_base_cam`` (N, 4, 4). Camera pose in the base frame.
* optional camera: ``K`` (3, 3), ``dist``, ``width``, ``height`` (or ``--camera``).

The event arrays are **streamed** out of the zip member (``np.lib.format`` header, then fixed-size reads of the
(possibly deflated) member), so memory does not grow with the archive; the pose and camera arrays are small and
read whole. Pickled object arrays are refused.
"""
from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np

from evpose.core.data.camera import CameraError, CameraModel
from evpose.core.importers.common import (
    TIME_UNITS,
    ImportContext,
    ImportFailure,
    SceneBuilder,
    float_to_us,
    load_camera,
    make_trajectory,
    poses_from_matrices,
    resolve_time_unit,
    result_summary,
    wrap_errors,
)
from evpose.core.importers.epose_bag import collect_objects

_CHUNK = 1 << 21
EVENT_KEYS = ("x", "y", "t", "p")


class _Member:
    """A 1-D array inside an npz, read in chunks."""

    def __init__(self, zf: zipfile.ZipFile, key: str, path: Path):
        self.key, self.path = key, path
        with wrap_errors(path, f"array {key!r}", key, "cannot open the member"):
            self.f = zf.open(f"{key}.npy")
            version = np.lib.format.read_magic(self.f)
            if version == (1, 0):
                shape, fortran, dtype = np.lib.format.read_array_header_1_0(self.f)
            elif version in ((2, 0), (3, 0)):
                shape, fortran, dtype = np.lib.format.read_array_header_2_0(self.f)
            else:
                raise ValueError(f"unsupported .npy version {version}")
        if dtype.hasobject:
            raise ImportFailure(path, f"array {key!r}", key, "object arrays (pickles) are refused")
        if len(shape) != 1:
            raise ImportFailure(path, f"array {key!r}", key, f"expected a 1-D array, got shape {shape}")
        if dtype.kind not in "iufb":
            raise ImportFailure(path, f"array {key!r}", key, f"expected numbers, got dtype {dtype}")
        self.n, self.dtype = int(shape[0]), dtype

    def read(self, count: int) -> np.ndarray:
        nbytes = count * self.dtype.itemsize
        with wrap_errors(self.path, f"array {self.key!r}", self.key, "cannot read"):
            buf = self.f.read(nbytes)
        if len(buf) != nbytes:
            raise ImportFailure(self.path, f"array {self.key!r}", self.key, f"truncated: {len(buf)} of {nbytes} bytes")
        return np.frombuffer(buf, self.dtype)

    def close(self):
        try:
            self.f.close()
        except Exception:  # noqa: BLE001
            pass


def _open_zip(path: Path) -> zipfile.ZipFile:
    with wrap_errors(path, "(file)", "-", "not a readable .npz (zip) archive"):
        return zipfile.ZipFile(path, "r")


def _small(zf: zipfile.ZipFile, path: Path, key: str) -> np.ndarray:
    with wrap_errors(path, f"array {key!r}", key, "cannot read"):
        with zf.open(f"{key}.npy") as f:
            return np.lib.format.read_array(f, allow_pickle=False)


def import_npz(sources, out, ctx: ImportContext) -> dict:
    opts, rep = ctx.options, ctx.report
    if not sources or len(sources) > 2:
        raise ImportFailure(", ".join(map(str, sources)) or "(none)", "(arguments)", "SRC",
                            "give one .npz (events and poses) or two (events, poses)")
    paths = [Path(s) for s in sources]
    for p in paths:
        if not p.is_file():
            raise ImportFailure(p, "(file)", "SRC", "no such file")
    zfs = [_open_zip(p) for p in paths]
    try:
        return _import(paths, zfs, out, ctx)
    finally:
        for z in zfs:
            z.close()


def _import(paths, zfs, out, ctx: ImportContext) -> dict:
    opts, rep = ctx.options, ctx.report
    names = [{n[:-4] for n in z.namelist() if n.endswith(".npy")} for z in zfs]
    ev_i = next((i for i, nm in enumerate(names) if set(EVENT_KEYS) <= nm), None)
    if ev_i is None:
        raise ImportFailure(paths[0], "(archive)", "x/y/t/p", f"no archive holds all of x, y, t, p "
                            f"(keys: {', '.join(sorted(set().union(*names)))})")
    ps_i = next((i for i, nm in enumerate(names) if ("t_us" in nm or "pose_t" in nm)), None)
    if ps_i is None:
        raise ImportFailure(paths[-1], "(archive)", "t_us", "no pose times (t_us or pose_t)")
    epath, ppath, ezf, pzf = paths[ev_i], paths[ps_i], zfs[ev_i], zfs[ps_i]
    # ---- poses
    pn = names[ps_i]
    tkey = "t_us" if "t_us" in pn else "pose_t"
    tp = _small(pzf, ppath, tkey)
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
        unit = _stored_unit(pzf, ppath, pn, "pose_t_unit") or resolve_time_unit(
            ctx, tp, what=f"{ppath.name}:pose_t", kind="poses")
    with wrap_errors(ppath, f"array {tkey!r}", tkey):
        t_pose = float_to_us(tp, unit)
    rec = lambda i: f"pose {i}"  # noqa: E731
    if "T_base_cam" in pn:
        T = _small(pzf, ppath, "T_base_cam")
        if T.ndim != 3 or T.shape[1:] not in ((4, 4), (3, 4)) or len(T) != len(tp):
            raise ImportFailure(ppath, "array 'T_base_cam'", "T_base_cam", f"expected ({len(tp)}, 4, 4), got {T.shape}")
        if T.dtype.kind not in "iuf":
            raise ImportFailure(ppath, "array 'T_base_cam'", "T_base_cam", f"expected numbers, got {T.dtype}")
        pos, quat, _ = poses_from_matrices(ctx, ppath, T, rec)
    elif {"position", "quaternion"} <= pn:
        pos = _small(pzf, ppath, "position")
        quat = _small(pzf, ppath, "quaternion")
        for k, a, c in (("position", pos, 3), ("quaternion", quat, 4)):
            if a.shape != (len(tp), c) or a.dtype.kind not in "iuf":
                raise ImportFailure(ppath, f"array {k!r}", k, f"expected ({len(tp)}, {c}) numbers, got {a.shape} {a.dtype}")
    else:
        raise ImportFailure(ppath, "(archive)", "position/quaternion", "give position + quaternion or T_base_cam")
    traj = make_trajectory(ctx, ppath, t_pose, pos, quat, record_of=rec,
                           fields=(tkey, "position[0]", "position[1]", "position[2]", "quaternion[0]",
                                   "quaternion[1]", "quaternion[2]", "quaternion[3]"))
    # ---- camera
    if opts.camera:
        camera = load_camera(opts.camera, ctx)
    elif "K" in names[ev_i] or "K" in pn:
        zf, pth, nm = (ezf, epath, names[ev_i]) if "K" in names[ev_i] else (pzf, ppath, pn)
        K = _small(zf, pth, "K")
        dist = _small(zf, pth, "dist").ravel() if "dist" in nm else []
        try:
            w = int(opts.width or _small(zf, pth, "width").reshape(-1)[0])
            h = int(opts.height or _small(zf, pth, "height").reshape(-1)[0])
        except ImportFailure:
            raise ImportFailure(pth, "(archive)", "width/height", "K is stored but width/height are not") from None
        try:
            camera = CameraModel(K, dist, w, h, source=str(pth))
        except (CameraError, TypeError, ValueError) as exc:
            raise ImportFailure(pth, "(archive)", "K/dist", str(exc)) from None
    else:
        raise ImportFailure(epath, "(archive)", "K", "no calibration: store K/dist/width/height or give --camera")
    objects = collect_objects(ctx, None)
    # ---- events, streamed
    members = [_Member(ezf, k, epath) for k in EVENT_KEYS]
    try:
        n = members[2].n
        for m in members:
            if m.n != n:
                raise ImportFailure(epath, f"array {m.key!r}", m.key, f"length {m.n} != {n} (t)")
        if n == 0:
            raise ImportFailure(epath, "array 't'", "t", "no events")
        t_member = members[2]
        stored = _stored_unit(ezf, epath, names[ev_i], "t_unit")
        with SceneBuilder(out, ctx) as sb:
            sink = sb.event_sink(camera.width, camera.height, expected_events=n)
            ev_unit = stored
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
                        rep.count("events_dropped_nonfinite_t", int(bad.sum()))
                if t.dtype.kind == "b":
                    raise ImportFailure(epath, "array 't'", "t", "boolean times")
                if ev_unit is None:
                    ev_unit = resolve_time_unit(ctx, t, what=f"{epath.name}:t (events)", kind="events")
                with wrap_errors(epath, r, "t"):
                    tu = float_to_us(t, ev_unit)
                sink.add(x, y, tu, p, file=epath, record=r)
                ctx.progress(0.97 * (i0 + k) / n, f"{i0 + k:,}/{n:,} events")
            sb.finish_events(sink, epath)
            sb.set_trajectory(traj, "cam")
            sb.add_cli_objects(objects)
            sb.commit(camera)
    finally:
        for m in members:
            m.close()
    ctx.progress(1.0, "done")
    return result_summary(ctx, sb.out)


def _stored_unit(zf, path: Path, names: set, key: str) -> str | None:
    if key not in names:
        return None
    v = _small(zf, path, key)
    u = str(v.reshape(-1)[0]) if v.size else ""
    if u not in TIME_UNITS:
        raise ImportFailure(path, f"array {key!r}", key, f"expected one of {', '.join(TIME_UNITS)}, got {u!r}")
    return u
