"""DSEC-layout event files plus a trajectory and a calibration (``evpose import dsec``).

Sources (any order; a folder is searched for ``events.h5``, ``events/left/events.h5``, ``*.yaml`` /
``calibration/cam_to_cam.yaml`` and a trajectory ``*.csv`` / ``*.txt``):

* events HDF5, DSEC layout: ``events/x``, ``events/y`` (uint16), ``events/t`` (uint32 or int64 µs relative to
  ``t_offset``), ``events/p`` (0/1 or -1/+1), optional ``t_offset`` (int64 µs) and ``ms_to_idx``. Opened
  read-only (``h5py`` mode ``"r"``); never modified.
* a trajectory: our ``t_us,x,y,z,qx,qy,qz,qw`` CSV or a headerless ``t x y z qx qy qz qw`` text file (TUM
  style; time unit guessed from the sampling period unless ``--time-unit``), ``T_base_cam`` in metres. Without one
  the scene is event-only (no trajectory, no objects).
* calibration (or ``--camera``): DSEC ``cam_to_cam.yaml`` (``intrinsics: camN: camera_matrix [fx fy cx cy],
  distortion_coeffs, resolution``; ``--camera-key``, default ``cam0``, the left event camera), Kalibr YAML,
  or our JSON.

``--events-mode``:

* ``copy`` (default): the events are streamed through validation into the scene's own ``events.h5``
  (int64 µs, Blosc-LZ4, fresh ``ms_to_idx``): out-of-sensor events dropped, unsorted stretches merged, a
  uint32 wrap-around unwrapped. Self-contained; costs one read and one write.
* ``link``: ``events.h5`` in the scene is a symlink to the absolute source path (no copy).
* ``reference``: ``scene.toml`` holds the absolute source path (no copy).

``link``/``reference`` still read the whole file once to validate it, and refuse a file that would need a
repair (unsorted, out-of-sensor events): use ``copy`` for those. Note that :class:`~evpose.core.data.event_store.EventStore`
caches an ms index beside an event file that has none (``<file>.msidx.npz``; for ``link`` that lands in the
scene folder, for ``reference`` beside the source) -- the event file itself is never written.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from evpose.core.importers.calibration import load_camera
from evpose.core.importers.event_sink import EventSink
from evpose.core.importers.failure import ImportFailure, wrap_errors
from evpose.core.importers.object_args import collect_objects
from evpose.core.importers.pose_text import read_pose_text
from evpose.core.importers.report import ImportContext, result_summary
from evpose.core.importers.scene_builder import SceneBuilder, events_only

_CHUNK = 1 << 20
_WRAP = 1 << 32


def classify_sources(sources, ctx: ImportContext) -> dict:
    """Find the events file, trajectory and calibration among the sources (folders are searched)."""
    found: dict[str, Path] = {}

    def put(role: str, p: Path):
        if role in found and found[role] != p:
            raise ImportFailure(p, "(arguments)", "SRC", f"two {role} files given ({found[role]} and {p})")
        found[role] = p

    for s in map(Path, sources):
        if s.is_dir():
            for cand in ("events.h5", "events/left/events.h5", "events.hdf5"):
                if (s / cand).is_file():
                    put("events", s / cand)
                    break
            for cand in ("calibration/cam_to_cam.yaml", "cam_to_cam.yaml", "calibration.yaml", "camera.json"):
                if (s / cand).is_file():
                    put("camera", s / cand)
                    break
            for cand in ("trajectory.csv", "poses.txt", "groundtruth.txt", "trajectory.txt", "stamped_groundtruth.txt"):
                if (s / cand).is_file():
                    put("trajectory", s / cand)
                    break
            continue
        suf = s.suffix.lower()
        if not s.exists():
            raise ImportFailure(s, "(file)", "SRC", "no such file")
        if suf in (".h5", ".hdf5"):
            put("events", s)
        elif suf in (".yaml", ".yml"):
            put("camera", s)
        elif suf == ".json":
            put("camera", s)
        elif suf in (".csv", ".txt"):
            put("trajectory", s)
        else:
            raise ImportFailure(s, "(file)", "SRC", "unknown role (expected .h5 events, .csv/.txt trajectory, "
                                ".yaml/.json calibration)")
    return found


def import_dsec(sources, out, ctx: ImportContext) -> dict:
    """Import a DSEC-layout event file, a trajectory and a calibration into a scene folder; returns the summary."""
    import h5py
    import hdf5plugin  # noqa: F401  (filters of compressed DSEC files)

    opts, rep = ctx.options, ctx.report
    found = classify_sources(sources, ctx)
    if "events" not in found:
        raise ImportFailure(", ".join(map(str, sources)), "(arguments)", "events", "no events .h5 among the sources")
    cam_file = opts.camera or found.get("camera")
    if cam_file is None:
        raise ImportFailure(", ".join(map(str, sources)), "(arguments)", "camera", "no calibration: give "
                            "cam_to_cam.yaml or --camera")
    camera = load_camera(cam_file, ctx)
    src = found["events"]
    objects = collect_objects(ctx, None)
    traj = None
    if "trajectory" not in found:         # no trajectory .csv/.txt among the sources: an event-only scene
        events_only(ctx, src, objects)
    else:
        traj = read_pose_text(found["trajectory"], ctx)

    with wrap_errors(src, "(file)", "-", "cannot open as HDF5"):
        h5 = h5py.File(src, "r", locking=False)
    try:
        ds, n = _event_datasets(h5, src)
        t_offset = _t_offset(h5, src, ctx)
        rep.details["dsec"] = {"events": str(src), "n": int(n), "t_dtype": str(ds["t"].dtype), "t_offset_us": t_offset,
                               "has_ms_to_idx": "ms_to_idx" in h5, "events_mode": opts.events_mode}
        with SceneBuilder(out, ctx) as sb:
            if opts.events_mode == "copy":
                sink = sb.event_sink(camera.width, camera.height, expected_events=n)
            else:
                sink = EventSink(ctx, None, camera.width, camera.height)
            n_wraps = _stream_events(ctx, ds, n, t_offset, src, sink)
            if n_wraps:
                rep.repair(f"{src.name}: events/t (uint32) wraps around 2**32 µs {n_wraps} time(s); unwrapped")
            if opts.events_mode == "copy":
                sb.finish_events(sink, src)
            else:
                _reference(ctx, sb, sink, src, n_wraps)
            if traj is not None:
                sb.set_trajectory(traj, "cam")
                rep.assume(f"{found['trajectory'].name}: poses are T_base_cam (camera in the base frame, metres)")
                sb.add_cli_objects(objects)
            sb.commit(camera)
    finally:
        h5.close()
    ctx.progress(1.0, "done")
    return result_summary(ctx, sb.out)


def _event_datasets(h5, src: Path) -> tuple[dict, int]:
    """The ``events/x|y|t|p`` datasets (1-D integers of one length) and the number of events."""
    import h5py

    ds = {}
    for f in "xytp":
        with wrap_errors(src, "(file)", f"events/{f}", "cannot read"):
            obj = h5.get(f"events/{f}")
        if not isinstance(obj, h5py.Dataset):
            raise ImportFailure(src, "(file)", f"events/{f}", "missing" if obj is None else "not a dataset")
        if obj.ndim != 1:
            raise ImportFailure(src, "(file)", f"events/{f}", f"shape {obj.shape} is not 1-D")
        if obj.dtype.kind not in ("iub" if f == "p" else "iu"):
            raise ImportFailure(src, "(file)", f"events/{f}", f"dtype {obj.dtype} is not an integer type")
        ds[f] = obj
    n = ds["t"].shape[0]
    for f in "xyp":
        if ds[f].shape[0] != n:
            raise ImportFailure(src, "(file)", f"events/{f}", f"length {ds[f].shape[0]} != {n} (events/t)")
    if n == 0:
        raise ImportFailure(src, "(file)", "events/t", "no events")
    return ds, n


def _t_offset(h5, src: Path, ctx: ImportContext) -> int:
    """``t_offset`` (µs) added to ``events/t``; 0 when absent (reported)."""
    if "t_offset" not in h5:
        ctx.report.assume(f"{src.name}: no t_offset; events/t taken as absolute µs")
        return 0
    with wrap_errors(src, "(file)", "t_offset", "cannot read"):
        o = np.asarray(h5["t_offset"][()])
    if o.size != 1 or o.dtype.kind not in "iu":
        raise ImportFailure(src, "(file)", "t_offset", f"expected an integer scalar, got {o.dtype} {o.shape}")
    return int(o.reshape(-1)[0])


class _Uint32Unwrap:
    """A uint32 clock that wraps around 2**32 µs (71.6 min): big negative steps unwrapped, chunk by chunk."""

    def __init__(self):
        self.wrap_add, self.prev_last, self.n_wraps = 0, None, 0

    def __call__(self, traw: np.ndarray, t: np.ndarray) -> None:
        """Unwrap ``t`` (int64 copy of the uint32 ``traw``) in place."""
        first_wrap = self.prev_last is not None and int(t[0]) - self.prev_last < -(1 << 31)
        dec = np.flatnonzero(traw[1:] < traw[:-1]) + 1          # cheap: only decreasing steps
        wpos = dec[(t[dec] - t[dec - 1]) < -(1 << 31)] if len(dec) else dec
        self.prev_last = int(t[-1])
        if first_wrap or len(wpos) or self.wrap_add:
            steps = np.zeros(len(t), np.int64)
            steps[wpos] = _WRAP
            if first_wrap:
                steps[0] += _WRAP
            t += self.wrap_add + np.cumsum(steps)
            nw = len(wpos) + int(first_wrap)
            self.n_wraps += nw
            self.wrap_add += _WRAP * nw


def _stream_events(ctx: ImportContext, ds: dict, n: int, t_offset: int, src: Path, sink: EventSink) -> int:
    """The events chunk by chunk into ``sink`` (uint32 wraps unwrapped, ``t_offset`` added); returns the
    number of wraps."""
    unwrap = _Uint32Unwrap() if ds["t"].dtype == np.uint32 else None
    for i0 in range(0, n, _CHUNK):
        i1 = min(i0 + _CHUNK, n)
        rec = f"events [{i0}, {i1})"
        with wrap_errors(src, rec, "events", "cannot read"):
            x, y, traw, p = (ds[f][i0:i1] for f in "xytp")
        t = traw.astype(np.int64)
        if unwrap is not None:
            unwrap(traw, t)
        if t_offset:
            t += t_offset
        sink.add(x, y, t, p, file=src, record=rec)
        ctx.progress(0.97 * i1 / n, f"{i1:,}/{n:,} events")
    return unwrap.n_wraps if unwrap is not None else 0


def _reference(ctx: ImportContext, sb: SceneBuilder, sink: EventSink, src: Path, n_wraps: int) -> None:
    """``--events-mode link|reference``: the validated source file is used as it is, or refused if it needs
    a repair."""
    opts, rep = ctx.options, ctx.report
    sink.close()
    needs = [k for k in ("events_dropped_outside_sensor", "events_decreasing_steps", "chunks_overlapping",
                         "events_dropped_late") if rep.counts.get(k)]
    if needs or n_wraps:
        raise ImportFailure(src, "(file)", "events", f"the file needs repairs ({', '.join(needs or ['uint32 wrap'])}); "
                            f"--events-mode {opts.events_mode} cannot change it: use --events-mode copy")
    sb.reference_events(src, opts.events_mode)
    rep.assume(f"events {'linked' if opts.events_mode == 'link' else 'referenced'} from {src.resolve()} "
               "(not copied; the scene depends on that file)")
    rep.details["events"] = {"n": sink.n_out, "t_first_us": sink.t_first, "t_last_us": sink.t_last}
