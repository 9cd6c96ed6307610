"""One export run, step by step: check the options, lock and prepare the output folder, select the
windows and interpolate their poses, run them (:mod:`evpose.core.export.pool`), write the aggregate
files and the manifest -- or, when anything fails or is cancelled, leave the folder resumable.

Every file is written to a temporary file beside its target and renamed into place
(:mod:`evpose.core.data.atomic`), so a reader never sees a partial file; the files of one window are
renamed in order, its last file last, and the window is journaled (:mod:`evpose.core.export.journal`)
only once its files are durable. The folder's rules (resume, refuse, replace) are those of
:mod:`evpose.core.export.out_folder`.
"""
from __future__ import annotations

import contextlib
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from evpose.core.data.events import Cancelled
from evpose.core.data.owned_log import STATE_DIR, OwnedLog
from evpose.core.data.temp_files import clean_temp_files
from evpose.core.document.corrections import Corrections
from evpose.core.export.fingerprint import export_fingerprint, fingerprint_sha
from evpose.core.export.journal import Journal
from evpose.core.export.manifest import write_manifest
from evpose.core.export.options import (
    ExportError,
    check_events_only,
    check_jobs,
    check_margin,
    durability_mode,
    export_objects,
)
from evpose.core.export.out_folder import (
    EXPORT_ROLE,
    JOURNAL_NAME,
    MANIFEST_NAME,
    README_NAME,
    lock_folder,
    prepare_out_dir,
    scene_inputs,
)
from evpose.core.export.pool import run_windows
from evpose.core.export.summary import ExportSummary, count_review_usage, set_unlabeled
from evpose.core.export.windows import build_windows, review_usage, scene_staleness, unlabeled_windows
from evpose.core.export.worker import STAGES, WorkerSpec
from evpose.core.export.writer import ExportContext, FormatWriter, WindowTask
from evpose.core.label.labels import label_poses
from evpose.core.label.windows import DEFAULT_WINDOW_US

__all__ = ["run_export"]


def run_export(scene, writer: FormatWriter, out_dir, *, window_us=DEFAULT_WINDOW_US, window_events=None, label_at="center",
               only_verified=False, objects=None, margin_m=0.0, jobs=1, force=False, durable=True,
               include_stale=False, progress: Callable[[float, str], None] | None = None,
               cancel: Callable[[], bool] | None = None, executor=None, label_sigma=None) -> ExportSummary:
    """Run one export (see :func:`evpose.core.export.export_scene` for the parameters)."""
    t_start = time.perf_counter()
    out_dir = Path(out_dir)
    durable = durability_mode(durable)
    scene.events                          # opened once and shared with the snapshot (closed by its owner)
    scene = _snapshot_scene(scene)        # frozen corrections: the GUI may go on editing meanwhile
    if check_events_only(scene, writer, objects, only_verified):
        names, sel = [], np.zeros(0, np.intp)             # events and event frames only: no pose is asked for
    else:
        names, sel = export_objects(scene, objects)
    check_margin(margin_m)
    jobs = check_jobs(jobs)
    if window_events is not None and window_us is not None and window_us != DEFAULT_WINDOW_US:
        raise ExportError("window: give either window_us or window_events, not both")

    windows = build_windows(scene.events, window_us=window_us, window_events=window_events, label_at=label_at)
    if out_dir.exists() and not out_dir.is_dir():
        raise ExportError(f"{out_dir}: --out: exists and is not a folder")
    out_dir.mkdir(parents=True, exist_ok=True)
    lock = lock_folder(out_dir)
    try:
        doc = export_fingerprint(scene, names, fmt=writer.fmt, format_options=writer.options(), window_us=window_us,
                                 window_events=window_events, label_at=label_at, only_verified=only_verified,
                                 margin_m=float(margin_m), include_stale=include_stale)
        if label_sigma is not None:
            doc["label_sigma"] = label_sigma.to_json()
            if label_sigma.auto:           # the inputs are the document's: a changed sigma is another export
                doc["label_sigma"]["stored"] = {p: v for p, v in sorted(scene.corrections.sigmas.items())}
        ctx = _open_folder(scene, writer, out_dir, windows, names, sel, doc, force=force, durable=durable,
                           margin_m=float(margin_m), label_at=label_at)
        ctx.extra["label_sigma_options"] = label_sigma
        selection = _select(ctx, only_verified, include_stale)
        summary = _new_summary(ctx, selection, jobs, only_verified, include_stale)
        try:
            records = _run(ctx, selection, summary, jobs, progress, cancel, executor)
            _finish(ctx, selection, summary, records, t_start, progress)
        except BaseException:
            _abort(ctx)
            raise
        return summary
    finally:
        os.close(lock)


def _snapshot_scene(scene):
    """The scene with a frozen copy of its corrections (the GUI may go on editing during the export)."""
    corr = Corrections.from_json(scene.corrections.to_json())
    if hasattr(scene, "with_corrections"):
        return scene.with_corrections(corr)
    from evpose.core.data.scene import Scene  # pragma: no cover

    return Scene(scene.manifest, corr)


@dataclass
class _Selection:
    """The windows an export processes, with the poses the parent interpolated at their label times."""

    windows: list                # selected windows, in tiling order
    T_cam_obj: np.ndarray        # (N, K_all, 4, 4)
    T_base_cam: np.ndarray       # (N, 4, 4)
    valid: np.ndarray            # (N,) bool: the window has a label
    touched: np.ndarray          # (windows of the tiling,) bool: a verified mark overlaps it (only_verified)
    review_reasons: list         # why each touched window is not selected (only_verified)
    sigma: np.ndarray | None = None      # (N, K exported, 3): sigma_t_mm, sigma_R_deg, sigma_px (label_sigma given)


def _open_folder(scene, writer, out_dir, windows, names, sel, doc, *, force, durable, margin_m, label_at) -> ExportContext:
    """Prepare the locked folder for the configuration ``doc`` (resume, replace or refuse), remove
    leftover temp files, and open the journal and the ownership log."""
    sha = fingerprint_sha(doc)
    prepare_out_dir(out_dir, sha, doc, force, scene_inputs(scene))
    clean_temp_files(out_dir)
    n_digits = max(4, len(str(max(len(windows) - 1, 0))))
    journal = Journal(out_dir / STATE_DIR / JOURNAL_NAME, durable != "none")
    ctx = ExportContext(scene, writer, out_dir, names, sel, windows, doc, sha, margin_m, label_at,
                        journal, n_digits, durable)
    ctx.owned = OwnedLog(out_dir, EXPORT_ROLE, f"export {writer.fmt}")
    return ctx


def _select(ctx, only_verified: bool, include_stale: bool) -> _Selection:
    """The selected windows and their poses (one vectorised interpolation for all of them)."""
    scene, windows = ctx.scene, ctx.windows
    if only_verified:
        keep, touched, reasons = review_usage(windows, scene.corrections.reviews, ctx.names,
                                              None if include_stale else scene_staleness(scene))
    else:
        keep, touched, reasons = np.ones(len(windows), bool), np.zeros(len(windows), bool), []
    selected = [w for w, k in zip(windows, keep) if k]
    t_lab = np.array([w.t_label_us for w in selected], np.int64)
    if len(selected) and scene.has_poses:      # poses only: the driver loads no mesh (issue 27.2)
        T_co, T_bc, valid = label_poses(scene, t_lab, scene.object_names)
    else:                       # no window, or an event-only scene: no pose, no label
        N = len(selected)
        T_co, T_bc, valid = np.zeros((N, len(scene.object_names), 4, 4)), np.full((N, 4, 4), np.nan), np.zeros(N, bool)
    sigma = None
    opts = ctx.extra.get("label_sigma_options")
    if opts is not None and len(selected) and scene.has_poses:
        sel = ctx.sel                        # the exported objects among the scene's (label_poses gave them all)
        sig = opts.sigmas(scene, t_lab, ctx.names, K=(ctx.writer.output_camera(scene) or scene.camera).K,
                          labels=(T_co[:, sel], T_bc, valid))
        keep = opts.keep(sig)
        ctx.extra["label_sigma_left_out"] = {w.index for w, k in zip(selected, keep) if not k}
        selected = [w for w, k in zip(selected, keep) if k]
        T_co, T_bc, valid = T_co[keep], T_bc[keep], valid[keep]
        sigma = np.stack([sig.sigma_t_mm, sig.sigma_R_deg, sig.sigma_px], -1)[keep]      # (N, K, 3)
        ctx.extra["label_sigma"] = {w.index: s for w, s, v in zip(selected, sigma, valid) if v}
    ctx.extra["selected"] = selected
    ctx.extra["valid"] = valid
    ctx.extra["row_of"] = {w.index: r for r, w in enumerate(selected)}
    return _Selection(selected, T_co, T_bc, valid, touched, reasons, sigma)


def _new_summary(ctx, selection: _Selection, jobs: int, only_verified: bool, include_stale: bool) -> ExportSummary:
    n_all, n_sel = len(ctx.windows), len(selection.windows)
    n_sigma = len(ctx.extra.get("label_sigma_left_out", ()))
    summary = ExportSummary(format=ctx.writer.fmt, windows_total=n_all, selected=n_sel,
                            filtered_unverified=n_all - n_sel - n_sigma, filtered_label_sigma=n_sigma,
                            out_dir=str(ctx.out_dir), jobs=jobs,
                            config_sha256=ctx.sha, timings_s=dict.fromkeys(STAGES, 0.0),
                            events_only=not ctx.scene.has_poses)
    if ctx.scene.has_poses:       # an event-only scene's windows are not "unlabeled": it has nothing to label
        set_unlabeled(summary, unlabeled_windows(ctx.scene, selection.windows, selection.valid))
    if only_verified:
        count_review_usage(summary, ctx.windows, selection.touched, selection.review_reasons,
                           {u["index"] for u in summary.unlabeled_windows}, include_stale)
    return summary


def _progress_text(summary: ExportSummary) -> str:
    return f"{summary.written} written, {summary.skipped_complete} complete, {summary.unlabeled} unlabeled"


def _run(ctx, selection: _Selection, summary: ExportSummary, jobs: int, progress, cancel, executor) -> dict[int, dict]:
    """Begin the writer, skip the complete windows, run the others; returns the record of every
    complete window by index."""
    writer = ctx.writer
    writer.begin(ctx)
    done = writer.completed(ctx)
    tasks = []
    for r, (w, v) in enumerate(zip(selection.windows, selection.valid)):
        if w.index in done or (not v and not writer.process_unlabeled):
            continue
        tasks.append(WindowTask(w, selection.T_cam_obj[r], selection.T_base_cam[r], bool(v), r,
                                None if selection.sigma is None else selection.sigma[r]))
    summary.skipped_complete = sum(1 for w, v in zip(selection.windows, selection.valid)
                                   if w.index in done and (v or writer.process_unlabeled))
    records = dict(done)
    total = max(len(selection.windows), 1)
    base = len(selection.windows) - len(tasks)

    def report(n_done):
        if progress is not None:
            progress((base + n_done) / total, _progress_text(summary))

    report(0)
    if cancel is not None and cancel():
        raise Cancelled(f"{ctx.out_dir}: export cancelled")
    spec = WorkerSpec(ctx.scene.manifest, ctx.scene.corrections.to_json(), writer, str(ctx.out_dir), ctx.names,
                      ctx.sel.tolist(), writer.request(ctx.margin_m), ctx.n_digits, ctx.durable)
    run_windows(ctx, spec, tasks, records, summary, report, cancel, jobs, executor)
    return records


def _finish(ctx, selection: _Selection, summary: ExportSummary, records: dict, t_start: float, progress) -> None:
    """Make the last windows durable, write the aggregate files, then the manifest. Every window is done, so a
    temporary file left now is a killed worker's (a Dask worker lost mid-chunk, whose chunk ran again
    elsewhere): removed, so the folder holds exactly the export."""
    clean_temp_files(ctx.out_dir)
    ctx.writer.flush(ctx)
    ctx.journal.close()
    files, patterns = ctx.writer.finish(ctx, records)
    summary.timings_s["write"] += ctx.extra.get("parent_write_s", 0.0)
    summary.files = sorted(set(files) | {MANIFEST_NAME, README_NAME})
    ctx.extra["window_file_patterns"] = patterns
    n_top = len(files) - ctx.extra.get("n_window_files", 0)
    ctx.extra["top_files"] = sorted(set(files[:n_top]) | {MANIFEST_NAME, README_NAME})
    summary.runtime_s = time.perf_counter() - t_start
    write_manifest(ctx, summary, records, selection.windows, selection.valid, summary.unlabeled_windows)
    ctx.owned.close()
    if progress is not None:
        progress(1.0, _progress_text(summary))


def _abort(ctx) -> None:
    """Failed or cancelled: keep what is complete (journaled), let the writer leave its files
    resumable, and remove every temp file (the workers' too)."""
    with contextlib.suppress(Exception):
        ctx.writer.flush(ctx)
    with contextlib.suppress(Exception):
        ctx.journal.close()
    with contextlib.suppress(Exception):
        ctx.writer.abort(ctx)
    ctx.owned.close()
    clean_temp_files(ctx.out_dir)
