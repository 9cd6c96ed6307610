"""The contract between the export runner and a dataset format: :class:`FormatWriter`, the parent-side
:class:`ExportContext` it receives, and the :class:`WindowTask` of one window.

A writer runs in two places. In the parent: :meth:`FormatWriter.begin` (folders, files that do not
depend on windows), :meth:`~FormatWriter.completed` (resume), :meth:`~FormatWriter.accept` (each window's
record), :meth:`~FormatWriter.flush` (make accepted windows durable), :meth:`~FormatWriter.finish`
(aggregate files) or :meth:`~FormatWriter.abort`. In each worker process
(:mod:`evpose.core.export.worker`): :meth:`~FormatWriter.setup_worker` and
:meth:`~FormatWriter.process`, which writes one window's files with
:class:`evpose.core.data.atomic.AtomicBatch`, its last file last.

Durability across a power cut (``ExportContext.durable``): "batch" (default) syncs the filesystem
(``syncfs``) before the parent writes and fsyncs the journal lines of a chunk of windows, so a journaled
window is on disk; "file" fsyncs every file before its rename (2-3 ms per file on the development disk:
30+ ms per 3-object E-POSE window); "none" never syncs.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from evpose.core.data import atomic
from evpose.core.data.events import EventArray
from evpose.core.data.owned_log import OwnedLog
from evpose.core.export.journal import Journal
from evpose.core.label.labels import Request
from evpose.core.label.windows import Window

if TYPE_CHECKING:  # pragma: no cover - the worker module imports this one
    from evpose.core.export.worker import WorkerContext

__all__ = ["WindowTask", "FormatWriter", "ExportContext"]


@dataclass
class WindowTask:
    """One window handed to a worker, with its pose interpolated by the parent."""

    window: Window
    T_cam_obj: np.ndarray      # (K_all, 4, 4)
    T_base_cam: np.ndarray     # (4, 4)
    valid: bool
    row: int = -1              # position among the selected windows (HDF5 row)
    #: (K exported, 3): each label's sigma_t_mm, sigma_R_deg, sigma_px (None: the export computes none)
    sigma: np.ndarray | None = None

    def __reduce__(self):
        """Pickled with its poses as bytes: in-band, where Dask's pickling sends every numpy array of a chunk as
        its own out-of-band frame (two a window: ~0.1 ms a window of the driver's CPU, issue 27.2)."""
        T_co = np.ascontiguousarray(self.T_cam_obj, np.float64)
        sigma = None if self.sigma is None else np.asarray(self.sigma, np.float64).tolist()
        return _task_from_bytes, (self.window, T_co.tobytes(), T_co.shape,
                                  np.ascontiguousarray(self.T_base_cam, np.float64).tobytes(), self.valid, self.row,
                                  sigma)


def _task_from_bytes(window, T_co: bytes, shape, T_bc: bytes, valid, row, sigma=None) -> WindowTask:
    return WindowTask(window, np.frombuffer(T_co, np.float64).reshape(shape).copy(),
                      np.frombuffer(T_bc, np.float64).reshape(4, 4).copy(), valid, row,
                      None if sigma is None else np.asarray(sigma, np.float64))


class FormatWriter:
    """A dataset format. Instances are pickled to the workers: keep only options in ``__init__``;
    per-process state goes into the dict returned by :meth:`setup_worker`.

    Parent side: :meth:`begin`, :meth:`completed`, :meth:`accept`, :meth:`finish`, :meth:`abort`.
    Worker side: :meth:`setup_worker`, :meth:`process`.
    """

    fmt = ""
    #: Whether windows without labels still go through :meth:`process` (with ``labels=None``).
    process_unlabeled = False

    def options(self) -> dict:
        """Format options that change the output bytes (part of the fingerprint)."""
        return {}

    def request(self, margin_m: float) -> Request:
        raise NotImplementedError

    def output_camera(self, scene):
        """Camera the labels are computed in (None: the scene's raw camera)."""
        return None

    # -- parent
    def begin(self, ctx: "ExportContext") -> None:
        """Create folders and the files that do not depend on windows."""

    def completed(self, ctx: "ExportContext") -> dict[int, dict]:
        """Records of the windows already complete (resume)."""
        recs = ctx.journal.load()
        return {i: r for i, r in recs.items() if self.last_file(ctx, i) is None or self.last_file(ctx, i).exists()}

    def last_file(self, ctx: "ExportContext", index: int) -> Path | None:
        return None

    def accept(self, ctx: "ExportContext", record: dict, payload, line: str | None = None) -> None:
        """A window's result arrived (``line``: its journal line, encoded by the worker, or None)."""
        ctx.journal.append(record, line)

    def flush(self, ctx: "ExportContext") -> None:
        """Make the accepted windows durable, then their journal lines ("batch" mode: one ``syncfs``
        covers every file the workers wrote, whatever process wrote it; none when the workers synced their chunks,
        ``ctx.extra["chunks_durable"]``)."""
        if ctx.journal.pending:
            if ctx.durable == "batch" and not ctx.extra.get("chunks_durable"):
                t = time.perf_counter()
                atomic.sync_filesystem(ctx.out_dir)
                ctx.extra["parent_write_s"] = ctx.extra.get("parent_write_s", 0.0) + time.perf_counter() - t
            ctx.journal.sync()

    def finish(self, ctx: "ExportContext", records: dict[int, dict]) -> tuple[list[str], list[str]]:
        """Write the aggregate files; return ``(files, window_patterns)``: every file of the export
        relative to ``out_dir``, the per-window files last (``ctx.extra["n_window_files"]`` of them), and
        the per-window file name patterns (``{index}`` = window index) for the manifest."""
        return [], []

    def abort(self, ctx: "ExportContext") -> None:
        """Interrupted: leave the folder resumable."""

    def readme(self, ctx: "ExportContext") -> str:
        return ""

    def chunk_group(self):
        """None, or ``group(task)``: windows of one group go to one worker in one chunk, whose end calls
        :meth:`end_chunk` (a file holding many windows, e.g. a BOP shard)."""
        return None

    # -- worker
    def setup_worker(self, wctx: "WorkerContext") -> dict:
        return {}

    def begin_chunk(self, wctx: "WorkerContext") -> None:
        """A chunk starts: forget what a failed earlier chunk of this worker left half grouped."""

    def end_chunk(self, wctx: "WorkerContext") -> None:
        """A chunk's windows were processed (whole groups of :meth:`chunk_group`): write what spans them."""

    def process(self, wctx: "WorkerContext", task: WindowTask, events: EventArray, labels) -> tuple[dict, object]:
        """Write/compute one window; return ``(record, payload)`` for :meth:`accept`."""
        raise NotImplementedError


@dataclass
class ExportContext:
    """Parent-side state of one export run."""

    scene: object
    writer: FormatWriter
    out_dir: Path
    names: list
    sel: np.ndarray              # indices of the exported objects among the scene's objects
    windows: list
    fingerprint: dict
    sha: str
    margin_m: float
    label_at: str
    journal: Journal
    n_digits: int
    durable: str = "batch"       # durability mode, see evpose.core.export.options.durability_mode
    extra: dict = field(default_factory=dict)
    #: the parent's record of the files it writes (evpose.core.data.owned_log); workers keep their own
    owned: OwnedLog | None = None

    @property
    def fsync(self) -> bool:
        """fsync the (few) aggregate files the parent writes."""
        return self.durable != "none"
