"""Corrected-dataset exports: E-POSE layout, BOP, HDF5.

Atomic per file, resumable, with ``progress(fraction, message)`` and ``cancel() -> bool`` callbacks;
no knowledge of threads or GUI (the app calls :func:`export_scene` from a worker thread).
One module per role:

- formats: :mod:`~evpose.core.export.epose`, :mod:`~evpose.core.export.bop`, :mod:`~evpose.core.export.h5`
  (each a :class:`~evpose.core.export.writer.FormatWriter`; file encodings in :mod:`~evpose.core.export.encode`);
- the run: :mod:`~evpose.core.export.runner` (step by step), :mod:`~evpose.core.export.pool` (this process
  or a process pool), :mod:`~evpose.core.export.worker` (per-process context);
- what is exported: :mod:`~evpose.core.export.options`, :mod:`~evpose.core.export.windows` (tiling,
  ``--only-verified``, unlabeled windows);
- the output folder: :mod:`~evpose.core.export.out_folder` (lock, resume / refuse / replace),
  :mod:`~evpose.core.export.fingerprint`, :mod:`~evpose.core.export.journal`;
- what it did: :mod:`~evpose.core.export.summary`, :mod:`~evpose.core.export.manifest`.
"""
from __future__ import annotations

from pathlib import Path

from evpose.core.export.options import FORMATS, ExportError
from evpose.core.export.runner import run_export
from evpose.core.export.summary import ExportSummary
from evpose.core.label.windows import DEFAULT_WINDOW_US

__all__ = ["export_scene", "make_writer", "ExportSummary", "ExportError", "FORMATS"]


def make_writer(fmt: str, format_options: dict | None = None):
    """The :class:`~evpose.core.export.writer.FormatWriter` of a format name, with its options."""
    opts = dict(format_options or {})
    if fmt == "epose":
        from evpose.core.export.epose import EposeWriter

        cls = EposeWriter
    elif fmt == "bop":
        from evpose.core.export.bop import BopWriter

        cls = BopWriter
    elif fmt == "h5":
        from evpose.core.export.h5 import H5Writer

        cls = H5Writer
    else:
        raise ExportError(f"format: unknown export format {fmt!r} (choose from {', '.join(FORMATS)})")
    try:
        return cls(**opts)
    except TypeError as exc:
        raise ExportError(f"format_options: {exc}") from None


def export_scene(scene_or_path, fmt: str, out_dir, *, window_us: int = DEFAULT_WINDOW_US, window_events: int | None = None,
                 label_at: str = "center", only_verified: bool = False, objects=None, margin_m: float = 0.0,
                 jobs: int = 1, force: bool = False, progress=None, cancel=None, format_options: dict | None = None,
                 durable=True, include_stale: bool = False, executor=None, label_sigma=None) -> ExportSummary:
    """Export a scene's corrected labels.

    Parameters
    ----------
    scene_or_path : evpose.core.data.scene.Scene or path
        A scene (its current corrections are used, frozen at the start) or a scene folder / scene.toml
        (its ``corrections.json`` is loaded).
    fmt : {"epose", "bop", "h5"}
    out_dir : path
        Output folder: new, empty, or an earlier export of the same configuration (resumed).
    window_us : int
        Window length in µs (ignored when ``window_events`` is given).
    window_events : int, optional
        Events per window instead of a fixed length.
    label_at : {"center", "end"}
        Label time of a window: its centre (default) or its end (E-POSE's timing).
    only_verified : bool
        Export only windows whose every instant is effectively ``verified`` for every exported object
        by a mark that is not stale; partly covered windows are left out (see
        :func:`evpose.core.export.windows.review_usage`). The summary counts the windows verified marks
        touch and why those not exported were left out.
    include_stale : bool
        With ``only_verified``: also use verified marks made before a later change of the clock or of
        the object's pose (default False: such marks verified another label and are left out).
    objects : list of str or comma-separated str, optional
        Objects to export (default all). Objects not exported still occlude exported ones.
    margin_m : float
        Enlarge the 3D box by this many metres on every side (keypoints).
    jobs : int
        Worker processes (``spawn`` pool); 1 runs in this process.
    force : bool
        Replace an earlier evpose export of a different configuration in ``out_dir``.
    progress : callable, optional
        ``progress(fraction, message)``.
    cancel : callable, optional
        ``cancel() -> bool``; True stops the export, raising :class:`evpose.core.data.events.Cancelled`. The
        folder is left without partial or temp files and a rerun resumes.
    executor : evpose.core.export.pool.WindowExecutor, optional
        Runs the chunks of windows elsewhere instead of ``jobs`` local processes (a Dask cluster:
        :class:`evpose.core.dataset.dask_windows.DaskWindows`); the files are the same.
    label_sigma : evpose.core.label.uncertainty.LabelSigmaOptions, optional
        Write each label's 1-sigma (:mod:`evpose.core.label.uncertainty`, from the inputs' sigma it holds) in every
        format, and leave out the windows above its ``max_mm`` / ``max_deg`` (counted as ``filtered_label_sigma``).
        None (default): no uncertainty is written.
    format_options : dict, optional
        Writer options: epose ``png_compression``; bop ``K_new`` (3x3, default K), ``scene_id``,
        ``png_compression``; h5 ``three_channel`` (bool), ``compression`` ("blosc-lz4" | "gzip" | None).
    durable : bool or {"batch", "file", "none"}
        Durability across a power cut; every mode keeps each file atomic for readers (temp file +
        rename). ``True`` / "batch" (default): after each chunk of windows the filesystem is synced
        (``syncfs``) before the parent journals the chunk as complete, so a journaled window is
        durable (one commit per chunk instead of one fsync per file: per-file fsync costs 2-3 ms on
        the development disk, i.e. 30+ ms for the 13 files of a 3-object E-POSE window). "file":
        fsync every file before its rename (``evpose.core.data.atomic.atomic_path`` semantics). ``False`` /
        "none": no fsync at all.

    Returns
    -------
    ExportSummary
    """
    from evpose.core.data.scene import Scene

    writer = make_writer(fmt, format_options)
    if isinstance(objects, str):
        objects = [s.strip() for s in objects.split(",") if s.strip()]
    if isinstance(scene_or_path, (str, Path)):
        scene = Scene.open(scene_or_path)
        try:
            return run_export(scene, writer, out_dir, window_us=window_us, window_events=window_events,
                              label_at=label_at, only_verified=only_verified, objects=objects, margin_m=margin_m,
                              jobs=jobs, force=force, durable=durable, progress=progress, cancel=cancel,
                              include_stale=include_stale, executor=executor, label_sigma=label_sigma)
        finally:
            scene.close()
    return run_export(scene_or_path, writer, out_dir, window_us=window_us, window_events=window_events,
                      label_at=label_at, only_verified=only_verified, objects=objects, margin_m=margin_m,
                      jobs=jobs, force=force, durable=durable, progress=progress, cancel=cancel,
                      include_stale=include_stale, executor=executor, label_sigma=label_sigma)
