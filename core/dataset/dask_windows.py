"""The export's chunks of windows as Dask tasks (:class:`DaskWindows`, a
:class:`~evpose.core.export.pool.WindowExecutor`).

A task is one chunk of one scene's windows with the poses the scene's driver interpolated; the worker
opens the scene from its paths (the pickled manifest and a JSON copy of the corrections), writes the
chunk's files atomically into the shared output folder, syncs them (``batch`` durability) and returns
the records. The driver journals a window only after its record arrived, so a worker killed mid-chunk
loses nothing: Dask runs the chunk again elsewhere and the rerun writes the same bytes.

Each worker process keeps the contexts of the last few export configurations (scene, annotator,
rasteriser caches), so a scene's chunks after the first pay no set-up; when a scene's last chunk is in, the
driver asks every worker to drop that scene's context and give the freed heap back (:func:`evict_context`):
an idle worker returns near its start size instead of holding two scenes' meshes and caches.
"""
from __future__ import annotations

import threading
from collections import OrderedDict
from pathlib import Path

from evpose.core.data.events import Cancelled
from evpose.core.export.chunks import result_bytes
from evpose.core.export.pool import WindowExecutor, run_worker_chunk
from evpose.core.export.worker import WorkerContext, WorkerSpec

__all__ = ["DaskWindows", "evict_context", "run_chunk"]

#: Worker contexts kept per worker process (each holds an open event file and mesh caches): more than the scenes
#: driven at once (core/dataset/export.SCENE_DRIVERS = 3), or chunks of interleaved scenes evict each other's.
CONTEXTS_KEPT = 4
_contexts: OrderedDict = OrderedDict()
_lock = threading.Lock()


def _context(spec: WorkerSpec, key: str) -> WorkerContext:
    with _lock:
        wctx = _contexts.get(key)
        if wctx is None:
            import cv2

            cv2.setNumThreads(1)      # one single-threaded worker per core: OpenCV's threads would compete
            wctx = _contexts[key] = WorkerContext(spec)
            while len(_contexts) > CONTEXTS_KEPT:
                _, old = _contexts.popitem(last=False)
                old.scene.close()
        _contexts.move_to_end(key)
        return wctx


def evict_context(key: str) -> int:
    """Run on every worker after a scene's last chunk: close and drop that export's context, collect, and give
    the free heap pages back to the kernel. Returns the contexts still kept."""
    import gc

    from evpose.core.data.heap import trim_heap

    with _lock:
        wctx = _contexts.pop(key, None)
        if wctx is not None:
            wctx.scene.close()
        kept = len(_contexts)
    del wctx
    gc.collect()
    trim_heap()
    return kept


def run_chunk(spec: WorkerSpec, key: str, tasks: list) -> tuple[list, dict]:
    """The Dask task: run one chunk of windows and make its files durable before returning."""
    from evpose.core.data import atomic

    wctx = _context(spec, key)
    out = run_worker_chunk(wctx, tasks)
    if spec.durable == "batch":
        atomic.sync_filesystem(spec.out_dir)     # the driver may be on another machine: sync here
    return out


class DaskWindows(WindowExecutor):
    """Run chunks of windows on the workers of a ``distributed.Client``."""

    syncs_chunks = True          # run_chunk syncs the chunk's files before it returns

    def __init__(self, client, *, retries: int = 0, events=None):
        self.client = client
        self.retries = retries        # besides Dask's own rescheduling of tasks of a lost worker
        #: a :class:`~evpose.core.dataset.cluster_events.ClusterEvents` told each chunk's key and scene (optional)
        self.events = events
        self._lock = threading.Lock()
        self._pending: set = set()
        self._stopped = False
        #: (cpu s, result bytes) per window measured on the last finished scene: the next scene starts from it
        #: instead of probing again
        self.prior = None
        #: whether scenes are still to come (set by the dataset export; None: this is the only one): a scene's end is
        #: cut finer only when it is the last work (:class:`~evpose.core.export.chunks.ChunkPlanner`)
        self.more_scenes = None
        self._runs = 0

    def cancel_all(self) -> None:
        """Cancel every chunk not yet done (the runs waiting on them end with ``Cancelled``); later
        runs are refused. Called from another thread on Ctrl-C or a cancel."""
        with self._lock:
            self._stopped = True
            pending = list(self._pending)
        self.client.cancel(pending)

    @property
    def workers(self) -> int:
        return max(1, sum(self.client.nthreads().values()))

    def run(self, spec: WorkerSpec, planner, key: str):
        """Submit ``planner``'s chunks, about two per worker in flight, each sized from the CPU the finished
        ones took (:class:`~evpose.core.export.chunks.ChunkPlanner`); yield their results as they complete."""
        from distributed import as_completed

        scene = Path(spec.out_dir).name           # the dataset export writes each scene to OUT/<scene name>
        ac = as_completed()
        active: set = set()
        if planner.cpu_per_window_s is None and self.prior is not None:
            planner.record_prior(self.prior)
        n_workers = self.workers                   # one scheduler round trip per scene, not per submission
        planner.tail_workers = lambda: n_workers if self._is_last_work() else 0

        def submit_more() -> None:
            while len(active) < 2 * n_workers and planner.may_submit(len(active)):
                chunk = planner.next()
                if chunk is None:
                    return
                with self._lock:
                    if self._stopped:
                        raise Cancelled(f"{spec.out_dir}: export cancelled")
                    f = self.client.submit(run_chunk, spec, key, chunk, pure=False, retries=self.retries)
                    self._pending.add(f)
                active.add(f)
                ac.add(f)
                if self.events is not None:
                    self.events.track(f.key, scene)

        finished = False
        with self._lock:
            self._runs += 1
        try:
            submit_more()
            for future in ac:
                active.discard(future)
                if future.cancelled() or self._stopped:
                    raise Cancelled(f"{spec.out_dir}: export cancelled")
                results, timings = future.result()
                planner.record(len(results), timings.get("worker_cpu", sum(timings.values())), result_bytes(results))
                with self._lock:
                    self._pending.discard(future)
                submit_more()
                yield results, timings
            finished = True
            if planner.measured is not None:
                self.prior = planner.measured
        finally:
            with self._lock:
                self._runs -= 1
            self.client.cancel([f for f in active if not f.done()])
            with self._lock:
                self._pending.difference_update(active)
            if finished:
                self._evict(key)

    def _is_last_work(self) -> bool:
        """No other scene is being run or still to come."""
        with self._lock:
            alone = self._runs <= 1
        return alone and not (self.more_scenes is not None and self.more_scenes())

    def _evict(self, key: str) -> None:
        """Every worker drops the finished scene's context (best effort: a worker gone or busy does not fail
        the export; a context left behind is evicted by the bounded cache later)."""
        try:
            self.client.run(evict_context, key, wait=True)
        except Exception:
            pass
