"""iniVation DV recordings, AEDAT 4.0 (``evpose import aedat4 REC.aedat4 [TRAJECTORY [CALIB]]``).

AEDAT4 is the native container of DV and of the DAVIS346 that recorded E-POSE: LZ4/ZSTD-compressed
flatbuffer packets of events (int64 µs, int16 x/y, polarity), frames, IMU, triggers and poses, with a packet
table at the end. It is read with iniVation's own library, ``dv-processing`` (PyPI ``dv-processing``, module
``dv_processing``; the reference implementation, which also writes the format, so the tests write their files
with it). No decoder of our own.

Why ``dv-processing`` and not the Rust ``aedat`` reader (also on PyPI): ``aedat`` 2.3 refuses any file holding a
pose stream ("unsupported stream type"), and reading the pose stream is part of this format's import; it is
also slower here (40 M vs 130 M events/s decoded). ``dv-processing``'s drawback -- on some corrupt packets it
spins forever holding the GIL -- is contained by running it in a child process with a stall timeout
(:mod:`evpose.core.importers.aedat4_reader`), so a damaged file still ends in one error line.

Sources and options are those of ``import dsec`` (:mod:`evpose.core.importers.recording`):

* the sensor size is the event stream's resolution in the file (``--width/--height`` override it);
* the trajectory: the TRAJECTORY file when given (a pose stream in the file is then ignored, reported); else the
  file's pose stream (``poses``, or the first stream of pose type), taken as ``T_base_cam``: the pose of the
  ``targetFrame`` (camera) in the ``referenceFrame`` (base), translation in metres, quaternion w x y z (float32 in
  the file), time stamps in µs of the event clock. Without either, the scene is event-only (no trajectory, no
  objects; a calibration then comes with ``--camera``);
* the event stream is ``events``, or the first stream of event type (reported when there are several).

Times are AEDAT4's int64 µs, written unchanged.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from evpose.core.importers.aedat4_reader import Aedat4Reader
from evpose.core.importers.failure import ImportFailure
from evpose.core.importers.object_args import collect_objects
from evpose.core.importers.pose_checks import make_trajectory
from evpose.core.importers.pose_text import read_pose_text
from evpose.core.importers.recording import build_recording_scene, recording_camera, recording_sources
from evpose.core.importers.report import ImportContext
from evpose.core.importers.scene_builder import events_only

SUFFIXES = (".aedat4",)
POSE_FIELDS = ("timestamp", "translation.x", "translation.y", "translation.z", "rotation.x", "rotation.y",
               "rotation.z", "rotation.w")


def import_aedat4(sources, out, ctx: ImportContext) -> dict:
    """Import an AEDAT4 recording (+ trajectory, calibration) into a scene folder; returns the summary."""
    rec, traj_file, calib = recording_sources(sources, "aedat4", SUFFIXES)
    with Aedat4Reader(rec, ctx, poses=traj_file is None) as reader:      # the reading process starts meanwhile
        traj = read_pose_text(traj_file, ctx) if traj_file is not None else None
        objects = collect_objects(ctx, None)
        head = reader.header
        _check_header(ctx, rec, head, traj_file)
        no_poses = traj_file is None and not head["pose_streams"]
        if no_poses:
            events_only(ctx, rec, objects)
        camera = recording_camera(ctx, calib, tuple(head["resolution"]), rec)
        ctx.report.details["aedat4"] = {"camera": head["camera"], "streams": head["streams"],
                                        "event_stream": head["event_stream"], "pose_streams": head["pose_streams"],
                                        "resolution": head["resolution"]}
        chunks = _chunks(reader, rec, head.get("time_range"))
        return build_recording_scene(
            ctx, out, rec, camera, chunks,
            lambda: None if no_poses else traj if traj is not None else _pose_stream(ctx, rec, reader), objects)


def _check_header(ctx: ImportContext, rec: Path, head: dict, traj_file) -> None:
    rep = ctx.report
    if not head["event_stream"]:
        streams = ", ".join(head["streams"]) or "none"
        raise ImportFailure(rec, "(streams)", "events", f"no event stream (streams: {streams})")
    if not head["resolution"]:
        raise ImportFailure(rec, f"stream {head['event_stream']}", "resolution", "the event stream has no resolution")
    if len(head["event_streams"]) > 1:
        rep.assume(f"{rec.name}: events from stream {head['event_stream']!r} (event streams: "
                   f"{', '.join(head['event_streams'])})")
    if traj_file is not None:
        rep.assume(f"{Path(traj_file).name}: poses are T_base_cam (camera in the base frame, metres)")
        if head["pose_streams"]:
            rep.assume(f"{rec.name}: pose stream(s) {', '.join(head['pose_streams'])} ignored (TRAJECTORY given)")


def _chunks(reader: Aedat4Reader, rec: Path, time_range):
    """``(x, y, t, p, record, fraction)`` per frame of the reader; fraction from the file's time range."""
    t0, t1 = (time_range or (0, 0))
    span = max(int(t1) - int(t0), 1)
    n = 0
    for t, x, y, p in reader.events():
        frac = min(max((int(t[-1]) - int(t0)) / span, 0.0), 1.0) if len(t) else 0.0
        yield x, y, t, p, f"events [{n}, {n + len(t)})", frac
        n += len(t)


def _pose_stream(ctx: ImportContext, rec: Path, reader: Aedat4Reader):
    """The file's pose stream as a ``T_base_cam`` trajectory (read after the events, validated)."""
    t, v = reader.poses
    stream = "poses" if "poses" in reader.header["pose_streams"] else reader.header["pose_streams"][0]
    frames = (reader.done or {}).get("pose_frames", {})
    if len(t) == 0:
        raise ImportFailure(rec, f"stream {stream}", "poses", "the pose stream has no poses and no TRAJECTORY was "
                            "given")
    ctx.report.assume(f"{rec.name}: pose stream {stream!r} is T_base_cam (pose of the target frame in the reference "
                      f"frame, metres; frames {', '.join(frames) or 'unnamed'})")
    if len(frames) > 1:
        ctx.report.warn(f"{rec.name}: pose stream {stream!r} mixes frames ({', '.join(frames)}); all taken as "
                        "T_base_cam")
    quat_xyzw = np.column_stack([v[:, 4:7], v[:, 3]])
    return make_trajectory(ctx, rec, t, v[:, :3], quat_xyzw, record_of=lambda i: f"stream {stream}, pose {i}",
                           fields=POSE_FIELDS)
