"""What the single-recording importers share (``evpose import aedat4|prophesee REC [TRAJECTORY [CALIB]]``).

Sources are positional: the recording, then optionally a trajectory (our ``t_us,x,y,z,qx,qy,qz,qw`` CSV or a
TUM-style text file, ``T_base_cam`` in metres, read by :func:`~evpose.core.importers.pose_text.read_pose_text`),
then optionally a calibration (any file ``--camera`` takes). The options are those of ``import dsec``. Without a
trajectory (and a recording holding no poses) the scene is event-only (no ``[trajectory]``, no objects:
:func:`~evpose.core.importers.scene_builder.events_only`); a calibration then comes with ``--camera``.

The sensor size comes from the recording; a calibration made for another size is refused (``--width/--height``
override both). Without a calibration a 346x260 sensor gets E-POSE's DAVIS346 calibration (reported, as
``import epose-bag`` does); any other size needs one.

:func:`build_recording_scene` streams a reader's event chunks through the validating
:class:`~evpose.core.importers.event_sink.EventSink` into the scene's ``events.h5`` (memory bounded by the
sink's reorder window, never by the file) and commits the scene atomically.
"""
from __future__ import annotations

from pathlib import Path
from typing import Callable, Iterable

from evpose.core.data.camera import CameraModel
from evpose.core.importers.calibration import load_camera
from evpose.core.importers.failure import ImportFailure
from evpose.core.importers.object_args import collect_objects
from evpose.core.importers.report import ImportContext, result_summary
from evpose.core.importers.scene_builder import SceneBuilder

#: One chunk of a reader: ``(x, y, t_us int64, p, record, fraction of the file read)``.
Chunk = tuple


def recording_sources(sources, fmt: str, suffixes: tuple[str, ...]) -> tuple[Path, Path | None, Path | None]:
    """``(recording, trajectory or None, calibration or None)`` from ``REC [TRAJECTORY [CALIB]]``.

    The recording must exist, be a regular file (a FIFO or a device is refused before it is opened) and end in
    one of ``suffixes``; the other two must exist."""
    from evpose.core.data.input_files import InputFileError, check_regular

    srcs = [Path(s) for s in sources]
    usage = f"give REC{'|'.join(suffixes)} [TRAJECTORY [CALIB]]"
    if not 1 <= len(srcs) <= 3:
        raise ImportFailure(", ".join(map(str, srcs)) or "(none)", "(arguments)", "SRC", f"{fmt}: {usage}")
    rec = srcs[0]
    try:
        check_regular(rec)
    except InputFileError as exc:
        raise ImportFailure(rec, "(file)", "SRC", exc.reason) from None
    if rec.suffix.lower() not in suffixes:
        raise ImportFailure(rec, "(file)", "SRC", f"not a {fmt} recording (expected {', '.join(suffixes)}); {usage}")
    for s in srcs[1:]:
        if not s.is_file():
            raise ImportFailure(s, "(file)", "SRC", "no such file")
    return rec, (srcs[1] if len(srcs) > 1 else None), (srcs[2] if len(srcs) > 2 else None)


def recording_camera(ctx: ImportContext, calib: Path | None, size: tuple[int, int], rec: Path) -> CameraModel:
    """The camera of a recording whose sensor is ``size`` (width, height) pixels: ``CALIB`` or ``--camera``, else
    the DAVIS346 default for a 346x260 sensor (reported)."""
    opts = ctx.options
    if calib is not None and opts.camera:
        raise ImportFailure(calib, "(arguments)", "CALIB", f"give the calibration once (CALIB or --camera "
                            f"{opts.camera})")
    calib = calib or (Path(opts.camera) if opts.camera else None)
    w, h = (int(opts.width), int(opts.height)) if opts.width and opts.height else (int(size[0]), int(size[1]))
    if calib is None:
        if (w, h) == (346, 260):
            ctx.report.assume(f"no calibration: DAVIS346 calibration of E-POSE (sensor 346x260 from {rec.name})")
            return CameraModel.davis346()
        raise ImportFailure(rec, "(arguments)", "CALIB", f"no calibration for the {w}x{h} sensor: give CALIB or "
                            "--camera")
    cam = load_camera(calib, ctx, default_size=(w, h))
    if (cam.width, cam.height) != (w, h):
        raise ImportFailure(calib, "(file)", "resolution", f"the calibration is for {cam.width}x{cam.height}, the "
                            f"sensor of {rec.name} is {w}x{h} (--width/--height override both)")
    return cam


def build_recording_scene(ctx: ImportContext, out, rec: Path, camera: CameraModel, chunks: Iterable[Chunk],
                          trajectory: Callable[[], object], objects: dict | None = None,
                          clock_offset_us: Callable[[], int] | None = None) -> dict:
    """Stream ``chunks`` into the scene's events, add ``trajectory()`` (a ``T_base_cam``
    :class:`~evpose.core.data.trajectory.Trajectory`, called once the events are in; None: an event-only scene, for
    which :func:`~evpose.core.importers.scene_builder.events_only` was called) and the ``--objects``, commit with the
    clock prior ``clock_offset_us()`` (called then; default 0, ``--offset-us`` overrides); returns the import
    summary."""
    objects = collect_objects(ctx, None) if objects is None else objects
    with SceneBuilder(out, ctx) as sb:
        sink = sb.event_sink(camera.width, camera.height)
        n = 0
        for x, y, t, p, record, fraction in chunks:
            sink.add(x, y, t, p, file=rec, record=record, first=n)
            n += len(t)
            ctx.progress(0.97 * fraction, f"{n:,} events")
        sb.finish_events(sink, rec)
        traj = trajectory()
        if traj is not None:
            sb.set_trajectory(traj, "cam")
            sb.add_cli_objects(objects)
        ctx.progress(0.99, "writing scene")
        sb.commit(camera, clock_offset_us=int(clock_offset_us()) if clock_offset_us is not None else 0)
    ctx.progress(1.0, "done")
    return result_summary(ctx, sb.out)
