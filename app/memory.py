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

:class:`IdleReleaser` does both once nothing has happened for :data:`IDLE_MS` (every session change restarts
the count), so the work never lands in the middle of scrubbing. Two things keep them from growing in the first place,
both done by ``evpose gui`` before the window exists (:func:`evpose.app.startup.prepare_process`, which imports no
Qt):

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

import linecache

from PySide6 import QtCore

from evpose.app.startup import libc

#: Quiet time after the last session change before memory is released, ms.
IDLE_MS = 2000


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
    """Calls :func:`release_memory` once the app has been idle for ``idle_ms`` after the last :meth:`poke`."""

    def __init__(self, parent=None, idle_ms: int = IDLE_MS):
        super().__init__(parent)
        self.releases = 0
        self.timer = QtCore.QTimer(self, singleShot=True, interval=int(idle_ms))
        self.timer.timeout.connect(self._release)

    def poke(self) -> None:
        """Something happened: (re)start the quiet period."""
        self.timer.start()

    def _release(self) -> None:
        release_memory()
        self.releases += 1
