"""Memory the app holds without using it, handed back to the system while the user is idle (tracker issue 14).

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
the count), so the work never lands in the middle of scrubbing.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import linecache

from PySide6 import QtCore

#: Quiet time after the last session change before memory is released, ms.
IDLE_MS = 2000

_LIBC = None


def _libc():
    """glibc, or None (another C library, or none found)."""
    global _LIBC
    if _LIBC is None:
        try:
            lib = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
            lib.malloc_trim.argtypes = [ctypes.c_size_t]
            lib.malloc_trim.restype = ctypes.c_int
            _LIBC = lib
        except (OSError, AttributeError):
            _LIBC = False
    return _LIBC or None


def trim_heap() -> bool:
    """``malloc_trim(0)``: give the free pages of every malloc arena back to the kernel. False when the C
    library has no ``malloc_trim`` (not glibc) or nothing could be released."""
    lib = _libc()
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
