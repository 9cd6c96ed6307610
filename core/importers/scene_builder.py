"""The scene folder an import builds, atomically (:class:`SceneBuilder`).

The scene is built in a hidden, locked staging folder beside ``--out`` (:class:`~evpose.core.data.scene_folder.
StagingFolder`), synced, and renamed into place at the end; on any error, cancel or ``KeyboardInterrupt`` the
staging folder is removed, so a partial scene folder never exists. Every file it writes is logged first, so
that a later ``--force`` removes only what evpose wrote.

A scene committed without :meth:`SceneBuilder.set_trajectory` is *event-only*: no ``[trajectory]``, no objects
(:func:`events_only` refuses ``--objects`` for it before anything is read, and says in the report what the scene
is); :mod:`evpose.core.importers.scene_edit` adds a trajectory later.
"""
from __future__ import annotations

import contextlib
import json
import os
import re
import time
from pathlib import Path

import numpy as np

from evpose.core.data.atomic import atomic_write_text
from evpose.core.data.camera import CameraModel
from evpose.core.data.event_writer import EventWriter
from evpose.core.data.geometry import ROTATION_TOLERANCE, make_T, orthonormalize
from evpose.core.data.manifest import SCENE_FILENAME, ObjectSpec, SceneError, SceneManifest
from evpose.core.data.manifest_reader import load_manifest
from evpose.core.data.objects import size_warnings
from evpose.core.data.trajectory import Trajectory
from evpose.core.importers.event_sink import EventSink
from evpose.core.importers.failure import ImportFailure
from evpose.core.importers.meshes import place_mesh
from evpose.core.importers.output import check_out, import_inputs, output_failure
from evpose.core.importers.report import REPORT_FILENAME, ImportContext


class SceneBuilder:
    """Builds a scene folder atomically: a hidden sibling ``.NAME.import-*`` folder renamed into place at the end.

    Use as a context manager; leaving it with an exception (including ``KeyboardInterrupt`` and
    :class:`Cancelled`) removes the temporary folder, and nothing exists at ``out`` that was not there before.
    """

    def __init__(self, out, ctx: ImportContext):
        from evpose.core.data.scene_folder import StagingFolder

        self.ctx = ctx
        self.inputs = import_inputs(ctx.report.sources, ctx.options)
        self.out = check_out(out, ctx.options.force, self.inputs)
        self.staging = StagingFolder(self.out, "import", f"import {ctx.report.fmt}")
        self.tmp = self.staging.path
        self.writer: EventWriter | None = None
        self.events_ref: str = "events.h5"
        self.objects: list[ObjectSpec] = []
        self.trajectory_frame = "cam"
        self.hand_eye = None
        self._has_traj = False
        self._has_events = False

    def __enter__(self) -> "SceneBuilder":
        try:
            self.staging.create()
            (self.tmp / "models").mkdir()
        except OSError as exc:
            self.staging.abort()
            raise ImportFailure(self.out, "(output)", "--out", f"cannot create the scene folder "
                                f"({exc.strerror or exc})") from None
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is not None:
            self.abort()
            if isinstance(exc, OSError):
                failure = output_failure(exc, self.out, self.tmp)
                if failure is not None:
                    raise failure from None

    def abort(self) -> None:
        if self.writer is not None:
            with contextlib.suppress(Exception):
                self.writer.abort()
            self.writer = None
        self.staging.abort()

    # ------------------------------------------------------------------ events
    def event_sink(self, width: int, height: int, expected_events: int | None = None) -> EventSink:
        """A sink that writes ``events.h5`` (int64 µs, Blosc-LZ4) in the scene."""
        self.writer = EventWriter(self.tmp / "events.h5", time_dtype="int64", compression=self.ctx.options.compression,
                                  cancel=self.ctx.cancelled, expected_events=expected_events)
        self._has_events = True
        return EventSink(self.ctx, self.writer, width, height)

    def finish_events(self, sink: EventSink, file) -> None:
        sink.close()
        if sink.n_out == 0:
            raise ImportFailure(file, "(all records)", "events", "no events (empty topic/file, or every event was "
                                "dropped: see the report)")
        if self.writer is not None:
            self.writer.close()
            self.writer = None
        self.ctx.report.details["events"] = {"n": sink.n_out, "t_first_us": sink.t_first, "t_last_us": sink.t_last,
                                             "x_range": [sink.x_min, sink.x_max], "y_range": [sink.y_min, sink.y_max]}

    def reference_events(self, src: Path, mode: str) -> None:
        """Use an existing event file: ``link`` (symlink ``events.h5`` -> absolute source) or ``reference``
        (absolute path in ``scene.toml``). The source is never modified."""
        src = Path(src).absolute()
        self.inputs.append(src)
        if mode == "link":
            os.symlink(src, self.tmp / "events.h5")
            self.events_ref = "events.h5"
        else:
            self.events_ref = str(src)
        self._has_events = True

    # ------------------------------------------------------------------ trajectory / objects
    def set_trajectory(self, traj: Trajectory, frame: str = "cam", hand_eye=None) -> None:
        traj.save_csv(self.tmp / "trajectory.csv")
        self.trajectory_frame, self.hand_eye = frame, hand_eye
        self._has_traj = True
        self.ctx.report.details["trajectory"] = {"n": len(traj), "frame": frame, "t_first_us": traj.t_first_us,
                                                 "t_last_us": traj.t_last_us}

    def add_cli_objects(self, objects: dict) -> None:
        """Add the ``--objects`` of a command (name -> (mesh, T_base_obj, class id, source)); warn
        when there are none (a scene without objects can be viewed but has nothing to label)."""
        for name, (mesh, T, cid, s) in objects.items():
            self.add_object(name, mesh, T, class_id=cid, source=s)
        if not objects:
            self.ctx.report.warn("no objects (give --objects name=mesh:T_base_obj.json)")

    def add_object(self, name: str, mesh, T_raw, *, residual: float = 0.0, mesh_scale: float = 1.0,
                   class_id: int = 0, symmetric: bool = False, source: str = "") -> None:
        """Add an object. ``mesh`` is a mesh file (copied verbatim, plus a sibling ``.mtl``) or a
        ``(vertices_m, faces)`` pair (written as PLY in metres). ``T_raw`` is ``T_base_obj`` as read; it is
        written unchanged, with ``repair_rotation = true`` when its residual exceeds the tolerance."""
        if any(o.name == name for o in self.objects):
            raise ImportFailure(source or "(objects)", name, "name", f"duplicate object name {name!r}")
        safe = re.sub(r"[^A-Za-z0-9_.-]+", "_", name) or "object"
        dst = place_mesh(mesh, self.tmp / "models", safe, name, self.ctx.report, self.inputs)
        T_raw = np.asarray(T_raw, dtype=np.float64)
        R, res = orthonormalize(T_raw[:3, :3])
        T = make_T(R, T_raw[:3, 3])
        repair = bool(res > ROTATION_TOLERANCE)
        self.objects.append(ObjectSpec(name, dst, T, float(mesh_scale), int(class_id), bool(symmetric), repair,
                                       float(res), T_raw))
        self.ctx.report.details.setdefault("objects", {})[name] = {
            "mesh": f"models/{dst.name}", "mesh_source": str(mesh) if not isinstance(mesh, tuple) else "(generated)",
            "rotation_residual": float(res), "class_id": int(class_id), "T_base_obj": T_raw.tolist(),
            **({"source": source} if source else {})}

    def save_source_poses(self, t_us, tracks: dict[str, dict[int, np.ndarray]]) -> None:
        """Keep the object poses exactly as the source gave them (``source_poses.npz``: ``t_us`` (F,),
        ``names`` (K,), ``T_cam_obj`` (F, K, 4, 4), NaN where an object has no pose), so that the labels of an
        exported dataset can be compared with the scene's after correction."""
        names = list(tracks)
        T = np.full((len(t_us), len(names), 4, 4), np.nan)
        for j, nm in enumerate(names):
            for k, M in tracks[nm].items():
                T[k, j] = M
        with open(self.tmp / "source_poses.npz", "wb") as f:
            np.savez(f, t_us=np.asarray(t_us, np.int64), names=np.asarray(names), T_cam_obj=T)
        self.ctx.report.details["source_poses"] = "source_poses.npz (T_cam_obj per frame and object, as read)"

    # ------------------------------------------------------------------ commit
    def commit(self, camera: CameraModel, *, clock_offset_us: int = 0, clock_skew_ppm: float = 0.0,
               name: str | None = None) -> Path:
        """Write ``scene.toml`` and ``import_report.json``, check the manifest loads, rename into place."""
        import tomli_w

        if not self._has_events:
            raise ImportFailure(self.out, "(scene)", "events", "internal: no events were written")
        if not self._has_traj and self.objects:
            raise ImportFailure(self.out, "(scene)", "trajectory", "internal: objects without a trajectory")
        if self.ctx.options.offset_us is not None:
            self.ctx.report.assume(f"clock prior offset {int(self.ctx.options.offset_us)} µs (--offset-us)")
            clock_offset_us = int(self.ctx.options.offset_us)
        name = name or self.ctx.options.name or self.out.name
        warn_if_no_time_overlap(self.ctx.report, int(clock_offset_us), float(clock_skew_ppm))
        specs = [ObjectSpec(o.name, o.mesh, o.T_base_obj, o.mesh_scale, o.class_id, o.symmetric, o.repair_rotation,
                            o.rotation_residual, o.T_base_obj_raw) for o in self.objects]
        manifest = SceneManifest(self.tmp / SCENE_FILENAME, name, camera, self.tmp / "events.h5",
                                 self.tmp / "trajectory.csv" if self._has_traj else None, self.trajectory_frame,
                                 self.hand_eye,
                                 int(clock_offset_us), float(clock_skew_ppm), specs)
        doc = manifest.to_toml_dict()
        doc["events"]["path"] = self.events_ref          # link/reference modes: never resolved through a symlink
        atomic_write_text(self.tmp / SCENE_FILENAME, tomli_w.dumps(doc))
        rep = self.ctx.report
        for line in size_warnings(specs):              # the scene is written; evpose refuses it until fixed
            rep.warn(line)
        rep.details["runtime_s"] = time.perf_counter() - self.ctx.t_start
        rep.details["scene"] = {"name": name, "camera": camera.to_dict(), "clock": {
            "offset_us": int(clock_offset_us), "skew_ppm": float(clock_skew_ppm)}, "events_path": self.events_ref}
        atomic_write_text(self.tmp / REPORT_FILENAME, json.dumps(rep.to_dict(), indent=1, default=_json_default) + "\n")
        try:
            load_manifest(self.tmp)
        except SceneError as exc:
            raise ImportFailure(self.out / SCENE_FILENAME, "(manifest)", exc.field or "-",
                                f"the written manifest does not load: {exc}") from None
        self._place()
        return self.out

    def _place(self) -> None:
        from evpose.core.data.scene_folder import NotOurs

        try:
            self.staging.commit(self.inputs, self.ctx.options.force)
        except NotOurs as exc:
            raise ImportFailure(exc.path, "(output)", "--out", exc.reason) from None


def events_only(ctx: ImportContext, src, objects: dict) -> None:
    """The import of ``src`` has no trajectory: the scene will be event-only. Refuse ``--objects`` (placed in the
    base frame, they need the camera's trajectory) before anything is read; say what the scene is in the report
    (``events_only``: true)."""
    if objects:
        raise ImportFailure(src, "(arguments)", "--objects", f"objects ({', '.join(objects)}) are placed in the base "
                            "frame and need a camera trajectory: give the TRAJECTORY too, or leave out --objects for "
                            "an event-only scene")
    ctx.report.details["events_only"] = True
    ctx.report.assume("no trajectory: an event-only scene (events and event frames, no labels; evpose scene "
                      "set-trajectory SCENE TRAJECTORY adds one later)")


def warn_if_no_time_overlap(report, offset_us: int, skew_ppm: float) -> None:
    """Warn when the events, mapped to pose time by the clock prior (``offset_us`` µs, ``skew_ppm``; DESIGN
    section 3), and the trajectory do not overlap in time: no window of such a scene gets a label until its clock
    is corrected. A warning, not a refusal: the clock is what ``sync`` and the corrections fix, and a scene
    imported with the wrong prior can still be corrected. ``time_overlap_us`` goes into the report."""
    ev, tr = report.details.get("events"), report.details.get("trajectory")
    if not ev or not tr or ev.get("t_first_us") is None or tr.get("t_first_us") is None:
        return
    t0, t1 = int(ev["t_first_us"]), int(ev["t_last_us"])
    p0, p1 = (t + offset_us + skew_ppm * 1e-6 * (t - t0) for t in (t0, t1))
    overlap = min(p1, tr["t_last_us"]) - max(p0, tr["t_first_us"])
    report.details["time_overlap_us"] = int(max(overlap, 0))
    if overlap < 0:
        report.warn(f"the events [{t0}, {t1}] µs (pose time [{int(p0)}, {int(p1)}] µs with the clock prior offset "
                    f"{offset_us} µs) and the trajectory [{tr['t_first_us']}, {tr['t_last_us']}] µs do not overlap "
                    "in time: no window can get a label (wrong time unit or clock? --offset-us sets the prior; the "
                    "offset can also be corrected later)")


def _json_default(o):
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, (np.floating,)):
        return float(o)
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    return str(o)
