"""Memory the app holds without using it: kept from piling up at start-up, handed back to the system while the
user is idle (tracker issue 14).

Two holders of dead memory, measured with ``bench/bench_memory.py`` on the 5-object YCB scene:

* **glibc's malloc arenas.** Freed blocks stay in the arena of the thread that allocated them (the GUI thread,
  the frame and space-time workers, Mesa's llvmpipe threads under software OpenGL); after a few minutes of
  scrubbing 70-145 MB were free but kept. ``malloc_trim(0)`` returns every whole free page to the kernel
  (about 20 ms with a 400 MB heap).
* **Module source text in** :mod:`linecache`. PySide6's import hook reads the source of every module that
  imports something once PySide6 is loaded (``inspect.getsource``, to look for ``from __feature__ import``),
  and ``linecache`` keeps it: ~900 modules, 18 MB of text (~30 MB with the line objects). Only tracebacks
  use it, and they read the lines again when needed.

A third holder is the views' own caches (tracker issue 25.4): what the workers computed ahead of the user (the
overlays of the next window, decoded event blocks) and what the views out of sight keep for their next request (the
space-time view's silhouette slices, fields and surfaces, the kymograph's label maps, their annotators). All of it is
made again on demand.

:class:`IdleReleaser` acts once nothing has happened for :data:`IDLE_MS` (every session change and the end of every
background job restarts the count), so the work never lands in the middle of scrubbing: it empties those caches, each
on its worker's thread between requests (``tasks``: see :meth:`evpose.app.feeds.ViewFeeds.idle_release_tasks`), then
collects the young generations' cycles (``gc.collect(1)``: under 1 ms; a full collection takes 100-200 ms of the GUI
thread with the window's ~230 k tracked objects and found nothing worth an MB in ``bench/bench_memory.py``'s
sessions) and :func:`release_memory`. Two things keep memory from growing in the first place,
* :func:`~evpose.app.startup.configure_malloc`: a fixed mmap threshold (256 KiB) so that large temporaries (event
  windows, frames, the space-time points) are mapped and unmapped instead of fragmenting the heap (glibc otherwise
  raises its threshold to 32 MB after the first large free), and at most 2 malloc arenas (one per
  thread otherwise: GUI, three workers, the raster pool, llvmpipe's threads). ``bench/bench_memory.py``, 1-minute
  session on ``ycb_5obj_5s``: RSS at the end 839 -> 752 MB, peak 857 -> 763 MB.
* :func:`~evpose.app.startup.preload_engine`: the engine's modules (numpy, scipy, numba, trimesh, OpenCV, h5py, evpose.core) are
  imported before PySide6, whose import hook reads the source of every module imported after it: 3.7 instead of
  13.2 MB of source text held in :mod:`linecache` (262 instead of 734 files).
"""
from __future__ import annotations

import gc
import linecache
import threading
import time
import traceback

from PySide6 import QtCore

from evpose.app.startup import libc
from evpose.app.workers import JOB_EVENTS

#: Quiet time after the last session change before memory is released, ms.
IDLE_MS = 2000
#: While the user is busy (no quiet period), the heap's free pages are given back at most this often, s, on a thread
#: of their own (:meth:`IdleReleaser.poke`): freed blocks of the views' computations leave holes in the heap that only
#: ``malloc_trim`` returns (bench_memory: 100-150 MB free but resident at the end of a session before this).
BUSY_TRIM_S = 5.0
#: Once more this long after a release when nothing has happened since, ms: memory freed after the release without a
#: session change (the job threads' leftovers once Qt's thread pool lets them go after 30 s idle, late redraws) is
#: given back too (bench_memory, 10-minute session: 15 MB still trimmable 60 s into the idle phase before this).
LATE_TRIM_MS = 40_000


def trim_heap() -> bool:
    """``malloc_trim(0)``: give the free pages of every malloc arena back to the kernel. False when the C
    library has no ``malloc_trim`` (not glibc) or nothing could be released."""
    lib = libc()
    return bool(lib.malloc_trim(0)) if lib is not None else False


def release_memory() -> bool:
    """Drop the source text cached by :mod:`linecache`, then :func:`trim_heap`. Returns what ``trim_heap`` did."""
    linecache.clearcache()
    return trim_heap()


class IdleReleaser(QtCore.QObject):
    """Once the app has been idle for ``idle_ms`` after the last :meth:`poke` (or the end of a background job,
    :data:`~evpose.app.workers.JOB_EVENTS`): runs ``tasks()`` -- ``[(worker, fn)]``, each ``fn`` on its
    :class:`~evpose.app.workers.LatestWorker`'s thread between requests (``worker`` None: at once) -- then, when
    all have run, ``gc.collect(1)`` and :func:`release_memory`; ``late_trim_ms`` later, if nothing happened in
    between, :func:`trim_heap` once more. ``releases`` counts the completed releases."""

    def __init__(self, parent=None, idle_ms: int = IDLE_MS, tasks=None, busy_trim_s: float = BUSY_TRIM_S,
                 late_trim_ms: int = LATE_TRIM_MS):
        super().__init__(parent)
        self.releases = 0
        #: trims :data:`LATE_TRIM_MS` after a release with nothing in between
        self.late_trims = 0
        self.late_timer = QtCore.QTimer(self, singleShot=True, interval=int(late_trim_ms))
        self.late_timer.timeout.connect(self._late_trim)
        #: heap trims while busy (:meth:`poke`), and the time of the last trim of either kind (time.monotonic)
        self.busy_trims = 0
        self.busy_trim_s = float(busy_trim_s)
        self._last_trim = time.monotonic()
        self._tasks = tasks
        self._pending = 0
        self._connected: set[int] = set()
        #: what the last release's tasks returned (bytes dropped, by the tasks that return a number)
        self.last_released: list = []
        self.timer = QtCore.QTimer(self, singleShot=True, interval=int(idle_ms))
        self.timer.timeout.connect(self._release)
        JOB_EVENTS.ended.connect(self.poke)

    def poke(self) -> None:
        """Something happened: (re)start the quiet period; and when the last trim is :attr:`busy_trim_s` old, trim
        the heap now on a thread of its own (``malloc_trim`` runs without the GIL; the GUI thread waits only if it
        allocates from the arena being trimmed, a few ms at most)."""
        self.timer.start()
        self.late_timer.stop()
        now = time.monotonic()
        if now - self._last_trim >= self.busy_trim_s:
            self._last_trim = now
            threading.Thread(target=self._busy_trim, name="heap-trim", daemon=True).start()

    def _busy_trim(self) -> None:
        trim_heap()
        self.busy_trims += 1

    def _release(self) -> None:
        self.last_released = []
        posted = 0
        for worker, fn in (self._tasks() if self._tasks is not None else ()):
            if worker is None:
                self.last_released.append(fn())
                continue
            if id(worker) not in self._connected:
                worker.called.connect(self._task_done)
                self._connected.add(id(worker))
            worker.call_soon(_Task(self, fn))
            posted += 1
        self._pending += posted
        if self._pending == 0:
            self._give_back()

    def _task_done(self, result) -> None:
        if not (isinstance(result, tuple) and len(result) == 2 and result[0] is self) or self._pending == 0:
            return                                          # another caller's call_soon
        self.last_released.append(result[1])
        self._pending -= 1
        if self._pending == 0:
            self._give_back()

    def _give_back(self) -> None:
        gc.collect(1)
        release_memory()
        self._last_trim = time.monotonic()
        self.releases += 1
        self.late_timer.start()

    def _late_trim(self) -> None:
        trim_heap()
        self._last_trim = time.monotonic()
        self.late_trims += 1


class _Task:
    """``fn()`` on a worker's thread, its result tagged with the releaser (``LatestWorker.called`` is shared)."""

    def __init__(self, owner, fn):
        self.owner, self.fn = owner, fn

    def __call__(self):
        try:
            return self.owner, self.fn()
        except Exception:       # reported, and counted as done: a failed task must not stop the release
            traceback.print_exc()
            return self.owner, None
