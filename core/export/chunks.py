"""Chunks of windows sized in work, not in counts (issue 27.2): each task of a cluster export should take a few
seconds of a worker's CPU whatever the number of workers and whatever a window costs on that scene.

A dataset's first scene starts with at most :data:`PROBE_CHUNKS` small probes (:data:`PROBE_WINDOWS` windows) in
flight, whatever the number of workers (at 64 workers, two probes per worker put 47 % of E-POSE's windows in
probe chunks: bench/bench_cluster_scale.py); later scenes start from the cost measured on the earlier ones
(``prior``). Every chunk that comes back tells its CPU seconds, and the following chunks hold
``TARGET_TASK_CPU_S / (CPU s per window so far)`` windows (clamped to ``1 .. MAX_CHUNK_WINDOWS``, to
:data:`MAX_CHUNK_BYTES` of results and to what is left). A scene whose windows cost 0.2 s gets chunks of ~20
windows, one whose windows cost 5 ms gets ~512: per-task overheads (scheduling, the round trip, the result's
deserialisation, the driver's bookkeeping) stay a small share of the work, and the scheduler sees tasks it
can place (~1 per 4 s per worker: 16 tasks/s for 64 workers) instead of ~150 small ones per second.

The last work of a run is cut finer: when no other scene's chunks can fill the workers (``tail_workers``), a chunk
holds at most ``remaining / (2 x workers)`` windows, and not less than :data:`MIN_TASK_CPU_S` of CPU, so the workers
finish together instead of one of them running a last 4 s chunk alone (a single 501-window scene on 2 workers:
the tail was ~10 % of its wall time, issue 27.1). While other scenes are in flight their chunks fill that time, and
the chunks keep their size (at 64 workers, splitting every sequence's end would multiply the tasks by ~7).

Windows are cut contiguously in order, so a chunk is a run of consecutive windows (read sequentially from the
event file); the records are per window, so the output does not depend on the cut. A writer that groups windows
into one file (BOP shards, :mod:`evpose.core.export.bop_shards`) gives ``group(task)``: a chunk then ends only where
the group changes (it is extended to the end of its last group), so every group is written whole by one worker.
"""
from __future__ import annotations

import threading

__all__ = ["ChunkPlanner", "MAX_CHUNK_BYTES", "MAX_CHUNK_WINDOWS", "MIN_TASK_CPU_S", "PROBE_CHUNKS", "PROBE_WINDOWS",
           "TARGET_TASK_CPU_S", "result_bytes", "whole_groups"]

#: CPU seconds a task aims at (issue 27: 2-10 s).
TARGET_TASK_CPU_S = 4.0
#: The smallest task the tail is cut into, CPU seconds (the per-task overhead stays a few per cent of it).
MIN_TASK_CPU_S = 0.5
#: Windows of a probe chunk (before any cost is known) ...
PROBE_WINDOWS = 4
#: ... and at most this many probes out before the first comes back.
PROBE_CHUNKS = 2
#: At most this many windows a chunk (the records come back in one message) ...
MAX_CHUNK_WINDOWS = 512
#: ... and at most about this many bytes of results (HDF5: a DAVIS346 window's frames and label map are ~0.7 MB,
#: so ~90 windows a chunk; BOP and E-POSE write their files on the worker and return a few hundred bytes).
MAX_CHUNK_BYTES = 64 << 20


class ChunkPlanner:
    """Cut ``tasks`` into chunks as they are asked for (:meth:`next`), sized from the CPU the finished ones took
    (:meth:`record`). Thread-safe; ``sizes`` lists the sizes handed out, in order."""

    def __init__(self, tasks: list, *, target_s: float = TARGET_TASK_CPU_S, probe: int = PROBE_WINDOWS,
                 max_windows: int = MAX_CHUNK_WINDOWS, max_bytes: int = MAX_CHUNK_BYTES, prior=None, group=None):
        self._tasks = tasks
        self._group = group
        self._next = 0
        self._lock = threading.Lock()
        self.target_s = float(target_s)
        self.probe = max(1, int(probe))
        self.max_windows = max(1, int(max_windows))
        self.max_bytes = max(1, int(max_bytes))
        self.windows_measured = 0
        self.cpu_measured_s = 0.0
        self.bytes_per_window = 0.0          # the largest result per window seen
        self.sizes: list[int] = []
        #: asked at each chunk: the workers the rest of this scene is spread over at its end (0: none)
        self.tail_workers = lambda: 0
        self._prior = False
        if prior is not None:
            self.record_prior(prior)

    def record_prior(self, prior) -> None:
        """Start from ``prior`` = (cpu s per window, result bytes per window) measured on earlier scenes (no
        probes); the first chunk of this scene that comes back replaces it."""
        cost, n_bytes = prior
        with self._lock:
            self.windows_measured, self.cpu_measured_s = 1, float(cost)
            self.bytes_per_window = float(n_bytes)
            self._prior = True

    @property
    def measured(self) -> tuple[float, float] | None:
        """``(cpu s per window, result bytes per window)`` measured so far (a prior for the next scene)."""
        cost = self.cpu_per_window_s
        return None if cost is None else (cost, self.bytes_per_window)

    def may_submit(self, in_flight: int) -> bool:
        """Whether another chunk may go out with ``in_flight`` out: only :data:`PROBE_CHUNKS` probes before the
        first cost is known (the others would be probes too)."""
        return self.cpu_per_window_s is not None or in_flight < PROBE_CHUNKS

    @property
    def remaining(self) -> int:
        return len(self._tasks) - self._next

    @property
    def cpu_per_window_s(self) -> float | None:
        """The measured CPU seconds per window (None before the first chunk came back)."""
        if self.windows_measured == 0:
            return None
        return self.cpu_measured_s / self.windows_measured

    def size(self) -> int:
        """The size the next chunk gets (before clamping to what is left)."""
        cost = self.cpu_per_window_s
        if cost is None:
            return self.probe
        cap = self.max_windows
        if self.bytes_per_window > 0:
            cap = min(cap, max(1, int(self.max_bytes // self.bytes_per_window)))
        if cost <= 0.0:
            return cap
        n = int(min(cap, max(1, round(self.target_s / cost))))
        workers = self.tail_workers()
        if workers:                   # the run's last work: split what is left over the workers
            share = -(-self.remaining // (2 * int(workers)))
            n = min(n, max(share, int(round(MIN_TASK_CPU_S / cost)), 1))
        return n

    def next(self) -> list | None:
        """The next chunk of consecutive tasks, or None when every task was handed out."""
        with self._lock:
            if self._next >= len(self._tasks):
                return None
            n = min(self.size(), len(self._tasks) - self._next)
            n = whole_groups(self._tasks, self._next, n, self._group)
            chunk = self._tasks[self._next:self._next + n]
            self._next += n
            self.sizes.append(n)
            return chunk

    def record(self, n_windows: int, cpu_s: float, n_bytes: int = 0) -> None:
        """A chunk of ``n_windows`` came back having taken ``cpu_s`` CPU seconds on its worker, its results
        ``n_bytes`` long (:func:`result_bytes`)."""
        with self._lock:
            if n_windows > 0 and cpu_s >= 0.0:
                if self._prior:              # the scene's own measurement replaces the earlier scenes' cost
                    self.windows_measured, self.cpu_measured_s, self._prior = 0, 0.0, False
                self.windows_measured += int(n_windows)
                self.cpu_measured_s += float(cpu_s)
                self.bytes_per_window = max(self.bytes_per_window, n_bytes / n_windows)


def whole_groups(tasks: list, start: int, n: int, group) -> int:
    """``n`` extended so that ``tasks[start:start + n]`` ends where ``group(task)`` changes (or at the end); ``n``
    itself when ``group`` is None."""
    if group is None:
        return n
    end = start + n
    if end < len(tasks):
        last = group(tasks[end - 1])
        while end < len(tasks) and group(tasks[end]) == last:
            end += 1
    return end - start


def result_bytes(results: list) -> int:
    """The bytes of a chunk's ``(record, payload, journal line)`` results that matter for its message: the arrays of
    the payloads (records and lines are small)."""
    n = 0
    for _rec, payload, _line in results:
        if isinstance(payload, dict):
            n += sum(int(getattr(v, "nbytes", 0)) for v in payload.values())
    return n
