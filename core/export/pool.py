"""Running the window tasks of an export: in this process, or in a ``spawn`` process pool.

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
from evpose.core.export.worker import WorkerContext, WorkerSpec

__all__ = ["FLUSH_WINDOWS", "FLUSH_SECONDS", "run_windows"]

#: The parent makes accepted windows durable (syncfs + journal fsync, or HDF5 flush + fsync) after this
#: many windows or seconds, whichever comes first: a crash redoes at most that much work, and syncfs,
#: which flushes the whole filesystem (other programs' writes too), stays off the per-window cost.
FLUSH_WINDOWS = 64
FLUSH_SECONDS = 5.0


def run_windows(ctx, spec: WorkerSpec, tasks: list, records: dict, summary, report, cancel, jobs: int) -> None:
    """Process ``tasks`` (:class:`~evpose.core.export.writer.WindowTask`) and accept their results:
    ``records`` gets each window's record, ``summary`` the counts and stage timings, ``report(n_done)``
    is called after each window (serial) or chunk (pool); ``cancel()`` True raises
    :class:`~evpose.core.data.events.Cancelled`."""
    if jobs == 1 or len(tasks) <= 1:
        _run_serial(ctx, spec, tasks, records, summary, report, cancel)
    else:
        _run_pool(ctx, spec, tasks, records, summary, report, cancel, jobs)


def _accept(ctx, index: int, rec: dict, payload, records: dict, summary) -> None:
    ctx.writer.accept(ctx, rec, payload)
    records[index] = rec
    if rec.get("status") == "written":
        summary.written += 1


def _run_serial(ctx, spec, tasks, records, summary, report, cancel) -> None:
    if not tasks:
        return
    wctx = WorkerContext(spec, scene=ctx.scene, owned=ctx.owned)
    for k, task in enumerate(tasks):
        rec, payload = wctx.run(task)
        _accept(ctx, task.window.index, rec, payload, records, summary)
        _maybe_flush(ctx)
        report(k + 1)
        if cancel is not None and cancel():
            _add_timings(summary, wctx.take_timings())
            raise Cancelled(f"{ctx.out_dir}: export cancelled after {k + 1} windows")
    _add_timings(summary, wctx.take_timings())


def _run_pool(ctx, spec, tasks, records, summary, report, cancel, jobs) -> None:
    import multiprocessing as mp

    size = max(1, min(32, math.ceil(len(tasks) / (jobs * 8))))
    chunks = [tasks[i:i + size] for i in range(0, len(tasks), size)]
    t_pool = time.perf_counter()
    pool = mp.get_context("spawn").Pool(jobs, initializer=_worker_init, initargs=(spec,))
    ok = False
    try:
        n_done = 0
        for results, timings in pool.imap_unordered(_worker_run, chunks):
            if n_done == 0:
                summary.pool_startup_s = max(0.0, time.perf_counter() - t_pool - sum(timings.values()))
            for rec, payload in results:
                _accept(ctx, rec["i"], rec, payload, records, summary)
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
    out = [_WORKER.run(t) for t in tasks]
    return out, _WORKER.take_timings()
