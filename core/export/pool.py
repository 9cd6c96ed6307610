"""Running the window tasks of an export: in this process, in a ``spawn`` process pool, or through a
window executor (:class:`WindowExecutor`, e.g. :class:`evpose.core.dataset.dask_windows.DaskWindows` on a
Dask cluster).

Each result goes to the writer's :meth:`~evpose.core.export.writer.FormatWriter.accept` in the parent,
which makes accepted windows durable every :data:`FLUSH_WINDOWS` windows or :data:`FLUSH_SECONDS`
seconds (:meth:`~evpose.core.export.writer.FormatWriter.flush`).

With ``jobs > 1`` every worker builds one :class:`~evpose.core.export.worker.WorkerContext` and processes
contiguous chunks of windows whose poses the parent interpolated in one vectorised call. Workers ignore
SIGINT; the parent turns Ctrl-C or a ``cancel()`` into ``pool.terminate()`` (the caller then removes
the temp files the workers left and re-raises).
"""
from __future__ import annotations

import math
import signal
import time

from evpose.core.data.events import Cancelled
from evpose.core.export.chunks import ChunkPlanner, whole_groups
from evpose.core.export.journal import journal_line
from evpose.core.export.worker import WorkerContext, WorkerSpec

__all__ = ["FLUSH_WINDOWS", "FLUSH_SECONDS", "WindowExecutor", "chunk_tasks", "run_worker_chunk", "run_windows"]

#: The parent makes accepted windows durable (syncfs + journal fsync, or HDF5 flush + fsync) after this
#: many windows or seconds, whichever comes first: a crash redoes at most that much work, and syncfs,
#: which flushes the whole filesystem (other programs' writes too), stays off the per-window cost.
FLUSH_WINDOWS = 64
FLUSH_SECONDS = 5.0


class WindowExecutor:
    """Runs chunks of window tasks somewhere else (another process, another machine).

    :meth:`run` takes its chunks from ``planner`` (:class:`~evpose.core.export.chunks.ChunkPlanner`: ``next()``
    as it can place them, ``record(n_windows, cpu_s)`` as they come back) and yields ``(results, timings)`` per
    chunk in completion order, each result the ``(record, payload)`` of
    :meth:`~evpose.core.export.worker.WorkerContext.run`; closing the generator early (an error, a cancel)
    cancels the chunks not yet done. ``key`` names the export configuration (a worker may keep one context per
    key). ``workers`` says how many chunks run at once.
    """

    workers = 1
    #: Whether a chunk's files are as durable as ``spec.durable`` asks when its result arrives (the worker synced
    #: them, as :func:`evpose.core.dataset.dask_windows.run_chunk` does): the driver then writes and fsyncs its
    #: journal lines without a ``syncfs`` of its own (on ext4 the syncfs's writeback of the workers' files was
    #: charged to the driver's thread: ~0.5 ms a 16-file E-POSE window, issue 27.2).
    syncs_chunks = False

    def run(self, spec: WorkerSpec, planner, key: str):  # pragma: no cover - interface
        raise NotImplementedError


def chunk_tasks(tasks: list, workers: int, group=None) -> list[list]:
    """Contiguous chunks of about ``len(tasks) / (8 workers)`` tasks (1..32): small enough to balance
    the load and to lose little to a killed worker, large enough to keep the per-chunk cost low; each extended to
    the end of its last ``group`` (:func:`~evpose.core.export.chunks.whole_groups`)."""
    size = max(1, min(32, math.ceil(len(tasks) / (max(workers, 1) * 8))))
    chunks, i = [], 0
    while i < len(tasks):
        n = whole_groups(tasks, i, min(size, len(tasks) - i), group)
        chunks.append(tasks[i:i + n])
        i += n
    return chunks


def run_windows(ctx, spec: WorkerSpec, tasks: list, records: dict, summary, report, cancel, jobs: int,
                executor: WindowExecutor | None = None) -> None:
    """Process ``tasks`` (:class:`~evpose.core.export.writer.WindowTask`) and accept their results:
    ``records`` gets each window's record, ``summary`` the counts and stage timings, ``report(n_done)``
    is called after each window (serial) or chunk (pool, executor); ``cancel()`` True raises
    :class:`~evpose.core.data.events.Cancelled`. An ``executor`` takes the place of ``jobs``."""
    if executor is not None and tasks:
        ctx.extra["chunks_durable"] = bool(executor.syncs_chunks)
        planner = ChunkPlanner(tasks, group=ctx.writer.chunk_group())   # chunks sized in CPU s as costs come back
        _run_chunks(ctx, records, summary, report, cancel, executor.run(spec, planner, f"{ctx.out_dir}|{ctx.sha}"))
        summary.chunks = list(planner.sizes)
    elif jobs == 1 or len(tasks) <= 1:
        _run_serial(ctx, spec, tasks, records, summary, report, cancel)
    else:
        _run_pool(ctx, spec, tasks, records, summary, report, cancel, jobs)


def _accept(ctx, index: int, rec: dict, payload, records: dict, summary, line: str | None = None) -> None:
    ctx.writer.accept(ctx, rec, payload, line)
    records[index] = rec
    if rec.get("status") == "written":
        summary.written += 1


def _run_serial(ctx, spec, tasks, records, summary, report, cancel) -> None:
    if not tasks:
        return
    wctx = WorkerContext(spec, scene=ctx.scene, owned=ctx.owned)
    group = ctx.writer.chunk_group()
    for k, task in enumerate(tasks):
        if group is not None and (k == 0 or group(tasks[k - 1]) != group(task)):
            wctx.writer.begin_chunk(wctx)
        rec, payload = wctx.run(task)
        if group is not None and (k + 1 == len(tasks) or group(tasks[k + 1]) != group(task)):
            wctx.end_chunk()            # the group's file, before its windows are journaled
        _accept(ctx, task.window.index, rec, payload, records, summary)
        _maybe_flush(ctx)
        report(k + 1)
        if cancel is not None and cancel():
            _add_timings(summary, wctx.take_timings())
            raise Cancelled(f"{ctx.out_dir}: export cancelled after {k + 1} windows")
    _add_timings(summary, wctx.take_timings())


def _run_pool(ctx, spec, tasks, records, summary, report, cancel, jobs) -> None:
    import multiprocessing as mp

    t_pool = time.perf_counter()
    pool = mp.get_context("spawn").Pool(jobs, initializer=_worker_init, initargs=(spec,))
    ok = False
    try:
        _run_chunks(ctx, records, summary, report, cancel,
                    pool.imap_unordered(_worker_run, chunk_tasks(tasks, jobs, ctx.writer.chunk_group())), t_pool)
        ok = True
    finally:
        if ok:
            pool.close()
        else:
            pool.terminate()     # workers may be mid-write: their temp files are removed by the caller
        pool.join()


def _run_chunks(ctx, records, summary, report, cancel, results_iter, t_pool: float | None = None) -> None:
    """Accept the chunk results ``results_iter`` yields, in completion order (``t_pool``: when the
    workers were asked for, for ``summary.pool_startup_s``)."""
    t_pool = time.perf_counter() if t_pool is None else t_pool
    n_done = 0
    try:
        for results, timings in results_iter:
            if n_done == 0:
                work_s = sum(v for k, v in timings.items() if k != "worker_cpu")     # (the stages' wall time)
                summary.pool_startup_s = max(0.0, time.perf_counter() - t_pool - work_s)
            for rec, payload, line in results:
                _accept(ctx, rec["i"], rec, payload, records, summary, line)
            n_done += len(results)
            _add_timings(summary, timings)
            _maybe_flush(ctx, len(results))
            report(n_done)
            if cancel is not None and cancel():
                raise Cancelled(f"{ctx.out_dir}: export cancelled after {n_done} windows")
    finally:
        close = getattr(results_iter, "close", None)
        if close is not None:
            close()


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


# ------------------------------------------------------------------------------------------- worker processes
_WORKER: WorkerContext | None = None


def _worker_init(spec: WorkerSpec) -> None:
    global _WORKER
    signal.signal(signal.SIGINT, signal.SIG_IGN)    # the parent handles Ctrl-C and terminates the pool
    import cv2

    cv2.setNumThreads(1)     # one process per core already: OpenCV's own threads would only compete
    _WORKER = WorkerContext(spec)


def _worker_run(tasks: list) -> tuple[list, dict]:
    return run_worker_chunk(_WORKER, tasks)


def run_worker_chunk(wctx: WorkerContext, tasks: list) -> tuple[list, dict]:
    """Run a chunk of window tasks in a worker; returns their ``(record, payload, journal line)`` and the stage
    timings, with the CPU seconds the chunk took on this thread as ``worker_cpu`` (the window work is
    single-threaded: numba kernels serial, OpenCV at one thread), from which
    :class:`~evpose.core.export.chunks.ChunkPlanner` sizes the next chunks. The journal lines are encoded here so
    that the driver's work per window is an append (issue 27.2)."""
    c0 = time.thread_time()
    out = []
    wctx.writer.begin_chunk(wctx)
    for t in tasks:
        rec, payload = wctx.run(t)
        out.append((rec, payload, journal_line(rec)))
    wctx.end_chunk()
    timings = wctx.take_timings()
    timings["worker_cpu"] = time.thread_time() - c0
    return out, timings
