"""The per-process side of an export: what a worker needs (:class:`WorkerSpec`) and what it keeps
(:class:`WorkerContext`: the scene, one Annotator, the writer's state, stage timings).

With ``jobs > 1`` each worker process rebuilds the scene from the pickled manifest and a JSON copy of the
corrections and opens its own event store (an h5py handle never crosses processes); with one job the
parent's scene is used. :meth:`WorkerContext.run` reads a window's events, annotates it with the pose the
parent interpolated and hands both to the writer's :meth:`~evpose.core.export.writer.FormatWriter.process`.
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from evpose.core.data.events import EventArray
from evpose.core.data.owned_log import OwnedLog
from evpose.core.document.corrections import Corrections
from evpose.core.export.out_folder import EXPORT_ROLE
from evpose.core.export.writer import FormatWriter, WindowTask
from evpose.core.label.labels import Request

__all__ = ["STAGES", "WorkerSpec", "WorkerContext"]

#: Stages of the per-window time split (seconds summed over windows, all processes).
STAGES = ("events", "annotate", "images", "mat", "write")


@dataclass
class WorkerSpec:
    """Everything a worker process needs (pickled once per worker)."""

    manifest: object
    corrections_json: dict
    writer: FormatWriter
    out_dir: str
    names: list
    sel: list
    request: Request
    n_digits: int
    durable: str


class WorkerContext:
    """Per-process state: the scene, one Annotator, the writer's buffers, stage timings."""

    def __init__(self, spec: WorkerSpec, scene=None, owned: OwnedLog | None = None):
        from evpose.core.data.scene import Scene

        if scene is None:
            scene = Scene(spec.manifest, Corrections.from_json(spec.corrections_json))
        self.scene = scene
        self.spec = spec
        self.writer = spec.writer
        self.out_dir = Path(spec.out_dir)
        self.names = spec.names
        self.sel = np.asarray(spec.sel, np.intp)
        self.camera = self.writer.output_camera(scene) or scene.camera
        # all objects are rasterised (objects that are not exported still occlude the exported ones); an event-only
        # scene has nothing to label: no annotator, so neither meshes nor the rasteriser (numba) are loaded
        self.annotator = None
        if scene.has_poses:
            from evpose.core.label.annotate import Annotator

            self.annotator = Annotator(scene, spec.request, camera=self.camera, objects=scene.object_names)
        self.timings = dict.fromkeys(STAGES, 0.0)
        #: fsync each file before its rename ("file" mode); "batch" syncs the filesystem per chunk
        self.fsync_files = spec.durable == "file"
        #: every file this process writes is logged here before it appears (evpose.core.data.owned_log)
        self.owned = owned if owned is not None else OwnedLog(self.out_dir, EXPORT_ROLE, f"export {self.writer.fmt}")
        self.state = self.writer.setup_worker(self)

    def run(self, task: WindowTask) -> tuple[dict, object]:
        t = time.perf_counter()
        w = task.window
        ev = self.scene.events.read(w.i0, w.i1) if w.i1 > w.i0 else EventArray.empty()
        t1 = time.perf_counter()
        labels = None
        if task.valid:
            labels = self.annotator.annotate(w, ev, pose=(task.T_cam_obj, task.T_base_cam, True))
        t2 = time.perf_counter()
        self.timings["events"] += t1 - t
        self.timings["annotate"] += t2 - t1
        return self.writer.process(self, task, ev, labels)

    def end_chunk(self) -> None:
        """The chunk's windows are done: the writer writes what it grouped (BOP shards), timed as "write"."""
        t = time.perf_counter()
        self.writer.end_chunk(self)
        self.timings["write"] += time.perf_counter() - t

    def take_timings(self) -> dict:
        t = self.timings
        self.timings = dict.fromkeys(STAGES, 0.0)
        return t
