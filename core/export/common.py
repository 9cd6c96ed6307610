"""Machinery shared by the dataset writers: windows, review filter, configuration fingerprint,
output folder state (resume / refuse / force), atomic file batches, the serial and process-pool
runners, and the export manifest.

Vocabulary
----------
*window*
    One half-open event-time interval ``[t0_us, t1_us)`` of the tiling (:func:`evpose.core.label.annotate.time_windows`
    or :func:`evpose.core.label.annotate.count_windows`); ``index`` is its position in the tiling and names its files.
*selected*
    Windows that pass ``only_verified`` (all windows when it is off).
*unlabeled*
    Selected windows whose label time falls outside the trajectory under the clock in effect, or inside a
    hole of it (samples more than ``max_gap_us`` apart): no labels (no extrapolation, no bridging of holes);
    listed with the reason in the summary and the manifest.
*complete*
    A window whose outputs a previous run with the same configuration wrote entirely. For the file
    formats a window is complete when the parent recorded it in the journal ``.evpose/journal.jsonl``
    (it does so only after the worker renamed the window's last file into place) **and** that last file
    exists. The HDF5 writer keeps its own per-row flags inside the partial file.

Output folder state
-------------------
``OUT/.evpose/config.json`` holds the configuration fingerprint (:func:`export_fingerprint`). A run into
a folder with the same fingerprint resumes. Otherwise (:func:`_prepare_out_dir`) only what evpose can
prove it wrote is ever removed: every file is logged in ``OUT/.evpose/owned-*.log`` before it appears
under its name (:mod:`core.owned_files`; the workers log their own). Anything else in the folder -- a
file the user added, or one of ours changed since -- refuses the run, even with ``force``, naming it;
so does a folder holding an input (the scene). An earlier export with results (journaled windows or a
finished export) is replaced only with ``force``; one without (a run that failed early) is replaced
without. evpose's temporary files (``.<name>.<pid>-<n>.tmp``) are removed on start and on interrupt.

Atomicity and durability
------------------------
Every file is written to a hidden temp file beside its target (``.<name>.<pid>-<n>.tmp``) and renamed
into place, so a reader never sees a partial file; the files of one window are renamed in order, its
last file last. Durability across a power cut (``durable``): "batch" (default) syncs the filesystem
(``syncfs``) before the parent fsyncs the journal lines of a chunk of windows, so a journaled window is
on disk; "file" fsyncs every file before its rename, like :func:`evpose.core.data.atomic.atomic_path` (2-3 ms per
file on the development disk: 30+ ms per 3-object E-POSE window); "none" never syncs.

Processes
---------
``jobs > 1`` runs a ``spawn`` process pool. Each worker rebuilds the scene from the pickled manifest and
a JSON copy of the corrections and opens its own event store (an h5py handle never crosses processes),
builds one :class:`~evpose.core.label.annotate.Annotator`, and processes contiguous chunks of windows whose poses the
parent interpolated in one vectorised call. Workers ignore SIGINT; the parent turns Ctrl-C or a
``cancel()`` into ``pool.terminate()``, removes temp files and re-raises.
"""
from __future__ import annotations

import contextlib
import hashlib
import io
import json
import math
import os
import signal
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from evpose.core.data.atomic import sync_filesystem, write_atomic
from evpose.core.data.events import Cancelled, EventArray
from evpose.core.data.os_errors import with_path
from evpose.core.data.owned_files import held_input, in_the_way, inventory, remove_owned
from evpose.core.data.owned_log import OwnedLog
from evpose.core.data.temp_files import clean_temp_files
from evpose.core.data.trajectory import REASON_AFTER, REASON_BEFORE
from evpose.core.document.corrections import Corrections
from evpose.core.errors import InputError
from evpose.core.label.annotate import (
    Annotator,
    Request,
    Window,
    count_windows,
    time_windows,
)

__all__ = [
    "EXPORT_LAYOUT_VERSION", "FORMATS", "STATE_DIR", "MANIFEST_NAME", "ExportError", "ExportSummary",
    "FormatWriter", "WindowTask", "evpose_version", "build_windows", "verified_mask", "review_usage", "export_fingerprint",
    "encode_png", "savemat_bytes", "run_export",
]

EXPORT_LAYOUT_VERSION = 1
FORMATS = ("epose", "bop", "h5")
STATE_DIR = ".evpose"
CONFIG_NAME = "config.json"
JOURNAL_NAME = "journal.jsonl"
MANIFEST_NAME = "export_manifest.json"
README_NAME = "README.txt"
UNLABELED_BEFORE = REASON_BEFORE     # "label time outside the trajectory: pose time before its first pose ..."
UNLABELED_AFTER = REASON_AFTER       # holes: evpose.core.data.trajectory.hole_reason, "label time in a trajectory hole [a, b] us ..."
UNLABELED_OTHER = "label time outside the trajectory (no extrapolation)"
#: Stages of the per-window time split (seconds summed over windows, all processes).
STAGES = ("events", "annotate", "images", "mat", "write")


class ExportError(InputError):
    """A user-facing export error; the message names the file or the option at fault."""


def evpose_version() -> str:
    try:
        from importlib.metadata import version

        return version("evpose")
    except Exception:  # pragma: no cover - not installed
        return "unknown"


# ------------------------------------------------------------------------------------------- summary
@dataclass
class ExportSummary:
    """What an export did.

    Attributes
    ----------
    windows_total : int
        Windows of the tiling (before any filter).
    selected : int
        Windows left after ``only_verified``.
    written : int
        Windows whose outputs this run wrote.
    skipped_complete : int
        Windows already complete from an earlier run with the same configuration.
    unlabeled : int
        Selected windows without labels (label time outside the trajectory).
    unlabeled_windows : list of dict
        ``{"index", "t_label_us", "reason"}`` per unlabeled window.
    unlabeled_reasons : dict
        reason -> number of windows.
    filtered_unverified : int
        Windows left out by ``only_verified``.
    review_marked : int
        ``only_verified``: windows that a verified review mark overlaps (for an exported object).
    review_unused : int
        Of those, windows not exported (not selected, or selected without a label).
    review_unused_reasons : dict
        reason -> number of those windows (:data:`REVIEW_PARTLY`, :data:`REVIEW_MIXED`,
        :data:`REVIEW_STALE`, :data:`REVIEW_NO_LABEL`).
    include_stale : bool
        ``only_verified``: stale verified marks counted as verified.
    runtime_s : float
    out_dir : str
    files : list of str
        Every file of the export, relative to ``out_dir`` (including those written by an earlier run).
    timings_s : dict
        Seconds per stage (``events``, ``annotate``, ``images``, ``mat``, ``write``) summed over the
        windows processed in this run, over all processes.
    """

    format: str = ""
    windows_total: int = 0
    selected: int = 0
    written: int = 0
    skipped_complete: int = 0
    unlabeled: int = 0
    unlabeled_windows: list = field(default_factory=list)
    unlabeled_reasons: dict = field(default_factory=dict)
    filtered_unverified: int = 0
    review_marked: int = 0
    review_unused: int = 0
    review_unused_reasons: dict = field(default_factory=dict)
    include_stale: bool = False
    runtime_s: float = 0.0
    out_dir: str = ""
    files: list = field(default_factory=list)
    timings_s: dict = field(default_factory=dict)
    jobs: int = 1
    config_sha256: str = ""
    #: jobs > 1: seconds from creating the process pool until its first chunk of results came back,
    #: minus that chunk's processing time (spawn, imports, opening the scene in each worker).
    pool_startup_s: float = 0.0

    def to_json(self, *, with_files: bool = True) -> dict:
        d = asdict(self)
        if not with_files:
            d.pop("files")
            d["n_files"] = len(self.files)
        return d


# ------------------------------------------------------------------------------------------- windows
def build_windows(store, *, window_us=10_000, window_events=None, label_at="center") -> list[Window]:
    """The tiling of the recording: by time (``window_us``) or by count (``window_events``)."""
    if label_at not in ("center", "end"):
        raise ExportError(f"label_at: expected 'center' or 'end', got {label_at!r}")
    if window_events is not None:
        if isinstance(window_events, bool) or int(window_events) != window_events or window_events <= 0:
            raise ExportError(f"window_events: must be a positive integer, got {window_events!r}")
        return count_windows(store, int(window_events), label_at=label_at)
    if window_us is None or isinstance(window_us, bool) or int(window_us) != window_us or window_us <= 0:
        raise ExportError(f"window_us: must be a positive integer number of microseconds, got {window_us!r}")
    return time_windows(store, int(window_us), label_at=label_at)


#: Why a window touched by a verified mark is not exported (summary ``review_unused_reasons``).
REVIEW_PARTLY = "partly covered: the verified marks do not cover the whole window (marks off this export's window grid)"
REVIEW_MIXED = "partly rejected or flagged"
REVIEW_STALE = "stale: verified before a later change of the clock or of the object's pose"
REVIEW_NO_LABEL = "no label: label time outside the trajectory"
#: Piece categories of :func:`_status_pieces`.
_NONE, _FRESH, _STALE, _OTHER = 0, 1, 2, 3


def _status_pieces(reviews, obj: str, is_stale=None) -> tuple[np.ndarray, np.ndarray]:
    """Piecewise-constant effective review status of one object: breakpoints (sorted int64) and a
    category per piece ``[b[j], b[j+1])``: none, verified, verified but stale (``is_stale(mark, obj)``),
    rejected/flagged. The effective mark is the object's own mark, else the all-objects mark (the rule
    of :func:`evpose.core.document.review.effective_status`; later marks win within a scope)."""
    marks = [m for m in reviews if m.object is None or m.object == obj]
    if not marks:
        return np.zeros(0, np.int64), np.zeros(0, np.int8)
    b = np.unique(np.array([v for m in marks for v in (m.t0_us, m.t1_us)], np.int64))
    cat = np.zeros(max(len(b) - 1, 0), np.int8)
    winner = [None] * len(cat)
    rank = [-1] * len(cat)
    for order, m in enumerate(marks):          # later in the list wins within a scope
        own = 1 if m.object is not None else 0
        j0, j1 = np.searchsorted(b, m.t0_us), np.searchsorted(b, m.t1_us)
        for j in range(j0, j1):
            r = own * (len(marks) + 1) + order
            if r > rank[j]:
                rank[j], winner[j] = r, m
    for j, m in enumerate(winner):
        if m is None:
            continue
        if m.status != "verified":
            cat[j] = _OTHER
        else:
            cat[j] = _STALE if (is_stale is not None and is_stale(m, obj)) else _FRESH
    return b, cat


def review_usage(windows, reviews, objects, is_stale=None) -> tuple[np.ndarray, np.ndarray, list]:
    """Which windows ``--only-verified`` exports, and why windows touched by verified marks are not.

    A window ``[t0, t1)`` is exported iff, for every exported object and at every instant of
    ``[t0, t1)``, the effective review status (:func:`evpose.core.document.review.effective_status`) is ``verified``
    by a mark that is not stale (``is_stale(mark, obj)``; None: no mark is stale). **Partly covered
    windows are never exported**: a window must be covered entirely by verified marks, and a
    rejected or flagged mark over any part of it excludes it. Empty windows (``t1 <= t0``) are never
    exported.

    Returns
    -------
    keep : (N,) bool
    touched : (N,) bool
        Windows that a verified mark (fresh or stale) overlaps for some exported object.
    reasons : list of str or None
        For each window touched but not kept: :data:`REVIEW_MIXED`, :data:`REVIEW_PARTLY` or
        :data:`REVIEW_STALE` (the first that applies); None otherwise.
    """
    n = len(windows)
    t0 = np.array([w.t0_us for w in windows], np.int64)
    t1 = np.array([w.t1_us for w in windows], np.int64)
    nonempty = t1 > t0
    any_none = np.zeros(n, bool)
    any_other = np.zeros(n, bool)
    any_stale = np.zeros(n, bool)
    touched = np.zeros(n, bool)
    if not objects:
        any_none[:] = True
    for obj in objects:
        b, cat = _status_pieces(reviews, obj, is_stale)
        if len(b) < 2:
            any_none[:] = True
            continue
        # first / last piece that the window touches: piece j spans [b[j], b[j+1])
        j0 = np.clip(np.searchsorted(b, t0, side="right") - 1, 0, len(cat) - 1)
        j1 = np.clip(np.searchsorted(b, t1 - 1, side="right") - 1, 0, len(cat) - 1)
        outside = (t0 < b[0]) | (t1 - 1 >= b[-1])
        counts = {}
        for c in (_NONE, _FRESH, _STALE, _OTHER):
            pre = np.concatenate([[0], np.cumsum(cat == c)])
            counts[c] = pre[j1 + 1] - pre[j0]
        meets = (t1 > b[0]) & (t0 < b[-1]) & nonempty     # overlaps the span of the breakpoints at all
        any_none |= outside | (counts[_NONE] > 0)
        any_other |= meets & (counts[_OTHER] > 0)
        any_stale |= meets & (counts[_STALE] > 0)
        touched |= meets & ((counts[_FRESH] > 0) | (counts[_STALE] > 0))
    keep = nonempty & ~any_none & ~any_other & ~any_stale
    reasons = [None] * n
    for i in np.flatnonzero(touched & ~keep):
        reasons[i] = REVIEW_MIXED if any_other[i] else REVIEW_PARTLY if any_none[i] else REVIEW_STALE
    return keep, touched, reasons


def verified_mask(windows, reviews, objects, is_stale=None) -> np.ndarray:
    """Which windows ``--only-verified`` exports (the ``keep`` of :func:`review_usage`)."""
    return review_usage(windows, reviews, objects, is_stale)[0]


def scene_staleness(scene):
    """``is_stale(mark, obj)`` for :func:`review_usage`: the mark was made under another clock or
    another pose of ``obj`` than ``scene`` has now (:func:`evpose.core.document.review.stale_reasons`)."""
    from evpose.core.document.review import mark_state, stale_reasons

    now = mark_state(scene)
    return lambda mark, obj: bool(stale_reasons(scene, mark, obj, now=now))


# ------------------------------------------------------------------------------------------- fingerprint
def _file_digest(path) -> dict:
    path = Path(path)
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return {"file": path.name, "size": path.stat().st_size, "sha256": h.hexdigest()}


def _T_list(T) -> list:
    return [[float(v) for v in row] for row in np.asarray(T, np.float64)]


def export_fingerprint(scene, names, *, fmt, format_options, window_us, window_events, label_at,
                       only_verified, margin_m, include_stale=False) -> dict:
    """Everything the exported bytes depend on (JSON-able). Two runs with equal fingerprints write
    identical files, so a rerun may resume; anything else must not be mixed into one folder."""
    m = scene.manifest
    clock = scene.clock
    ev = scene.events
    objects = []
    for n in names:
        spec = m.object(n)
        objects.append({"name": n, "class_id": int(spec.class_id), "T_base_obj": _T_list(scene.T_base_obj(n)),
                        "mesh": _file_digest(spec.mesh), "mesh_scale": float(spec.mesh_scale)})
    occluders = [{"name": n, "T_base_obj": _T_list(scene.T_base_obj(n)), "mesh": _file_digest(m.object(n).mesh)}
                 for n in scene.object_names if n not in names]
    doc = {
        "layout": EXPORT_LAYOUT_VERSION,
        "format": fmt,
        "format_options": format_options,
        "windows": {"window_us": None if window_events is not None else int(window_us),
                    "window_events": None if window_events is None else int(window_events),
                    "label_at": label_at},
        "only_verified": bool(only_verified),
        "reviews": [r.to_json() for r in scene.corrections.reviews] if only_verified else None,
        "margin_m": float(margin_m),
        "scene": scene.name,
        "camera": m.camera.to_dict(),
        "events": {"file": Path(m.events_path).name, "size": Path(m.events_path).stat().st_size,
                   "n_events": int(ev.n_events), "t_first_us": ev.t_first_us, "t_last_us": ev.t_last_us},
        "trajectory": {**_file_digest(m.trajectory_path), "frame": m.trajectory_frame,
                       "hand_eye": None if m.hand_eye is None else _T_list(m.hand_eye),
                       "hand_eye_delta": _T_list(scene.corrections.hand_eye_delta),
                       # an explicit max gap changes the holes; the default follows from the file digest
                       **({} if getattr(m, "trajectory_max_gap_us", None) is None
                          else {"max_gap_us": int(m.trajectory_max_gap_us)})},
        "clock": {"offset_us": int(clock.offset_us), "skew_ppm": float(clock.skew_ppm), "t_ref_us": int(clock.t_ref_us)},
        "objects": objects,
        "occluders": occluders,
    }
    if only_verified and include_stale:
        doc["include_stale"] = True       # absent otherwise: fingerprints of earlier exports stay valid
    return doc


def fingerprint_sha(doc: dict) -> str:
    return hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()


# ------------------------------------------------------------------------------------------- files
def durability_mode(durable) -> str:
    """``True``/"batch" -> "batch", "file" -> "file", ``False``/"none" -> "none"."""
    if durable is True or durable == "batch":
        return "batch"
    if durable == "file":
        return "file"
    if durable is False or durable == "none" or durable is None:
        return "none"
    raise ExportError(f"durable: expected True, False, 'batch', 'file' or 'none', got {durable!r}")


def json_text(obj, indent=1) -> str:
    return json.dumps(obj, indent=indent) + "\n"


def encode_png(img: np.ndarray, *, bilevel: bool = False, compression: int = 1) -> bytes:
    """PNG bytes of a uint8/uint16 image (``(H, W)`` gray or ``(H, W, 3)`` **BGR**, OpenCV order).

    ``bilevel`` writes a 1-bit PNG (any non-zero pixel is 1; OpenCV reads it back as 0/255, PIL and
    MATLAB as a logical image). Otherwise zlib level ``compression`` with the run-length strategy and no
    row filter. Measured on DAVIS346 event frames (16 k events, CPU time): RGB 0.8 ms / 18 kB against
    1.6 ms / 32 kB (level 1, "sub" filter) and 2.6 ms / 24 kB (level 1, adaptive filters); gray
    0.3 ms / 5 kB against 0.8 ms / 9 kB (level 1, adaptive). Sparse event images are mostly runs.
    """
    import cv2

    if bilevel:
        params = [cv2.IMWRITE_PNG_BILEVEL, 1]
    else:
        params = [cv2.IMWRITE_PNG_COMPRESSION, int(compression), cv2.IMWRITE_PNG_STRATEGY,
                  cv2.IMWRITE_PNG_STRATEGY_RLE, cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_NONE]
    ok, buf = cv2.imencode(".png", img, params)
    if not ok:  # pragma: no cover
        raise RuntimeError("PNG encoding failed")
    return buf.tobytes()


_MAT_DESCRIPTION = "MATLAB 5.0 MAT-file, Platform: evpose export"


def savemat_bytes(fields: dict) -> bytes:
    """``scipy.io.savemat`` (MATLAB 5, uncompressed, 1-D arrays as rows) into bytes, with a fixed
    header text instead of scipy's creation date, so equal inputs give byte-identical files."""
    from scipy.io import savemat

    bio = io.BytesIO()
    savemat(bio, fields, oned_as="row", do_compression=False)
    data = bytearray(bio.getvalue())
    desc = _MAT_DESCRIPTION.encode("latin1")[:116].ljust(116, b" ")
    data[:116] = desc
    return bytes(data)


# ------------------------------------------------------------------------------------------- journal
class Journal:
    """Append-only JSON-lines record of the windows whose outputs are complete (parent process only).
    A line is valid JSON or it is ignored (a crash or a full disk may cut the last line; the next
    append starts on a fresh line).

    :meth:`append` only buffers in memory: nothing reaches the file before :meth:`sync`, which the
    caller runs after making the files the lines name durable (``syncfs``), then writes the lines
    and fsyncs them. So a journaled window is on disk even when the journal is written before its
    files could be (a buffered file object would write its buffer whenever it fills).
    """

    def __init__(self, path: Path, durable: bool = True):
        self.path = Path(path)
        self.durable = durable
        self._fd: int | None = None
        self._buf = bytearray()
        self._since_sync = 0

    def load(self) -> dict[int, dict]:
        out = {}
        if not self.path.exists():
            return out
        with open(self.path, "rb") as f:
            for line in f:
                try:
                    rec = json.loads(line)
                    out[int(rec["i"])] = rec
                except (ValueError, KeyError, TypeError):
                    continue
        return out

    def append(self, rec: dict) -> None:
        self._buf += json.dumps(rec, separators=(",", ":")).encode()
        self._buf += b"\n"
        self._since_sync += 1

    def _open(self) -> int:
        fd = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o666)
        size = os.fstat(fd).st_size
        if size > 0:
            with open(self.path, "rb") as r:
                r.seek(size - 1)
                if r.read(1) != b"\n":      # a cut last line: start on a fresh one
                    self._buf[:0] = b"\n"
        return fd

    def sync(self) -> None:
        """Write the buffered lines and fsync them (``durable``). On an error the lines are dropped
        (their windows are redone by the next run) and the error names the journal."""
        if not self._since_sync:
            return
        try:
            if self._fd is None:
                self._fd = self._open()
            view = memoryview(bytes(self._buf))
            self._buf.clear()
            self._since_sync = 0
            while view:
                view = view[os.write(self._fd, view):]
            if self.durable:
                os.fsync(self._fd)
        except OSError as exc:
            self._buf.clear()
            self._since_sync = 0
            self._close_fd()
            raise with_path(exc, self.path) from None

    def _close_fd(self) -> None:
        if self._fd is not None:
            with contextlib.suppress(OSError):
                os.close(self._fd)
            self._fd = None

    def close(self) -> None:
        try:
            self.sync()
        finally:
            self._buf.clear()
            self._since_sync = 0
            self._close_fd()


# ------------------------------------------------------------------------------------------- writers
@dataclass
class WindowTask:
    """One window handed to a worker, with its pose interpolated by the parent."""

    window: Window
    T_cam_obj: np.ndarray      # (K_all, 4, 4)
    T_base_cam: np.ndarray     # (4, 4)
    valid: bool
    row: int = -1              # position among the selected windows (HDF5 row)


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

    def accept(self, ctx: "ExportContext", record: dict, payload) -> None:
        ctx.journal.append(record)

    def flush(self, ctx: "ExportContext") -> None:
        """Make the accepted windows durable, then their journal lines ("batch" mode: one ``syncfs``
        covers every file the workers wrote, whatever process wrote it)."""
        if ctx.journal._since_sync:
            if ctx.durable == "batch":
                t = time.perf_counter()
                sync_filesystem(ctx.out_dir)
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

    # -- worker
    def setup_worker(self, wctx: "WorkerContext") -> dict:
        return {}

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
    durable: str = "batch"       # durability mode, see durability_mode()
    extra: dict = field(default_factory=dict)
    #: the parent's record of the files it writes (evpose.core.data.owned_files); workers keep their own
    owned: OwnedLog | None = None

    @property
    def fsync(self) -> bool:
        """fsync the (few) aggregate files the parent writes."""
        return self.durable != "none"


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
        # all objects are rasterised (objects that are not exported still occlude the exported ones)
        self.annotator = Annotator(scene, spec.request, camera=self.camera, objects=scene.object_names)
        self.timings = dict.fromkeys(STAGES, 0.0)
        #: fsync each file before its rename ("file" mode); "batch" syncs the filesystem per chunk
        self.fsync_files = spec.durable == "file"
        #: every file this process writes is logged here before it appears (evpose.core.data.owned_files)
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

    def take_timings(self) -> dict:
        t = self.timings
        self.timings = dict.fromkeys(STAGES, 0.0)
        return t


# ------------------------------------------------------------------------------------------- pool
_WORKER: WorkerContext | None = None


def _worker_init(spec: WorkerSpec) -> None:
    global _WORKER
    signal.signal(signal.SIGINT, signal.SIG_IGN)    # the parent handles Ctrl-C and terminates the pool
    import cv2

    cv2.setNumThreads(1)     # one process per core already: OpenCV's own threads would only compete
    _WORKER = WorkerContext(spec)


def _worker_run(tasks: list) -> tuple[list, dict]:
    out = [_WORKER.run(t) for t in tasks]
    return out, _WORKER.take_timings()


# ------------------------------------------------------------------------------------------- runner
EXPORT_ROLE = "export"
#: Files of ``.evpose`` that belong to an export besides the ownership logs.
EXPORT_STATE_FILES = (CONFIG_NAME, JOURNAL_NAME)


def scene_inputs(scene) -> list[Path]:
    """Every file an export reads: scene.toml, events (a link and its target), trajectory, meshes,
    corrections.json. An output folder that holds one of them is never cleared."""
    m = scene.manifest
    out = [Path(m.path), Path(m.events_path), Path(m.trajectory_path)]
    out += [Path(o.mesh) for o in m.objects]
    cp = getattr(scene, "corrections_path", None)
    if cp is not None:
        out.append(Path(cp))
    return out


def _read_config(cfg: Path) -> dict | None:
    """The earlier export's ``config.json``: None when absent, ``{}`` when unreadable."""
    if not cfg.is_file():
        return None
    try:
        old = json.loads(cfg.read_text())
    except (OSError, ValueError):
        return {}
    return old if isinstance(old, dict) else {}


def _has_results(out_dir: Path) -> bool:
    """Whether an earlier export left anything worth keeping: a journaled window or a finished export."""
    return (out_dir / MANIFEST_NAME).exists() or bool(Journal(out_dir / STATE_DIR / JOURNAL_NAME).load())


def _prepare_out_dir(out_dir: Path, sha: str, doc: dict, force: bool, inputs=()) -> None:
    """Make ``out_dir`` ready for an export with fingerprint ``sha`` (the caller holds its lock).

    * empty or new: used;
    * an earlier export with the same fingerprint: resumed (nothing removed);
    * otherwise every entry is sorted by :func:`evpose.core.data.owned_files.inventory`: anything evpose did not
      write (or that changed since) is never removed and refuses the run, naming it; a folder holding
      an input of this export (the scene) is refused; an earlier export with results (journaled
      windows or a finished export) is replaced only with ``force``; one without results -- a failed
      run, or only ``.evpose`` state -- is replaced without ``force``. Only evpose's own files are
      removed.
    """
    state = out_dir / STATE_DIR
    cfg = state / CONFIG_NAME
    if out_dir.exists() and not out_dir.is_dir():
        raise ExportError(f"{out_dir}: --out: exists and is not a folder")
    entries = list(out_dir.iterdir()) if out_dir.is_dir() else []
    if entries:
        inp = held_input(out_dir, inputs)
        if inp is not None:
            raise ExportError(f"{out_dir}: --out: holds {inp}, an input of this export; evpose never clears a "
                              "folder that holds an input: choose another folder")
        old = _read_config(cfg)
        if old is None or old.get("sha256") != sha:
            inv = inventory(out_dir, EXPORT_ROLE, state_files=EXPORT_STATE_FILES, temps="all")
            if old is None and not inv.clean:
                raise ExportError(f"{out_dir}: --out: the folder is not empty and holds no evpose export "
                                  f"({inv.describe_foreign()}); choose an empty or new folder "
                                  "(--force only replaces an earlier evpose export)")
            if old is not None and not force and _has_results(out_dir):
                diff = _describe_difference(old.get("fingerprint", {}), doc)
                note = "" if inv.clean else f" (--force would still keep {inv.describe_foreign()}, not evpose's)"
                raise ExportError(f"{out_dir}: --out: holds an export with a different configuration "
                                  f"({diff}); use --force to replace it, or another folder{note}")
            if not inv.clean:
                raise ExportError(f"{out_dir}: --out: {in_the_way(inv)}")
            remove_owned(inv)
    out_dir.mkdir(parents=True, exist_ok=True)
    state.mkdir(exist_ok=True)
    old = _read_config(cfg)
    if old is None or old.get("sha256") != sha:
        write_atomic(cfg, json_text({"sha256": sha, "fingerprint": doc}).encode())


def _describe_difference(old: dict, new: dict, prefix: str = "") -> str:
    """The first few keys whose values differ (for the refusal message)."""
    diffs = []
    for k in sorted(set(old) | set(new)):
        a, b = old.get(k), new.get(k)
        if a == b:
            continue
        if isinstance(a, dict) and isinstance(b, dict):
            sub = _describe_difference(a, b, f"{prefix}{k}.")
            diffs.append(sub)
        else:
            diffs.append(f"{prefix}{k}")
    return ", ".join(d for d in diffs if d)[:300] or "unknown"


def _unlabeled_reason(scene, t_label_us: int) -> str:
    """Why a window has no label: its label time maps before or after the trajectory, or into a hole
    of it (``in a trajectory hole [a, b] us``; see :meth:`evpose.core.data.scene.Scene.unlabeled_reasons`)."""
    reasons = getattr(scene, "unlabeled_reasons", None)
    r = reasons(np.array([t_label_us], np.int64))[0] if reasons is not None else None
    return r or UNLABELED_OTHER


def _chunks(seq: list, size: int) -> list[list]:
    return [seq[i:i + size] for i in range(0, len(seq), size)]


def run_export(scene, writer: FormatWriter, out_dir, *, window_us=10_000, window_events=None, label_at="center",
               only_verified=False, objects=None, margin_m=0.0, jobs=1, force=False, durable=True,
               include_stale=False, progress: Callable[[float, str], None] | None = None,
               cancel: Callable[[], bool] | None = None) -> ExportSummary:
    """Run one export (see :func:`evpose.core.export.export_scene` for the parameters)."""
    t_start = time.perf_counter()
    out_dir = Path(out_dir)
    durable = durability_mode(durable)
    scene.events                          # opened once and shared with the snapshot (closed by its owner)
    scene = _snapshot_scene(scene)        # frozen corrections: the GUI may go on editing meanwhile
    names = list(scene.object_names) if objects is None else list(objects)
    for n in names:
        if n not in scene.object_names:
            raise ExportError(f"objects: no object named {n!r} in {scene.manifest.path} "
                              f"(objects: {', '.join(scene.object_names)})")
    if not names:
        raise ExportError("objects: at least one object must be exported")
    names = [n for n in scene.object_names if n in names]           # scene order
    sel = np.array([scene.object_names.index(n) for n in names], np.intp)
    if not (isinstance(margin_m, (int, float)) and math.isfinite(margin_m) and margin_m >= 0):
        raise ExportError(f"margin: must be a finite number >= 0 (metres), got {margin_m!r}")
    if isinstance(jobs, bool) or int(jobs) != jobs or jobs < 1:
        raise ExportError(f"jobs: must be a positive integer, got {jobs!r}")
    jobs = int(jobs)
    if window_events is not None and window_us is not None and window_us != 10_000:
        raise ExportError("window: give either window_us or window_events, not both")

    windows = build_windows(scene.events, window_us=window_us, window_events=window_events, label_at=label_at)
    if out_dir.exists() and not out_dir.is_dir():
        raise ExportError(f"{out_dir}: --out: exists and is not a folder")
    out_dir.mkdir(parents=True, exist_ok=True)
    lock = _lock_folder(out_dir)
    try:
        return _run_locked(scene, writer, out_dir, windows, names, sel, window_us=window_us,
                           window_events=window_events, label_at=label_at, only_verified=only_verified,
                           include_stale=include_stale, margin_m=margin_m, jobs=jobs, force=force, durable=durable,
                           progress=progress, cancel=cancel, t_start=t_start)
    finally:
        os.close(lock)


def _lock_folder(out_dir: Path) -> int:
    """An exclusive ``flock`` on the output folder for the whole run: a second export into the same
    folder (another process or thread) is refused instead of mixing files or deleting live temp files."""
    fd = os.open(out_dir, os.O_RDONLY)
    try:
        import fcntl

        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except ImportError:  # pragma: no cover - not POSIX
        pass
    except OSError:
        os.close(fd)
        raise ExportError(f"{out_dir}: --out: another export is writing into this folder") from None
    return fd


def _run_locked(scene, writer, out_dir, windows, names, sel, *, window_us, window_events, label_at, only_verified,
                margin_m, jobs, force, durable, progress, cancel, t_start, include_stale=False) -> ExportSummary:
    doc = export_fingerprint(scene, names, fmt=writer.fmt, format_options=writer.options(), window_us=window_us,
                             window_events=window_events, label_at=label_at, only_verified=only_verified,
                             margin_m=float(margin_m), include_stale=include_stale)
    sha = fingerprint_sha(doc)
    _prepare_out_dir(out_dir, sha, doc, force, scene_inputs(scene))
    clean_temp_files(out_dir)

    n_digits = max(4, len(str(max(len(windows) - 1, 0))))
    journal = Journal(out_dir / STATE_DIR / JOURNAL_NAME, durable != "none")
    ctx = ExportContext(scene, writer, out_dir, names, sel, windows, doc, sha, float(margin_m), label_at,
                        journal, n_digits, durable)
    ctx.owned = OwnedLog(out_dir, EXPORT_ROLE, f"export {writer.fmt}")

    # selection and poses (one vectorised interpolation for all windows)
    if only_verified:
        keep, touched, review_reasons = review_usage(windows, scene.corrections.reviews, names,
                                                     None if include_stale else scene_staleness(scene))
    else:
        keep, touched, review_reasons = np.ones(len(windows), bool), np.zeros(len(windows), bool), []
    selected = [w for w, k in zip(windows, keep) if k]
    request = writer.request(float(margin_m))
    pose_ann = Annotator(scene, Request(keypoints=False, masks_visible=False), objects=scene.object_names)
    t_lab = np.array([w.t_label_us for w in selected], np.int64)
    if len(selected):
        T_co, T_bc, valid = pose_ann.poses(t_lab)
    else:
        T_co, T_bc, valid = np.zeros((0, len(scene.object_names), 4, 4)), np.zeros((0, 4, 4)), np.zeros(0, bool)
    ctx.extra["selected"] = selected
    ctx.extra["valid"] = valid
    ctx.extra["row_of"] = {w.index: r for r, w in enumerate(selected)}

    summary = ExportSummary(format=writer.fmt, windows_total=len(windows), selected=len(selected),
                            filtered_unverified=len(windows) - len(selected), out_dir=str(out_dir), jobs=jobs,
                            config_sha256=sha, timings_s=dict.fromkeys(STAGES, 0.0))
    unlabeled = []
    for w, v in zip(selected, valid):
        if not v:
            unlabeled.append({"index": w.index, "t_label_us": w.t_label_us, "reason": _unlabeled_reason(scene, w.t_label_us)})
    summary.unlabeled = len(unlabeled)
    summary.unlabeled_windows = unlabeled
    for u in unlabeled:
        summary.unlabeled_reasons[u["reason"]] = summary.unlabeled_reasons.get(u["reason"], 0) + 1
    if only_verified:
        _count_review_usage(summary, windows, touched, review_reasons, {u["index"] for u in unlabeled}, include_stale)

    try:
        writer.begin(ctx)
        done = writer.completed(ctx)
        tasks = []
        for r, (w, v) in enumerate(zip(selected, valid)):
            if w.index in done:
                continue
            if not v and not writer.process_unlabeled:
                continue
            tasks.append(WindowTask(w, T_co[r], T_bc[r], bool(v), r))
        n_labeled = int(valid.sum())
        summary.skipped_complete = sum(1 for w, v in zip(selected, valid) if w.index in done and (v or writer.process_unlabeled))
        records = {i: r for i, r in done.items()}
        total = max(len(selected), 1)
        base = len(selected) - len(tasks)

        def report(n_done):
            if progress is not None:
                progress((base + n_done) / total,
                         f"{summary.written} written, {summary.skipped_complete} complete, {summary.unlabeled} unlabeled")

        report(0)
        if cancel is not None and cancel():
            raise Cancelled(f"{out_dir}: export cancelled")
        spec = WorkerSpec(scene.manifest, scene.corrections.to_json(), writer, str(out_dir), names, sel.tolist(),
                          request, n_digits, durable)
        if jobs == 1 or len(tasks) <= 1:
            _run_serial(ctx, spec, tasks, records, summary, report, cancel)
        else:
            _run_pool(ctx, spec, tasks, records, summary, report, cancel, jobs)
        writer.flush(ctx)
        journal.close()
        files, patterns = writer.finish(ctx, records)
        summary.timings_s["write"] += ctx.extra.get("parent_write_s", 0.0)
        summary.files = sorted(set(files) | {MANIFEST_NAME, README_NAME})
        ctx.extra["window_file_patterns"] = patterns
        n_top = len(files) - ctx.extra.get("n_window_files", 0)
        ctx.extra["top_files"] = sorted(set(files[:n_top]) | {MANIFEST_NAME, README_NAME})
        summary.runtime_s = time.perf_counter() - t_start
        _write_manifest(ctx, summary, records, selected, valid, unlabeled, n_labeled)
        ctx.owned.close()
        if progress is not None:
            progress(1.0, f"{summary.written} written, {summary.skipped_complete} complete, {summary.unlabeled} unlabeled")
    except BaseException:
        with contextlib.suppress(Exception):
            writer.flush(ctx)
        with contextlib.suppress(Exception):
            journal.close()
        with contextlib.suppress(Exception):
            writer.abort(ctx)
        ctx.owned.close()
        clean_temp_files(out_dir)
        raise
    return summary


def _count_review_usage(summary, windows, touched, reasons, unlabeled_idx, include_stale) -> None:
    """Count the windows verified marks touch and why those not exported were left out."""
    summary.include_stale = bool(include_stale)
    summary.review_marked = int(np.count_nonzero(touched))
    out: dict = {}
    for i in np.flatnonzero(touched):
        why = reasons[i] if reasons[i] is not None else (REVIEW_NO_LABEL if windows[i].index in unlabeled_idx else None)
        if why is not None:
            out[why] = out.get(why, 0) + 1
    summary.review_unused = sum(out.values())
    summary.review_unused_reasons = out


def _run_serial(ctx, spec, tasks, records, summary, report, cancel) -> None:
    if not tasks:
        return
    wctx = WorkerContext(spec, scene=ctx.scene, owned=ctx.owned)
    for k, task in enumerate(tasks):
        rec, payload = wctx.run(task)
        ctx.writer.accept(ctx, rec, payload)
        records[task.window.index] = rec
        if rec.get("status") == "written":
            summary.written += 1
        _maybe_flush(ctx)
        report(k + 1)
        if cancel is not None and cancel():
            _add_timings(summary, wctx.take_timings())
            raise Cancelled(f"{ctx.out_dir}: export cancelled after {k + 1} windows")
    _add_timings(summary, wctx.take_timings())


def _snapshot_scene(scene):
    """The scene with a frozen copy of its corrections (the GUI may go on editing during the export)."""
    corr = Corrections.from_json(scene.corrections.to_json())
    if hasattr(scene, "with_corrections"):
        return scene.with_corrections(corr)
    from evpose.core.data.scene import Scene  # pragma: no cover

    return Scene(scene.manifest, corr)


def _run_pool(ctx, spec, tasks, records, summary, report, cancel, jobs) -> None:
    import multiprocessing as mp

    size = max(1, min(32, math.ceil(len(tasks) / (jobs * 8))))
    chunks = _chunks(tasks, size)
    t_pool = time.perf_counter()
    pool = mp.get_context("spawn").Pool(jobs, initializer=_worker_init, initargs=(spec,))
    ok = False
    try:
        n_done = 0
        for results, timings in pool.imap_unordered(_worker_run, chunks):
            if n_done == 0:
                summary.pool_startup_s = max(0.0, time.perf_counter() - t_pool - sum(timings.values()))
            for rec, payload in results:
                ctx.writer.accept(ctx, rec, payload)
                records[rec["i"]] = rec
                if rec.get("status") == "written":
                    summary.written += 1
            n_done += len(results)
            _add_timings(summary, timings)
            _maybe_flush(ctx, len(results))
            report(n_done)
            if cancel is not None and cancel():
                raise Cancelled(f"{ctx.out_dir}: export cancelled after {n_done} windows")
        ok = True
    finally:
        if ok:
            pool.close()
        else:
            pool.terminate()     # workers may be mid-write: their temp files are removed by the caller
        pool.join()


#: The parent makes accepted windows durable (syncfs + journal fsync, or HDF5 flush + fsync) after this
#: many windows or seconds, whichever comes first: a crash redoes at most that much work, and syncfs,
#: which flushes the whole filesystem (other programs' writes too), stays off the per-window cost.
FLUSH_WINDOWS = 64
FLUSH_SECONDS = 5.0


def _maybe_flush(ctx, n_new: int = 1) -> None:
    n = ctx.extra.get("unflushed", 0) + n_new
    last = ctx.extra.setdefault("last_flush", time.perf_counter())
    if n >= FLUSH_WINDOWS or time.perf_counter() - last >= FLUSH_SECONDS:
        ctx.writer.flush(ctx)
        n = 0
        ctx.extra["last_flush"] = time.perf_counter()
    ctx.extra["unflushed"] = n


def _add_timings(summary, t: dict) -> None:
    for k, v in t.items():
        summary.timings_s[k] = summary.timings_s.get(k, 0.0) + v


def _write_manifest(ctx, summary, records, selected, valid, unlabeled, n_labeled) -> None:
    scene = ctx.scene
    m = scene.manifest
    clock = scene.clock
    corr = scene.corrections
    status = {}
    for w, v in zip(selected, valid):
        status[w.index] = "written" if (w.index in records and v) else ("unlabeled" if not v else "missing")
    win = {"index": [], "t0_us": [], "t1_us": [], "t_label_us": [], "i0": [], "i1": [], "status": []}
    for w in ctx.windows:
        win["index"].append(w.index)
        win["t0_us"].append(w.t0_us)
        win["t1_us"].append(w.t1_us)
        win["t_label_us"].append(w.t_label_us)
        win["i0"].append(w.i0)
        win["i1"].append(w.i1)
        win["status"].append(status.get(w.index, "filtered_unverified"))
    objs = []
    for k, n in zip(ctx.sel, ctx.names):
        spec = m.object(n)
        objs.append({"name": n, "class_id": int(spec.class_id), "index": int(k),
                     "T_base_obj_manifest": _T_list(spec.T_base_obj),
                     "dT_base": _T_list(corr.object_delta(n)),
                     "T_base_obj": _T_list(scene.T_base_obj(n)),
                     **ctx.extra.get("object_extra", {}).get(n, {})})
    fp = ctx.fingerprint
    doc = {
        "format": ctx.writer.fmt,
        "evpose_version": evpose_version(),
        "layout": EXPORT_LAYOUT_VERSION,
        "config_sha256": ctx.sha,
        "scene": {"name": scene.name, "path": str(Path(m.path).resolve())},
        "windows_config": fp["windows"],
        "only_verified": fp["only_verified"],
        "margin_m": ctx.margin_m,
        "format_options": fp["format_options"],
        "clock": {"offset_us": int(clock.offset_us), "skew_ppm": float(clock.skew_ppm), "t_ref_us": int(clock.t_ref_us),
                  "prior_offset_us": int(m.clock_offset_us), "prior_skew_ppm": float(m.clock_skew_ppm),
                  "correction_offset_us": int(corr.offset_us), "correction_skew_ppm": float(corr.skew_ppm),
                  "model": "t_pose_us = t_event_us + offset_us + skew_ppm * 1e-6 * (t_event_us - t_ref_us)"},
        "hand_eye": {"trajectory_frame": m.trajectory_frame,
                     "hand_eye": None if m.hand_eye is None else _T_list(m.hand_eye),
                     "dT_cam": _T_list(corr.hand_eye_delta)},
        "camera": m.camera.to_dict(),
        "objects": objs,
        "occluders_not_exported": [n for n in scene.object_names if n not in ctx.names],
        "counts": {"windows_total": summary.windows_total, "selected": summary.selected,
                   "labeled": n_labeled, "unlabeled": summary.unlabeled,
                   "filtered_unverified": summary.filtered_unverified},
        "unlabeled": unlabeled,
        "unlabeled_reasons": summary.unlabeled_reasons,
        "windows": win,
        "files": ctx.extra["top_files"],
        "window_files": ctx.extra["window_file_patterns"],
        "extra": ctx.extra.get("manifest_extra", {}),
        "run": {"written": summary.written, "skipped_complete": summary.skipped_complete,
                "runtime_s": summary.runtime_s, "jobs": summary.jobs},
    }
    write_atomic(ctx.out_dir / MANIFEST_NAME, json_text(doc).encode(), ctx.fsync, ctx.owned)
